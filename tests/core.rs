//! Library-level checks of the estimation core, with synthetic ground truth and stated
//! tolerances. Only the solver comparison reads the shared data folder (for grace).

use brdfd_bench::{embedded_materials, studio_envmap};
use brdfd_core::basis::Basis;
use brdfd_core::bivariate::{Bivariate, Grid};
use brdfd_core::brdf::{dot, normalize, IsotropicBrdf, Vec3};
use brdfd_core::envmap::{EnvMap, LightSet};
use brdfd_core::estimate::{
    estimate, BasisOptions, BasisOutcome, Estimate, EstimateOptions, Model, ModelOptions, Outcome,
    SelectionMethod, View,
};
use brdfd_core::geometry::{Camera, GeomPixel, PixelGeometry, Shape};
use brdfd_core::merl::MerlBrdf;
use brdfd_core::raster::Raster;
use brdfd_core::render::{render_bivariate, render_full, render_merl, RenderingMatrix};
use brdfd_core::select::{self, Blocks, SwapParams};
use brdfd_core::solve::{Colour, ColourChoice, Solver};
use brdfd_core::stop::Stop;
use brdfd_eval::paper::brdf_error;

/// The basis model's own outcome of an estimate that must be one.
fn of_basis(e: &Estimate) -> &BasisOutcome {
    e.outcome.basis().expect("a basis estimate")
}

/// The embedded basis's rendering matrix for a sphere under the studio map.
fn studio_matrix(basis: &Basis, size: usize) -> RenderingMatrix {
    let g = sphere(size);
    basis.rendering_matrix(&g.pixels, &studio_envmap(256).compressed(2048, 0.0))
}

/// The reference data, which CI provides next to the repository.
fn shared_data() -> Option<std::path::PathBuf> {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data");
    if dir.is_dir() {
        Some(dir)
    } else {
        eprintln!("SKIPPED: ../shared/data is missing (CI has it)");
        None
    }
}

/// Gold's projection onto the basis: coefficients whose BRDF the basis holds exactly.
fn in_span_gold(basis: &Basis) -> Vec<f64> {
    let truth = Bivariate::reduce(
        embedded_materials().get("gold-metallic-paint").unwrap(),
        basis.header.grid,
    );
    basis.project(&truth)
}

/// In-span coefficients whose BRDF is ≥ 0 in every cell (gold's projection is not): the
/// training set's mean shape, nudged by a tenth of a spread along every component.
fn in_span_nonnegative(basis: &Basis) -> Vec<f64> {
    nudged_mean(basis, 0.1)
}

/// The training set's mean shape plus `nudge` spreads along every component; checked ≥ 0.
fn nudged_mean(basis: &Basis, nudge: f64) -> Vec<f64> {
    let c: Vec<f64> = basis
        .column_prior()
        .iter()
        .map(|p| p.map_or(1.0, |s| nudge * s))
        .collect();
    let brdf = basis.reconstruct(&c);
    let lowest = brdf.values.iter().copied().fold(f64::INFINITY, f64::min);
    assert!(
        lowest >= 0.0,
        "the test's coefficients go negative: {lowest}"
    );
    c
}

/// [`in_span_nonnegative`] and its render on a 48² sphere under the studio map.
fn in_span_photo(basis: &Basis) -> (Vec<f64>, PixelGeometry, LightSet, Raster) {
    let c_true = in_span_nonnegative(basis);
    let g = sphere(48);
    let lights = studio_envmap(256).compressed(2048, 0.0);
    let photo = render_bivariate(&g, &lights, &basis.reconstruct(&c_true));
    (c_true, g, lights, photo)
}

/// One view whose chosen pixels keep their candidate rows (no finer lights).
fn one_view<'a>(g: &'a PixelGeometry, lights: &'a LightSet, photo: &'a Raster) -> View<'a> {
    View {
        geometry: g,
        lights,
        chosen_lights: None,
        photo,
    }
}

fn sphere(size: usize) -> PixelGeometry {
    PixelGeometry::rasterize(&Camera::eval_orthographic(size), &Shape::unit_sphere()).unwrap()
}

#[test]
fn merl_round_trip_through_file() {
    let gold = MerlBrdf::tabulate(embedded_materials().get("gold-metallic-paint").unwrap());
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("gold.binary");
    gold.write(&path).unwrap();
    assert_eq!(
        std::fs::metadata(&path).unwrap().len() as usize,
        brdfd_core::merl::FILE_BYTES
    );
    let back = MerlBrdf::read(&path).unwrap();
    // Stored = value / scale, read = stored × scale: at most one rounding each way.
    for (ih, jd, kp) in [(0, 0, 0), (3, 40, 90), (89, 89, 179), (45, 10, 5)] {
        for c in 0..3 {
            let (a, b) = (gold.cell(c, ih, jd, kp), back.cell(c, ih, jd, kp));
            assert!((a - b).abs() <= 1e-14 * a.abs().max(1.0), "{a} {b}");
        }
    }
    assert_eq!(back.to_bytes(), gold.to_bytes());
}

#[test]
fn truncated_merl_file_names_the_file_and_size() {
    let dir = tempfile::tempdir().unwrap();
    let full = MerlBrdf::from_cells(|_, _, _| [0.1, 0.2, 0.3]).to_bytes();
    let path = dir.path().join("cut.binary");
    std::fs::write(&path, &full[..full.len() / 2]).unwrap();
    let e = MerlBrdf::read(&path).err().unwrap().to_string();
    assert!(
        e.contains("cut.binary")
            && e.contains("truncated")
            && e.contains(&(full.len() / 2).to_string()),
        "{e}"
    );
}

/// ‖a − b‖ / ‖b‖.
fn relative_error(a: &[f64], b: &[f64]) -> f64 {
    let d: f64 = a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum();
    let n: f64 = b.iter().map(|v| v * v).sum();
    (d / n).sqrt()
}

/// A solve kept non-negative gives back in-span coefficients whose BRDF is non-negative, as
/// the unconstrained solve does; where the unconstrained answer goes negative (gold's
/// projection, from 20 pixels), it keeps every cell ≥ 0, and no feasible step from its answer
/// fits the pixels better (it is the constrained optimum, not a clamp).
#[test]
fn the_nonnegative_solve_keeps_every_cell_and_is_optimal() {
    use rand::{Rng, SeedableRng};
    let basis = Basis::embedded();
    let model = basis.model();
    let prior = basis.column_prior();
    let a = studio_matrix(&basis, 64);
    let observe = |c: &[f64]| -> Vec<[f64; 3]> {
        a.predict(c).chunks(3).map(|c| [c[0], c[1], c[2]]).collect()
    };
    let blocks = Blocks::scaled(&a, &basis.column_scales());
    let sel = select::fast_exchange(&blocks, 20, &Stop::default()).unwrap();
    let c_true = in_span_nonnegative(&basis);
    for solver in [Solver::LeastSquares, Solver::Prior] {
        let sol = solver
            .solve(&a, &sel.pixels, &observe(&c_true), &prior, Some(&model))
            .unwrap();
        let err = relative_error(&sol.coefficients, &c_true);
        assert!(err < 1e-6, "{solver:?}: relative coefficient error {err}");
    }
    // Gold's projection goes negative in some cells; solved from its own render.
    let y = observe(&in_span_gold(&basis));
    let negative = |c: &[f64]| {
        basis
            .reconstruct(c)
            .values
            .iter()
            .filter(|v| **v < 0.0)
            .count()
    };
    let free = Solver::LeastSquares
        .solve(&a, &sel.pixels, &y, &prior, None)
        .unwrap();
    assert!(
        negative(&free.coefficients) > 0,
        "the test needs negative cells"
    );
    let kept = Solver::LeastSquares
        .solve(&a, &sel.pixels, &y, &prior, Some(&model))
        .unwrap();
    assert_eq!(negative(&kept.coefficients), 0);
    let misfit = |c: &[f64]| -> f64 {
        let p = a.predict(c);
        sel.pixels
            .iter()
            .flat_map(|&i| (0..3).map(move |ch| (i, ch)))
            .map(|(i, ch)| (p[3 * i + ch] - y[i][ch]).powi(2))
            .sum()
    };
    let best = misfit(&kept.coefficients);
    assert!(best >= misfit(&free.coefficients) * (1.0 - 1e-9));
    let mut rng = rand::rngs::StdRng::seed_from_u64(5);
    let scale: f64 = kept.coefficients.iter().map(|v| v * v).sum::<f64>().sqrt();
    let mut tried = 0;
    for _ in 0..2_000 {
        let step: Vec<f64> = (0..kept.coefficients.len())
            .map(|_| rng.random_range(-1.0..1.0) * 1e-3 * scale)
            .collect();
        let c: Vec<f64> = kept
            .coefficients
            .iter()
            .zip(&step)
            .map(|(a, b)| a + b)
            .collect();
        if negative(&c) == 0 {
            tried += 1;
            assert!(
                misfit(&c) >= best * (1.0 - 1e-9),
                "a feasible step fits better"
            );
        }
    }
    assert!(tried > 0, "no feasible step was tried");
}

/// Observations made by the model itself (y = A·c) must give back c: the only error is
/// floating point, so 1e-6 relative is generous.
#[test]
fn coefficients_inside_the_span_are_recovered() {
    let basis = Basis::embedded();
    let c_true = in_span_gold(&basis);
    let a = studio_matrix(&basis, 64);
    let y: Vec<[f64; 3]> = a
        .predict(&c_true)
        .chunks(3)
        .map(|c| [c[0], c[1], c[2]])
        .collect();
    let blocks = Blocks::scaled(&a, &basis.column_scales());
    for sel in [
        select::fast_exchange(&blocks, 20, &Stop::default()).unwrap(),
        select::paper_swap(
            &blocks,
            20,
            &SwapParams {
                restarts: 2,
                seed: 3,
                max_evaluations: 20_000,
            },
            &Stop::default(),
        )
        .unwrap(),
        select::all_pixels(&blocks),
    ] {
        for solver in [Solver::LeastSquares, Solver::Prior] {
            let sol = solver
                .solve(&a, &sel.pixels, &y, &basis.column_prior(), None)
                .unwrap();
            let err = relative_error(&sol.coefficients, &c_true);
            assert!(
                err < 1e-6,
                "{solver:?}: relative coefficient error {err} with {} pixels",
                sel.pixels.len()
            );
        }
    }
}

/// Colour the joint basis cannot hold: each channel a different in-span material (R gold, G
/// nickel, B blue-fabric). Per-channel coefficients recover all three sets from 20 pixels and
/// from all; the joint model, one set for every channel, cannot fit the photo.
#[test]
fn per_channel_colour_recovers_what_the_joint_basis_cannot() {
    use brdfd_core::basis::channel_coefficients;
    use brdfd_core::solve::Colour;
    let basis = Basis::embedded();
    // A different in-span shape and scale per channel, each ≥ 0 in every cell: a colour the
    // joint basis's RGB patterns cannot mix.
    let truth: Vec<f64> = [(0.1, 1.0), (-0.05, 0.6), (0.0, 0.3)]
        .iter()
        .flat_map(|(nudge, scale)| {
            nudged_mean(&basis, *nudge)
                .into_iter()
                .map(move |c| c * scale)
        })
        .collect();
    let m = basis.model().columns.len();
    let brdf = basis.reconstruct_channels(channel_coefficients(&truth, m).unwrap());
    let g = sphere(48);
    let lights = studio_envmap(256).compressed(2048, 0.0);
    let photo = render_bivariate(&g, &lights, &brdf);
    for pixels in [Some(20), None] {
        let run = |colour| {
            let opts = EstimateOptions {
                model: ModelOptions::Basis(BasisOptions {
                    pixel_count: pixels,
                    solver: Solver::LeastSquares,
                    colour,
                    ..BasisOptions::default()
                }),
                ..Default::default()
            };
            estimate(&basis, one_view(&g, &lights, &photo), &opts).unwrap()
        };
        let per_channel = run(ColourChoice::PerChannel);
        assert_eq!(per_channel.names.len(), 3 * m);
        assert_eq!(per_channel.names[m], "mean.G");
        let err = relative_error(&per_channel.solution.coefficients, &truth);
        let joint = run(ColourChoice::Joint);
        eprintln!(
            "{pixels:?} pixels: per-channel coefficient error {err:.1e}, fit {:.1e}; joint fit {:.3}",
            per_channel.fit_error, joint.fit_error
        );
        // f32 renders, and the 20 chosen rows rebuilt under 65,536 lights where the photo had
        // 2,048: the cap that reads the map inside a sharp lobe sits at each set's own light
        // spacing, so the two quadratures differ a little (measured 1.2e-4 with 20 pixels).
        assert!(err < 5e-4, "{pixels:?} pixels: per-channel error {err}");
        assert!(per_channel.fit_error < 1e-5, "{}", per_channel.fit_error);
        assert!(joint.fit_error > 0.05, "joint fit {}", joint.fit_error);
        // The automatic choice tries both and keeps per channel, the better fit: the same
        // pixels and coefficients as asking for it.
        let auto = run(ColourChoice::Auto);
        assert_eq!(auto.colour(), Colour::PerChannel);
        assert_eq!(
            auto.solution.coefficients,
            per_channel.solution.coefficients
        );
        assert_eq!(
            of_basis(&auto).selection.pixels,
            of_basis(&per_channel).selection.pixels
        );
        assert_eq!(
            of_basis(&auto).colour_fits,
            [
                (Colour::Joint, joint.fit_error),
                (Colour::PerChannel, per_channel.fit_error)
            ]
        );
        let back = basis
            .reconstruct_solution(&per_channel.solution.coefficients)
            .unwrap();
        assert!(brdf_error(&back, &brdf, basis.header.cell_weight) < 1e-4);
    }
    let e = basis.reconstruct_solution(&truth[..m + 1]).unwrap_err();
    assert!(
        e.to_string().contains("expected 6 (joint colour) or 18"),
        "{e}"
    );
}

/// The automatic colour choice keeps the paper's joint model unless per channel re-renders
/// the photo better by more than `COLOUR_FIT_MARGIN`. An in-span joint BRDF is a tie (both
/// models hold it, and both fit to f32 rounding), which rounding must not decide.
#[test]
fn auto_colour_keeps_joint_on_a_tie() {
    use brdfd_core::estimate::COLOUR_FIT_MARGIN;
    let basis = Basis::embedded();
    let (c_true, g, lights, photo) = in_span_photo(&basis);
    let opts = EstimateOptions {
        model: ModelOptions::Basis(BasisOptions {
            solver: Solver::LeastSquares,
            colour: ColourChoice::Auto,
            ..BasisOptions::default()
        }),
        ..Default::default()
    };
    let est = estimate(&basis, one_view(&g, &lights, &photo), &opts).unwrap();
    let fits: Vec<(Colour, f64)> = of_basis(&est).colour_fits.clone();
    eprintln!("in span: fits {fits:?}");
    // Measured: joint 1.01e-6, per channel 1.05e-6.
    assert_eq!(fits.len(), 2);
    assert!(fits.iter().all(|(_, f)| *f < COLOUR_FIT_MARGIN));
    assert_eq!(est.colour(), Colour::Joint);
    assert!(relative_error(&est.solution.coefficients, &c_true) < 1e-4);
}

/// A photo with clipped highlights: the clipped values are lower bounds, and fitting them as
/// values drags the estimate. Told the white level, the estimate leaves those pixels out and
/// recovers in-span coefficients as if nothing had clipped.
#[test]
fn clipped_pixels_are_left_out() {
    let basis = Basis::embedded();
    let (c_true, g, lights, mut photo) = in_span_photo(&basis);
    let mut values: Vec<f32> = photo.pixels.iter().flatten().copied().collect();
    values.sort_by(f32::total_cmp);
    let white = values[values.len() * 99 / 100];
    for v in photo.pixels.iter_mut().flatten() {
        *v = v.min(white);
    }
    let error = |white: Option<f32>| {
        let opts = EstimateOptions {
            model: ModelOptions::Basis(BasisOptions {
                pixel_count: None,
                solver: Solver::LeastSquares,
                // The truth is a joint-colour BRDF; per channel would fit the clipped values too.
                colour: ColourChoice::Joint,
                ..BasisOptions::default()
            }),
            white,
            ..Default::default()
        };
        let est = estimate(&basis, one_view(&g, &lights, &photo), &opts).unwrap();
        (
            relative_error(&est.solution.coefficients, &c_true),
            est.clipped,
        )
    };
    let (told, clipped) = error(Some(white));
    let (not_told, none) = error(None);
    eprintln!("{clipped} clipped pixels; coefficient error {told:.2e} told, {not_told:.2e} not");
    assert!(clipped > 0 && none == 0);
    // f32 renders: measured 1.1e-6 told; 0.85 when the 33 clipped pixels are fitted.
    assert!(told < 1e-4, "told the white level: {told}");
    assert!(
        not_told > 10.0 * told,
        "clipping made no difference: {not_told}"
    );
}

/// With few pixels, the paper's least squares follows the model error (bivariate reduction,
/// K = 5, light compression) into implausible coefficients; brdfd's basis solve, with the
/// training prior and the BRDF kept ≥ 0, keeps it closer to the truth. The evaluation's scene at 64²: a sphere under grace, rendered from the full 3D BRDF,
/// for the ten test materials, none of them in the embedded basis's training set. Under a
/// smooth studio map least squares rarely goes astray and the two solvers agree (docs/evaluation.md).
#[test]
fn the_prior_steadies_few_pixel_estimates_under_grace() {
    let Some(data) = shared_data() else { return };
    let grace = EnvMap::load(&data.join("envmaps/grace.hdr")).unwrap();
    let (truth_lights, lights) = (grace.compressed(4096, 0.0), grace.compressed(2048, 0.0));
    let basis = Basis::embedded();
    let g = sphere(64);
    let materials = embedded_materials();
    let mut ratios = Vec::new();
    for (name, fit) in &materials.materials {
        let table = MerlBrdf::tabulate(fit);
        let photo = render_merl(&g, &truth_lights, &table);
        let truth = Bivariate::reduce(&table, basis.header.grid);
        let error = |solver, nonnegative| {
            let opts = EstimateOptions {
                model: ModelOptions::Basis(BasisOptions {
                    pixel_count: Some(5),
                    solver,
                    // The paper's model: its least squares solves 5 pixels, per channel cannot.
                    colour: ColourChoice::Joint,
                    nonnegative,
                    ..BasisOptions::default()
                }),
                ..Default::default()
            };
            let est = estimate(&basis, one_view(&g, &lights, &photo), &opts).unwrap();
            brdf_error(&est.brdf, &truth, basis.header.cell_weight)
        };
        let (ls, prior) = (
            error(Solver::LeastSquares, false),
            error(Solver::Prior, true),
        );
        eprintln!("{name}: BRDF error with 5 pixels, the paper's {ls:.3}, brdfd's {prior:.3}");
        ratios.push(prior / ls);
    }
    ratios.sort_by(f64::total_cmp);
    let median = ratios[ratios.len() / 2];
    assert!(
        median < 0.8,
        "median BRDF error ratio brdfd / paper {median:.3} (ratios {ratios:?})"
    );
}

/// A BRDF with a closed form: Lambertian plus a normalised Blinn-Phong lobe in θh.
struct Analytic;
const RHO_D: f64 = 0.4;
const RHO_S: f64 = 0.3;
const EXPONENT: i32 = 20;

impl IsotropicBrdf for Analytic {
    fn eval_angles(&self, theta_h: f64, _theta_d: f64, _phi_d: f64) -> [f64; 3] {
        let s = RHO_S * (EXPONENT as f64 + 2.0) / (2.0 * std::f64::consts::PI)
            * theta_h.cos().powi(EXPONENT);
        let v = RHO_D / std::f64::consts::PI + s;
        [v, 0.5 * v, 0.25 * v]
    }
}

/// A smooth sky, so a fine lat-long grid integrates it accurately.
fn sky(d: Vec3) -> f64 {
    1.0 + 0.6 * d[1] + 0.3 * d[0] - 0.2 * d[2]
}

fn sky_map(width: usize) -> EnvMap {
    let h = width / 2;
    let px = (0..width * h)
        .map(|i| {
            let d = brdfd_core::envmap::direction(
                ((i % width) as f64 + 0.5) / width as f64,
                ((i / width) as f64 + 0.5) / h as f64,
                0.0,
            );
            [sky(d) as f32; 3]
        })
        .collect();
    EnvMap::from_pixels(width, h, px, "sky").unwrap()
}

/// Independent integration: a midpoint rule over the hemisphere of the pixel's own normal,
/// with the analytic sky, sharing no code with the renderers beyond the BRDF.
fn quadrature(px: &GeomPixel) -> f64 {
    let n = px.normal.map(|c| c as f64);
    let v = px.view.map(|c| c as f64);
    let (t, b) = brdfd_core::brdf::tangent_frame(n);
    let wo = [dot(v, t), dot(v, b), dot(v, n)];
    let (nt, np) = (400, 800);
    let mut sum = 0.0;
    for i in 0..nt {
        let theta = (i as f64 + 0.5) / nt as f64 * std::f64::consts::FRAC_PI_2;
        for j in 0..np {
            let phi = (j as f64 + 0.5) / np as f64 * 2.0 * std::f64::consts::PI;
            let wi = [
                theta.sin() * phi.cos(),
                theta.sin() * phi.sin(),
                theta.cos(),
            ];
            let world = normalize([0, 1, 2].map(|k| wi[0] * t[k] + wi[1] * b[k] + wi[2] * n[k]));
            let f = Analytic.eval_dirs(wi, wo)[0];
            sum += f * sky(world) * theta.cos() * theta.sin();
        }
    }
    sum * (std::f64::consts::FRAC_PI_2 / nt as f64) * (2.0 * std::f64::consts::PI / np as f64)
}

#[test]
fn forward_model_matches_independent_integration() {
    let g = sphere(16);
    let lights = sky_map(512).lights(0.0);
    let full = render_full(&g, &lights, &Analytic);
    let table = MerlBrdf::tabulate(&Analytic);
    let merl = render_merl(&g, &lights, &table);
    let biv = render_bivariate(&g, &lights, &Bivariate::reduce(&Analytic, Grid::default()));
    let mut worst = [0.0f64; 3];
    for px in g.pixels.iter().step_by(7) {
        let q = quadrature(px);
        for (k, img) in [&full, &merl, &biv].iter().enumerate() {
            let r = img.get(px.x as usize, px.y as usize)[0] as f64;
            worst[k] = worst[k].max((r - q).abs() / q);
        }
    }
    // Direct evaluation: only the lat-long discretisation of the sky and the horizon (0.5%).
    assert!(worst[0] < 5e-3, "render_full vs quadrature: {worst:?}");
    // Tabulated paths add 1° binning of θd and √-binning of θh on a lobe 15° wide (2%).
    assert!(
        worst[1] < 2e-2 && worst[2] < 2e-2,
        "binned renderers vs quadrature: {worst:?}"
    );
}

/// Map with one bright light at the column that faces +X (u = ¾).
fn light_at_plus_x() -> EnvMap {
    let (w, h) = (128, 64);
    let px = (0..w * h)
        .map(|i| {
            let d = brdfd_core::envmap::direction(
                ((i % w) as f64 + 0.5) / w as f64,
                ((i / w) as f64 + 0.5) / h as f64,
                0.0,
            );
            if d[0] > 0.9 {
                [50.0f32; 3]
            } else {
                [0.1; 3]
            }
        })
        .collect();
    EnvMap::from_pixels(w, h, px, "asymmetric").unwrap()
}

/// The orientation test of the conventions (docs/bench-setup.md): a light the convention puts at +X must light
/// the right side of the sphere (image right = world +X).
fn lit_from_plus_x(map: &EnvMap, yaw: f64) -> bool {
    let g = sphere(32);
    let img = render_bivariate(
        &g,
        &map.lights(yaw),
        &Bivariate::reduce(&Analytic, Grid::default()),
    );
    let side = |right: bool| -> f64 {
        g.pixels
            .iter()
            .filter(|p| (p.x >= 16) == right)
            .map(|p| img.get(p.x as usize, p.y as usize)[0] as f64)
            .sum()
    };
    side(true) > 2.0 * side(false)
}

#[test]
fn mirrored_map_fails_the_orientation_test() {
    let map = light_at_plus_x();
    assert!(lit_from_plus_x(&map, 0.0));
    assert!(
        !lit_from_plus_x(&map.mirrored(), 0.0),
        "a mirrored map must not pass"
    );
    // A yaw of 180° turns the light to −X.
    assert!(!lit_from_plus_x(&map, std::f64::consts::PI));
}

/// Compression must leave renders unchanged for sharp materials too: a mirror-like metal
/// reflects the map's small bright sources, which a uniform grid of lights smears over 4°
/// cells. Reference: every pixel of the map as a light.
#[test]
fn compression_keeps_renders_unchanged() {
    let map = studio_envmap(512);
    let g = sphere(32);
    let full = map.lights(0.0);
    let adaptive = map.compressed(brdfd_core::envmap::DEFAULT_LIGHTS, 0.0);
    // The uniform 90 × 45 grid earlier versions used, for comparison.
    let grid = map.downsample(90, 45).lights(0.0);
    let materials = embedded_materials();
    // Measured (adaptive / uniform grid): blue-fabric 0.0002 / 0.010, nickel 0.009 / 0.50,
    // chrome-steel 0.063 / 0.93. Chrome's remainder is the sharp rim of the small window,
    // which no few thousand lights can draw exactly.
    for (name, limit) in [
        ("blue-fabric", 1e-3),
        ("nickel", 2e-2),
        ("chrome-steel", 0.1),
    ] {
        let table = MerlBrdf::tabulate(materials.get(name).unwrap());
        let truth = render_merl(&g, &full, &table);
        let err = render_merl(&g, &adaptive, &table).relative_rmse(&truth);
        let grid_err = render_merl(&g, &grid, &table).relative_rmse(&truth);
        eprintln!("{name}: relative change {err:.4} adaptive, {grid_err:.4} uniform grid");
        assert!(err < limit, "{name}: relative change {err}");
    }
    // Several counts in one pass (an estimate's candidate and chosen lights) give each
    // count's own compression, light for light.
    let levels = map.compressed_levels(&[512, brdfd_core::envmap::DEFAULT_LIGHTS, 16_384], 0.0);
    for (set, alone) in levels.iter().zip([
        map.compressed(512, 0.0),
        adaptive,
        map.compressed(16_384, 0.0),
    ]) {
        assert_eq!(set.directions, alone.directions);
        assert_eq!(set.radiance, alone.radiance);
        assert_eq!(set.solid_angle, alone.solid_angle);
        assert_eq!(set.spread, alone.spread);
    }
    assert_eq!(levels[2].len(), 16_384);
}

/// A stop requested while a selection runs ends it with `Stopped`, within a pass over the
/// candidates: the paper's search, left to itself here, takes far longer than the bound.
#[test]
fn a_stop_ends_either_pixel_selection_promptly() {
    let basis = Basis::embedded();
    let a = studio_matrix(&basis, 64);
    let blocks = Blocks::scaled(&a, &basis.column_scales());
    let endless = SwapParams {
        restarts: 1_000,
        seed: 7,
        max_evaluations: u64::MAX,
    };
    let stopped_within = |search: &dyn Fn(&Stop) -> brdfd_core::Result<select::Selection>| {
        let stop = Stop::default();
        let asker = stop.clone();
        let started = std::time::Instant::now();
        let (result, asked_at) = std::thread::scope(|s| {
            let asked = s.spawn(move || {
                std::thread::sleep(std::time::Duration::from_millis(50));
                asker.request();
                started.elapsed()
            });
            (search(&stop), asked.join().unwrap())
        });
        let lag = started.elapsed().saturating_sub(asked_at);
        assert!(
            matches!(result, Err(brdfd_core::CoreError::Stopped)),
            "the search ended without seeing the stop"
        );
        lag
    };
    let paper = stopped_within(&|stop| select::paper_swap(&blocks, 20, &endless, stop));
    assert!(
        paper.as_secs_f64() < 1.0,
        "paper's search stopped {paper:?} after the request"
    );
    // The fast search is over in well under a second, so it is stopped before it starts.
    let stop = Stop::default();
    stop.request();
    assert!(matches!(
        select::fast_exchange(&blocks, 20, &stop),
        Err(brdfd_core::CoreError::Stopped)
    ));
}

#[test]
fn selection_beats_random_and_fast_matches_paper() {
    let basis = Basis::embedded();
    let a = studio_matrix(&basis, 48);
    let blocks = Blocks::scaled(&a, &basis.column_scales());
    let mut random: Vec<f64> = (0..20)
        .map(|s| select::random_pixels(&blocks, 20, s).condition)
        .collect();
    random.sort_by(f64::total_cmp);
    let paper = select::paper_swap(
        &blocks,
        20,
        &SwapParams {
            restarts: 3,
            seed: 7,
            max_evaluations: 200_000,
        },
        &Stop::default(),
    )
    .unwrap();
    let fast = select::fast_exchange(&blocks, 20, &Stop::default()).unwrap();
    assert!(
        paper.condition < random[10] && fast.condition < random[10],
        "paper {} fast {} random median {}",
        paper.condition,
        fast.condition,
        random[10]
    );
    // Ours must be at least as good as the paper's within 25% (measured ratios in docs/evaluation.md).
    assert!(
        fast.condition < 1.25 * paper.condition,
        "fast {} paper {}",
        fast.condition,
        paper.condition
    );
    // Recomputing κ from the chosen set gives the reported value (summation order differs).
    assert!((blocks.condition(&fast.pixels) - fast.condition).abs() < 1e-12 * fast.condition);
}

/// Per-channel colour solves each channel from its own rows, so selection conditions those
/// three systems, not the joint one whose three rows per pixel no single channel gets.
#[test]
fn per_channel_selection_conditions_each_channel() {
    let basis = Basis::embedded();
    let a = studio_matrix(&basis, 48);
    let scales = basis.column_scales();
    let joint = Blocks::scaled(&a, &scales);
    let channels = Blocks::per_channel(&a, &scales);
    let for_joint = select::fast_exchange(&joint, 20, &Stop::default()).unwrap();
    let for_channels = select::fast_exchange(&channels, 20, &Stop::default()).unwrap();
    let paper = select::paper_swap(
        &channels,
        20,
        &SwapParams {
            restarts: 2,
            seed: 7,
            // Enough to converge (it spends under 1M). The search minimises a guided score
            // and reports the channels' κ, which a truncated search leaves to where it was
            // cut: at 100,000 evaluations, matrices that differ in the map's filtering gave
            // 38.5 or 107.8; converged, both give 39.0.
            max_evaluations: 2_000_000,
        },
        &Stop::default(),
    )
    .unwrap();
    // The reported κ is the worst channel's, recomputed from the set.
    let worst = channels.condition(&for_channels.pixels);
    assert!((worst - for_channels.condition).abs() < 1e-12 * worst);
    // Measured (studio map, 48² sphere, the rows read through the cap): the joint choice
    // leaves its worst channel at κ 51.4, the channels' choice at 38.9, and the paper's search
    // on the same blocks at 39.0 (80.2, 49.3 and 62.3 with the lights alone, a budget of
    // 100,000 evaluations). The search is
    // deterministic; the margins allow for rounding.
    let joint_choice = channels.condition(&for_joint.pixels);
    eprintln!(
        "worst channel's κ: joint choice {joint_choice:.1}, per-channel fast {:.1}, paper {:.1} ({} evaluations)",
        for_channels.condition, paper.condition, paper.evaluations
    );
    assert!(
        for_channels.condition < 0.8 * joint_choice && paper.condition < 0.8 * joint_choice,
        "per channel: fast {} paper {}; the joint choice {joint_choice}",
        for_channels.condition,
        paper.condition
    );
    // With fewer rows per channel than unknowns (5 pixels, 6 columns) every set is singular in
    // each channel, so the joint κ guides the choice, and the report says the truth.
    let five = select::fast_exchange(&channels, 5, &Stop::default()).unwrap();
    assert_eq!(
        five.pixels,
        select::fast_exchange(&joint, 5, &Stop::default())
            .unwrap()
            .pixels
    );
    assert!(five.condition.is_infinite(), "{}", five.condition);
    assert!(five
        .condition_text()
        .starts_with("infinite (fewer equations than unknowns"));
    assert_eq!(
        for_channels.condition_text(),
        format!("{:.2}", for_channels.condition)
    );
}

#[test]
fn estimate_recovers_an_embedded_material_on_the_virtual_bench() {
    let bench = brdfd_bench::VirtualBench::embedded("pearl-paint", 96).unwrap();
    let photo = bench.photo().unwrap();
    let g = bench.pixels().unwrap();
    let lights = bench
        .env
        .compressed(brdfd_core::envmap::DEFAULT_LIGHTS, 0.0);
    let basis = Basis::embedded();
    for method in [SelectionMethod::Fast, SelectionMethod::Paper] {
        let opts = EstimateOptions {
            model: ModelOptions::Basis(BasisOptions {
                pixel_count: Some(20),
                method,
                swap: SwapParams {
                    restarts: 2,
                    seed: 1,
                    max_evaluations: 50_000,
                },
                ..BasisOptions::default()
            }),
            ..Default::default()
        };
        let est = estimate(&basis, one_view(&g, &lights, &photo), &opts).unwrap();
        let re = render_bivariate(&g, &lights, &est.brdf);
        // Pearl paint is well inside the basis: measured 0.08–0.19 image error (docs/evaluation.md).
        assert!(
            re.relative_rmse(&photo) < 0.25,
            "{method:?}: {}",
            re.relative_rmse(&photo)
        );
    }
}

#[test]
fn nan_in_an_exr_is_rejected_with_its_pixel() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad.exr");
    let mut px = vec![[1.0f32; 3]; 16 * 8];
    px[8 * 16 + 5 - 16] = [1.0, f32::NAN, 1.0];
    brdfd_core::envmap::write_exr(&path, 16, 8, &px).unwrap();
    let e = EnvMap::load(&path).unwrap_err().to_string();
    assert!(
        e.contains("bad.exr") && e.contains("x=5, y=7") && e.contains("channel 1"),
        "{e}"
    );
    let e = Raster::read(&path).unwrap_err().to_string();
    assert!(e.contains("x=5, y=7"), "{e}");
}

#[test]
fn basis_files_round_trip_and_reject_damage() {
    let basis = Basis::embedded();
    let dir = tempfile::tempdir().unwrap();
    let stem = dir.path().join("b");
    basis.write(&stem).unwrap();
    let back = Basis::read(&stem).unwrap();
    assert_eq!(back.header.id, basis.header.id);
    for (a, b) in back.components.iter().zip(&basis.components) {
        // Stored as f32 EXR samples.
        assert!(a
            .iter()
            .zip(b)
            .all(|(x, y)| (x - y).abs() <= 1e-6 * y.abs().max(1e-3)));
    }
    let exr = std::fs::read(stem.with_extension("exr")).unwrap();
    std::fs::write(stem.with_extension("exr"), &exr[..exr.len() / 3]).unwrap();
    let e = Basis::read(&stem).unwrap_err().to_string();
    assert!(e.contains("EXR"), "{e}");
    std::fs::write(
        stem.with_extension("json"),
        "{\"format\": \"brdfd-basis/1\"}",
    )
    .unwrap();
    let e = Basis::read(&stem).unwrap_err().to_string();
    assert!(e.contains("header") && e.contains("missing field"), "{e}");
}

/// K beyond what an estimate can carry is refused when the basis is built and when a basis
/// file claims it, rather than failing later inside the renderer.
#[test]
fn bases_with_more_components_than_estimates_use_are_refused() {
    use brdfd_core::basis::{CellWeight, Normalisation, MAX_K};
    let grid = Grid::default();
    // Twelve training materials: the ten test fits, and the square roots of two of them (a
    // repeat would add no rank).
    let set = embedded_materials();
    let mut training: Vec<(String, Bivariate)> = set
        .materials
        .iter()
        .map(|(n, m)| (n.clone(), Bivariate::reduce(m, grid)))
        .collect();
    for i in 0..2 {
        let (n, mut b) = training[i].clone();
        b.values.iter_mut().for_each(|v| *v = v.max(0.0).sqrt());
        training.push((format!("{n}-sqrt"), b));
    }
    let build = |k| {
        Basis::build(
            &training,
            k,
            Normalisation::Rms,
            CellWeight::SolidAngle,
            true,
        )
    };
    let e = build(MAX_K + 1).unwrap_err().to_string();
    assert!(e.contains("K must be between 1 and 10"), "{e}");
    let basis = build(MAX_K).unwrap();
    assert_eq!(basis.components.len(), MAX_K);

    let dir = tempfile::tempdir().unwrap();
    let stem = dir.path().join("b");
    basis.write(&stem).unwrap();
    let json = std::fs::read_to_string(stem.with_extension("json")).unwrap();
    let claimed = json.replace("\"k\": 10", "\"k\": 11");
    assert_ne!(json, claimed, "the header should record k");
    std::fs::write(stem.with_extension("json"), claimed).unwrap();
    let e = Basis::read(&stem).unwrap_err().to_string();
    assert!(e.contains("K is 11") && e.contains("1 to 10"), "{e}");
}

/// A photo's white level survives its EXR (the attribute brdfd writes), PNG reads as clipping
/// at 1.0, and a damaged attribute is an error that names it.
#[test]
fn photo_files_carry_their_white_level() {
    use brdfd_core::envmap::WHITE_LEVEL_ATTRIBUTE;
    let dir = tempfile::tempdir().unwrap();
    let photo = Raster {
        width: 3,
        height: 2,
        pixels: vec![[0.5, 2.0, 8.0]; 6],
    };
    let merged = dir.path().join("merged.exr");
    photo.write_exr_with_white(&merged, Some(8.0)).unwrap();
    let (back, white) = Raster::read_with_white(&merged).unwrap();
    assert_eq!((back, white), (photo.clone(), Some(8.0)));
    let plain = dir.path().join("plain.exr");
    photo.write_exr(&plain).unwrap();
    assert_eq!(Raster::read_with_white(&plain).unwrap().1, None);
    let png = dir.path().join("p.png");
    photo.write_png(&png, 1.0).unwrap();
    assert_eq!(Raster::read_with_white(&png).unwrap().1, Some(1.0));
    let damaged = dir.path().join("damaged.exr");
    photo.write_exr_with_white(&damaged, Some(-1.0)).unwrap();
    let e = Raster::read_with_white(&damaged).unwrap_err().to_string();
    assert!(
        e.contains(WHITE_LEVEL_ATTRIBUTE) && e.contains("damaged.exr"),
        "{e}"
    );
}

#[test]
fn embedded_defaults_load() {
    let b = Basis::embedded();
    assert_eq!(b.header.k, 5);
    assert_eq!(b.header.materials.len(), 90);
    assert!(brdfd_eval::paper::TEST_SET
        .iter()
        .all(|m| !b.header.materials.iter().any(|t| t == m)));
    assert_eq!(embedded_materials().materials.len(), 10);
}

/// A turntable (issue 5): three views of a corrugated sheet at −30°, 0° and +30°, as the
/// object turns under a fixed camera and light (a sheet faces away beyond ±90°: a view there
/// is an error naming it). In the object's frame each view is the camera and the map
/// turned by −θ. Photos rendered by the model itself must give back the coefficients, and the
/// extra normals must condition the all-pixel system better than one view does.
#[test]
fn turntable_views_recover_the_coefficients_and_improve_conditioning() {
    use brdfd_core::estimate::estimate_views;
    let basis = Basis::embedded();
    let c_true = in_span_nonnegative(&basis);
    let in_span = basis.reconstruct(&c_true);
    let sheet = Shape::Corrugated {
        center: [0.0; 3],
        half_size: 0.8,
        amplitude: 0.12,
        period: 0.5,
        tilt_deg: 25.0,
    };
    let camera = Camera::eval_orthographic(48);
    let map = studio_envmap(256);
    // Each view's photo is rendered under a fine compression of the turned map; the estimate
    // builds its candidates' rows under a coarse one and the chosen rows under the fine one.
    let views: Vec<(PixelGeometry, LightSet, LightSet, Raster)> = [0.0f64, 30.0, -30.0]
        .iter()
        .map(|deg| {
            let theta = deg.to_radians();
            let g = PixelGeometry::rasterize(&camera.turned_about_y(-theta), &sheet).unwrap();
            let mut levels = map.compressed_levels(&[256, 8192], -theta);
            let (fine, coarse) = (levels.pop().unwrap(), levels.pop().unwrap());
            let photo = render_bivariate(&g, &fine, &in_span);
            (g, coarse, fine, photo)
        })
        .collect();
    let as_views = |n: usize, refine: bool| -> Vec<View> {
        views[..n]
            .iter()
            .map(|(geometry, lights, fine, photo)| View {
                geometry,
                lights,
                chosen_lights: refine.then_some(fine),
                photo,
            })
            .collect()
    };
    // The turned views see different normals: the sheet is not symmetric about +Y.
    assert_ne!(views[0].3.pixels, views[1].3.pixels);

    // The truth is a joint-colour BRDF, and the coarse rows' compression error could make
    // an automatic choice pick per channel.
    let twenty = EstimateOptions {
        model: ModelOptions::Basis(BasisOptions {
            colour: ColourChoice::Joint,
            ..BasisOptions::default()
        }),
        ..EstimateOptions::default()
    };
    let est = estimate_views(&basis, &as_views(3, true), &twenty).unwrap();
    assert_eq!(of_basis(&est).chosen_lights, views[0].2.len());
    let err = relative_error(&est.solution.coefficients, &c_true);
    let coarse = estimate_views(&basis, &as_views(3, false), &twenty).unwrap();
    let coarse_err = relative_error(&coarse.solution.coefficients, &c_true);
    eprintln!("20 pixels of 3 views: coefficient error {err:.1e} with each view's chosen rows under its fine lights, {coarse_err:.1e} under the coarse ones");
    // The photos are f32 renders of the model: single-precision rounding, not the 1e-6 of
    // the f64 check above, bounds the error. Under the coarse lights, compression error.
    assert!(err < 1e-3, "relative coefficient error {err}");
    assert!(
        coarse_err > 10.0 * err,
        "coarse rows did as well: {coarse_err}"
    );
    let views_used: std::collections::BTreeSet<_> = of_basis(&est).chosen_views.iter().collect();
    assert!(views_used.len() > 1, "selection used views {views_used:?}");

    let all = EstimateOptions {
        model: ModelOptions::Basis(BasisOptions {
            pixel_count: None,
            colour: ColourChoice::Joint,
            ..BasisOptions::default()
        }),
        ..twenty.clone()
    };
    let one = estimate_views(&basis, &as_views(1, true), &all)
        .unwrap()
        .condition();
    let three = estimate_views(&basis, &as_views(3, true), &all)
        .unwrap()
        .condition();
    eprintln!("all-pixel condition number: 1 view {one:.2}, 3 views {three:.2}");
    assert!(
        three < one,
        "three views κ {three} not below one view κ {one}"
    );
}

#[test]
fn analytic_model_recovers_a_tabulated_ggx_material() {
    // Issue 18: a GGX material tabulated in MERL layout, rendered from the full table (not
    // through the model's own columns), is recovered by the analytic model. Tolerances: the
    // render and the fit disagree only through the full table's bin centres against the
    // bivariate grid's φd mean, and the compressed lights; measured α within 0.1%, kd and F₀
    // within 0.004, fit 0.015, so 5%, 0.03 and 0.02 leave room without hiding a wrong lobe.
    use brdfd_core::analytic::Microfacet;
    let truth = Microfacet::one_lobe([0.30, 0.10, 0.05], [0.9, 0.7, 0.4], [1.0; 3], 0.15);
    let table = MerlBrdf::tabulate(&truth);
    let g = sphere(96);
    let env = studio_envmap(256);
    let photo = render_merl(&g, &env.compressed(8192, 0.0), &table);
    let lights = env.compressed(brdfd_core::envmap::DEFAULT_LIGHTS, 0.0);
    let opts = EstimateOptions {
        model: ModelOptions::Analytic { lobes: 1 },
        ..Default::default()
    };
    let est = estimate(&Basis::embedded(), one_view(&g, &lights, &photo), &opts).unwrap();
    let Outcome::Analytic(got) = est.outcome else {
        panic!("analytic parameters: {:?}", est.outcome);
    };
    let (lobe, true_lobe) = (got.lobes[0], truth.lobes[0]);
    assert!(
        (lobe.alpha / true_lobe.alpha - 1.0).abs() < 0.05,
        "alpha {} against {}",
        lobe.alpha,
        true_lobe.alpha
    );
    for c in 0..3 {
        assert!((got.diffuse[c] - truth.diffuse[c]).abs() < 0.03, "{got:?}");
        assert!((lobe.f0[c] - true_lobe.f0[c]).abs() < 0.03, "{got:?}");
    }
    assert!(est.fit_error < 0.02, "fit {}", est.fit_error);
    // Non-negative in every cell by construction, and the written coefficients are the
    // parameters.
    assert!(est.brdf.values.iter().all(|v| *v >= 0.0));
    assert_eq!(est.names.len(), est.solution.coefficients.len());
    assert_eq!(est.names.last().map(String::as_str), Some("lobe1.alpha"));
}

#[test]
fn default_estimates_are_plausible_on_every_evaluation_material() {
    // Issue 18: f ≥ 0 in every cell and directional albedo ≤ 1, for the default model's
    // estimate (and f ≥ 0 for the basis model's) of each of the 10 test materials (embedded NBRDF fits) and of brdfd's own GGX
    // materials, from a 48² sphere under the studio map.
    use brdfd_eval::relight::analytic_materials;
    use brdfd_report::results::Plausibility;
    let set = embedded_materials();
    let mut tables: Vec<(String, MerlBrdf)> = set
        .materials
        .iter()
        .map(|(n, m)| (n.clone(), MerlBrdf::tabulate(m)))
        .collect();
    tables.extend(
        analytic_materials()
            .into_iter()
            .map(|(n, m)| (n.to_string(), MerlBrdf::tabulate(&m))),
    );
    assert_eq!(tables.len(), 16);
    let g = sphere(48);
    let lights = studio_envmap(256).compressed(2048, 0.0);
    let basis = Basis::embedded();
    for (name, table) in &tables {
        // The materials themselves first: an estimate can only be as plausible as its truth.
        let truth = Plausibility::of(&Bivariate::reduce(table, Grid::default()));
        assert!(truth.albedo_at_most_one, "{name} itself: {truth:?}");
        let photo = render_merl(&g, &lights, table);
        let est = estimate(
            &basis,
            one_view(&g, &lights, &photo),
            &EstimateOptions::default(),
        )
        .unwrap();
        let p = Plausibility::of(&est.brdf);
        assert_eq!(p.negative_cells, 0, "{name}: {p:?}");
        assert!(p.albedo_at_most_one, "{name}: {p:?}");
        // The basis model keeps f ≥ 0 in its solve, from 20 pixels and from every pixel (its
        // albedo is reported, not bounded: coefficients.json's plausibility).
        for pixel_count in [Some(20), None] {
            let options = EstimateOptions {
                model: ModelOptions::Basis(BasisOptions {
                    pixel_count,
                    ..BasisOptions::default()
                }),
                ..EstimateOptions::default()
            };
            let est = estimate(&basis, one_view(&g, &lights, &photo), &options).unwrap();
            let p = Plausibility::of(&est.brdf);
            assert_eq!(p.negative_cells, 0, "{name}, basis, {pixel_count:?}: {p:?}");
        }
    }
}

#[test]
fn hybrid_model_recovers_a_measured_material_in_its_mix() {
    // Issue 18: a photo of one of the basis's measured materials (scaled, over a little
    // Lambert) is re-rendered by the hybrid model to within 2%, the material carries the mix,
    // and the estimate relights under a turned map as the truth does. Tolerances: the photo is
    // rendered under finer lights than the estimate uses, and the embedded tables are half
    // precision, so neither the fit nor the relight is exact (measured: fit 0.006, relight
    // 0.010; the tests hold 0.02 and 0.05).
    use brdfd_core::hybrid::HybridFit;
    let basis = Basis::embedded();
    let (name, table) = basis
        .atoms()
        .find(|(n, _)| *n == "gold-paint")
        .expect("gold-paint is a training material");
    let grid = basis.header.grid;
    let mut values: Vec<f64> = table.iter().map(|v| 0.7 * v).collect();
    for c in 0..3 {
        for g in 0..brdfd_core::bivariate::GRID_CELLS {
            values[c * brdfd_core::bivariate::GRID_CELLS + g] += 0.05 / std::f64::consts::PI;
        }
    }
    let reference = Bivariate::reduce(
        &brdfd_core::analytic::Microfacet::one_lobe([0.0; 3], [0.0; 3], [0.0; 3], 0.5),
        grid,
    );
    let truth = Bivariate::from_values(grid, values, reference.valid.clone());
    let g = sphere(96);
    let env = studio_envmap(256);
    let photo = render_bivariate(&g, &env.compressed(8192, 0.0), &truth);
    let lights = env.compressed(brdfd_core::envmap::DEFAULT_LIGHTS, 0.0);
    let opts = EstimateOptions {
        model: ModelOptions::of(Model::Hybrid),
        ..Default::default()
    };
    let est = estimate(&basis, one_view(&g, &lights, &photo), &opts).unwrap();
    assert!(est.fit_error < 0.02, "fit {}", est.fit_error);
    let Outcome::Hybrid { analytic, mixture } = &est.outcome else {
        panic!("a hybrid estimate: {:?}", est.outcome);
    };
    let main = mixture
        .iter()
        .max_by(|a, b| a.weight[1].total_cmp(&b.weight[1]))
        .expect("a mix");
    assert_eq!(main.material, name, "{mixture:?}");
    assert!(est.brdf.values.iter().all(|v| *v >= 0.0));
    // Relit under the map turned 120°, against the truth relit there.
    let turned = env.compressed(8192, 120f64.to_radians());
    let relit = render_bivariate(&g, &turned, &est.brdf);
    let error = relit.relative_rmse(&render_bivariate(&g, &turned, &truth));
    assert!(error < 0.05, "relight {error}");
    // What `render --coefficients` rebuilds from coefficients.json is the estimate itself.
    let rebuilt = HybridFit::rebuild(analytic, mixture, &basis).unwrap();
    let most = rebuilt
        .values
        .iter()
        .zip(&est.brdf.values)
        .map(|(a, b)| (a - b).abs() / (1.0 + b.abs()))
        .fold(0.0, f64::max);
    assert!(most < 1e-9, "rebuilt differs by {most}");
    assert_eq!(est.names.len(), est.solution.coefficients.len());
}

/// Issue 38: the hybrid model's renders made before the photo (a capture makes them while
/// its camera shoots) leave the estimate as it is without them, to the bit; and a photo that
/// leaves a pixel out (so other candidates) is estimated from renders of its own.
#[test]
fn renders_prepared_before_the_photo_leave_the_estimate_unchanged() {
    use brdfd_core::estimate::{estimate_views, estimate_views_shared, Shared};
    let basis = Basis::embedded();
    let g = sphere(48);
    let env = studio_envmap(128);
    let lights = env.compressed(1024, 0.0);
    let truth = Bivariate::reduce(
        embedded_materials().get("gold-metallic-paint").unwrap(),
        basis.header.grid,
    );
    let photo = render_bivariate(&g, &lights, &truth);
    let mut gap = photo.clone();
    let p = &g.pixels[g.pixels.len() / 2];
    gap.set(p.x as usize, p.y as usize, [f32::NAN; 3]);
    let options = EstimateOptions {
        model: ModelOptions::of(Model::Hybrid),
        checks: false,
        ..EstimateOptions::default()
    };
    for (photo, uses_them) in [(&photo, true), (&gap, false)] {
        let view = [one_view(&g, &lights, photo)];
        let alone = estimate_views(&basis, &view, &options).unwrap();
        let shared = Shared::default();
        shared.prepare(&basis, &[(&g, &lights)], &options).unwrap();
        let prepared = estimate_views_shared(&basis, &view, &options, &shared).unwrap();
        assert_eq!(alone.solution.coefficients, prepared.solution.coefficients);
        assert_eq!(alone.brdf.values, prepared.brdf.values);
        assert_eq!(alone.fit_error.to_bits(), prepared.fit_error.to_bits());
        assert_eq!(prepared.timings.prepared, uses_them);
        assert!(!alone.timings.prepared);
    }
}

/// The hybrid fit takes its lobes' rows from the roughness search's renders: they are the
/// rows a pass of Lambert and the found lobes alone gives, in its layout (row 3·p + c;
/// Lambert, then each lobe's F₀ and F₉₀). A sharp lobe may read, beside the search's
/// sharper ones, cap rings it would leave out alone (below 0.2% of its light).
#[test]
fn the_roughness_search_s_rows_are_its_lobes_rendered() {
    use brdfd_core::analytic::{columns, lambert_column, roughnesses, ViewPixels};
    use brdfd_core::render::RenderingMatrix;
    use brdfd_core::stop::Stop;
    let grid = Basis::embedded().header.grid;
    let g = sphere(40);
    let lights = studio_envmap(128).compressed(1024, 0.0);
    for material in ["gold-metallic-paint", "chrome-steel"] {
        let truth = Bivariate::reduce(embedded_materials().get(material).unwrap(), grid);
        let photo = render_bivariate(&g, &lights, &truth);
        let observed: Vec<[f64; 3]> = g
            .pixels
            .iter()
            .map(|p| photo.get(p.x as usize, p.y as usize).map(f64::from))
            .collect();
        let views = [ViewPixels {
            pixels: &g.pixels,
            observed: &observed,
            lights: &lights,
        }];
        let found = roughnesses(&views, grid, 2, None, None, &Stop::default()).unwrap();
        let lobes: Vec<[Vec<f64>; 3]> =
            found.lobes.iter().map(|(a, _)| columns(grid, *a)).collect();
        let lambert = lambert_column(grid);
        let mut cols: Vec<&[f64]> = vec![&lambert];
        for l in &lobes {
            cols.extend([l[1].as_slice(), l[2].as_slice()]);
        }
        // Fewer candidates than the search takes: every pixel is a search pixel.
        let alone = RenderingMatrix::build(&g.pixels, &lights, &cols, None, grid.theta_h_binning);
        let m = cols.len();
        assert_eq!(found.rows.len(), alone.rows.len(), "{material}");
        for j in 0..m {
            let (mut d2, mut r2) = (0.0, 0.0);
            for (a, b) in found
                .rows
                .iter()
                .skip(j)
                .step_by(m)
                .zip(alone.rows.iter().skip(j).step_by(m))
            {
                d2 += (a - *b as f64).powi(2);
                r2 += (*b as f64).powi(2);
            }
            let e = (d2 / r2.max(f64::MIN_POSITIVE)).sqrt();
            assert!(e < 0.002, "{material}: column {j} differs by {e}");
        }
    }
}

/// Issue 40: a stop requested of an estimate ends each model's with `CoreError::Stopped`,
/// whose words ("cancelled") are what a capture records as its cancel; a stop requested
/// after the work is no error; and the MERL renderer (the simulated camera's) stops too.
#[test]
fn a_requested_stop_ends_every_models_estimate_and_the_render() {
    use brdfd_core::render::render_merl_until;
    use brdfd_core::stop::Stop;
    use brdfd_core::CoreError;
    let g = sphere(32);
    let lights = studio_envmap(128).compressed(512, 0.0);
    let table = MerlBrdf::tabulate(embedded_materials().get("gold-metallic-paint").unwrap());
    let photo = render_merl(&g, &lights, &table);
    let basis = Basis::embedded();
    for model in [Model::Basis, Model::Analytic, Model::Hybrid] {
        let options = EstimateOptions {
            model: ModelOptions::of(model),
            ..EstimateOptions::default()
        };
        options.stop.request();
        let stopped = estimate(&basis, one_view(&g, &lights, &photo), &options);
        assert!(
            matches!(stopped, Err(CoreError::Stopped)),
            "{model:?}: {:?}",
            stopped.map(|e| e.fit_error)
        );
        assert_eq!(CoreError::Stopped.to_string(), "cancelled");
    }
    // Requested from another thread while the estimate runs (the hybrid fit of a 48² sphere
    // under 2,048 lights takes far longer than the 50 ms it is given).
    let big = sphere(48);
    let many = studio_envmap(256).compressed(2048, 0.0);
    let big_photo = render_merl(&big, &many, &table);
    let options = EstimateOptions::default();
    let stop = options.stop.clone();
    let asking = std::thread::spawn(move || {
        std::thread::sleep(std::time::Duration::from_millis(50));
        stop.request();
    });
    let stopped = estimate(&basis, one_view(&big, &many, &big_photo), &options);
    asking.join().unwrap();
    assert!(
        matches!(stopped, Err(CoreError::Stopped)),
        "stopped part-way: {:?}",
        stopped.map(|e| e.fit_error)
    );

    let stop = Stop::default();
    let done = render_merl_until(&g, &lights, &table, &stop).unwrap();
    assert_eq!(done.pixels, photo.pixels);
    stop.request();
    assert!(matches!(
        render_merl_until(&g, &lights, &table, &stop),
        Err(CoreError::Stopped)
    ));
}
