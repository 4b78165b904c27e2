//! The evaluation protocol of docs/evaluation.md, made runnable: `brdfd eval`.
//!
//! - Materials: the 100 MERL materials as NBRDF fits, tabulated to full (θh, θd, φd) tables, so
//!   the bivariate approximation counts as error. Test set [`TEST_SET`]; training: the other 90.
//! - Scene: unit sphere, orthographic camera, `size`² pixels. Ground truth is rendered from the
//!   full table with [`GT_LIGHTS`] lights; estimates use the default compression
//!   ([`DEFAULT_LIGHTS`]), so compression error counts too, as it would for a real photo.
//! - Pixel counts 5, 10, 20 and all; noise-free and with sensor noise (`add_sensor_noise`).
//! - Errors: BRDF error = ‖w⊙(f̂ − f)‖ / ‖w⊙f‖ over the bivariate grid in the basis's cell
//!   weighting (the "normalised" BRDF of the paper: each material relative to its own scale);
//!   image error = relative RMSE of the re-render against the ground-truth image.
//! - Leave-one-out over all 100 materials (basis from the other 99), and a second lighting.
//! - Four methods: the paper's least squares, ours with the training set's prior, the prior
//!   with one set of coefficients per colour channel, and brdfd's default, which keeps the
//!   prior's joint or per-channel estimate, whichever fits the photo better ([`METHODS`]).
//!
//! Every estimate runs through the estimate's own pipeline (`estimate_views_shared`, as
//! `brdfd estimate` does). Selection depends only on the basis, the lights and the geometry,
//! not on the material, so the estimates of one lighting share it (`Shared`): it runs once
//! per lighting, pixel count and colour model, as it would before a real measurement.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use rand::SeedableRng;
use rand_distr::{Distribution, Poisson};

use crate::{OnProgress, Progress};
use brdfd_core::basis::channel_coefficients;
use brdfd_core::basis::{Basis, CellWeight, Normalisation, DEFAULT_K};
use brdfd_core::bivariate::{Bivariate, Grid, GRID_CELLS};
use brdfd_core::envmap::{EnvMap, LightSet, CHOSEN_LIGHTS, DEFAULT_LIGHTS};
use brdfd_core::error::{CoreError, Result};
use brdfd_core::estimate::{
    estimate_views_shared, BasisOptions, EstimateOptions, ModelOptions, SelectionMethod, Shared,
    View,
};
use brdfd_core::geometry::{Camera, PixelGeometry, Shape};
use brdfd_core::merl::MerlBrdf;
use brdfd_core::nbrdf::NbrdfSet;
use brdfd_core::raster::Raster;
use brdfd_core::render::{render_bivariate, render_merl, RenderingMatrix};
use brdfd_core::solve::{ColourChoice, Solver};

pub const TEST_SET: [&str; 10] = [
    "black-soft-plastic",
    "nickel",
    "blue-metallic-paint",
    "gold-metallic-paint",
    "blue-fabric",
    "chrome-steel",
    "green-latex",
    "red-specular-plastic",
    "white-paint",
    "pearl-paint",
];

/// Lights for ground-truth images: four times the estimate's, so the estimate's own compression
/// shows up as error. Measured against every map pixel as a light (`--choices`), these renders
/// change by 0.4% (grace) and 1.3% (courtyard) on average.
pub const GT_LIGHTS: usize = 16_384;
/// Pixel counts of the paper's Fig. 5 (`None` = all pixels).
pub const PIXEL_COUNTS: [Option<usize>; 4] = [Some(5), Some(10), Some(20), None];
/// Sensor model for the noisy runs: full-well capacity in electrons at the 12-bit white point.
pub const FULL_WELL_ELECTRONS: f64 = 20_000.0;
pub const ADC_LEVELS: f64 = 4095.0;
/// The image percentile placed at the sensor's white point (a photographer exposes so that
/// only specular glints clip).
pub const EXPOSURE_PERCENTILE: f64 = 0.995;
/// Image size of the leave-one-out runs (100 ground-truth renders).
pub const LOO_SIZE: usize = 128;
/// How an estimate is solved: the solver and the colour model.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Method {
    pub solver: Solver,
    pub colour: ColourChoice,
}

impl Method {
    /// `least-squares`, `prior`, `prior-per-channel`, `prior-auto`: the name in tables, CSV
    /// and file names.
    pub fn name(self) -> String {
        match self.colour {
            ColourChoice::Joint => self.solver.name().to_string(),
            other => format!("{}-{}", self.solver.name(), other.name()),
        }
    }

    /// The estimate's settings for this method with `pixels`: the basis model, with the
    /// protocol's fast selection. The paper's method solves unconstrained, as published; the
    /// others keep the BRDF ≥ 0 in every cell, as `brdfd estimate` does.
    pub fn options(self, pixels: Option<usize>, white: Option<f32>) -> EstimateOptions {
        EstimateOptions {
            model: ModelOptions::Basis(BasisOptions {
                pixel_count: pixels,
                method: SelectionMethod::Fast,
                solver: self.solver,
                colour: self.colour,
                nonnegative: self != METHODS[0],
                ..BasisOptions::default()
            }),
            white,
            checks: false,
            ..EstimateOptions::default()
        }
    }
}

/// The methods compared, the paper's first.
pub const METHODS: [Method; 4] = [
    Method {
        solver: Solver::LeastSquares,
        colour: ColourChoice::Joint,
    },
    Method {
        solver: Solver::Prior,
        colour: ColourChoice::Joint,
    },
    Method {
        solver: Solver::Prior,
        colour: ColourChoice::PerChannel,
    },
    // brdfd's basis default: the prior's joint or per-channel estimate, whichever re-renders
    // the photo better.
    Method {
        solver: Solver::Prior,
        colour: ColourChoice::Auto,
    },
];

pub struct EvalConfig {
    pub data: PathBuf,
    pub out: PathBuf,
    pub size: usize,
    pub leave_one_out: bool,
    pub choices: bool,
    /// Principal components of the basis the protocol estimates with ([`DEFAULT_K`], the
    /// paper's, unless told otherwise).
    pub k: usize,
}

/// One row of the results table.
#[derive(Clone, Debug)]
pub struct Row {
    pub lighting: String,
    pub material: String,
    pub pixels: Option<usize>,
    pub method: Method,
    pub noisy: bool,
    pub brdf_error: f64,
    pub image_error: f64,
    pub condition: f64,
}

/// Shot noise (Poisson in electrons) and 12-bit quantisation, with the exposure set so the
/// [`EXPOSURE_PERCENTILE`] of the object's values reaches the white point. Clipped values stay
/// clipped, as on a real sensor, at exactly the returned white level, which the estimate is
/// told (as `brdfd estimate` knows an 8-bit photo's): clipped pixels are lower bounds only.
pub(crate) fn add_sensor_noise(img: &Raster, seed: u64) -> (Raster, Option<f32>) {
    let mut values: Vec<f32> = img
        .pixels
        .iter()
        .flat_map(|p| p.iter().copied())
        .filter(|v| *v > 0.0)
        .collect();
    if values.is_empty() {
        return (img.clone(), None);
    }
    let k = ((values.len() as f64 * EXPOSURE_PERCENTILE) as usize).min(values.len() - 1);
    let (_, white, _) = values.select_nth_unstable_by(k, f32::total_cmp);
    let white = *white;
    let electrons_per_unit = FULL_WELL_ELECTRONS / white as f64;
    let electrons_per_dn = FULL_WELL_ELECTRONS / ADC_LEVELS;
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let mut out = img.clone();
    for p in out.pixels.iter_mut() {
        for v in p.iter_mut() {
            if *v <= 0.0 {
                continue;
            }
            let mean = *v as f64 * electrons_per_unit;
            let e = Poisson::new(mean)
                .map(|d| d.sample(&mut rng))
                .unwrap_or(mean);
            let dn = (e / electrons_per_dn).round().clamp(0.0, ADC_LEVELS);
            *v = if dn >= ADC_LEVELS {
                white
            } else {
                (dn * electrons_per_dn / electrons_per_unit) as f32
            };
        }
    }
    (out, Some(white))
}

/// ‖w⊙(a − b)‖ / ‖w⊙b‖ over the grid, with the basis's cell weights.
pub fn brdf_error(estimate: &Bivariate, truth: &Bivariate, weight: CellWeight) -> f64 {
    let w = weight.weights(truth.grid);
    let (mut num, mut den) = (0.0, 0.0);
    for i in 0..estimate.values.len() {
        let wi = w[i % GRID_CELLS];
        num += (wi * (estimate.values[i] - truth.values[i])).powi(2);
        den += (wi * truth.values[i]).powi(2);
    }
    (num / den.max(f64::MIN_POSITIVE)).sqrt()
}

/// A lighting with its discretisations: the ground truth's, the estimate's candidate rows',
/// and the estimate's chosen rows'.
pub(crate) struct Lighting {
    pub(crate) gt: LightSet,
    pub(crate) est: LightSet,
    pub(crate) chosen: LightSet,
}

pub(crate) fn load_lighting(data: &Path, name: &str) -> Result<Lighting> {
    let map = EnvMap::load(&data.join("envmaps").join(format!("{name}.hdr")))?;
    let mut levels = map.compressed_levels(&[DEFAULT_LIGHTS, GT_LIGHTS, CHOSEN_LIGHTS], 0.0);
    let chosen = levels.pop().expect("three levels");
    let gt = levels.pop().expect("three levels");
    Ok(Lighting {
        gt,
        est: levels.pop().expect("three levels"),
        chosen,
    })
}

/// A material's ground truth: full table, its bivariate reduction.
struct Truth {
    name: String,
    table: MerlBrdf,
    bivariate: Bivariate,
}

/// The default basis settings (the measured choice; see docs/evaluation.md) with `k` components.
pub(crate) fn default_basis(training: &[(String, Bivariate)], k: usize) -> Result<Basis> {
    Basis::build(
        training,
        k,
        Normalisation::Rms,
        CellWeight::SolidAngle,
        true,
    )
}

/// One scene of the protocol: the sphere under one lighting, with the work its estimates
/// share (each selection is made once per lighting, as in the paper).
struct Scene<'s> {
    geometry: &'s PixelGeometry,
    lighting: &'s Lighting,
    /// The basis's rows for every object pixel under the estimate's lights, to re-render an
    /// estimate (A·c) without rendering again. The estimates share it too ([`Shared::seed`]):
    /// with nothing clipped, every object pixel is a candidate.
    a: std::sync::Arc<RenderingMatrix>,
    shared: Shared,
}

impl<'s> Scene<'s> {
    fn new(basis: &Basis, geometry: &'s PixelGeometry, lighting: &'s Lighting) -> Scene<'s> {
        let a = std::sync::Arc::new(basis.rendering_matrix(&geometry.pixels, &lighting.est));
        let shared = Shared::default();
        shared.seed(basis, &geometry.pixels, &lighting.est, a.clone());
        Scene {
            geometry,
            lighting,
            a,
            shared,
        }
    }
}

/// The image of `y`, A's prediction (A·c, 3 values a pixel) for some coefficients: A covers
/// every object pixel, so this is the re-render under the estimate's lights, without
/// rendering again.
fn predicted_image(a: &RenderingMatrix, y: &[f64], width: usize, height: usize) -> Raster {
    let mut img = Raster::black(width, height);
    for (p, px) in a.pixels.iter().enumerate() {
        img.set(
            px.x as usize,
            px.y as usize,
            [y[3 * p] as f32, y[3 * p + 1] as f32, y[3 * p + 2] as f32],
        );
    }
    img
}

/// One estimate: pixel count, method, reconstructed BRDF, its re-render, condition number.
type Outcome = (Option<usize>, Method, Bivariate, Raster, f64);

/// Estimates from `photo` with every pixel count and method, each by the estimate's own
/// pipeline ([`estimate_views_shared`]). Pixels with a channel at the photo's `white` level
/// are not candidates, as for `brdfd estimate`.
fn estimate_all(
    basis: &Basis,
    scene: &Scene,
    photo: &Raster,
    white: Option<f32>,
) -> Result<Vec<Outcome>> {
    let view = View {
        geometry: scene.geometry,
        lights: &scene.lighting.est,
        chosen_lights: Some(&scene.lighting.chosen),
        photo,
    };
    let mut out = Vec::new();
    for method in METHODS {
        for l in PIXEL_COUNTS {
            let est = estimate_views_shared(
                basis,
                std::slice::from_ref(&view),
                &method.options(l, white),
                &scene.shared,
            )?;
            let per_channel = channel_coefficients(&est.solution.coefficients, scene.a.columns)?;
            let predicted = scene.a.predict_per_channel(per_channel);
            let img = predicted_image(&scene.a, &predicted, photo.width, photo.height);
            let condition = est.condition();
            out.push((l, method, est.brdf, img, condition));
        }
    }
    Ok(out)
}

fn method_index(m: Method) -> usize {
    METHODS.iter().position(|x| *x == m).unwrap_or(0)
}

/// File-name suffix: none for the paper's method, so its figures keep their names.
fn suffix(m: Method) -> String {
    if m == METHODS[0] {
        String::new()
    } else {
        format!("-{}", m.name())
    }
}

fn label(l: Option<usize>) -> String {
    l.map_or("all".into(), |n| n.to_string())
}

/// Runs the protocol, writes `results.csv`, `results.md`, `fig5-*.svg`, `fig6-*.svg` and
/// (unless disabled) `loo.csv`; returns the Markdown report.
pub fn run(cfg: &EvalConfig, progress: OnProgress) -> Result<String> {
    let t0 = Instant::now();
    progress(Progress {
        stage: "preparing",
        item: "reading the measured materials and building the basis",
        index: 1,
        total: 1,
    });
    std::fs::create_dir_all(&cfg.out).map_err(|e| CoreError::io(&cfg.out, e))?;
    let nbrdf_path = cfg.data.join("merl-nbrdf").join("merl_nbrdf.json");
    let set = NbrdfSet::read(&nbrdf_path)?;
    let grid = Grid::default();
    let reduced: Vec<(String, Bivariate)> = set
        .materials
        .iter()
        .map(|(n, m)| (n.clone(), Bivariate::reduce(m, grid)))
        .collect();
    let training: Vec<(String, Bivariate)> = reduced
        .iter()
        .filter(|(n, _)| !TEST_SET.contains(&n.as_str()))
        .cloned()
        .collect();
    let basis = default_basis(&training, cfg.k)?;
    let geometry =
        PixelGeometry::rasterize(&Camera::eval_orthographic(cfg.size), &Shape::unit_sphere())?;
    let truths: Vec<Truth> = TEST_SET
        .iter()
        .map(|n| {
            let table = MerlBrdf::tabulate(set.get(n)?);
            let bivariate = Bivariate::reduce(&table, grid);
            Ok(Truth {
                name: n.to_string(),
                table,
                bivariate,
            })
        })
        .collect::<Result<_>>()?;

    let mut rows = Vec::new();
    let mut floors = Vec::new();
    // Per material, per method: ground truth, then the estimates' re-renders.
    let mut fig6: Vec<(String, Vec<Vec<Raster>>)> = Vec::new();
    for light_name in ["grace", "courtyard"] {
        let lighting = load_lighting(&cfg.data, light_name)?;
        let scene = Scene::new(&basis, &geometry, &lighting);
        let stage = format!("the paper's protocol under {light_name}");
        for (i, truth) in truths.iter().enumerate() {
            progress(Progress {
                stage: &stage,
                item: &truth.name,
                index: i + 1,
                total: truths.len(),
            });
            let gt = render_merl(&geometry, &lighting.gt, &truth.table);
            let floor =
                render_bivariate(&geometry, &lighting.est, &truth.bivariate).relative_rmse(&gt);
            floors.push((light_name.to_string(), truth.name.clone(), floor));
            let mut renders: Vec<Vec<Raster>> = METHODS.iter().map(|_| vec![gt.clone()]).collect();
            for noisy in [false, true] {
                let (photo, white) = if noisy {
                    add_sensor_noise(&gt, 1000 + i as u64)
                } else {
                    (gt.clone(), None)
                };
                for (l, method, est, re, cond) in estimate_all(&basis, &scene, &photo, white)? {
                    rows.push(Row {
                        lighting: light_name.into(),
                        material: truth.name.clone(),
                        pixels: l,
                        method,
                        noisy,
                        brdf_error: brdf_error(&est, &truth.bivariate, basis.header.cell_weight),
                        image_error: re.relative_rmse(&gt),
                        condition: cond,
                    });
                    if !noisy && light_name == "grace" {
                        renders[method_index(method)].push(re);
                    }
                }
            }
            if light_name == "grace" {
                fig6.push((truth.name.clone(), renders));
            }
        }
        for method in METHODS {
            write_fig5(
                &cfg.out
                    .join(format!("fig5-{light_name}{}.svg", suffix(method))),
                &rows,
                light_name,
                method,
            )?;
        }
    }
    for method in METHODS {
        let per_method: Vec<(String, Vec<Raster>)> = fig6
            .iter()
            .map(|(n, r)| (n.clone(), r[method_index(method)].clone()))
            .collect();
        write_fig6(
            &cfg.out.join(format!("fig6-grace{}.svg", suffix(method))),
            &per_method,
            method,
        )?;
    }
    write_csv(&cfg.out.join("results.csv"), &rows)?;

    let loo = if cfg.leave_one_out {
        Some(leave_one_out(cfg, &set, &reduced, progress)?)
    } else {
        None
    };
    let choices = if cfg.choices {
        Some(measure_choices(cfg, &set, &reduced, progress)?)
    } else {
        None
    };
    let report = markdown(
        &rows,
        &floors,
        loo.as_deref(),
        choices.as_deref(),
        cfg,
        t0.elapsed().as_secs_f64(),
    );
    std::fs::write(cfg.out.join("results.md"), &report)
        .map_err(|e| CoreError::io(cfg.out.join("results.md"), e))?;
    Ok(report)
}

/// Leave-one-out over all materials, under grace, at [`LOO_SIZE`], with each method: image and
/// BRDF error at 20 pixels and with all pixels.
fn leave_one_out(
    cfg: &EvalConfig,
    set: &NbrdfSet,
    reduced: &[(String, Bivariate)],
    progress: OnProgress,
) -> Result<String> {
    let lighting = load_lighting(&cfg.data, "grace")?;
    let geometry =
        PixelGeometry::rasterize(&Camera::eval_orthographic(LOO_SIZE), &Shape::unit_sphere())?;
    let mut csv = String::from(
        "material,method,image_error_20,image_error_all,brdf_error_20,brdf_error_all\n",
    );
    // Per method: (image error at 20, with all, BRDF error at 20, with all) per material.
    let mut per_method: Vec<Vec<[f64; 4]>> = METHODS.iter().map(|_| Vec::new()).collect();
    for (i, (name, truth_biv)) in reduced.iter().enumerate() {
        progress(Progress {
            stage: "leave-one-out",
            item: name,
            index: i + 1,
            total: reduced.len(),
        });
        let others: Vec<(String, Bivariate)> =
            reduced.iter().filter(|(n, _)| n != name).cloned().collect();
        let basis = default_basis(&others, cfg.k)?;
        let scene = Scene::new(&basis, &geometry, &lighting);
        let gt = render_merl(&geometry, &lighting.gt, &MerlBrdf::tabulate(set.get(name)?));
        // (image error, BRDF error) per method, at 20 pixels and with all.
        let mut twenty = [(0.0, 0.0); METHODS.len()];
        let mut all = twenty;
        for (l, method, est, re, _) in estimate_all(&basis, &scene, &gt, None)? {
            let errors = (
                re.relative_rmse(&gt),
                brdf_error(&est, truth_biv, basis.header.cell_weight),
            );
            match l {
                Some(20) => twenty[method_index(method)] = errors,
                None => all[method_index(method)] = errors,
                _ => {}
            }
        }
        for (mi, method) in METHODS.iter().enumerate() {
            let e = [twenty[mi].0, all[mi].0, twenty[mi].1, all[mi].1];
            let _ = writeln!(
                csv,
                "{name},{},{:.5},{:.5},{:.5},{:.5}",
                method.name(),
                e[0],
                e[1],
                e[2],
                e[3]
            );
            per_method[mi].push(e);
        }
    }
    std::fs::write(cfg.out.join("loo.csv"), &csv)
        .map_err(|e| CoreError::io(cfg.out.join("loo.csv"), e))?;
    let mut s = format!("Leave-one-out over {} materials (grace, {LOO_SIZE}², basis of K = {} from the other 99, noise-free). Per material: `loo.csv`.\n\n| method | image error, 20 px | image error, all px | BRDF error, 20 px | BRDF error, all px | 20 px within 10% of all (image) | (BRDF) |\n|---|---|---|---|---|---|---|\n", reduced.len(), cfg.k);
    for (method, rows) in METHODS.iter().zip(&per_method) {
        let col = |i: usize| rows.iter().map(|r| r[i]).collect::<Vec<f64>>();
        let within = |a: usize, b: usize| rows.iter().filter(|r| r[a] <= r[b] * 1.1).count();
        let _ = writeln!(
            s,
            "| {} | {:.3} | {:.3} | {:.3} | {:.3} | {} of {} | {} of {} |",
            method.name(),
            median(&col(0)),
            median(&col(1)),
            median(&col(2)),
            median(&col(3)),
            within(0, 1),
            rows.len(),
            within(2, 3),
            rows.len()
        );
    }
    s.push_str("\nMedians over the materials.\n");
    Ok(s)
}

/// Measures the grid and normalisation choices: (a) how far each bivariate grid renders from the
/// full BRDF; (b) how much light compression changes renders ([`measure_compression`]);
/// (c) image error of all-pixel and 20-pixel estimates for each basis variant.
fn measure_choices(
    cfg: &EvalConfig,
    set: &NbrdfSet,
    reduced: &[(String, Bivariate)],
    progress: OnProgress,
) -> Result<String> {
    use brdfd_core::bivariate::{PhiReduction, ThetaHBinning};
    let size = LOO_SIZE;
    let lighting = load_lighting(&cfg.data, "grace")?;
    let geometry =
        PixelGeometry::rasterize(&Camera::eval_orthographic(size), &Shape::unit_sphere())?;
    let tables: Vec<(String, MerlBrdf, Raster)> = TEST_SET
        .iter()
        .map(|n| {
            let t = MerlBrdf::tabulate(set.get(n)?);
            let gt = render_merl(&geometry, &lighting.gt, &t);
            Ok((n.to_string(), t, gt))
        })
        .collect::<Result<_>>()?;
    let mut out = String::from("| grid (θh binning, φd reduction) | mean image error of the bivariate reduction |\n|---|---|\n");
    for binning in [ThetaHBinning::Sqrt, ThetaHBinning::Uniform] {
        for phi in [PhiReduction::ValidMean, PhiReduction::Slice90] {
            let grid = Grid {
                theta_h_binning: binning,
                phi_reduction: phi,
            };
            let errs: Vec<f64> = tables
                .iter()
                .map(|(_, t, gt)| {
                    render_bivariate(&geometry, &lighting.gt, &Bivariate::reduce(t, grid))
                        .relative_rmse(gt)
                })
                .collect();
            let _ = writeln!(out, "| {binning:?}, {phi:?} | {:.4} |", mean(&errs));
        }
    }
    out.push_str(&measure_compression(cfg, set)?);
    out.push_str("\n| normalisation | cell weight | mean term | mean image error, all pixels | mean image error, 20 pixels | mean BRDF error, all pixels |\n|---|---|---|---|---|---|\n");
    let training: Vec<(String, Bivariate)> = reduced
        .iter()
        .filter(|(n, _)| !TEST_SET.contains(&n.as_str()))
        .cloned()
        .collect();
    let variants = [
        (Normalisation::Rms, CellWeight::SolidAngle, true),
        (Normalisation::Rms, CellWeight::None, true),
        (Normalisation::Rms, CellWeight::SolidAngle, false),
        (Normalisation::None, CellWeight::SolidAngle, true),
        (Normalisation::None, CellWeight::None, true),
    ];
    for (i, (norm, weight, with_mean)) in variants.into_iter().enumerate() {
        let item = format!("{norm:?} normalisation, {weight:?} cell weight, mean {with_mean}");
        progress(Progress {
            stage: "the basis's choices",
            item: &item,
            index: i + 1,
            total: variants.len(),
        });
        let basis = Basis::build(&training, DEFAULT_K, norm, weight, with_mean)?;
        let scene = Scene::new(&basis, &geometry, &lighting);
        let (mut all, mut twenty, mut brdf) = (Vec::new(), Vec::new(), Vec::new());
        for (name, _, gt) in &tables {
            let truth = reduced_of(reduced, name);
            for (l, method, est, re, _) in estimate_all(&basis, &scene, gt, None)? {
                // The basis choices were measured with the paper's method.
                if method != METHODS[0] {
                    continue;
                }
                let e = re.relative_rmse(gt);
                match l {
                    Some(20) => twenty.push(e),
                    None => {
                        all.push(e);
                        brdf.push(brdf_error(&est, truth, CellWeight::SolidAngle));
                    }
                    _ => {}
                }
            }
        }
        let _ = writeln!(
            out,
            "| {norm:?} | {weight:?} | {with_mean} | {:.3} | {:.3} | {:.3} |",
            mean(&all),
            mean(&twenty),
            mean(&brdf)
        );
    }
    out.push_str(&measure_k(
        cfg, &geometry, &lighting, &tables, &training, reduced, progress,
    )?);
    Ok(out)
}

/// Principal components compared by [`measure_k`]: the paper's 5 and larger bases.
const K_CHOICES: [usize; 3] = [5, 8, 10];

/// The protocol's medians for each K of [`K_CHOICES`], noise-free, under both lightings and
/// with each method: whether more components than the paper's 5 pay for their extra unknowns.
fn measure_k(
    cfg: &EvalConfig,
    geometry: &PixelGeometry,
    grace_lighting: &Lighting,
    grace: &[(String, MerlBrdf, Raster)],
    training: &[(String, Bivariate)],
    reduced: &[(String, Bivariate)],
    progress: OnProgress,
) -> Result<String> {
    let mut out = String::from("\n| K | lighting | method | image error, 20 px | image error, all px | BRDF error, 20 px | BRDF error, all px | 20 px within 10% of all (BRDF) |\n|---|---|---|---|---|---|---|---|\n");
    let courtyard = load_lighting(&cfg.data, "courtyard")?;
    let courtyard_gt: Vec<Raster> = grace
        .iter()
        .map(|(_, t, _)| render_merl(geometry, &courtyard.gt, t))
        .collect();
    for (i, k) in K_CHOICES.into_iter().enumerate() {
        progress(Progress {
            stage: "the number of components",
            item: &format!("K = {k}"),
            index: i + 1,
            total: K_CHOICES.len(),
        });
        let basis = default_basis(training, k)?;
        for (light_name, lighting, truths) in [
            (
                "grace",
                grace_lighting,
                grace.iter().map(|(_, _, gt)| gt).collect::<Vec<_>>(),
            ),
            ("courtyard", &courtyard, courtyard_gt.iter().collect()),
        ] {
            let scene = Scene::new(&basis, geometry, lighting);
            let mut rows = Vec::new();
            for ((name, _, _), gt) in grace.iter().zip(truths) {
                let truth = reduced_of(reduced, name);
                for (l, method, est, re, cond) in estimate_all(&basis, &scene, gt, None)? {
                    rows.push(Row {
                        lighting: light_name.into(),
                        material: name.clone(),
                        pixels: l,
                        method,
                        noisy: false,
                        brdf_error: brdf_error(&est, truth, basis.header.cell_weight),
                        image_error: re.relative_rmse(gt),
                        condition: cond,
                    });
                }
            }
            for method in METHODS {
                let sel: Vec<&Row> = rows.iter().filter(|r| r.method == method).collect();
                let med = |l, f| median_at(&sel, l, f);
                let _ = writeln!(
                    out,
                    "| {k} | {light_name} | {} | {:.3} | {:.3} | {:.3} | {:.3} | {} of 10 |",
                    method.name(),
                    med(Some(20), |r| r.image_error),
                    med(None, |r| r.image_error),
                    med(Some(20), |r| r.brdf_error),
                    med(None, |r| r.brdf_error),
                    within_ten_percent(&sel, |r| r.brdf_error),
                );
            }
        }
    }
    Ok(out)
}

/// Size of the sphere for [`measure_compression`]: its reference renders every map pixel as a
/// light (half a million), so it is kept small.
const COMPRESSION_SIZE: usize = 32;

/// How far renders with compressed lights are from renders with every pixel of the map as a
/// light, for the uniform grid earlier versions used and for the adaptive compression.
fn measure_compression(cfg: &EvalConfig, set: &NbrdfSet) -> Result<String> {
    let geometry = PixelGeometry::rasterize(
        &Camera::eval_orthographic(COMPRESSION_SIZE),
        &Shape::unit_sphere(),
    )?;
    let mut out = String::from(
        "\n| lighting | lights | mean image change | largest (material) |\n|---|---|---|---|\n",
    );
    for light_name in ["grace", "courtyard"] {
        let map = EnvMap::load(&cfg.data.join("envmaps").join(format!("{light_name}.hdr")))?;
        let full = map.lights(0.0);
        let grid_rows = ((DEFAULT_LIGHTS as f64 / 2.0).sqrt().round()) as usize;
        let variants = [
            (
                format!("uniform grid, {}", 2 * grid_rows * grid_rows),
                map.downsample(2 * grid_rows, grid_rows).lights(0.0),
            ),
            (
                format!("adaptive, {DEFAULT_LIGHTS} (estimates)"),
                map.compressed(DEFAULT_LIGHTS, 0.0),
            ),
            (
                format!("adaptive, {GT_LIGHTS} (ground truth)"),
                map.compressed(GT_LIGHTS, 0.0),
            ),
        ];
        let mut errors = vec![Vec::new(); variants.len()];
        for name in TEST_SET {
            let table = MerlBrdf::tabulate(set.get(name)?);
            let reference = render_merl(&geometry, &full, &table);
            for (e, (_, lights)) in errors.iter_mut().zip(&variants) {
                e.push((
                    render_merl(&geometry, lights, &table).relative_rmse(&reference),
                    name,
                ));
            }
        }
        for (e, (label, _)) in errors.iter().zip(&variants) {
            let values: Vec<f64> = e.iter().map(|(v, _)| *v).collect();
            let (worst, name) = e
                .iter()
                .copied()
                .fold((0.0, ""), |a, b| if b.0 > a.0 { b } else { a });
            let _ = writeln!(
                out,
                "| {light_name} | {label} | {:.3} | {worst:.3} ({name}) |",
                mean(&values)
            );
        }
    }
    Ok(out)
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    if s.is_empty() {
        return f64::NAN;
    }
    s[s.len() / 2]
}

fn write_csv(path: &Path, rows: &[Row]) -> Result<()> {
    let mut s =
        String::from("lighting,material,pixels,method,noise,brdf_error,image_error,condition\n");
    for r in rows {
        let _ = writeln!(
            s,
            "{},{},{},{},{},{:.5},{:.5},{:.3}",
            r.lighting,
            r.material,
            label(r.pixels),
            r.method.name(),
            if r.noisy { "sensor" } else { "none" },
            r.brdf_error,
            r.image_error,
            r.condition
        );
    }
    std::fs::write(path, s).map_err(|e| CoreError::io(path, e))
}

fn markdown(
    rows: &[Row],
    floors: &[(String, String, f64)],
    loo: Option<&str>,
    choices: Option<&str>,
    cfg: &EvalConfig,
    secs: f64,
) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "Sphere {0}×{0}, orthographic; ground truth from the full 3D table with {GT_LIGHTS} lights; estimates with {DEFAULT_LIGHTS} lights for every candidate and {CHOSEN_LIGHTS} for the chosen pixels' rows, K = {1}, fast selection. Run time {secs:.0} s.\n", cfg.size, cfg.k);
    s.push_str(&summary(rows));
    for method in METHODS {
        for lighting in ["grace", "courtyard"] {
            for noisy in [false, true] {
                let _ = writeln!(
                    s,
                    "**{lighting}, {}, {}** — image relative RMSE (BRDF error in parentheses)\n",
                    if noisy {
                        "sensor noise (shot + 12-bit)"
                    } else {
                        "noise-free"
                    },
                    method.name()
                );
                s.push_str(
                "| material | 5 px | 10 px | 20 px | all px | floor |\n|---|---|---|---|---|---|\n",
            );
                for m in TEST_SET {
                    let _ = write!(s, "| {m} |");
                    for l in PIXEL_COUNTS {
                        if let Some(r) = rows.iter().find(|r| {
                            r.lighting == lighting
                                && r.material == m
                                && r.pixels == l
                                && r.noisy == noisy
                                && r.method == method
                        }) {
                            let _ = write!(s, " {:.3} ({:.3}) |", r.image_error, r.brdf_error);
                        }
                    }
                    let floor = floors
                        .iter()
                        .find(|f| f.0 == lighting && f.1 == m)
                        .map_or(f64::NAN, |f| f.2);
                    let _ = writeln!(s, " {floor:.3} |");
                }
                let sel: Vec<&Row> = rows
                    .iter()
                    .filter(|r| r.lighting == lighting && r.noisy == noisy && r.method == method)
                    .collect();
                let _ = write!(s, "| **median** |");
                for l in PIXEL_COUNTS {
                    let im: Vec<f64> = sel
                        .iter()
                        .filter(|r| r.pixels == l)
                        .map(|r| r.image_error)
                        .collect();
                    let br: Vec<f64> = sel
                        .iter()
                        .filter(|r| r.pixels == l)
                        .map(|r| r.brdf_error)
                        .collect();
                    let _ = write!(s, " {:.3} ({:.3}) |", median(&im), median(&br));
                }
                let within = within_ten_percent(&sel, |r| r.brdf_error);
                let _ = writeln!(s, " |\n\n20 pixels within 10% of the all-pixel BRDF error: {within} of 10 materials.\n");
            }
        }
    }
    s.push_str("Floor: the image error of the material's own bivariate reduction rendered with the estimate's lights — the best any K, any pixel choice could do.\n\n");
    if let Some(l) = loo {
        s.push_str(l);
        s.push('\n');
    }
    if let Some(c) = choices {
        s.push_str("\n### Measured choices\n\n");
        s.push_str(c);
    }
    s
}

/// Test materials whose 20-pixel error is at most 1.1 times their all-pixel error.
fn within_ten_percent(rows: &[&Row], error: impl Fn(&Row) -> f64) -> usize {
    TEST_SET
        .iter()
        .filter(|m| {
            let get = |l| {
                rows.iter()
                    .find(|r| r.material == **m && r.pixels == l)
                    .map(|r| error(r))
            };
            matches!((get(Some(20)), get(None)), (Some(a), Some(b)) if a <= b * 1.1)
        })
        .count()
}

/// A test material's bivariate reduction, by name.
fn reduced_of<'a>(reduced: &'a [(String, Bivariate)], name: &str) -> &'a Bivariate {
    &reduced
        .iter()
        .find(|(n, _)| n == name)
        .expect("every test material is reduced")
        .1
}

/// The median of `f` over the rows with `pixels`.
fn median_at(rows: &[&Row], pixels: Option<usize>, f: fn(&Row) -> f64) -> f64 {
    median(
        &rows
            .iter()
            .filter(|r| r.pixels == pixels)
            .map(|r| f(r))
            .collect::<Vec<f64>>(),
    )
}

/// One line per method, lighting and noise: medians over the test set at 20 pixels and with
/// all, and how many materials meet the paper's claim.
fn summary(rows: &[Row]) -> String {
    let mut s = String::from("| method | lighting | noise | BRDF error, 20 px | BRDF error, all px | image error, 20 px | image error, all px | 20 px within 10% of all (BRDF) | (image) |\n|---|---|---|---|---|---|---|---|---|\n");
    for method in METHODS {
        for lighting in ["grace", "courtyard"] {
            for noisy in [false, true] {
                let sel: Vec<&Row> = rows
                    .iter()
                    .filter(|r| r.lighting == lighting && r.noisy == noisy && r.method == method)
                    .collect();
                let med = |l, f| median_at(&sel, l, f);
                let _ = writeln!(
                    s,
                    "| {} | {lighting} | {} | {:.3} | {:.3} | {:.3} | {:.3} | {} of 10 | {} of 10 |",
                    method.name(),
                    if noisy { "sensor" } else { "none" },
                    med(Some(20), |r| r.brdf_error),
                    med(None, |r| r.brdf_error),
                    med(Some(20), |r| r.image_error),
                    med(None, |r| r.image_error),
                    within_ten_percent(&sel, |r| r.brdf_error),
                    within_ten_percent(&sel, |r| r.image_error),
                );
            }
        }
    }
    s.push('\n');
    s
}

/// Fig. 5: BRDF error against pixel count, one line per test material (in the order of
/// [`TEST_SET`]), as SVG with axes and a legend.
fn write_fig5(path: &Path, rows: &[Row], lighting: &str, method: Method) -> Result<()> {
    let sel: Vec<&Row> = rows
        .iter()
        .filter(|r| r.lighting == lighting && !r.noisy && r.method == method)
        .collect();
    let series: Vec<(String, Vec<Option<f64>>)> = TEST_SET
        .iter()
        .map(|m| {
            let values = PIXEL_COUNTS
                .iter()
                .map(|l| {
                    sel.iter()
                        .find(|r| r.material == *m && r.pixels == *l)
                        .map(|r| r.brdf_error)
                })
                .collect();
            (m.to_string(), values)
        })
        .collect();
    let categories: Vec<String> = PIXEL_COUNTS.iter().map(|l| label(*l)).collect();
    let svg = super::figures::category_lines(
        &format!(
            "Fig. 5: BRDF error against pixels used ({lighting}, {}, no noise)",
            method.name()
        ),
        "pixels used",
        "BRDF error (relative RMSE over the grid)",
        &categories,
        &series,
    )?;
    std::fs::write(path, svg).map_err(|e| CoreError::io(path, e))
}

/// Fig. 6: one row per test material: ground truth, then estimates with 5, 10, 20 and all
/// pixels, each row tone-mapped with the ground truth's exposure, as SVG with labels.
fn write_fig6(path: &Path, rows: &[(String, Vec<Raster>)], method: Method) -> Result<()> {
    let mut columns = vec!["truth".to_string()];
    columns.extend(PIXEL_COUNTS.iter().map(|l| format!("{} pixels", label(*l))));
    let columns: Vec<&str> = columns.iter().map(String::as_str).collect();
    let svg = super::figures::image_grid(
        &format!(
            "Fig. 6: the truth and estimates re-rendered (grace, {})",
            method.name()
        ),
        &columns,
        rows,
    )?;
    std::fs::write(path, svg).map_err(|e| CoreError::io(path, e))
}
