//! The relighting evaluation (`brdfd eval --relight`): an estimate is for rendering a material
//! under other light, so each estimate, made from a photo under one map, is rendered under
//! every other map of the data folder and compared with the ground truth rendered there from
//! the full (θh, θd, φd) BRDF.
//!
//! - Materials: the 10 test materials of [`TEST_SET`] (basis from the other 90), and analytic
//!   GGX materials that brdfd tabulates itself ([`analytic_materials`]), which no basis was
//!   trained on.
//! - Photo: a unit sphere, orthographic, `size`², rendered from the full table under the
//!   capture map with [`GT_LIGHTS`](crate::paper::GT_LIGHTS) lights, with sensor noise (`add_sensor_noise`).
//! - Each method is an [`EstimateOptions`] run through the one estimate pipeline
//!   ([`estimate`]), exactly as `brdfd estimate` runs it.
//! - Measures, per held-out map: relative RMSE of the linear images over the object (as
//!   [`Raster::relative_rmse`]), PSNR of tone-mapped images (`tone_mapped_psnr`), and once
//!   per estimate the cosine-weighted log error of Liu, Fischer & Ritschel 2023
//!   (`log_error`).
//!
//! Everything is seeded: the same data give the same table.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use rand::{Rng, SeedableRng};

use crate::paper::{add_sensor_noise, default_basis, load_lighting, Lighting, TEST_SET};
use crate::{OnProgress, Progress};
use brdfd_core::analytic::Microfacet;
use brdfd_core::bivariate::{Bivariate, Grid};
use brdfd_core::brdf::IsotropicBrdf;
use brdfd_core::error::{CoreError, Result};
use brdfd_core::estimate::{estimate, BasisOptions, EstimateOptions, ModelOptions, View};
use brdfd_core::geometry::{Camera, PixelGeometry, Shape};
use brdfd_core::merl::MerlBrdf;
use brdfd_core::nbrdf::NbrdfSet;
use brdfd_core::raster::{linear_to_srgb, Raster};
use brdfd_core::render::{render_bivariate, render_merl};
use brdfd_core::solve::{ColourChoice, Solver};

/// Directions of the log error's Monte Carlo mean (uniform over both hemispheres): its
/// standard error is below 1% of the error at this count.
const LOG_ERROR_SAMPLES: usize = 200_000;
/// The tone-mapped images are exposed so that the truth's mean is this (middle grey), then
/// mapped by x/(1 + x) and encoded as sRGB, as a viewer would see them.
pub const TONE_MAP_MEAN: f64 = 0.18;

/// The reference row: the truth itself reduced to the (θh, θd) grid every estimate is written
/// on (its mean over φd), relit like an estimate. It shows how much the form alone loses. It
/// is not a bound: an estimate fitted to the photo can relight better than the φd mean does.
pub const REFERENCE: &str = "truth-on-grid";

/// The methods of a leave-one-out run (each of the 100 materials costs a basis build and a
/// full table): the paper's, the analytic baseline and the default.
pub const LEAVE_ONE_OUT_METHODS: [&str; 3] = ["paper", "analytic", "hybrid-2"];

/// A method of the table: a name and the estimate's settings.
pub struct Method {
    pub name: &'static str,
    pub options: EstimateOptions,
}

/// The methods compared: the paper's exactly as published, brdfd's basis defaults at 20 pixels
/// and with every pixel, the analytic model (the baseline) and the hybrid model (the default),
/// each with one and two lobes.
pub fn methods() -> Vec<Method> {
    let basis = |pixel_count, solver, colour, nonnegative| {
        ModelOptions::Basis(BasisOptions {
            pixel_count,
            solver,
            colour,
            nonnegative,
            ..BasisOptions::default()
        })
    };
    let method = |name, model| Method {
        name,
        options: EstimateOptions {
            model,
            ..EstimateOptions::default()
        },
    };
    vec![
        method(
            "paper",
            basis(Some(20), Solver::LeastSquares, ColourChoice::Joint, false),
        ),
        method(
            "basis-20",
            basis(Some(20), Solver::Prior, ColourChoice::Auto, true),
        ),
        method(
            "basis-all",
            basis(None, Solver::Prior, ColourChoice::Auto, true),
        ),
        method("analytic", ModelOptions::Analytic { lobes: 1 }),
        method("analytic-2", ModelOptions::Analytic { lobes: 2 }),
        method("hybrid", ModelOptions::Hybrid { lobes: 1 }),
        method("hybrid-2", ModelOptions::Hybrid { lobes: 2 }),
    ]
}

/// GGX materials tabulated by brdfd, rough to sharp: conductors and plastics.
pub fn analytic_materials() -> Vec<(&'static str, Microfacet)> {
    let conductor = |f0: [f64; 3], alpha| Microfacet::one_lobe([0.0; 3], f0, [1.0; 3], alpha);
    let plastic =
        |diffuse: [f64; 3], alpha| Microfacet::one_lobe(diffuse, [0.04; 3], [1.0; 3], alpha);
    const GOLD: [f64; 3] = [0.95, 0.75, 0.33];
    const STEEL: [f64; 3] = [0.56, 0.57, 0.58];
    const RED: [f64; 3] = [0.5, 0.05, 0.04];
    // Lambert is not dimmed by (1 − F) in this model, so a plastic's diffuse albedo plus its
    // lobe's must stay ≤ 1 at grazing views (checked in the tests): 0.6 leaves room.
    const WHITE: [f64; 3] = [0.6, 0.6, 0.6];
    vec![
        ("ggx-gold-sharp", conductor(GOLD, 0.03)),
        ("ggx-gold-rough", conductor(GOLD, 0.3)),
        ("ggx-steel-mid", conductor(STEEL, 0.1)),
        ("ggx-red-plastic-sharp", plastic(RED, 0.02)),
        ("ggx-red-plastic-rough", plastic(RED, 0.25)),
        ("ggx-white-plastic-mid", plastic(WHITE, 0.08)),
    ]
}

pub struct RelightConfig {
    pub data: PathBuf,
    /// Every MERL material instead of the test set, each estimated with a basis (and measured
    /// materials) built from the other 99, with [`LEAVE_ONE_OUT_METHODS`] only.
    pub leave_one_out: bool,
    pub out: PathBuf,
    pub size: usize,
    /// The maps the photos are taken under; each estimate is relit under every other map.
    pub capture_maps: Vec<String>,
    /// Only these materials (test-set or analytic names); all of them if empty.
    pub materials: Vec<String>,
}

/// One estimate relit under one held-out map.
#[derive(Clone, Debug)]
pub struct Row {
    pub capture: String,
    pub relight: String,
    pub material: String,
    /// Whether the material is one of brdfd's own analytic ones.
    pub analytic: bool,
    pub method: &'static str,
    /// How well the estimate re-renders its own photo (`fit_error`).
    pub fit: f64,
    /// The BRDF's bootstrap spread (`uncertainty.bootstrap_spread`).
    pub spread: f64,
    /// Whether the estimate's summary warns not to trust it (a poor fit, or unsteady).
    pub flagged: bool,
    pub relight_error: f64,
    pub psnr: f64,
    pub log_error: f64,
}

/// The maps of `data/envmaps/` (`.hdr`), sorted by name.
fn map_names(data: &Path) -> Result<Vec<String>> {
    let dir = data.join("envmaps");
    let mut names: Vec<String> = std::fs::read_dir(&dir)
        .map_err(|e| CoreError::io(&dir, e))?
        .filter_map(|e| e.ok())
        .filter_map(|e| {
            let p = e.path();
            (p.extension()? == "hdr").then(|| p.file_stem()?.to_str().map(String::from))?
        })
        .collect();
    names.sort();
    Ok(names)
}

/// PSNR (dB) of the tone-mapped estimate against the tone-mapped truth, over the object: both
/// exposed by the same factor (the truth's mean to [`TONE_MAP_MEAN`]), mapped by x/(1 + x),
/// sRGB-encoded.
pub(crate) fn tone_mapped_psnr(estimate: &Raster, truth: &Raster) -> f64 {
    let object: Vec<usize> = (0..truth.pixels.len())
        .filter(|&i| truth.pixels[i].iter().any(|v| *v != 0.0))
        .collect();
    let mean = object
        .iter()
        .map(|&i| truth.pixels[i].iter().map(|v| *v as f64).sum::<f64>() / 3.0)
        .sum::<f64>()
        / object.len().max(1) as f64;
    let exposure = TONE_MAP_MEAN / mean.max(f64::MIN_POSITIVE);
    let map = |v: f32| {
        let x = (v.max(0.0) as f64 * exposure) as f32;
        linear_to_srgb(x / (1.0 + x)) as f64
    };
    let mut mse = 0.0;
    for &i in &object {
        for c in 0..3 {
            mse += (map(estimate.pixels[i][c]) - map(truth.pixels[i][c])).powi(2);
        }
    }
    mse /= (3 * object.len()).max(1) as f64;
    10.0 * (1.0 / mse.max(1e-12)).log10()
}

/// The cosine-weighted log error of Liu, Fischer & Ritschel 2023: the mean over random
/// direction pairs (uniform on the hemisphere, seeded) and channels of
/// |log(1 + ρ cos θi) − log(1 + ρ̂ cos θi)|.
pub(crate) fn log_error(estimate: &dyn IsotropicBrdf, truth: &dyn IsotropicBrdf, seed: u64) -> f64 {
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let mut hemisphere = || {
        // Uniform in solid angle: cos θ uniform on [0, 1).
        let z: f64 = rng.random_range(0.0..1.0);
        let phi: f64 = rng.random_range(0.0..std::f64::consts::TAU);
        let r = (1.0 - z * z).max(0.0).sqrt();
        [r * phi.cos(), r * phi.sin(), z]
    };
    let mut sum = 0.0;
    for _ in 0..LOG_ERROR_SAMPLES {
        let (wi, wo) = (hemisphere(), hemisphere());
        let (a, b) = (estimate.eval_dirs(wi, wo), truth.eval_dirs(wi, wo));
        for c in 0..3 {
            sum += ((1.0 + a[c].max(0.0) * wi[2]).ln() - (1.0 + b[c] * wi[2]).ln()).abs();
        }
    }
    sum / (3 * LOG_ERROR_SAMPLES) as f64
}

/// A material under test: its name, its full table, and whether it is analytic.
struct Material {
    name: String,
    table: MerlBrdf,
    analytic: bool,
}

/// Runs the relighting evaluation; writes `relight.csv`, `relight.md` and `relight.svg` (the
/// relighting figure) into `out` and returns the Markdown.
pub fn run(cfg: &RelightConfig, progress: OnProgress) -> Result<String> {
    let t0 = std::time::Instant::now();
    progress(Progress {
        stage: "preparing",
        item: "reading the measured materials and building the basis",
        index: 1,
        total: 1,
    });
    std::fs::create_dir_all(&cfg.out).map_err(|e| CoreError::io(&cfg.out, e))?;
    let set = NbrdfSet::read(&cfg.data.join("merl-nbrdf").join("merl_nbrdf.json"))?;
    let grid = Grid::default();
    // Every material's reduction for leave-one-out (each basis is built from the other 99),
    // else the 90 training materials' for the one shared basis.
    let reduced: Vec<(String, Bivariate)> = set
        .materials
        .iter()
        .filter(|(n, _)| cfg.leave_one_out || !TEST_SET.contains(&n.as_str()))
        .map(|(n, m)| (n.clone(), Bivariate::reduce(m, grid)))
        .collect();
    let shared = if cfg.leave_one_out {
        None
    } else {
        Some(default_basis(&reduced, brdfd_core::basis::DEFAULT_K)?)
    };
    // Names first, so that a filtered run tabulates only what it uses.
    let mut chosen: Vec<(String, Option<Microfacet>)> = if cfg.leave_one_out {
        set.materials.keys().map(|n| (n.clone(), None)).collect()
    } else {
        TEST_SET
            .iter()
            .map(|n| (n.to_string(), None))
            .chain(
                analytic_materials()
                    .into_iter()
                    .map(|(n, m)| (n.to_string(), Some(m))),
            )
            .collect()
    };
    if !cfg.materials.is_empty() {
        let known: Vec<&str> = chosen.iter().map(|(n, _)| n.as_str()).collect();
        if let Some(unknown) = cfg.materials.iter().find(|n| !known.contains(&n.as_str())) {
            return Err(CoreError::Invalid(format!(
                "no evaluation material {unknown} (they are {})",
                known.join(", ")
            )));
        }
        chosen.retain(|(n, _)| cfg.materials.contains(n));
    }
    let names = map_names(&cfg.data)?;
    let lightings: Vec<Lighting> = names
        .iter()
        .map(|n| load_lighting(&cfg.data, n))
        .collect::<Result<_>>()?;
    let geometry =
        PixelGeometry::rasterize(&Camera::eval_orthographic(cfg.size), &Shape::unit_sphere())?;
    let methods: Vec<Method> = methods()
        .into_iter()
        .filter(|m| !cfg.leave_one_out || LEAVE_ONE_OUT_METHODS.contains(&m.name))
        .collect();
    let mut rows = Vec::new();
    let stage = if cfg.leave_one_out {
        "relighting, leave-one-out"
    } else {
        "relighting"
    };
    for (mi, (name, analytic)) in chosen.iter().enumerate() {
        progress(Progress {
            stage,
            item: name,
            index: mi + 1,
            total: chosen.len(),
        });
        // Tabulated one at a time: a full table is 35 MB, and leave-one-out has 100.
        let material = Material {
            name: name.clone(),
            table: match analytic {
                Some(m) => MerlBrdf::tabulate(m),
                None => MerlBrdf::tabulate(set.get(name)?),
            },
            analytic: analytic.is_some(),
        };
        let own;
        let basis = match &shared {
            Some(b) => b,
            None => {
                let others: Vec<(String, Bivariate)> =
                    reduced.iter().filter(|(n, _)| n != name).cloned().collect();
                own = default_basis(&others, brdfd_core::basis::DEFAULT_K)?;
                &own
            }
        };
        let truths: Vec<Raster> = lightings
            .iter()
            .map(|l| render_merl(&geometry, &l.gt, &material.table))
            .collect();
        let reduced = Bivariate::reduce(&material.table, grid);
        for capture in &cfg.capture_maps {
            let ci = names.iter().position(|n| n == capture).ok_or_else(|| {
                CoreError::Invalid(format!(
                    "no map {capture}.hdr in the data folder (it has {})",
                    names.join(", ")
                ))
            })?;
            let lighting = &lightings[ci];
            let (photo, white) = add_sensor_noise(&truths[ci], 7000 + mi as u64);
            let log = log_error(&reduced, &material.table, 11 + mi as u64);
            for (li, other) in lightings.iter().enumerate().filter(|(li, _)| *li != ci) {
                let relit = render_bivariate(&geometry, &other.gt, &reduced);
                rows.push(Row {
                    capture: capture.clone(),
                    relight: names[li].clone(),
                    material: material.name.clone(),
                    analytic: material.analytic,
                    method: REFERENCE,
                    fit: f64::NAN,
                    spread: f64::NAN,
                    flagged: false,
                    relight_error: relit.relative_rmse(&truths[li]),
                    psnr: tone_mapped_psnr(&relit, &truths[li]),
                    log_error: log,
                });
            }
            for method in &methods {
                let view = View {
                    geometry: &geometry,
                    lights: &lighting.est,
                    chosen_lights: Some(&lighting.chosen),
                    photo: &photo,
                };
                let options = EstimateOptions {
                    white,
                    checks: false,
                    ..method.options.clone()
                };
                let est = estimate(basis, view, &options)?;
                let log = log_error(&est.brdf, &material.table, 11 + mi as u64);
                let flagged = est.certainty_text().1;
                let spread = est.uncertainty.bootstrap_spread;
                for (li, other) in lightings.iter().enumerate() {
                    if li == ci {
                        continue;
                    }
                    let relit = render_bivariate(&geometry, &other.gt, &est.brdf);
                    rows.push(Row {
                        capture: capture.clone(),
                        relight: names[li].clone(),
                        material: material.name.clone(),
                        analytic: material.analytic,
                        method: method.name,
                        fit: est.fit_error,
                        spread,
                        flagged,
                        relight_error: relit.relative_rmse(&truths[li]),
                        psnr: tone_mapped_psnr(&relit, &truths[li]),
                        log_error: log,
                    });
                }
            }
        }
        tracing::info!(material = material.name, "relit");
    }
    write_csv(&cfg.out.join("relight.csv"), &rows)?;
    let mut shown: Vec<&'static str> = methods.iter().map(|m| m.name).collect();
    shown.push(REFERENCE);
    write_figure(&cfg.out.join("relight.svg"), &rows, &shown)?;
    let report = markdown(&rows, &shown, cfg, t0.elapsed().as_secs_f64());
    let md = cfg.out.join("relight.md");
    std::fs::write(&md, &report).map_err(|e| CoreError::io(&md, e))?;
    Ok(report)
}

fn write_csv(path: &Path, rows: &[Row]) -> Result<()> {
    let mut s = String::from(
        "capture,relight,material,analytic,method,fit_error,bootstrap_spread,flagged,relight_error,psnr_db,log_error\n",
    );
    for r in rows {
        let _ = writeln!(
            s,
            "{},{},{},{},{},{:.6},{:.6},{},{:.6},{:.3},{:.6}",
            r.capture,
            r.relight,
            r.material,
            r.analytic,
            r.method,
            r.fit,
            r.spread,
            r.flagged,
            r.relight_error,
            r.psnr,
            r.log_error
        );
    }
    std::fs::write(path, s).map_err(|e| CoreError::io(path, e))
}

/// The relighting figure: per material, each method's relight error (the median over its
/// captures and held-out maps), one marker per method.
fn write_figure(path: &Path, rows: &[Row], methods: &[&'static str]) -> Result<()> {
    let mut materials: Vec<String> = Vec::new();
    for r in rows {
        if !materials.contains(&r.material) {
            materials.push(r.material.clone());
        }
    }
    let series: Vec<(String, Vec<Option<f64>>)> = methods
        .iter()
        .map(|method| {
            let values = materials
                .iter()
                .map(|m| {
                    let v: Vec<f64> = rows
                        .iter()
                        .filter(|r| r.material == *m && r.method == *method)
                        .map(|r| r.relight_error)
                        .collect();
                    (!v.is_empty()).then(|| median(v))
                })
                .collect();
            (method.to_string(), values)
        })
        .collect();
    let svg = super::figures::category_dots(
        "Relighting: error under maps the estimate never saw (median per material)",
        "relight error (relative RMSE)",
        &materials,
        &series,
    )?;
    std::fs::write(path, svg).map_err(|e| CoreError::io(path, e))
}

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Per material and method, the median over held-out maps (one number per estimate).
fn per_estimate(
    rows: &[Row],
    f: fn(&Row) -> f64,
) -> Vec<(String, String, &'static str, bool, f64)> {
    let mut keys: Vec<(String, String, &'static str, bool)> = Vec::new();
    for r in rows {
        let k = (r.capture.clone(), r.material.clone(), r.method, r.analytic);
        if !keys.contains(&k) {
            keys.push(k);
        }
    }
    keys.into_iter()
        .map(|(c, m, method, analytic)| {
            let v = rows
                .iter()
                .filter(|r| r.capture == c && r.material == m && r.method == method)
                .map(f)
                .collect();
            (c, m, method, analytic, median(v))
        })
        .collect()
}

fn markdown(rows: &[Row], methods: &[&'static str], cfg: &RelightConfig, seconds: f64) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# Relighting\n\nEach estimate is made from one noisy photo ({0}² sphere) under the capture map, then rendered under every other map and compared with the truth rendered there from the full BRDF. Relight error: relative RMSE of the linear images over the object; PSNR: tone-mapped images; log error: Liu, Fischer & Ritschel 2023. Medians over held-out maps, then over estimates (one per capture map and material). Captured under: {1}.{4} The row {3} is no estimate: the truth reduced to the (θh, θd) grid estimates are written on (its mean over φd), what the form alone loses. {2:.0} s.\n",
        cfg.size,
        cfg.capture_maps.join(", "),
        seconds,
        REFERENCE,
        if cfg.leave_one_out {
            " Leave-one-out: every MERL material, each estimated with a basis and measured materials built from the other 99 (the column \"MERL test\" is over all of them)."
        } else {
            ""
        }
    );
    let relight = per_estimate(rows, |r| r.relight_error);
    let psnr = per_estimate(rows, |r| r.psnr);
    let log = per_estimate(rows, |r| r.log_error);
    let fit = per_estimate(rows, |r| r.fit);
    let _ = writeln!(
        s,
        "| method | relight, MERL test | relight, analytic | PSNR dB, all | log error, all | fit to photo, all |\n|---|---|---|---|---|---|"
    );
    for m in methods {
        let pick = |table: &[(String, String, &'static str, bool, f64)], analytic: Option<bool>| {
            median(
                table
                    .iter()
                    .filter(|e| e.2 == *m && analytic.is_none_or(|a| e.3 == a))
                    .map(|e| e.4)
                    .collect(),
            )
        };
        let _ = writeln!(
            s,
            "| {} | {:.4} | {:.4} | {:.2} | {:.4} | {:.4} |",
            *m,
            pick(&relight, Some(false)),
            pick(&relight, Some(true)),
            pick(&psnr, None),
            pick(&log, None),
            pick(&fit, None),
        );
    }
    // Does the warning catch the bad estimates? Per method: how many estimates it flags, and
    // the median relight error of the flagged and the unflagged ones.
    let _ = writeln!(
        s,
        "\n## The summary's warning (poor fit, or unsteady under resampling)\n\n| method | estimates flagged | relight, flagged | relight, not flagged |\n|---|---|---|---|"
    );
    for m in methods.iter().filter(|m| **m != REFERENCE) {
        let of = |flag: bool| -> Vec<f64> {
            let mut keys: Vec<(&str, &str)> = Vec::new();
            let mut out = Vec::new();
            for r in rows.iter().filter(|r| r.method == *m && r.flagged == flag) {
                if !keys.contains(&(r.capture.as_str(), r.material.as_str())) {
                    keys.push((r.capture.as_str(), r.material.as_str()));
                    out.push(median(
                        rows.iter()
                            .filter(|q| {
                                q.method == *m && q.capture == r.capture && q.material == r.material
                            })
                            .map(|q| q.relight_error)
                            .collect(),
                    ));
                }
            }
            out
        };
        let (flagged, clear) = (of(true), of(false));
        let _ = writeln!(
            s,
            "| {} | {} of {} | {:.4} | {:.4} |",
            *m,
            flagged.len(),
            flagged.len() + clear.len(),
            median(flagged.clone()),
            median(clear.clone()),
        );
    }
    let _ = writeln!(
        s,
        "\n## Per material (relight error, median over held-out maps)\n"
    );
    let _ = write!(s, "| capture | material |");
    for m in methods {
        let _ = write!(s, " {} |", *m);
    }
    let _ = writeln!(s, "\n|---|---|{}", "---|".repeat(methods.len()));
    let mut seen: Vec<(String, String)> = Vec::new();
    for (c, mat, _, _, _) in &relight {
        if seen.contains(&(c.clone(), mat.clone())) {
            continue;
        }
        seen.push((c.clone(), mat.clone()));
        let _ = write!(s, "| {c} | {mat} |");
        for m in methods {
            let v = relight
                .iter()
                .find(|e| &e.0 == c && &e.1 == mat && e.2 == *m)
                .map_or(f64::NAN, |e| e.4);
            let _ = write!(s, " {v:.4} |");
        }
        let _ = writeln!(s);
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identical_images_have_no_error() {
        let mut img = Raster::black(4, 4);
        img.set(1, 1, [0.5, 0.2, 0.1]);
        img.set(2, 1, [2.0, 1.0, 0.3]);
        assert!(tone_mapped_psnr(&img, &img) > 100.0);
        let m = analytic_materials()[0].1.clone();
        assert_eq!(log_error(&m, &m, 1), 0.0);
    }
}
