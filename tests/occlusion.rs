//! Issue 22, item 2: a mesh hides part of the sky from its own concave places. Checked
//! against closed forms under a uniform sky, through every renderer.

mod common;

use brdfd_bench::studio_envmap;
use brdfd_core::basis::Basis;
use brdfd_core::bivariate::{Bivariate, Grid};
use brdfd_core::brdf::IsotropicBrdf;
use brdfd_core::envmap::LightSet;
use brdfd_core::geometry::{Camera, GeomPixel, PixelGeometry, Pose, SceneGeometry};
use brdfd_core::merl::MerlBrdf;
use brdfd_core::mesh::{bowl, grooved_plate, uv_sphere, Mesh};
use brdfd_core::raster::Raster;
use brdfd_core::render::{render_bivariate, render_full, render_merl, visible_fraction};

/// A white Lambertian surface: under a sky of radiance 1 it returns the cosine-weighted
/// fraction of the sky it sees.
struct White;

impl IsotropicBrdf for White {
    fn eval_angles(&self, _: f64, _: f64, _: f64) -> [f64; 3] {
        [std::f64::consts::FRAC_1_PI; 3]
    }
}

/// A uniform sky of radiance 1 from `n` even directions (a Fibonacci sphere).
fn uniform_sky(n: usize) -> LightSet {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let omega = 4.0 * std::f64::consts::PI / n as f64;
    LightSet {
        directions: (0..n)
            .map(|i| {
                let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
                let r = (1.0 - z * z).sqrt();
                let a = golden * i as f64;
                [r * a.cos(), r * a.sin(), z].map(|c| c as f32)
            })
            .collect(),
        radiance: vec![[1.0; 3]; n],
        solid_angle: vec![omega as f32; n],
        spread: vec![(omega / std::f64::consts::PI).sqrt() as f32; n],
        map: None,
    }
}

/// Looking straight down at the part from above, orthographically.
fn from_above(size: usize, extent: f64) -> Camera {
    Camera::Orthographic {
        width: size,
        height: size,
        extent,
        pose: Pose {
            position: [0.0, 0.0, 5.0],
            look_at: [0.0, 0.0, 0.0],
            up: [0.0, 1.0, 0.0],
        },
    }
}

/// The three renderers of a white surface, and the visible fraction.
fn renders(g: &PixelGeometry, sky: &LightSet) -> [(&'static str, Raster); 4] {
    let grid = Grid::default();
    [
        ("full", render_full(g, sky, &White)),
        ("merl", render_merl(g, sky, &MerlBrdf::tabulate(&White))),
        (
            "matrix",
            render_bivariate(g, sky, &Bivariate::reduce(&White, grid)),
        ),
        ("fraction", visible_fraction(g, sky)),
    ]
}

/// "full 0.0005, merl …": each renderer's worst error.
fn worst_by_renderer(images: &[(&str, Raster); 4], worst: [f64; 4]) -> String {
    images
        .iter()
        .zip(worst)
        .map(|((name, _), w)| format!("{name} {w:.4}"))
        .collect::<Vec<_>>()
        .join(", ")
}

fn at(img: &Raster, px: &GeomPixel) -> f64 {
    img.get(px.x as usize, px.y as usize)[0] as f64
}

/// The world point a pixel of [`from_above`] looks at, in X and Y.
fn ground(px: &GeomPixel, size: usize, extent: f64) -> (f64, f64) {
    let step = extent / size as f64;
    (
        (px.x as f64 + 0.5) * step - extent / 2.0,
        extent / 2.0 - (px.y as f64 + 0.5) * step,
    )
}

/// A long V-groove: a point on a wall sees the sky between its own wall's plane and the
/// opposite rim. For a groove long enough to be taken as infinite, the cosine-weighted
/// fraction of a view bounded in the cross-section by directions at angles φ₁ < φ₂ from the
/// normal is (sin φ₂ − sin φ₁)/2; here φ₂ = 90° (up its own wall) and sin φ₁ is the
/// direction to the opposite rim along the wall's up-slope tangent.
#[test]
fn a_v_groove_sees_the_sky_its_closed_form_gives() {
    // One groove 0.2 wide and 0.1 deep (walls at 45°) across a plate 0.4 × 4: twenty times
    // as long as it is wide, so the ends add well under 1% of sky at the middle.
    let (width, length, depth) = (0.4, 4.0, 0.1);
    let mesh: Mesh = grooved_plate(width, length, 1, depth, 96, 240);
    let (size, extent) = (96, 0.4);
    let mut g = PixelGeometry::of_mesh(&from_above(size, extent), &mesh).unwrap();
    // Only the band across the middle is checked: the rest would only cost time.
    g.pixels
        .retain(|px| ground(px, size, extent).1.abs() <= 0.05);
    let sky = uniform_sky(32_768);
    let images = renders(&g, &sky);
    let half = width / 4.0; // the groove's half width
    let slope = depth / half;
    let closed_form = |x: f64| {
        // The wall at x (left wall for x < 0; the right is its mirror), its point, its
        // up-slope tangent, and the direction to the opposite rim, in the (x, z) plane.
        let x = x.abs();
        let z = -depth * (1.0 - x / half);
        let norm = (1.0 + slope * slope).sqrt();
        let tangent = (1.0 / norm, slope / norm);
        let (rx, rz) = (-half - x, -z);
        let r = (rx * rx + rz * rz).sqrt();
        (1.0 - (rx * tangent.0 + rz * tangent.1) / r) / 2.0
    };
    let step = extent / size as f64;
    let mut worst = [0f64; 4];
    let mut walls = 0;
    for px in &g.pixels {
        let (x, y) = ground(px, size, extent);
        // On a wall, two pixels clear of the rims and the bottom, near the middle.
        if x.abs() < 2.0 * step || x.abs() > half - 2.0 * step || y.abs() > 0.05 {
            continue;
        }
        walls += 1;
        let expect = closed_form(x);
        for (k, (_, img)) in images.iter().enumerate() {
            worst[k] = worst[k].max((at(img, px) - expect).abs());
        }
    }
    // The flat top, away from the groove, sees the whole sky.
    let mut top = 1f64;
    for px in &g.pixels {
        let (x, _) = ground(px, size, extent);
        if x.abs() > half + 2.0 * step {
            top = top.min(at(&images[3].1, px));
        }
    }
    eprintln!(
        "V-groove, {walls} wall pixels: worst |error| against the closed form: {}; the flat top's least visible fraction {top:.5}",
        worst_by_renderer(&images, worst)
    );
    assert!(walls > 100, "{walls} wall pixels");
    // 32,768 lights: the boundary of the visible sky cuts through lights about 1.1° across.
    for ((name, _), w) in images.iter().zip(worst) {
        assert!(w < 0.003, "{name}: {w}");
    }
    assert!(top > 0.999, "{top}");
}

/// Every point inside a hemispherical bowl sees exactly half of its cosine-weighted sky: the
/// opening shows it what the missing half of the sphere would, and from any point of a
/// sphere's inside, a piece of the sphere's surface takes its area over 4πR² of the view.
#[test]
fn a_hemispherical_bowl_sees_half_its_sky_everywhere() {
    let mesh = bowl(0.1, 96, 192);
    let (size, extent) = (96, 0.22);
    let mut g = PixelGeometry::of_mesh(&from_above(size, extent), &mesh).unwrap();
    // Clear of the rim, where the walls stand up and the interpolated normal tilts most: the
    // pixels outside are not checked, so not rendered.
    g.pixels.retain(|px| {
        let (x, y) = ground(px, size, extent);
        x.hypot(y) <= 0.09
    });
    let sky = uniform_sky(32_768);
    let images = renders(&g, &sky);
    let mut worst = [0f64; 4];
    let inside = g.pixels.len();
    for px in &g.pixels {
        for (k, (_, img)) in images.iter().enumerate() {
            worst[k] = worst[k].max((at(img, px) - 0.5).abs());
        }
    }
    eprintln!(
        "bowl, {inside} pixels: worst |error| against ½: {}",
        worst_by_renderer(&images, worst)
    );
    assert!(inside > 3000, "{inside}");
    for ((name, _), w) in images.iter().zip(worst) {
        assert!(w < 0.003, "{name}: {w}");
    }
}

/// A convex mesh hides nothing from itself: its faceting must not shadow its own points.
#[test]
fn a_sphere_mesh_sees_its_whole_sky() {
    let mesh = uv_sphere([0.0; 3], 1.0, 64, 128);
    let g = PixelGeometry::of_mesh(&Camera::eval_orthographic(64), &mesh).unwrap();
    let fraction = visible_fraction(&g, &uniform_sky(8192));
    let least = g
        .pixels
        .iter()
        .map(|px| at(&fraction, px))
        .fold(1f64, f64::min);
    eprintln!("sphere mesh: least visible fraction {least:.5}");
    assert!(least > 0.999, "{least}");
}

/// The shipped concave part (a block with three 90° V-grooves, leaning back 25°) seen by the
/// shipped D5100 geometry at an eighth of its size.
fn grooved_block() -> SceneGeometry {
    let file = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("config/geometry/grooved-block-d5100.toml");
    let mut scene = SceneGeometry::read(&file).unwrap();
    scene.camera = scene.camera.resized(616, 408);
    scene
}

/// Items 2 and 5: three turntable views of the grooved block, each the mesh turned about
/// the turntable's axis (in the object's frame, the camera and the map turned back).
/// Photos rendered by the model itself, with the part hiding its own light, must give back
/// the coefficients when the estimate knows what the part hides, and not when it does not.
#[test]
fn turned_views_of_a_concave_part_recover_the_material_only_with_occlusion() {
    use brdfd_core::estimate::{estimate_views, BasisOptions, EstimateOptions, ModelOptions, View};
    use brdfd_core::solve::ColourChoice;
    let basis = Basis::embedded();
    let c_true: Vec<f64> = basis
        .column_prior()
        .iter()
        .map(|p| p.map_or(1.0, |s| 0.1 * s))
        .collect();
    let in_span = basis.reconstruct(&c_true);
    let scene = grooved_block();
    let map = studio_envmap(256);
    let views: Vec<(PixelGeometry, LightSet, LightSet, Raster)> = [0.0f64, 30.0, -30.0]
        .iter()
        .map(|deg| {
            let theta = deg.to_radians();
            let mut turned = scene.clone();
            turned.camera = scene.camera.turned_about_y(-theta);
            let (w, h) = turned.camera.size();
            let g = turned.pixels(w, h).unwrap();
            let mut levels = map.compressed_levels(&[1024, 8192], -theta);
            let (fine, coarse) = (levels.pop().unwrap(), levels.pop().unwrap());
            let photo = render_bivariate(&g, &fine, &in_span);
            (g, coarse, fine, photo)
        })
        .collect();
    let hidden: Vec<f64> = views
        .iter()
        .map(|(g, _, fine, _)| {
            let f = visible_fraction(g, fine);
            g.pixels.iter().map(|px| 1.0 - at(&f, px)).sum::<f64>() / g.pixels.len() as f64
        })
        .collect();
    // The photos hold direct light only: nothing bounced to take out.
    let options = EstimateOptions {
        model: ModelOptions::Basis(BasisOptions {
            colour: ColourChoice::Joint,
            ..BasisOptions::default()
        }),
        bounce: false,
        ..EstimateOptions::default()
    };
    let error = |occlusion: bool| {
        let geometries: Vec<PixelGeometry> = views
            .iter()
            .map(|(g, ..)| {
                if occlusion {
                    g.clone()
                } else {
                    g.without_occlusion()
                }
            })
            .collect();
        let v: Vec<View> = views
            .iter()
            .zip(&geometries)
            .map(|((_, lights, fine, photo), geometry)| View {
                geometry,
                lights,
                chosen_lights: Some(fine),
                photo,
            })
            .collect();
        let est = estimate_views(&basis, &v, &options).unwrap();
        let c = &est.solution.coefficients;
        let d: f64 = c.iter().zip(&c_true).map(|(a, b)| (a - b).powi(2)).sum();
        (d / c_true.iter().map(|b| b * b).sum::<f64>()).sqrt()
    };
    let (on, off) = (error(true), error(false));
    eprintln!(
        "grooved block, 3 views of {:?} pixels (light hidden by the part: {:.1}% {:.1}% {:.1}% of each view's, cosine-weighted): coefficient error {on:.1e} with occlusion, {off:.1e} without",
        views.iter().map(|v| v.0.pixels.len()).collect::<Vec<_>>(),
        100.0 * hidden[0],
        100.0 * hidden[1],
        100.0 * hidden[2]
    );
    assert!(hidden.iter().all(|h| *h > 0.05), "{hidden:?}");
    assert!(on < 1e-3, "with occlusion: {on}");
    assert!(off > 10.0 * on, "without occlusion: {off}, with: {on}");
}

/// A measured material (gold paint) on the grooved block, rendered by the virtual bench with
/// the part hiding its own light, estimated with and without knowing what it hides, and
/// relit on a sphere under the held-out light.
#[test]
fn the_relight_error_on_a_concave_part_with_and_without_occlusion() {
    use brdfd_bench::VirtualBench;
    use brdfd_core::envmap::{CHOSEN_LIGHTS, DEFAULT_LIGHTS};
    use brdfd_core::estimate::{estimate, EstimateOptions, View};
    let mut bench = VirtualBench::embedded("gold", 128).unwrap();
    bench.geometry = grooved_block();
    let g = bench.pixels().unwrap();
    let photo = bench.photo().unwrap();
    let (lights, chosen) = bench
        .env
        .estimate_lights(DEFAULT_LIGHTS, CHOSEN_LIGHTS, bench.yaw);
    let relit = |geometry: &PixelGeometry, photo: &Raster| {
        let view = View {
            geometry,
            lights: &lights,
            chosen_lights: chosen.as_ref(),
            photo,
        };
        let est = estimate(&Basis::embedded(), view, &EstimateOptions::default()).unwrap();
        bench.relight_error(&est.brdf).unwrap()
    };
    let open = g.without_occlusion();
    let (on, off) = (relit(&g, &photo), relit(&open, &photo));
    // What the part's few flat faces allow at best: the same part, were it to hide nothing,
    // rendered and estimated so.
    let photo_open = render_merl(
        &open,
        &bench.env.compressed(brdfd_bench::PHOTO_LIGHTS, bench.yaw),
        &bench.material,
    );
    let floor = relit(&open, &photo_open);
    eprintln!(
        "gold on the grooved block ({} pixels), default model: relight error {on:.3} with occlusion, {off:.3} without; {floor:.3} for a part that hid nothing",
        g.pixels.len()
    );
    assert!(2.0 * on < off, "with {on}, without {off}");
    // Knowing what the part hides leaves it as well estimated as if it hid nothing.
    assert!(
        on < floor * 1.1 + 0.01,
        "with occlusion {on}, the open part's {floor}"
    );
}

/// Item 3: the simulated capture works on a mesh. The shipped rig with the grooved block
/// captures gold, estimates it, and its results show what the part hides from itself.
#[test]
fn a_simulated_capture_of_the_grooved_block_shows_what_it_hides() {
    use std::path::Path;
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = std::env::temp_dir().join(format!("brdfd-occlusion-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let rig = root.join("config/rigs/simulated-grooved-block.toml");
    let said = common::succeeds(
        &[
            "capture",
            "--rig",
            rig.to_str().unwrap(),
            "--material",
            "gold",
            "--size",
            "160",
            "--state-dir",
            "state",
        ],
        &dir,
    );
    let sessions: Vec<_> = std::fs::read_dir(dir.join("state/sessions"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    assert_eq!(sessions.len(), 1);
    let result = sessions[0].join("result");
    let picture = image::open(result.join("visibility.png"))
        .unwrap()
        .to_luma8();
    // Some pixels see all their light (the block's top), the grooves' walls less.
    let levels: Vec<u8> = picture
        .pixels()
        .map(|p| p.0[0])
        .filter(|v| *v > 0)
        .collect();
    let (least, most) = (levels.iter().min().unwrap(), levels.iter().max().unwrap());
    assert!(*most >= 250 && *least < 200, "{least}..{most}");
    let html = std::fs::read_to_string(result.join("report.html")).unwrap();
    let mean: f64 = html
        .split("On average ")
        .nth(1)
        .and_then(|s| s.split('%').next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no visible fraction in the report"));
    eprintln!(
        "grooved block, simulated capture at 160²: relit error {}; visible fraction on average {mean}%, {least}..{most} of 255",
        common::relit(&said)
    );
    assert!((50.0..99.0).contains(&mean), "{mean}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// The `gold-part` preset puts gold on the shipped grooved block on the simulated rig: the
/// capture says so, and the result shows what the part hides.
#[test]
fn the_gold_part_preset_captures_gold_on_the_grooved_block() {
    let dir = std::env::temp_dir().join(format!("brdfd-gold-part-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let said = common::succeeds(
        &[
            "capture",
            "--simulate",
            "--material",
            "gold-part",
            "--size",
            "160",
            "--state-dir",
            "state",
        ],
        &dir,
    );
    assert!(
        said.contains("on the mesh builtin:grooved-block.obj"),
        "{said}"
    );
    let sessions: Vec<_> = std::fs::read_dir(dir.join("state/sessions"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    assert!(sessions[0].join("result/visibility.png").exists());
    // The session records the object it was shot on, for a resume to estimate on it.
    let manifest = std::fs::read_to_string(sessions[0].join("manifest.json")).unwrap();
    assert!(manifest.contains("builtin:grooved-block.obj"), "{manifest}");
    let relit = common::relit(&said);
    eprintln!("gold-part on the simulated rig at 160²: relit error {relit}");
    assert!(relit < 0.3, "{said}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Shadow rays start just off the surface: on the shipped corrugated sample (3,000 long thin
/// triangles, curved across their short side, whose interpolated normals tilt up to several
/// degrees from their faces) within a fifth of a millimetre of it, where its valleys are
/// 12 mm deep.
#[test]
fn shadow_rays_start_just_off_the_surface() {
    use brdfd_core::bvh::Bvh;
    use brdfd_core::mesh::Placement;
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("config/geometry");
    let mut scene = SceneGeometry::read(&dir.join("corrugated-mesh-d5100.toml")).unwrap();
    scene.camera = scene.camera.resized(616, 408);
    let g = scene.pixels(616, 408).unwrap();
    let Some(brdfd_core::geometry::Shape::Mesh {
        file,
        units,
        rotation_deg,
        position,
    }) = &scene.shape
    else {
        panic!("not a mesh");
    };
    let placement = Placement {
        units: *units,
        rotation_deg: *rotation_deg,
        position: *position,
    };
    let mesh = Mesh::read(file, &placement).unwrap();
    let bvh = Bvh::build(&mesh);
    let occluder = &g.pixels[0].shadow.as_ref().unwrap().occluder;
    let lifts: Vec<f64> = occluder
        .points()
        .iter()
        .filter_map(|p| {
            let o = p.origin.map(|c| c as f64);
            let down = p.normal.map(|c| -c as f64);
            bvh.closest(o, down, 0.0, 1.0).map(|h| h.t)
        })
        .collect();
    let worst = lifts.iter().copied().fold(0.0, f64::max);
    eprintln!(
        "corrugated mesh: {} of {} ray origins above the surface, the highest {:.4} mm",
        lifts.len(),
        occluder.points().len(),
        worst * 1e3
    );
    assert!(lifts.len() * 100 > occluder.points().len() * 99);
    assert!(worst < 2e-4, "{worst} m");
}
