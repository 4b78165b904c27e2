//! brdfd's renderer against Mitsuba 3, an outside renderer (PyPI `mitsuba`): a sphere under
//! the embedded courtyard map, matte and as GGX mirrors from rough to nearly smooth, each
//! rendered by `scripts/mitsuba-reference.py` and by `brdfd render --gltf` of the same
//! material. The figure is the relative RMSE in linear light over the sphere's inside.
//!
//! And brdfd's own Mitsuba set (`scripts/mitsuba-scenes.py`): its geometry files against
//! Mitsuba's renders, and the flags of brdfd's estimates from its photos.
//!
//! It runs when `BRDFD_MITSUBA_PYTHON` names a Python with `mitsuba` installed; CI sets it and
//! `BRDFD_REQUIRE_MITSUBA=1`, so there it cannot skip.

mod common;

use std::path::Path;
use std::process::Command;

use brdfd_core::raster::Raster;

const SIZE: usize = 256;

fn python() -> Option<String> {
    match std::env::var("BRDFD_MITSUBA_PYTHON") {
        Ok(p) => Some(p),
        Err(_) => {
            assert!(
                std::env::var_os("BRDFD_REQUIRE_MITSUBA").is_none(),
                "BRDFD_REQUIRE_MITSUBA is set but BRDFD_MITSUBA_PYTHON is not"
            );
            eprintln!("skipped: set BRDFD_MITSUBA_PYTHON to a Python with mitsuba");
            None
        }
    }
}

/// The glTF material that is the case's BRDF: Lambert of albedo 0.5, or a metal whose base
/// colour 1 makes its Fresnel 1, so that only the GGX lobe remains.
fn gltf(case: &str) -> String {
    let (base, metallic, roughness, specular) = match case.strip_prefix("mirror-") {
        Some(alpha) => (1.0, 1.0, alpha.parse::<f64>().unwrap().sqrt(), 1.0),
        None => (0.5, 0.0, 1.0, 0.0),
    };
    serde_json::json!({
        "asset": { "version": "2.0" },
        "materials": [{
            "pbrMetallicRoughness": {
                "baseColorFactor": [base, base, base, 1.0],
                "metallicFactor": metallic,
                "roughnessFactor": roughness,
            },
            "extensions": { "KHR_materials_specular": { "specularFactor": specular } },
        }],
    })
    .to_string()
}

/// Relative RMSE of `ours` against `reference` over the sphere's inside (radius < 0.95: at
/// the silhouette a pixel is part sphere, part sky, differently in each renderer), and the
/// brightness of ours against it (a least-squares scale), which tells units from shape.
fn relative_rmse(ours: &Raster, reference: &Raster) -> (f64, f64) {
    let (mut diff, mut norm, mut product) = (0.0, 0.0, 0.0);
    for y in 0..SIZE {
        for x in 0..SIZE {
            let u = (x as f64 + 0.5) / SIZE as f64 * 2.0 - 1.0;
            let v = (y as f64 + 0.5) / SIZE as f64 * 2.0 - 1.0;
            if u * u + v * v >= 0.95 * 0.95 {
                continue;
            }
            let (a, b) = (ours.get(x, y), reference.get(x, y));
            for c in 0..3 {
                diff += (a[c] as f64 - b[c] as f64).powi(2);
                norm += (b[c] as f64).powi(2);
                product += a[c] as f64 * b[c] as f64;
            }
        }
    }
    ((diff / norm).sqrt(), product / norm)
}

#[test]
fn brdfd_renders_a_sphere_under_a_map_as_mitsuba_does() {
    let Some(python) = python() else { return };
    let dir = tempfile::tempdir().unwrap();
    let map = dir.path().join("courtyard.hdr");
    std::fs::write(
        &map,
        brdfd_report::export::maps::reference_map_file("courtyard").unwrap(),
    )
    .unwrap();
    // The limit each case is held to. Issue 38 asks for 0.05; the figures measured (256²,
    // 4,096 lights) are 0.039, 0.057, 0.042 and 0.042, of which Mitsuba's own sampling noise
    // is about 0.04 (two seeds against each other). The near mirror was 0.072 with the lights
    // alone; the cap (`brdfd_core::sharp`) reads the map itself there, and it is held to the
    // issue's figure. The others keep room for the reference's noise.
    let cases = [
        ("diffuse", 0.05),
        ("mirror-0.3", 0.07),
        ("mirror-0.1", 0.06),
        ("mirror-0.02", 0.05),
    ];
    script(&python, "mitsuba-reference.py", |c| {
        c.arg(&map)
            .arg(SIZE.to_string())
            .arg(dir.path())
            .args(cases.map(|(c, _)| c));
    });
    let mut failed = Vec::new();
    for (case, limit) in cases {
        std::fs::write(dir.path().join(format!("{case}.gltf")), gltf(case)).unwrap();
        let out = format!("ours-{case}.exr");
        // A quarter of the default light count: `render --gltf` evaluates the BRDF per light
        // and pixel, so this is 4 times faster (docs/evaluation.md's figures are at it too).
        let gltf = format!("{case}.gltf");
        let o = common::render_gltf(dir.path(), &gltf, "courtyard.hdr", SIZE, 4096, &out);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let ours = Raster::read(&dir.path().join(&out)).unwrap();
        let reference = Raster::read(&dir.path().join(format!("{case}.exr"))).unwrap();
        let (error, brightness) = relative_rmse(&ours, &reference);
        eprintln!(
            "{case}: brdfd against Mitsuba 3, relative RMSE {error:.4} (limit {limit}), \
             brightness {brightness:.3}"
        );
        if error > limit {
            failed.push(format!("{case}: {error:.4} > {limit}"));
        }
    }
    assert!(failed.is_empty(), "{failed:?}");
}

/// brdfd's own Mitsuba set (`scripts/mitsuba-scenes.py`), its photos at 32 samples a pixel
/// (the brushed dome's at 128).
///
/// Each scene's camera and part are written as a brdfd geometry file: brdfd must see the part
/// where Mitsuba drew it. The part's pixels in Mitsuba's region image and in `brdfd render` on
/// the geometry file agree to an IoU of 0.98 (the edges' pixels are part part, part
/// background, and each renderer decides them its own way).
///
/// A concave part lights itself: Mitsuba's path tracer draws the light the grooved part's
/// surface reflects into its grooves, and brdfd, which counts direct light only, flags the
/// estimate for interreflection; the same part rendered with direct light only is not
/// flagged (docs/evaluation.md, "brdfd's own Mitsuba set": 1.69 against 0.99 at 512
/// samples, flagged from 1.10). A dome of blue plastic with a gold stripe is flagged for
/// several materials (0.69, flagged from 0.25) and split into its two materials
/// ([`materials_are_found`]), and the plain dome for nothing, unless its map
/// is given turned 15° from where it was: then for misregistration, with the turn found. A dome of
/// aluminium brushed along one direction is flagged for anisotropy, with its grain and the
/// stretch of its highlights found ([`grain_is_found`]), and relights with its anisotropic
/// lobe ([`relights_with_its_lobe`]).
#[test]
fn the_mitsuba_set_lines_up_and_each_part_is_flagged_for_what_it_breaks() {
    let Some(python) = python() else { return };
    let (_dir, set) = mitsuba_set(&python, 32);
    for scene in ["groove-plastic", "two-tone"] {
        let d = set.join(scene);
        let o = common::brdfd(
            &[
                "render",
                "--material",
                "white-paint",
                "--geometry",
                "geometry.toml",
                "--env",
                "../../maps/courtyard.hdr",
                "--lights",
                "256",
                "--out",
                "ours.exr",
            ],
            &d,
        );
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let ours = Raster::read(&d.join("ours.exr")).unwrap();
        let regions = Raster::read(&d.join("regions.exr")).unwrap();
        assert_eq!((ours.width, ours.height), (regions.width, regions.height));
        let (mut both, mut either) = (0usize, 0usize);
        let mut second = 0usize;
        for (a, b) in ours.pixels.iter().zip(&regions.pixels) {
            let (in_ours, in_theirs) = (a.iter().any(|v| *v > 0.0), b[0] > 0.5);
            both += (in_ours && in_theirs) as usize;
            either += (in_ours || in_theirs) as usize;
            second += (b[0] > 1.5) as usize;
        }
        let iou = both as f64 / either as f64;
        eprintln!("{scene}: the part's pixels, brdfd against Mitsuba: IoU {iou:.4} over {either}");
        assert!(iou >= 0.98, "{scene}: IoU {iou:.4}");
        // The second region: the grooves, the stripe of the second material.
        assert!(
            second > 1000,
            "{scene}: {second} pixels in the second region"
        );
    }

    // The yaw the map is given with: the photos were taken at 0, so 15° is a panorama
    // whose north is set 15° off: measured 0.68 (flagged at 0.8), the turn back found at
    // −16.25°. At 10° this photo, at 32 samples, measured 0.77; at 512 samples 0.63.
    let cases = [
        // The grooves' bounced light taken out before the fit (the default): nothing to flag.
        // Left in (--no-bounce), it is flagged as interreflection; a photo without it is not.
        ("groove-plastic", "photo.exr", 0, true, None),
        (
            "groove-plastic",
            "photo.exr",
            0,
            false,
            Some("interreflection"),
        ),
        ("groove-plastic", "direct-photo.exr", 0, false, None),
        ("two-tone", "photo.exr", 0, true, Some("several_materials")),
        ("dome-plastic", "photo.exr", 0, true, None),
        (
            "dome-plastic",
            "photo.exr",
            15,
            true,
            Some("misregistration"),
        ),
        (
            "brushed-aluminium",
            "photo.exr",
            0,
            true,
            Some("anisotropy"),
        ),
    ];
    let mut relit_grooves = Vec::new();
    for (scene, photo, yaw, bounce, flag) in cases {
        let d = set.join(scene);
        let out = format!("estimate-{yaw}-{bounce}-{photo}");
        let mut args = vec![
            "estimate",
            "--photo",
            photo,
            "--env",
            "../../maps/courtyard.hdr",
            "--geometry",
            "geometry.toml",
            "-o",
            &out,
        ];
        let yaw_text = yaw.to_string();
        args.extend(["--yaw", &yaw_text]);
        if !bounce {
            args.push("--no-bounce");
        }
        let o = common::brdfd(&args, &d);
        let (stdout, stderr) = (
            String::from_utf8_lossy(&o.stdout),
            String::from_utf8_lossy(&o.stderr),
        );
        assert!(o.status.success(), "{stderr}");
        let json: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(d.join(&out).join("coefficients.json")).unwrap(),
        )
        .unwrap();
        let flags = json["flags"].as_array().unwrap();
        let figures: Vec<f64> = flags.iter().filter_map(|f| f["figure"].as_f64()).collect();
        eprintln!("{scene} {photo} yaw {yaw}: flags {figures:?}");
        let reasons: Vec<&str> = flags
            .iter()
            .map(|f| f["reason"].as_str().unwrap())
            .collect();
        assert_eq!(
            reasons,
            flag.into_iter().collect::<Vec<_>>(),
            "{scene} {photo}"
        );
        if scene == "brushed-aluminium" {
            grain_is_found(&d, &json["anisotropy"]);
            relights_with_its_lobe(&d, &out, &json);
        }
        if scene == "groove-plastic" && photo == "photo.exr" {
            relit_grooves.push((bounce, relit_against_truth(&d, &out, bounce)));
        }
        if flag == Some("misregistration") {
            // The map turned back by the yaw it was given too much, within two of the
            // refinement's steps (the plastic's one-lobe fit found 1.25° more at 512 samples).
            let turn = json["registration"]["turn_deg"].as_f64().unwrap();
            eprintln!("{scene} at yaw {yaw}: fits best turned {turn}°");
            assert!((turn + yaw as f64).abs() <= 2.5, "{}", json["registration"]);
        }
        // Only the two-material dome is split into materials.
        assert_eq!(
            json["materials"].is_object(),
            scene == "two-tone",
            "{scene} {photo}: {}",
            json["materials"]
        );
        if scene == "two-tone" {
            materials_are_found(&d, &out, &json, &format!("{stderr}{stdout}"));
            sessions_name_the_materials(&d.join(&out));
            continue;
        }
        if let Some(reason) = flag {
            let words = reason.replace('_', " ") + ":";
            assert!(stdout.contains(&words), "{stdout}");
            // A flagged estimate is never judged good, whatever its figures.
            assert!(
                !format!("{stdout}{stderr}").contains("good estimate"),
                "{stdout}"
            );
        }
    }
    // The grooved part relit under the held-out city map, as Mitsuba's path tracer lit it,
    // bounces and all: with its bounce taken out and rendered back, and without.
    let with = relit_grooves.iter().find(|r| r.0).unwrap().1;
    let without = relit_grooves.iter().find(|r| !r.0).unwrap().1;
    eprintln!("groove-plastic relit under city: {with:.4} with its bounces, {without:.4} without");
    // Measured 0.091 and 0.175 on these 32-sample photos and truths (0.087 with one
    // bounce); on the set at 512 samples, over four maps, 0.097 and 0.185 (docs/evaluation.md).
    assert!(with <= 0.1, "with its bounces: {with}");
    assert!(
        1.75 * with <= without,
        "with its bounces {with}, without {without}"
    );
}

/// A session whose result is the two-material dome's (`result`, a split estimate's folder) is
/// listed with its two materials and shown with each one's share, fit and folder, where it
/// was listed and shown as one estimate.
fn sessions_name_the_materials(result: &Path) {
    use brdfd_rig::session::{session_dir, Session, State};
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("state");
    let mut session =
        Session::create(&state, "two-tone", "simulated", None, serde_json::json!({})).unwrap();
    for next in [
        State::Capturing,
        State::Captured,
        State::Estimating,
        State::Done,
    ] {
        session.set_state(next, None).unwrap();
    }
    let id = session.manifest().id.clone();
    let copied = session_dir(&state, &id).join("result");
    std::fs::create_dir_all(&copied).unwrap();
    for entry in walk(result) {
        let to = copied.join(entry.strip_prefix(result).unwrap());
        std::fs::create_dir_all(to.parent().unwrap()).unwrap();
        std::fs::copy(&entry, to).unwrap();
    }
    let state = state.to_str().unwrap();
    let said = |args: &[&str]| {
        let o = common::brdfd(args, dir.path());
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        String::from_utf8_lossy(&o.stdout).into_owned()
    };
    let list = said(&["session", "list", "--state-dir", state]);
    assert!(list.contains("hybrid×2"), "{list}");
    let json: serde_json::Value =
        serde_json::from_str(&said(&["session", "list", "--json", "--state-dir", state])).unwrap();
    let parts = json[0]["materials"].as_array().unwrap();
    assert_eq!(parts.len(), 2, "{json}");
    let share: f64 = parts.iter().map(|p| p["share"].as_f64().unwrap()).sum();
    assert!((share - 1.0).abs() < 1e-6, "{json}");
    let shown = said(&["session", "show", &id, "--state-dir", state]);
    assert!(
        shown.contains("split into 2 materials, each estimated on its own pixels, which fit the photo together to 0."),
        "{shown}"
    );
    for folder in ["material-1", "material-2"] {
        assert!(
            shown.contains(&format!("its results in result/{folder}/")),
            "{shown}"
        );
    }
}

/// Every file under `dir`, at any depth.
fn walk(dir: &Path) -> Vec<std::path::PathBuf> {
    let mut files = Vec::new();
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            files.extend(walk(&path));
        } else {
            files.push(path);
        }
    }
    files
}

/// The two-material dome's split (issue 43, item 3): each of the truth's regions matches a
/// material of `materials-mask.png` with an IoU of 0.9 or more, the summary leads with the
/// two materials, and `brdfd render --coefficients` paints each material on its triangles:
/// under the photo's own light it re-renders the photo as closely as the materials together
/// fit it, where the one BRDF for the whole part missed it by 0.5.
fn materials_are_found(scene: &Path, estimate: &str, json: &serde_json::Value, said: &str) {
    // The summary's first line (on stderr when it warns): the split's verdict, as the
    // results keep it.
    assert!(said.contains(": 2 materials, "), "{said}");
    let headline = json["verdict_text"].as_str().unwrap();
    assert!(headline.starts_with("2 materials, "), "{json}");
    assert!(said.contains(&format!(": {headline}")), "{said}");
    let parts = json["materials"]["parts"].as_array().unwrap();
    assert_eq!(parts.len(), 2);
    let mask = image::open(scene.join(estimate).join("materials-mask.png"))
        .unwrap()
        .to_luma8();
    let regions = Raster::read(&scene.join("regions.exr")).unwrap();
    // Pixels wholly on one region (the edges mix the two, or the part and the background).
    let truth: Vec<(usize, u8)> = regions
        .pixels
        .iter()
        .enumerate()
        .filter(|(_, v)| v[0] > 0.5 && (v[0] - v[0].round()).abs() < 1e-3)
        .map(|(i, v)| (i, v[0].round() as u8))
        .collect();
    let found = |i: usize| mask.as_raw()[i];
    let iou = |region: u8, label: u8| {
        let both = truth
            .iter()
            .filter(|(i, r)| *r == region && found(*i) == label)
            .count();
        let either = truth
            .iter()
            .filter(|(i, r)| *r == region || found(*i) == label)
            .count();
        both as f64 / either as f64
    };
    let straight = [iou(1, 1), iou(2, 2)];
    let swapped = [iou(1, 2), iou(2, 1)];
    let best = if straight[0].min(straight[1]) >= swapped[0].min(swapped[1]) {
        straight
    } else {
        swapped
    };
    eprintln!("two-tone: materials against the truth's regions, IoU {best:?}");
    assert!(best.iter().all(|v| *v >= 0.9), "{best:?}");
    // Painted on the mesh by the materials' own estimates, under the photo's light.
    let coefficients = format!("{estimate}/coefficients.json");
    let painted = render_estimate(scene, &coefficients, "courtyard", true);
    let photo = Raster::read(&scene.join("photo.exr")).unwrap();
    let error = block_rmse(&painted, &photo, &regions);
    let whole = json["fit_error"].as_f64().unwrap();
    eprintln!("two-tone painted by its materials, against the photo: {error:.4} (one BRDF's fit {whole:.4})");
    // Measured 0.069 at 32 samples (on 4 × 4 blocks, which average the noise out), against
    // 0.57 for one BRDF.
    assert!(
        error <= 0.12 && error <= 0.25 * whole,
        "{error} against {whole}"
    );
}

/// The estimate `coefficients` (a `coefficients.json`, from `scene`) rendered by `brdfd render
/// --coefficients` on the scene's geometry under the map `map` (of the set's maps), with one
/// bounce or without.
fn render_estimate(scene: &Path, coefficients: &str, map: &str, bounce: bool) -> Raster {
    let env = format!("../../maps/{map}.hdr");
    let out = coefficients.replace(".json", &format!("-{map}-{bounce}.exr"));
    let mut args = vec![
        "render",
        "--coefficients",
        coefficients,
        "--geometry",
        "geometry.toml",
        "--env",
        &env,
        "--out",
        &out,
    ];
    if !bounce {
        args.push("--no-bounce");
    }
    let o = common::brdfd(&args, scene);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    Raster::read(&scene.join(&out)).unwrap()
}

/// The light a concave part throws on itself, as brdfd renders it and as Mitsuba's path tracer
/// does, with nothing of an estimate in it: the grooved part in a Lambertian paint (the set's
/// `groove-matte`), which glTF's BRDF with no specular is, under the embedded courtyard map.
/// In the grooves, the light that met the part once or twice (the photo less its direct
/// light) must agree within 5% per channel, which one bounce alone misses by about a quarter
/// (at 512 samples under grace, the second bounce was 0.0192 of Mitsuba's 0.0684 in red:
/// docs/evaluation.md). Measured here (32 samples, courtyard): +1.1%, +0.9% and +0.1%, and
/// the direct light −1.5%, −1.7% and −2.1%.
#[test]
fn the_grooves_bounce_light_as_mitsuba_s_path_tracer_does() {
    let Some(python) = python() else { return };
    let dir = tempfile::tempdir().unwrap();
    let maps = dir.path().join("maps");
    std::fs::create_dir(&maps).unwrap();
    std::fs::write(
        maps.join("courtyard.hdr"),
        brdfd_report::export::maps::reference_map_file("courtyard").unwrap(),
    )
    .unwrap();
    let set = dir.path().join("set");
    script(&python, "mitsuba-scenes.py", |c| {
        c.arg("render").args([&maps, &set]);
        c.args(["--spp", "32", "--photos-only", "groove-matte"]);
    });
    let d = set.join("groove-matte");
    let gltf = serde_json::json!({
        "asset": { "version": "2.0" },
        "materials": [{
            "pbrMetallicRoughness": {
                "baseColorFactor": [0.8, 0.6, 0.4, 1.0],
                "metallicFactor": 0.0,
                "roughnessFactor": 1.0,
            },
            "extensions": { "KHR_materials_specular": { "specularFactor": 0.0 } },
        }],
    });
    std::fs::write(d.join("matte.gltf"), gltf.to_string()).unwrap();
    let render = |out: &str, bounce: bool| {
        let mut args = vec![
            "render",
            "--gltf",
            "matte.gltf",
            "--geometry",
            "geometry.toml",
            "--env",
            "../../maps/courtyard.hdr",
            // A matte paint's light changes slowly over the map: 1,024 lights hold it, at
            // a seventh of the default's time.
            "--lights",
            "1024",
            "--out",
            out,
        ];
        if !bounce {
            args.push("--no-bounce");
        }
        let o = common::brdfd(&args, &d);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        Raster::read(&d.join(out)).unwrap()
    };
    let (ours, ours_direct) = (render("ours.exr", true), render("ours-direct.exr", false));
    let photo = Raster::read(&d.join("photo.exr")).unwrap();
    let direct = Raster::read(&d.join("direct-photo.exr")).unwrap();
    let regions = Raster::read(&d.join("regions.exr")).unwrap();
    // Sums over the grooves (region 2) of each image's red, green and blue.
    let grooves = |r: &Raster| {
        let mut sum = [0f64; 3];
        let mut count = 0;
        for (p, g) in r.pixels.iter().zip(&regions.pixels) {
            if (g[0] - 2.0).abs() < 1e-3 {
                count += 1;
                for c in 0..3 {
                    sum[c] += p[c] as f64;
                }
            }
        }
        assert!(count > 5000, "{count} pixels in the grooves");
        sum
    };
    let (a, b) = (grooves(&ours), grooves(&ours_direct));
    let (c, e) = (grooves(&photo), grooves(&direct));
    for k in 0..3 {
        let (bounced, theirs) = (a[k] - b[k], c[k] - e[k]);
        let direct_off = b[k] / e[k] - 1.0;
        eprintln!(
            "channel {k}: bounced light {bounced:.1} against Mitsuba's {theirs:.1} ({:+.1}%); direct light {:+.1}%",
            100.0 * (bounced / theirs - 1.0),
            100.0 * direct_off
        );
        assert!(
            (bounced / theirs - 1.0).abs() < 0.05,
            "channel {k}: the grooves' bounced light {bounced} against Mitsuba's {theirs}"
        );
        // The direct light must agree too, or the bounces are compared on a wrong footing.
        assert!(
            direct_off.abs() < 0.03,
            "channel {k}: direct light off by {direct_off}"
        );
    }
}

/// The estimate in `estimate` (a folder of `scene`) relit by `brdfd render` under the
/// embedded city map, with its bounces or without, against Mitsuba's truth there
/// ([`block_rmse`], as the set's score measures it).
fn relit_against_truth(scene: &Path, estimate: &str, bounce: bool) -> f64 {
    let ours = render_estimate(
        scene,
        &format!("{estimate}/coefficients.json"),
        "city",
        bounce,
    );
    let truth = Raster::read(&scene.join("truth-city.exr")).unwrap();
    let regions = Raster::read(&scene.join("regions.exr")).unwrap();
    block_rmse(&ours, &truth, &regions)
}

/// The brushed dome's grain, as `coefficients.json` records it, against the scene's truth:
/// within 5° on the dome's top (both laid on the surface there), and the lobe's stretch
/// (α across over α along) within 20% (issue 43's figures).
fn grain_is_found(scene: &Path, found: &serde_json::Value) {
    let truth: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(scene.join("scene.json")).unwrap()).unwrap();
    let vector = |v: &serde_json::Value| -> [f64; 3] {
        let a = v.as_array().expect("a vector");
        [0, 1, 2].map(|i| a[i].as_f64().unwrap())
    };
    let grain = &truth["grain"];
    let top = vector(&grain["world_normal_at_top"]);
    let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let laid = |g: [f64; 3]| {
        let n = dot(top, top).sqrt();
        let d = dot(g, top) / (n * n);
        let t = [0, 1, 2].map(|i| g[i] - d * top[i]);
        let len = dot(t, t).sqrt();
        t.map(|c| c / len)
    };
    let cos = dot(
        laid(vector(&grain["world_direction_at_top"])),
        laid(vector(&found["grain"])),
    );
    let off = cos.abs().min(1.0).acos().to_degrees();
    let stretch = |v: &serde_json::Value| {
        v["alpha_across"].as_f64().unwrap() / v["alpha_along"].as_f64().unwrap()
    };
    let (ours, theirs) = (stretch(found), stretch(grain));
    eprintln!("brushed-aluminium: grain {off:.1}° off, stretch {ours:.2} (truth {theirs:.2})");
    assert!(off <= 5.0, "the grain is {off:.1}° off: {found}");
    assert!(
        (ours / theirs - 1.0).abs() <= 0.2,
        "stretch {ours:.2}, truth {theirs:.2}"
    );
}

/// The brushed dome's estimate chose its anisotropic lobe, and relit with it by `brdfd render`
/// under the city map (which the photo was not taken under) it is close to Mitsuba's truth,
/// and much closer than the same estimate's isotropic model: the relative RMSE of 4 × 4
/// blocks wholly on the part, as `scripts/mitsuba-scenes.py score` measures it. At this
/// test's 128 samples a pixel the lobe relit at 0.068 and the isotropic model at 0.40
/// (measured); on the set at 512 samples, 0.033 under this map and 0.049 over the four held-out
/// maps, issue 43's figure (docs/evaluation.md).
fn relights_with_its_lobe(scene: &Path, estimate: &str, json: &serde_json::Value) {
    assert_eq!(json["anisotropy"]["chosen"], true, "{}", json["anisotropy"]);
    // The same estimate without its lobe: its isotropic (hybrid) model.
    let mut isotropic = json.clone();
    isotropic["anisotropy"]["chosen"] = false.into();
    std::fs::write(
        scene.join(estimate).join("isotropic.json"),
        isotropic.to_string(),
    )
    .unwrap();
    let truth = Raster::read(&scene.join("truth-city.exr")).unwrap();
    let regions = Raster::read(&scene.join("regions.exr")).unwrap();
    let relit = |coefficients: &str| {
        let ours = render_estimate(scene, &format!("{estimate}/{coefficients}"), "city", true);
        block_rmse(&ours, &truth, &regions)
    };
    let (lobe, model) = (relit("coefficients.json"), relit("isotropic.json"));
    eprintln!(
        "brushed-aluminium: relit under city {lobe:.4} from the truth with its lobe, {model:.4} with its isotropic model"
    );
    assert!(
        lobe <= 0.08,
        "relit {lobe:.4} from Mitsuba's truth under city"
    );
    assert!(
        lobe * 4.0 <= model,
        "lobe {lobe:.4}, isotropic model {model:.4}"
    );
}

/// The relative RMSE of `ours` against `truth` over the means of the 4 × 4 blocks whose every
/// pixel lies wholly on one region of the part (`regions`: 0 the background): the edges mix
/// part and background differently in each renderer.
fn block_rmse(ours: &Raster, truth: &Raster, regions: &Raster) -> f64 {
    const BLOCK: usize = 4;
    let on_part = |x: usize, y: usize| {
        let v = regions.get(x, y)[0];
        v > 0.5 && (v - v.round()).abs() < 1e-3
    };
    let (mut diff, mut norm, mut blocks) = (0.0f64, 0.0f64, 0);
    for by in 0..regions.height / BLOCK {
        for bx in 0..regions.width / BLOCK {
            let pixels = || {
                (0..BLOCK * BLOCK).map(move |k| (bx * BLOCK + k % BLOCK, by * BLOCK + k / BLOCK))
            };
            if !pixels().all(|(x, y)| on_part(x, y)) {
                continue;
            }
            blocks += 1;
            for c in 0..3 {
                let mean = |r: &Raster| {
                    pixels().map(|(x, y)| r.get(x, y)[c] as f64).sum::<f64>()
                        / (BLOCK * BLOCK) as f64
                };
                let (a, b) = (mean(ours), mean(truth));
                diff += (a - b).powi(2);
                norm += b * b;
            }
        }
    }
    assert!(blocks > 500, "{blocks} blocks on the part");
    (diff / norm).sqrt()
}

/// The photos (`--photos-only`) of the set's two-material dome and plain dome under the
/// embedded courtyard map, at `spp` samples a pixel, its grooved part's photos with its truth
/// under the embedded city map, and its brushed dome's at 4 × `spp`: the folder that holds
/// them, and the set.
fn mitsuba_set(python: &str, spp: u32) -> (tempfile::TempDir, std::path::PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let maps = dir.path().join("maps");
    std::fs::create_dir(&maps).unwrap();
    for name in ["courtyard", "city"] {
        std::fs::write(
            maps.join(format!("{name}.hdr")),
            brdfd_report::export::maps::reference_map_file(name).unwrap(),
        )
        .unwrap();
    }
    let set = dir.path().join("set");
    let render = |spp: u32, photos_only: bool, scenes: &[&str]| {
        script(python, "mitsuba-scenes.py", |c| {
            c.arg("render").args([&maps, &set]);
            c.args(["--spp", &spp.to_string()]);
            if photos_only {
                c.arg("--photos-only");
            }
            c.args(scenes);
        });
    };
    render(spp, true, &["two-tone", "dome-plastic"]);
    // The grooved part with its truth under city, to relight against.
    render(spp, false, &["groove-plastic"]);
    // The brushed dome's highlights are a path tracer's hardest: at 32 samples its photo's
    // noise (about 0.19 of a pixel, RMS) is as large as what the grain leaves unexplained,
    // and hides it (docs/evaluation.md). A merged bracket's noise is a tenth of that.
    render(4 * spp, false, &["brushed-aluminium"]);
    (dir, set)
}

/// Runs `scripts/NAME` with `python` and the arguments `args` gives it; it must succeed.
fn script(python: &str, name: &str, args: impl FnOnce(&mut Command)) {
    let mut c = Command::new(python);
    c.arg(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("scripts")
            .join(name),
    );
    args(&mut c);
    let o = c.output().unwrap();
    assert!(
        o.status.success(),
        "{name}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}
