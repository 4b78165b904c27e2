//! `brdfd bench`: speed of the estimation core, as medians of repeated runs, with the
//! machine's core count. Figures go in issue notes and docs/evaluation.md, never in timed tests.

use std::time::Instant;

use brdfd_bench::{embedded_materials, studio_envmap};
use brdfd_core::basis::Basis;
use brdfd_core::bivariate::{Bivariate, Grid};
use brdfd_core::envmap::{write_exr, DEFAULT_LIGHTS};
use brdfd_core::geometry::{Camera, PixelGeometry, Pose, Shape};
use brdfd_core::render::RenderingMatrix;
use brdfd_core::select::{self, Blocks, SwapParams};
use brdfd_core::stop::Stop;

#[derive(clap::Args)]
pub struct BenchArgs {
    /// Repetitions per measurement (the median is reported).
    #[arg(long, default_value_t = 5)]
    pub runs: usize,
    /// Skip the end-to-end estimate on a 4928 × 3264 photo (writes ~200 MB of temporary files).
    #[arg(long)]
    pub no_estimate: bool,
    /// Only the PTP/IP benchmark: a 25 MB capture-and-download from each simulated body
    /// (generic, Nikon D5100, THETA V, THETA Z1), with brdfd's client and with gphoto2.
    #[arg(long)]
    pub ptp: bool,
    /// Only the capture benchmark: `brdfd capture --simulate --material gold` as a process,
    /// phase by phase (from its session's manifest), and brdfd's own overhead: the wall time
    /// less the simulated devices' own (rendering, exposure delays).
    #[arg(long)]
    pub capture: bool,
    /// Image size of the simulated camera, with --capture.
    #[arg(long, default_value_t = 256)]
    pub size: usize,
    /// Only the RAW benchmark: decoding a 16 MP NEF (a D5100's sensor), and merging a
    /// bracket of five.
    #[arg(long)]
    pub raw: bool,
    /// Only the self-occlusion benchmark: which of 4,096 lights 50,000 pixels of a
    /// 100,000-triangle grooved part see past the part itself, and the rendering matrix on
    /// that part against the same on a sphere.
    #[arg(long)]
    pub occlusion: bool,
    /// Only the preview benchmark: `preview.png`'s render, a 512² sphere under 512 lights with
    /// its white sphere, for a sharp material, a mirror-like one and a broad one.
    #[arg(long)]
    pub preview: bool,
}

fn median_secs(runs: usize, mut f: impl FnMut()) -> f64 {
    let mut t: Vec<f64> = (0..runs.max(1))
        .map(|_| {
            let s = Instant::now();
            f();
            s.elapsed().as_secs_f64()
        })
        .collect();
    t.sort_by(f64::total_cmp);
    t[t.len() / 2]
}

fn sphere_pixels(count: usize) -> PixelGeometry {
    // A disc covers π/4 of the frame; the grazing cut trims a little more.
    let size = ((count as f64 / 0.76).sqrt().ceil() as usize).max(8);
    let mut g = PixelGeometry::rasterize(&Camera::eval_orthographic(size), &Shape::unit_sphere())
        .expect("sphere");
    g.pixels.truncate(count);
    g
}

pub fn run(a: BenchArgs) -> anyhow::Result<()> {
    let cores = std::thread::available_parallelism()
        .map(|n| n.get())
        .unwrap_or(1);
    println!("brdfd bench: {cores} cores, median of {} runs", a.runs);
    if a.ptp {
        return super::perf_ptp::run(a.runs);
    }
    if a.capture {
        return capture_bench(a.runs, a.size);
    }
    if a.raw {
        return raw_bench(a.runs);
    }
    if a.occlusion {
        return occlusion_bench(a.runs);
    }
    if a.preview {
        return preview_bench(a.runs);
    }
    let basis = Basis::embedded();
    let model = basis.model();
    let binning = basis.header.grid.theta_h_binning;
    let map = studio_envmap(1024);

    println!(
        "\nrendering matrix (K = {}, {} columns incl. mean):",
        basis.header.k,
        model.columns.len()
    );
    for (pixels, lights) in [
        (50_000, 4096),
        (25_000, 4096),
        (12_500, 4096),
        (50_000, 2048),
        (50_000, 8192),
    ] {
        let g = sphere_pixels(pixels);
        let l = map.compressed(lights, 0.0);
        let s = median_secs(a.runs, || {
            std::hint::black_box(RenderingMatrix::build(
                &g.pixels,
                &l,
                &model.columns,
                model.offset,
                binning,
            ));
        });
        println!(
            "  {:>6} pixels × {:>5} lights: {s:.3} s  ({:.1} ns per pixel-light pair)",
            g.pixels.len(),
            l.len(),
            s * 1e9 / (g.pixels.len() * l.len()) as f64
        );
    }

    println!("\nselection of 20 pixels from 100,000 candidates:");
    let g = sphere_pixels(100_000);
    let l = map.compressed(DEFAULT_LIGHTS, 0.0);
    let am = RenderingMatrix::build(&g.pixels, &l, &model.columns, model.offset, binning);
    let blocks_s = median_secs(a.runs, || {
        std::hint::black_box(Blocks::scaled(&am, &basis.column_scales()));
    });
    let blocks = Blocks::scaled(&am, &basis.column_scales());
    // The bench is a foreground command that Ctrl-C ends at once; nobody asks it to stop.
    let unstopped = Stop::default();
    let mut fast = None;
    let fast_s = median_secs(a.runs, || {
        fast = Some(select::fast_exchange(&blocks, 20, &unstopped).expect("nobody stops it"))
    });
    let fast = fast.expect("ran");
    println!("  per-pixel Gram blocks: {blocks_s:.3} s; fast exchange: {fast_s:.3} s, κ = {:.2} ({} κ evaluations)", fast.condition, fast.evaluations);
    let paper = select::paper_swap(&blocks, 20, &SwapParams::default(), &unstopped)?;
    println!(
        "  paper's swap search (8 restarts, ≤ {} κ per restart): {:.2} s, κ = {:.2} ({} κ evaluations); time ratio paper/fast {:.0}×, κ ratio paper/fast {:.3}",
        SwapParams::default().max_evaluations,
        paper.elapsed.as_secs_f64(),
        paper.condition,
        paper.evaluations,
        paper.elapsed.as_secs_f64() / fast_s,
        paper.condition / fast.condition
    );
    let mut random: Vec<f64> = (0..9)
        .map(|s| select::random_pixels(&blocks, 20, s).condition)
        .collect();
    random.sort_by(f64::total_cmp);
    println!("  random choice: median κ = {:.2}", random[4]);
    // Per-channel colour conditions three systems (one per channel) instead of one.
    let channels = Blocks::per_channel(&am, &basis.column_scales());
    let mut per_channel = None;
    let per_channel_s = median_secs(a.runs, || {
        per_channel =
            Some(select::fast_exchange(&channels, 20, &unstopped).expect("nobody stops it"))
    });
    let per_channel = per_channel.expect("ran");
    println!(
        "  per-channel colour (three systems): fast exchange {per_channel_s:.3} s, worst channel's κ = {:.2} ({} κ evaluations; the joint choice's worst channel: {:.2})",
        per_channel.condition,
        per_channel.evaluations,
        channels.condition(&fast.pixels)
    );

    println!(
        "\nbasis build from the {} embedded materials' bivariate reductions (PCA only):",
        embedded_materials().materials.len()
    );
    let set = embedded_materials();
    let reduce_s = median_secs(a.runs.min(3), || {
        for m in set.materials.values() {
            std::hint::black_box(Bivariate::reduce(m, Grid::default()));
        }
    });
    println!("  reduction of 10 NBRDF materials: {reduce_s:.2} s (× 10 for the 100-material build; `brdfd basis build` prints its own total)");

    preview_bench(a.runs)?;
    if !a.no_estimate {
        estimate_end_to_end(a.runs.min(3))?;
    }
    Ok(())
}

/// `preview.png`'s render, as the results write it: the estimate on a 512² sphere under the
/// capture's map compressed to 512 lights, with the white sphere that sets its scale. A
/// sharp material, a mirror-like one and a broad one: a lobe narrower than the lights'
/// spacing also reads the map itself in a cap about its peak ([`brdfd_core::sharp`]), at a
/// cost that grows with how much of the lobe is inside it; a broad lobe does not.
fn preview_bench(runs: usize) -> anyhow::Result<()> {
    use brdfd_core::render::SpherePicture;
    use brdfd_report::results::{PREVIEW_LIGHTS, PREVIEW_SIZE};
    println!(
        "
the preview ({PREVIEW_SIZE}² sphere, {PREVIEW_LIGHTS} lights, and its white sphere):"
    );
    let lights = studio_envmap(2048).compressed(PREVIEW_LIGHTS, 0.0);
    let set = embedded_materials();
    for name in ["gold-metallic-paint", "chrome-steel", "black-soft-plastic"] {
        let brdf = Bivariate::reduce(set.get(name)?, Grid::default());
        let mut failed = None;
        let s = median_secs(runs, || {
            if let Err(e) = SpherePicture::render(&brdf, &lights, PREVIEW_SIZE) {
                failed = Some(e);
            }
        });
        if let Some(e) = failed {
            return Err(e.into());
        }
        println!("  {name}: {s:.3} s");
    }
    Ok(())
}

/// `brdfd estimate` on a D5100-size photo (4928 × 3264, object on about a third of it) and a
/// 2048 × 1024 map, as a child process, so decoding and writing count.
fn estimate_end_to_end(runs: usize) -> anyhow::Result<()> {
    let dir = tempfile_dir()?;
    let (w, h) = (4928usize, 3264usize);
    // Orthographic extent so the unit sphere's disc covers a third of the frame.
    let radius_px = ((w * h) as f64 / 3.0 / std::f64::consts::PI).sqrt();
    let extent = w as f64 / radius_px;
    let camera = Camera::Orthographic {
        width: w,
        height: h,
        extent,
        pose: Pose {
            position: [0.0, 0.0, 10.0],
            look_at: [0.0; 3],
            up: [0.0, 1.0, 0.0],
        },
    };
    let geometry = brdfd_core::geometry::SceneGeometry {
        camera: camera.clone(),
        shape: Some(Shape::unit_sphere()),
        normal_map: None,
    };
    std::fs::write(dir.join("geometry.toml"), toml::to_string(&geometry)?)?;
    // The photo: a render at one eighth of the size, enlarged; content does not change timing.
    let small = brdfd_core::render::render_bivariate(
        &PixelGeometry::rasterize(&camera.resized(w / 8, h / 8), &Shape::unit_sphere())?,
        &studio_envmap(256).compressed(2048, 0.0),
        &Bivariate::reduce(
            embedded_materials().get("gold-metallic-paint")?,
            Grid::default(),
        ),
    );
    let big: Vec<[f32; 3]> = (0..w * h)
        .map(|i| {
            small.get(
                ((i % w) / 8).min(small.width - 1),
                ((i / w) / 8).min(small.height - 1),
            )
        })
        .collect();
    write_exr(&dir.join("photo.exr"), w, h, &big)?;
    let env = studio_envmap(2048);
    write_exr(&dir.join("env.exr"), env.width, env.height, &env.pixels)?;
    let exe = std::env::current_exe()?;
    let run = |extra: &[&str]| {
        median_secs(runs, || {
            let st = std::process::Command::new(&exe)
                .args([
                    "estimate",
                    "--photo",
                    "photo.exr",
                    "--env",
                    "env.exr",
                    "--geometry",
                    "geometry.toml",
                    "--out",
                    "est",
                ])
                .args(extra)
                .current_dir(&dir)
                .output()
                .expect("brdfd estimate runs");
            assert!(
                st.status.success(),
                "{}",
                String::from_utf8_lossy(&st.stderr)
            );
        })
    };
    // The default model, then the basis at 20 pixels (the paper's model) side by side.
    let s = run(&[]);
    let basis = run(&["--model", "basis", "--pixels", "20"]);
    println!(
        "\n`brdfd estimate` end to end, {w} × {h} photo (object ≈ ⅓), 2048 × 1024 map: {s:.2} s with the default (hybrid) model; {basis:.2} s with --model basis --pixels 20 (ratio {:.2})",
        s / basis
    );
    let _ = std::fs::remove_dir_all(&dir);
    Ok(())
}

fn tempfile_dir() -> anyhow::Result<std::path::PathBuf> {
    let dir = std::env::temp_dir().join(format!("brdfd-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    Ok(dir)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Runs the README's main command as a process `runs` times and reports the medians.
fn capture_bench(runs: usize, size: usize) -> anyhow::Result<()> {
    let exe = std::env::current_exe()?;
    let mut phases: Vec<(String, Vec<f64>, Vec<f64>)> = Vec::new();
    let (mut walls, mut own) = (Vec::new(), Vec::new());
    for _ in 0..runs.max(1) {
        let state = tempfile::tempdir()?;
        let t = Instant::now();
        let status = std::process::Command::new(&exe)
            .args([
                "capture",
                "--simulate",
                "--in-process",
                "--material",
                "gold",
            ])
            .arg("--size")
            .arg(size.to_string())
            .arg("--state-dir")
            .arg(state.path())
            .stdout(std::process::Stdio::null())
            .status()?;
        let wall = t.elapsed().as_secs_f64();
        anyhow::ensure!(status.success(), "brdfd capture failed: {status}");
        let manifest = brdfd_rig::session::Session::list(state.path())?
            .pop()
            .ok_or_else(|| anyhow::anyhow!("the capture left no session"))?;
        let mut device = 0.0;
        for p in manifest.phases {
            device += p.device_seconds;
            match phases.iter_mut().find(|(n, _, _)| *n == p.name) {
                Some((_, s, d)) => {
                    s.push(p.seconds);
                    d.push(p.device_seconds);
                }
                None => phases.push((p.name, vec![p.seconds], vec![p.device_seconds])),
            }
        }
        walls.push(wall);
        own.push(wall - device);
    }
    println!("\nsimulated capture of gold at {size}×{size} (process wall time, medians):");
    for (name, s, d) in phases {
        println!(
            "  {name:<52} {:>7.3} s  (devices {:.3} s)",
            median(s),
            median(d)
        );
    }
    println!("  {:<52} {:>7.3} s", "whole process", median(walls));
    println!(
        "  {:<52} {:>7.3} s  (target < 2 s)",
        "brdfd's own: whole process less the devices' time",
        median(own)
    );
    Ok(())
}

/// RAW decoding and merging at a D5100's full size: NEFs as the simulated camera writes them
/// (uncompressed 14-bit, 4992 × 3280 with a 4928 × 3264 crop) of a smooth scene with
/// highlights, one per exposure of the rig's default bracket.
fn raw_bench(runs: usize) -> anyhow::Result<()> {
    use brdfd_bench::camera::SENSOR_GAIN;
    use brdfd_bench::raw_file::{nef, ShotInfo, D5100};
    use brdfd_core::raster::Raster;
    use brdfd_radiometry::raw::{decode_raw, WhiteBalance};
    use brdfd_radiometry::{merge_hdr, Frame};

    let (w, h) = (4928, 3264);
    let mut scene = Raster::black(w, h);
    for (i, p) in scene.pixels.iter_mut().enumerate() {
        let (x, y) = ((i % w) as f32 / w as f32, (i / w) as f32 / h as f32);
        let v = 0.02 + 2.0 * (x * y).powi(3);
        *p = [v, 0.8 * v, 0.5 * v];
    }
    let shutters = [0.001, 0.004, 0.0166, 0.0666, 0.25];
    let files: Vec<Vec<u8>> = shutters
        .iter()
        .enumerate()
        .map(|(i, &t)| {
            let shot = ShotInfo {
                make: "NIKON CORPORATION",
                model: "NIKON D5100",
                shutter_s: t,
                f_number: 8.0,
                iso: 100,
            };
            let k = (t / 64.0 * SENSOR_GAIN) as f32;
            nef(&scene, k, &D5100, &shot, i as u64)
        })
        .collect();
    println!(
        "\nRAW: NEF of a D5100 (4992 × 3280 sensor, 14-bit uncompressed, {:.1} MB):",
        files[0].len() as f64 / 1e6
    );
    let decode = |bytes: &[u8]| {
        decode_raw(bytes, "bench.NEF", WhiteBalance::AsShot).expect("the simulated NEF decodes")
    };
    let one = median_secs(runs, || {
        std::hint::black_box(decode(&files[2]));
    });
    println!("  decode one (black and white level, crop, demosaic, clip marks): {one:.3} s");
    let frames: Vec<Frame> = files.iter().map(|f| decode(f)).collect();
    let merge = median_secs(runs, || {
        std::hint::black_box(merge_hdr(&frames, SENSOR_GAIN).expect("merges"));
    });
    let both = median_secs(runs.min(3), || {
        let frames: Vec<Frame> = files.iter().map(|f| decode(f)).collect();
        std::hint::black_box(merge_hdr(&frames, SENSOR_GAIN).expect("merges"));
    });
    println!("  merge of 5 decoded frames: {merge:.3} s; decode 5 and merge: {both:.3} s");
    Ok(())
}

/// The visibility of 4,096 studio lights from 50,000 pixels of a grooved plate of 100,352
/// triangles (eight V-grooves, walls at 62°), seen from 30° off its normal; the rendering
/// matrix and the whole estimate on those pixels against a sphere's.
fn occlusion_bench(runs: usize) -> anyhow::Result<()> {
    use brdfd_core::bvh::Bvh;
    use brdfd_core::mesh::grooved_plate;
    use brdfd_core::visibility::Occluder;
    use rayon::prelude::*;
    let mesh = grooved_plate(0.1, 0.1, 8, 0.006, 224, 224);
    let tilt = 30f64.to_radians();
    let camera = Camera::Orthographic {
        width: 300,
        height: 300,
        extent: 0.1,
        pose: Pose {
            position: [0.0, -tilt.sin(), tilt.cos()],
            look_at: [0.0; 3],
            up: [0.0, 1.0, 0.0],
        },
    };
    let mut g = PixelGeometry::of_mesh(&camera, &mesh)?;
    anyhow::ensure!(g.pixels.len() >= 50_000, "{} pixels", g.pixels.len());
    g.pixels.truncate(50_000);
    let lights = studio_envmap(1024).compressed(DEFAULT_LIGHTS, 0.0);
    let bvh = Bvh::build(&mesh);
    let occluder = g.pixels[0]
        .shadow
        .as_ref()
        .expect("a mesh pixel")
        .occluder
        .clone();
    let points = occluder.points()[..g.pixels.len()].to_vec();
    let up: usize = points
        .par_iter()
        .map(|p| {
            let n = p.normal;
            lights
                .directions
                .iter()
                // On the tangent plane counts as above, as the walk counts it.
                .filter(|d| n[0] * d[0] + n[1] * d[1] + n[2] * d[2] >= 0.0)
                .count()
        })
        .sum();
    let mut seen = 0;
    let visibility = median_secs(runs, || {
        // A new occluder each run: the old one keeps its answers.
        let fresh = Occluder::new(&bvh, points.clone());
        let table = fresh.table(&lights);
        seen = (0..points.len() as u32)
            .into_par_iter()
            .map(|id| {
                let row = table.row(&fresh, id);
                row.iter().map(|w| w.count_ones() as usize).sum::<usize>()
            })
            .sum();
    });
    let hidden = 1.0 - seen as f64 / up as f64;
    println!(
        "\nself-occlusion: {} pixels × {} lights, {}-triangle grooved plate:",
        points.len(),
        lights.len(),
        mesh.triangles.len()
    );
    println!(
        "  visibility: {visibility:.3} s ({:.1} ns per pixel-light pair); {:.1}% of the lights above the pixels' horizons are hidden by the part",
        visibility * 1e9 / (points.len() * lights.len()) as f64,
        100.0 * hidden
    );
    let basis = Basis::embedded();
    let model = basis.model();
    let binning = basis.header.grid.theta_h_binning;
    let build = |pixels: &[brdfd_core::geometry::GeomPixel]| {
        std::hint::black_box(RenderingMatrix::build(
            pixels,
            &lights,
            &model.columns,
            model.offset,
            binning,
        ));
    };
    // The first build works out the part's visibility; the timed ones reuse it, which leaves
    // the matrix's own loop.
    build(&g.pixels);
    let on_mesh = median_secs(runs, || build(&g.pixels));
    let sphere = sphere_pixels(g.pixels.len());
    let on_sphere = median_secs(runs, || build(&sphere.pixels));
    println!(
        "  rendering matrix ({} columns): {on_mesh:.3} s on the part (visibility known), {on_sphere:.3} s on a sphere of as many pixels: ratio {:.2}",
        model.columns.len() + 1,
        on_mesh / on_sphere
    );
    // The whole estimate, as `brdfd estimate` runs it (default model, candidates under 4,096
    // lights, chosen rows under 65,536), on the part and on the sphere: the part's time
    // includes casting its pixels and all of its visibility, worked out afresh each run.
    use brdfd_core::envmap::CHOSEN_LIGHTS;
    use brdfd_core::estimate::{estimate, EstimateOptions, View};
    let map = studio_envmap(1024);
    let (lights, chosen) = map.estimate_lights(DEFAULT_LIGHTS, CHOSEN_LIGHTS, 0.0);
    let gold = Bivariate::reduce(
        embedded_materials().get("gold-metallic-paint")?,
        basis.header.grid,
    );
    let part = || -> anyhow::Result<PixelGeometry> {
        let mut g = PixelGeometry::of_mesh(&camera, &mesh)?;
        g.pixels.truncate(50_000);
        Ok(g)
    };
    // The part's photo with the light its grooves throw on each other (two bounces).
    let seen = part()?;
    let mut photo_part = brdfd_core::render::render_bivariate(&seen, &lights, &gold);
    use brdfd_core::brdf::IsotropicBrdf;
    brdfd_core::bounce::add_to(
        &mut photo_part,
        &seen,
        &lights,
        brdfd_core::brdf::tangent_frame,
        |wi, wo| gold.eval_dirs(wi, wo),
    );
    let photo_sphere = brdfd_core::render::render_bivariate(&sphere, &lights, &gold);
    let run = |g: &PixelGeometry, photo, bounce: bool| {
        let view = View {
            geometry: g,
            lights: &lights,
            chosen_lights: chosen.as_ref(),
            photo,
        };
        let options = EstimateOptions {
            bounce,
            ..EstimateOptions::default()
        };
        std::hint::black_box(estimate(&basis, view, &options).expect("estimate"));
    };
    let part = || part().expect("the part");
    let est_part = median_secs(runs.min(3), || run(&part(), &photo_part, true));
    let est_direct = median_secs(runs.min(3), || run(&part(), &photo_part, false));
    let est_sphere = median_secs(runs.min(3), || run(&sphere, &photo_sphere, true));
    println!(
        "  estimate (default model): {est_part:.2} s on the part with its bounces, {est_direct:.2} s without (ratio {:.2}); {est_sphere:.2} s on the sphere: ratio {:.2} to the part's with its bounces",
        est_part / est_direct,
        est_part / est_sphere
    );
    Ok(())
}
