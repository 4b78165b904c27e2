//! Writing an estimate's results: `coefficients.json`, the bivariate BRDF as EXR, the full
//! MERL `.binary`, and a preview render. Used by `brdfd estimate` and the capture flow.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::export::{write_exports, Export, Prepared};
use crate::flags::Flag;
use crate::html::Context;
use crate::summary::Grade;
use brdfd_core::analytic::Microfacet;
use brdfd_core::basis::Basis;
use brdfd_core::bivariate::{Bivariate, Grid, ThetaHBinning, GRID_CELLS, N_THETA_D, N_THETA_H};
use brdfd_core::brdf::directional_albedo;
use brdfd_core::envmap::{write_exr_attributed, ExrAttribute, LightSet};
use brdfd_core::estimate::{Estimate, Timings};
use brdfd_core::hybrid::MixWeight;
use brdfd_core::uncertainty::Uncertainty;
use brdfd_core::{CoreError, Result};

/// `coefficients.json`'s format name and version: a reader checks both. The version grows
/// when a field changes meaning or goes; new fields may appear within a version.
pub const COEFFICIENTS_FORMAT: &str = "brdfd-coefficients";
pub const COEFFICIENTS_VERSION: u32 = 1;

/// The grid of `brdf-bivariate.exr` and `brdf-sigma.exr`, as `coefficients.json` records it.
#[derive(Serialize)]
pub struct GridRecord {
    pub theta_h_bins: usize,
    pub theta_d_bins: usize,
    #[serde(flatten)]
    pub grid: Grid,
    /// The BRDF's unit.
    pub unit: &'static str,
}

/// The contents of `coefficients.json`.
#[derive(Serialize)]
pub struct CoefficientsFile<'a> {
    /// [`COEFFICIENTS_FORMAT`].
    pub format: &'static str,
    /// [`COEFFICIENTS_VERSION`].
    pub format_version: u32,
    /// `brdfd` and its version.
    pub software: String,
    /// The session the estimate belongs to (absent for `brdfd estimate` on files).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub session: Option<&'a str>,
    /// `good`, `fair` or `poor`: the worst of the judged figures and flags below, as the
    /// summary's first line says it ([`crate::summary::grade`]). For a part split into
    /// materials, the worst material's, and no better than the whole part's other flags and
    /// relit error allow ([`crate::summary::parts_grade`]).
    pub verdict: Grade,
    /// The verdict in words, with what to do when it is not good.
    pub verdict_text: &'a str,
    /// The (θh, θd) grid the estimate's BRDF is tabulated on.
    pub grid: GridRecord,
    /// `basis` (the PCA basis's coefficients, as in the paper), `analytic` (Lambert plus GGX
    /// lobes: `columns` are their per-channel weights and each `alpha`; also in `analytic`) or
    /// `hybrid` (the analytic part, in `analytic`, plus the measured materials in `mixture`).
    pub model: &'a str,
    /// The analytic model's parameters, for `model = "analytic"`; the analytic part, for
    /// `model = "hybrid"`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub analytic: Option<&'a Microfacet>,
    /// For `model = "hybrid"`: each measured material kept (a training material of the basis
    /// `basis_id`) and its weight per channel.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mixture: Option<&'a [MixWeight]>,
    pub basis_id: &'a str,
    pub k: usize,
    /// Names of the model columns, in the order of `coefficients`.
    pub columns: &'a [String],
    pub coefficients: &'a [f64],
    /// Pixels used; equal to `candidates` for an all-pixel estimate.
    pub pixel_count: usize,
    pub selection_method: &'a str,
    /// `least-squares` (the paper's) or `prior` (with the training set's prior; docs/method.md).
    pub solver: &'a str,
    /// `joint` (one set of coefficients for all channels, the paper's) or `per-channel`
    /// (`coefficients` holds the R, G and B sets in turn, named in `columns`): the model that
    /// gave these coefficients.
    pub colour: &'a str,
    /// Each colour model tried and its `fit_error`: both when the choice was `auto`, which
    /// keeps joint unless per channel's is lower by more than 0.001 (`COLOUR_FIT_MARGIN`).
    pub colour_fits: BTreeMap<&'a str, f64>,
    /// (x, y) image positions of the pixels used (omitted for all-pixel estimates).
    pub chosen_pixels: Vec<(u32, u32)>,
    /// The view (turntable position, 0 for the first) of each chosen pixel.
    pub chosen_views: Vec<usize>,
    /// κ of the rows used, with columns scaled by the training spread of their coefficients
    /// (what the selection minimises). Per channel, the worst channel's; `null` (infinite)
    /// when each channel has fewer equations than unknowns, which only the prior solves.
    pub condition_number: f64,
    pub residual_rms: f64,
    pub relative_residual: f64,
    /// ‖A·c − y‖ / ‖y‖ over every candidate pixel: how well the estimate re-renders the photo.
    pub fit_error: f64,
    /// A simulated capture only: the estimate's relative RMSE against the truth, relit under
    /// light it was not fitted to.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub relight_error: Option<f64>,
    /// When the V4L2 fallback camera shot any view: which, and what averaging left of its
    /// noise.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fallback: Option<String>,
    pub candidates: usize,
    /// Object pixels left out because a channel was at the photo's white level.
    pub clipped_pixels: usize,
    /// Lights of every candidate's row.
    pub lights: usize,
    /// Lights the chosen pixels' rows were rebuilt with before the solve; 0 if they were not.
    pub chosen_lights: usize,
    pub timings: &'a Timings,
    /// Non-negativity and energy conservation of the estimated BRDF.
    pub plausibility: Plausibility,
    /// How sure the estimate is: each coefficient's 1-σ (in the order of `columns`), their
    /// covariance, and the relit sphere's bootstrap spread (the BRDF's per-cell band is
    /// `brdf-sigma.exr`).
    pub uncertainty: &'a Uncertainty,
    /// The estimate as a glTF material and an OpenPBR `.mtlx`, fitted to it, and how far they
    /// relight from the estimate itself.
    pub exports: Export,
    /// The assumptions of the model the photo says are broken ([`crate::flags`]).
    pub flags: &'a [Flag],
    /// The isotropic and anisotropic lobes compared ([`brdfd_core::anisotropy`]): the
    /// evidence of the `anisotropy` flag, and the grain's direction and roughnesses.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub anisotropy: Option<&'a brdfd_core::anisotropy::Anisotropy>,
    /// The fit with the light as given against the light turned about the vertical
    /// ([`brdfd_core::registration`]): the evidence of the `misregistration` flag. Absent when
    /// the fit is good and the check did not run.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub registration: Option<&'a brdfd_core::registration::Registration>,
    /// The light the part throws on itself, taken out of the photo before the fit (one
    /// bounce, [`brdfd_core::bounce`]): its share of the light measured and the fit before it.
    /// Absent off a mesh, on a convex part, and with `--no-bounce`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub bounce: Option<&'a brdfd_core::estimate::BounceFit>,
    /// The part's materials, each estimated on its own pixels in its own folder
    /// ([`crate::materials`]); absent for one material.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub materials: Option<&'a crate::materials::MaterialsRecord>,
}

/// What a reader takes back from `coefficients.json`: the model and its coefficients, how it
/// fits, and its exports' verdict. Written as [`CoefficientsFile`]; fields a reader does not
/// need are left unread, and fields an older version did not write are absent.
#[derive(Debug, Clone, Deserialize)]
pub struct StoredResult {
    /// Absent in files written before the format was named.
    #[serde(default)]
    pub format: Option<String>,
    #[serde(default)]
    pub format_version: Option<u32>,
    /// `basis`, `analytic` or `hybrid`; files written before the models had no field and
    /// were the basis's.
    #[serde(default = "basis_model")]
    pub model: String,
    /// The analytic part, read by [`StoredResult::analytic_model`] only where it is used, so
    /// that a reader of the summary does not depend on its form.
    #[serde(default)]
    analytic: Option<serde_json::Value>,
    #[serde(default)]
    mixture: Option<serde_json::Value>,
    pub basis_id: String,
    pub columns: Vec<String>,
    /// `null` where a coefficient was not a number (JSON has no NaN).
    pub coefficients: Vec<Option<f64>>,
    pub fit_error: Option<f64>,
    /// Absent in files written before the verdict was kept. A word, not a [`Grade`]: a word a
    /// later version adds is shown as written rather than making the file unreadable.
    #[serde(default)]
    pub verdict: Option<String>,
    #[serde(default)]
    pub verdict_text: Option<String>,
    #[serde(default)]
    pub relight_error: Option<f64>,
    #[serde(default)]
    pub fallback: Option<String>,
    #[serde(default)]
    pub exports: Option<StoredExports>,
    /// Absent in files written before flags were.
    #[serde(default)]
    pub flags: Vec<StoredFlag>,
    /// The anisotropy comparison, read by [`StoredResult::chosen_lobe`] only where it is
    /// used, as `analytic` is. Absent when the comparison did not run.
    #[serde(default)]
    anisotropy: Option<serde_json::Value>,
    /// The part's materials, when it holds two (absent for one, and in files written
    /// before parts were split).
    #[serde(default)]
    pub materials: Option<crate::materials::MaterialsRecord>,
}

/// One of `coefficients.json`'s `flags`, as far as a reader needs it.
#[derive(Debug, Clone, Deserialize)]
pub struct StoredFlag {
    pub reason: String,
    pub text: String,
}

/// `coefficients.json`'s `exports`, as far as a reader needs them.
#[derive(Debug, Clone, Default, Deserialize)]
pub struct StoredExports {
    pub relight_error: Option<f64>,
    pub verdict: Option<String>,
    /// Absent in files written before the `.mtlx` was measured, and for an anisotropic lobe.
    #[serde(default)]
    pub mtlx_relight_error: Option<f64>,
    #[serde(default)]
    pub mtlx_verdict: Option<String>,
}

fn basis_model() -> String {
    "basis".into()
}

/// Why `coefficients.json` could not be read back.
#[derive(Debug, thiserror::Error)]
pub enum ReadResultError {
    // The cause is the source, not the message: a chain printed whole (anyhow's `{:#}`, the
    // rig's `said`) would otherwise say it twice.
    #[error("reading {path}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    /// Not JSON, or a field of the wrong type (serde says which, with its line and column).
    #[error("{path}")]
    Parse {
        path: String,
        #[source]
        source: serde_json::Error,
    },
    #[error("{path} is {format:?} version {version}, not {COEFFICIENTS_FORMAT} up to version {COEFFICIENTS_VERSION}: written by another program or a newer brdfd")]
    Format {
        path: String,
        format: String,
        version: u32,
    },
}

impl StoredResult {
    /// Reads `coefficients.json` at `path`, checking its format's name and version.
    pub fn read(path: &Path) -> std::result::Result<StoredResult, ReadResultError> {
        let shown = || path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|source| ReadResultError::Io {
            path: shown(),
            source,
        })?;
        let r: StoredResult =
            serde_json::from_str(&text).map_err(|source| ReadResultError::Parse {
                path: shown(),
                source,
            })?;
        let format = r.format.as_deref().unwrap_or(COEFFICIENTS_FORMAT);
        let version = r.format_version.unwrap_or(COEFFICIENTS_VERSION);
        if format != COEFFICIENTS_FORMAT || version > COEFFICIENTS_VERSION {
            return Err(ReadResultError::Format {
                path: shown(),
                format: format.to_string(),
                version,
            });
        }
        Ok(r)
    }

    /// The analytic model's parameters (`analytic`), if the file has them.
    pub fn analytic_model(&self) -> std::result::Result<Option<Microfacet>, serde_json::Error> {
        self.analytic
            .clone()
            .map(serde_json::from_value)
            .transpose()
    }

    /// The hybrid model's measured materials and their weights (`mixture`); none if absent.
    pub fn mixture_weights(&self) -> std::result::Result<Vec<MixWeight>, serde_json::Error> {
        Ok(self
            .mixture
            .clone()
            .map(serde_json::from_value)
            .transpose()?
            .unwrap_or_default())
    }

    /// The anisotropic lobe the estimate relights with, when it chose one over its model
    /// (`anisotropy.chosen`, absent or false in files written before a lobe could be chosen);
    /// says which field is wrong when it cannot be rendered.
    pub fn chosen_lobe(
        &self,
    ) -> std::result::Result<Option<brdfd_core::anisotropic::AnisotropicLobe>, String> {
        let Some(a) = &self.anisotropy else {
            return Ok(None);
        };
        if !a.is_object() {
            return Err(format!("field `anisotropy` is {a}, not an object"));
        }
        match &a["chosen"] {
            serde_json::Value::Null | serde_json::Value::Bool(false) => return Ok(None),
            serde_json::Value::Bool(true) => {}
            other => {
                return Err(format!(
                    "field `anisotropy.chosen` is {other}, not true or false"
                ))
            }
        }
        let lobe = a
            .get("lobe")
            .ok_or("field `anisotropy`: `chosen` is true, but the `lobe` it chose is missing")?;
        let lobe: brdfd_core::anisotropic::AnisotropicLobe =
            serde_json::from_value(lobe.clone())
                .map_err(|e| format!("field `anisotropy.lobe`: {e}"))?;
        lobe.check()
            .map_err(|e| format!("field `anisotropy.lobe`: {e}"))?;
        Ok(Some(lobe))
    }

    /// The coefficients, `NaN` where the file holds `null`.
    pub fn coefficient_values(&self) -> Vec<f64> {
        self.coefficients
            .iter()
            .map(|c| c.unwrap_or(f64::NAN))
            .collect()
    }
}

/// Whether the estimated BRDF could be a real surface's (`coefficients.json`'s `plausibility`).
/// Reciprocity holds by construction: every model is a function of (θh, θd), which swapping the
/// light and the view leaves unchanged.
#[derive(Clone, Debug, Serialize)]
pub struct Plausibility {
    /// The smallest value of the bivariate BRDF over the cells that hold one (1/sr).
    pub min_value: f64,
    /// Values below zero, counted over the three channels' cells (8,100 each). The analytic model has none by construction;
    /// the basis's coefficients can make some negative.
    pub negative_cells: usize,
    /// The largest directional albedo over view angles 0°, 10°, …, 80°, per channel.
    pub max_albedo: [f64; 3],
    /// Whether every directional albedo is at most 1 (within [`ALBEDO_TOLERANCE`]).
    pub albedo_at_most_one: bool,
}

/// The albedo quadrature's own error (see `directional_albedo`): above 1 by less than this
/// is not counted against an estimate.
pub const ALBEDO_TOLERANCE: f64 = 0.005;

/// View angles (degrees) the directional albedo is checked at.
const ALBEDO_VIEWS_DEG: [f64; 9] = [0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0];

impl Plausibility {
    pub fn of(brdf: &Bivariate) -> Plausibility {
        use rayon::prelude::*;
        let cells = (0..3)
            .flat_map(|c| (0..GRID_CELLS).map(move |g| (c, g)))
            .filter(|&(_, g)| brdf.valid[g])
            .map(|(c, g)| brdf.values[c * GRID_CELLS + g]);
        let (min_value, negative_cells) = cells.fold((f64::INFINITY, 0), |(m, n), v| {
            (m.min(v), n + usize::from(v < 0.0))
        });
        let albedos: Vec<[f64; 3]> = ALBEDO_VIEWS_DEG
            .par_iter()
            .map(|d| directional_albedo(brdf, d.to_radians()))
            .collect();
        let max_albedo = std::array::from_fn(|c| {
            albedos
                .iter()
                .map(|a| a[c])
                .fold(f64::NEG_INFINITY, f64::max)
        });
        Plausibility {
            min_value,
            negative_cells,
            max_albedo,
            albedo_at_most_one: max_albedo.iter().all(|a| *a <= 1.0 + ALBEDO_TOLERANCE),
        }
    }
}

/// Paths written by [`write_results`].
pub struct ResultFiles {
    pub coefficients: PathBuf,
    pub brdf_exr: PathBuf,
    pub merl: PathBuf,
    pub preview_png: PathBuf,
    /// The photo beside the estimate, when the photo was given.
    pub compare_png: Option<PathBuf>,
    pub report: PathBuf,
    /// The exported materials and how far they relight from the estimate.
    pub exports: Export,
    /// The assumptions of the model the photo says are broken ([`crate::flags`]).
    pub flags: Vec<Flag>,
    /// The verdict on the estimate ([`crate::summary::grade`]), and in words
    /// ([`crate::summary::headline`]).
    pub verdict: Grade,
    pub headline: String,
    /// Every file written, the report first (what a person opens first), then the files a
    /// program reads, then the pictures.
    pub written: Vec<PathBuf>,
}

/// Writes a bivariate table (`quantity`: what its values are) as a 90 × 90 EXR whose header
/// says how to read it (docs/formats.md).
fn write_bivariate_exr(path: &Path, b: &Bivariate, quantity: &str, basis_id: &str) -> Result<()> {
    let binning = match b.grid.theta_h_binning {
        ThetaHBinning::Sqrt => "sqrt: bin i covers theta_h in [(i/90)^2, ((i+1)/90)^2] x 90 deg",
        ThetaHBinning::Uniform => "uniform: bin i covers theta_h in [i, i+1] deg",
    };
    let text = |s: &str| ExrAttribute::Text(s.to_string());
    let attributes = [
        ("brdfdQuantity", text(quantity)),
        (
            "brdfdAxes",
            text("rows: theta_h bins, top = 0; columns: theta_d bins of 1 deg, left = 0"),
        ),
        ("brdfdThetaHBinning", text(binning)),
        ("brdfdUnit", text("1/sr, linear RGB")),
        ("brdfdBasis", text(basis_id)),
    ];
    let px: Vec<[f32; 3]> = (0..GRID_CELLS)
        .map(|g| {
            [
                b.values[g] as f32,
                b.values[GRID_CELLS + g] as f32,
                b.values[2 * GRID_CELLS + g] as f32,
            ]
        })
        .collect();
    write_exr_attributed(path, N_THETA_D, N_THETA_H, &px, &attributes)
}

/// Size of the preview: the estimate on a sphere, like the paper's Fig. 6, whatever the photo's
/// size (a full-resolution re-render of a 16-megapixel photo would dominate the run time).
pub const PREVIEW_SIZE: usize = 512;
/// Lights the preview is rendered with: the capture's map compressed again, as for the
/// report's relit spheres. The estimate's 4,096 would cost 0.75 s at 512 × 512 on 2 cores
/// against 0.13 s; a mirror-like estimate shows its lights as discs either way (each light
/// is a disc of its own spread, docs/method.md).
pub const PREVIEW_LIGHTS: usize = 512;
pub const PREVIEW_FORMAT: &str = "brdfd-preview";
pub const PREVIEW_VERSION: u32 = 1;

/// `preview.json`: the scale `preview.png` is shown on, so that two previews can be compared.
#[derive(Serialize)]
struct PreviewScale {
    format: &'static str,
    format_version: u32,
    software: String,
    image: &'static str,
    size: usize,
    lights: usize,
    /// Radiance (the panorama's units) shown as full white in `preview.png`.
    white_peak: f32,
    meaning: &'static str,
}

/// Writes every result file into `dir`, `report.html` among them ([`crate::html`], with
/// what `cx` knows); with the first view's photo, also `compare.png` ([`crate::compare`]).
pub fn write_results(
    dir: &Path,
    basis: &Basis,
    estimate: &Estimate,
    method: &str,
    lights: &LightSet,
    cx: &Context,
) -> Result<ResultFiles> {
    std::fs::create_dir_all(dir).map_err(|e| CoreError::io(dir, e))?;
    let brdf = &estimate.brdf;
    let lobe = estimate.chosen_lobe();
    let merl_path = dir.join("brdf.binary");
    std::thread::scope(|s| {
        // The MERL table (35 MB) is written while the rest is worked out.
        let merl = s.spawn(|| brdf.to_merl().write(&merl_path));
        // The export's fit and the preview's render need nothing of each other: run side by
        // side, each fills the cores while the other is in a serial step.
        let capture = cx.env.map(|m| (m, cx.yaw));
        let prepared = cx.exports.filter(|p| p.is_for(capture));
        let (exports, preview) = rayon::join(
            || match prepared {
                Some(prepared) => write_exports(dir, "brdfd_estimate", brdf, lobe, prepared),
                None => {
                    let capture = capture.map(|(m, yaw)| (m.clone(), yaw));
                    let prepared = Prepared::new(capture, brdf.grid)?;
                    write_exports(dir, "brdfd_estimate", brdf, lobe, &prepared)
                }
            },
            || {
                let made = prepared.and_then(Prepared::preview_lights);
                write_preview(dir, &dir.join("preview.png"), estimate, (lights, made), cx)
            },
        );
        let files = write_the_rest(
            dir,
            basis,
            estimate,
            method,
            lights,
            cx,
            (exports?, preview?),
        )?;
        merl.join().expect("writing the MERL table panicked")?;
        Ok(files)
    })
}

/// [`write_results`] once the exports are fitted and the preview rendered: the files that
/// read them.
fn write_the_rest(
    dir: &Path,
    basis: &Basis,
    estimate: &Estimate,
    method: &str,
    lights: &LightSet,
    cx: &Context,
    (exports, preview): (Export, image::RgbImage),
) -> Result<ResultFiles> {
    let mut flags = crate::flags::of(estimate, cx.visibility);
    // Split into materials, the part's several materials are what the results hold.
    if let Some(m) = cx.materials {
        for f in &mut flags {
            if f.reason == crate::flags::Reason::SeveralMaterials {
                f.text.push_str(&format!(
                    "; so it was split into {} materials, each estimated on its own ({})",
                    m.record.parts.len(),
                    m.record
                        .parts
                        .iter()
                        .map(|p| format!("{}/", p.folder))
                        .collect::<Vec<_>>()
                        .join(", ")
                ));
            }
        }
    }
    let verdict = match cx.materials {
        Some(m) => {
            let parts: Vec<Grade> = m.files.iter().map(|f| f.verdict).collect();
            crate::summary::parts_grade(&parts, &flags, cx.relight_error)
        }
        None => crate::summary::grade(estimate, cx.relight_error, &flags),
    };
    let headline = match cx.materials {
        Some(m) => crate::summary::parts_headline(m.record.parts.len(), verdict),
        None => crate::summary::headline(estimate, verdict),
    };
    let files = ResultFiles {
        verdict,
        headline,
        coefficients: dir.join("coefficients.json"),
        brdf_exr: dir.join("brdf-bivariate.exr"),
        merl: dir.join("brdf.binary"),
        preview_png: dir.join("preview.png"),
        compare_png: cx.photo.map(|_| dir.join("compare.png")),
        report: dir.join("report.html"),
        exports,
        flags,
        written: Vec::new(),
    };
    // The page and the files beside it read the same results and nothing of each other: they
    // are written side by side, each with serial steps (encoding PNGs and EXRs, the page's
    // text) that leave a core to the other.
    let (page, written) = rayon::join(
        || {
            crate::html::write(
                &files.report,
                estimate,
                &basis.header.id,
                &preview,
                lights,
                &crate::html::Judged {
                    headline: &files.headline,
                    export: &files.exports,
                    flags: &files.flags,
                },
                cx,
            )
        },
        || write_records(dir, basis, estimate, method, cx, &files),
    );
    // The files' error first: before they were written side by side, they came first.
    let written = written?;
    page?;
    Ok(ResultFiles { written, ..files })
}

/// The files beside the report: `coefficients.json`, the BRDF's EXRs, the capture's light,
/// the export on the object's mesh, and the photo's and visibility's pictures. Returns every
/// result file's path, the report's and the exports' among them.
fn write_records(
    dir: &Path,
    basis: &Basis,
    estimate: &Estimate,
    method: &str,
    cx: &Context,
    files: &ResultFiles,
) -> Result<Vec<PathBuf>> {
    let brdf = &estimate.brdf;
    let basis_outcome = estimate.outcome.basis();
    let pixel_count = estimate.pixel_count();
    let all = pixel_count == estimate.candidates;
    let file = CoefficientsFile {
        verdict: files.verdict,
        verdict_text: &files.headline,
        format: COEFFICIENTS_FORMAT,
        format_version: COEFFICIENTS_VERSION,
        software: format!("brdfd {}", env!("CARGO_PKG_VERSION")),
        session: cx.session.as_deref(),
        grid: GridRecord {
            theta_h_bins: N_THETA_H,
            theta_d_bins: N_THETA_D,
            grid: brdf.grid,
            unit: "1/sr",
        },
        model: estimate.model().name(),
        analytic: estimate.outcome.analytic(),
        mixture: estimate.outcome.mixture(),
        basis_id: &basis.header.id,
        k: basis.header.k,
        columns: &estimate.names,
        coefficients: &estimate.solution.coefficients,
        pixel_count,
        selection_method: if all { "all" } else { method },
        // The analytic weights are solved by non-negative least squares, whatever `--solve`.
        solver: basis_outcome.map_or("non-negative-least-squares", |b| b.solver.name()),
        colour: estimate.colour().name(),
        colour_fits: match basis_outcome {
            Some(b) => b.colour_fits.iter().map(|(c, f)| (c.name(), *f)).collect(),
            // One colour model, per channel, by construction.
            None => BTreeMap::from([(estimate.colour().name(), estimate.model_fit)]),
        },
        chosen_pixels: basis_outcome
            .filter(|_| !all)
            .map_or(Vec::new(), |b| b.chosen.clone()),
        chosen_views: basis_outcome
            .filter(|_| !all)
            .map_or(Vec::new(), |b| b.chosen_views.clone()),
        condition_number: estimate.condition(),
        residual_rms: estimate.solution.residual_rms,
        relative_residual: estimate.solution.relative_residual,
        fit_error: estimate.fit_error,
        relight_error: cx.relight_error,
        fallback: cx.fallback.clone(),
        candidates: estimate.candidates,
        clipped_pixels: estimate.clipped,
        lights: estimate.lights,
        chosen_lights: basis_outcome.map_or(0, |b| b.chosen_lights),
        timings: &estimate.timings,
        plausibility: Plausibility::of(brdf),
        uncertainty: &estimate.uncertainty,
        exports: files.exports.clone(),
        flags: &files.flags,
        anisotropy: estimate.anisotropy.as_ref(),
        registration: estimate.registration.as_ref(),
        bounce: estimate.bounce.as_ref(),
        materials: cx.materials.map(|m| &m.record),
    };
    let mut written = vec![
        files.report.clone(),
        files.coefficients.clone(),
        dir.join("material.gltf"),
        dir.join("material.mtlx"),
        files.merl.clone(),
        files.brdf_exr.clone(),
    ];
    let json = serde_json::to_string_pretty(&file).expect("coefficients serialise");
    std::fs::write(&files.coefficients, json).map_err(|e| CoreError::io(&files.coefficients, e))?;
    let basis_id = &basis.header.id;
    write_bivariate_exr(&files.brdf_exr, brdf, "BRDF (the estimate)", basis_id)?;
    // Every resample may fail to solve (least squares on a few repeated pixels): then there is
    // no band to write.
    let u = &estimate.uncertainty;
    if u.band.len() == brdf.values.len() {
        let band = Bivariate::from_values(brdf.grid, u.band.clone(), brdf.valid.clone());
        let sigma = "BRDF 1-sigma (bootstrap over the pixels)";
        write_bivariate_exr(&dir.join("brdf-sigma.exr"), &band, sigma, basis_id)?;
        written.push(dir.join("brdf-sigma.exr"));
    }
    // The MERL-layout tables are isotropic by definition: a chosen anisotropic lobe is
    // tabulated beside them, in its own tangent frame (docs/formats.md).
    if let Some(lobe) = estimate.chosen_lobe() {
        let path = dir.join("brdf-anisotropic.binary");
        std::fs::write(&path, lobe.tabulate().to_bytes()).map_err(|e| CoreError::io(&path, e))?;
        written.push(path);
    }
    // The capture's light, for the web page's viewer to show the export under, and on a
    // mesh the export on the object itself, in the same world.
    if let Some(map) = cx.env {
        crate::export::maps::write_light(&dir.join("light.hdr"), map, cx.yaw)?;
        written.push(dir.join("light.hdr"));
    }
    if let Some(mesh) = cx.object {
        let path = dir.join("object.gltf");
        // With two materials, each triangle in its own (unseen ones in the commoner).
        let painted = cx.materials.and_then(|m| {
            let t = m.record.triangles.as_ref()?;
            (t.len() == mesh.triangles.len())
                .then(|| crate::materials::painted(t, m.record.parts.len()))
        });
        let text = match (cx.materials, painted) {
            (Some(m), Some(labels)) => {
                let gltf = m.gltf();
                let named: Vec<(&str, &crate::export::GltfMaterial)> =
                    gltf.iter().map(|(n, g)| (n.as_str(), *g)).collect();
                crate::export::gltf::document_of_materials("brdfd_estimate", &named, mesh, &labels)
            }
            _ => files
                .exports
                .material
                .document_on_mesh("brdfd_estimate", mesh),
        };
        std::fs::write(&path, text).map_err(|e| CoreError::io(&path, e))?;
        written.push(path);
    }
    written.extend([
        files.preview_png.clone(),
        dir.join("preview.exr"),
        dir.join("preview.json"),
    ]);
    if let (Some(photo), Some(path)) = (cx.photo, &files.compare_png) {
        crate::compare::write(path, photo, &estimate.rerender)?;
        written.push(path.clone());
    }
    if let Some(m) = cx.materials {
        written.extend(m.pictures.iter().cloned());
        written.extend(m.files.iter().map(|f| f.report.clone()));
    }
    if let Some(v) = cx.visibility {
        let path = dir.join("visibility.png");
        v.picture()
            .save(&path)
            .map_err(|e| CoreError::format(path.display(), format!("could not write PNG: {e}")))?;
        written.push(path);
    }
    Ok(written)
}

/// `preview.png` (on the fixed scale of `preview.json`) and `preview.exr` (linear): the
/// estimate on a sphere under the first view's light, seen from the front: the map's
/// [`PREVIEW_LIGHTS`] (`made` beforehand from `cx.env` at `cx.yaw`, or compressed here), or
/// the estimate's `lights` without a map.
fn write_preview(
    dir: &Path,
    png: &Path,
    estimate: &Estimate,
    (lights, made): (&LightSet, Option<&LightSet>),
    cx: &Context,
) -> Result<image::RgbImage> {
    let compressed;
    let lights = match (made, cx.env) {
        (Some(made), _) => made,
        (None, Some(map)) => {
            compressed = map.compressed(PREVIEW_LIGHTS, cx.yaw);
            &compressed
        }
        (None, None) => lights,
    };
    let picture = estimate.sphere_picture(lights, PREVIEW_SIZE)?;
    picture.radiance.write_exr(&dir.join("preview.exr"))?;
    let image = picture.to_srgb8();
    image
        .save(png)
        .map_err(|e| CoreError::format(png.display(), format!("could not write PNG: {e}")))?;
    let scale = PreviewScale {
        format: PREVIEW_FORMAT,
        format_version: PREVIEW_VERSION,
        software: format!("brdfd {}", env!("CARGO_PKG_VERSION")),
        image: "preview.png",
        size: PREVIEW_SIZE,
        lights: lights.len(),
        white_peak: picture.white_peak,
        meaning: "preview.png is the estimate's radiance divided by white_peak, sRGB-encoded and \
                  clipped at 1: full white is the brightest pixel of a white Lambertian sphere \
                  (albedo 1) under the same lights. preview.exr holds the radiance itself.",
    };
    let path = dir.join("preview.json");
    let json = serde_json::to_string_pretty(&scale).expect("the preview's scale serialises");
    std::fs::write(&path, json).map_err(|e| CoreError::io(&path, e))?;
    Ok(image)
}

/// "coefficients:" and one `  name = +value` line per column: how the CLI, the daemon's
/// event stream and `brdfd estimate` show coefficients.
pub fn coefficient_lines(title: &str, names: &[String], coefficients: &[f64]) -> String {
    let mut s = format!("{title}:");
    for (n, c) in names.iter().zip(coefficients) {
        s.push_str(&format!("\n  {n:>5} = {c:+.6}"));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read(text: &str) -> std::result::Result<StoredResult, ReadResultError> {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("coefficients.json");
        std::fs::write(&path, text).unwrap();
        StoredResult::read(&path)
    }

    const BASIS: &str = r#""basis_id": "b1", "columns": ["c0", "c1"], "coefficients": [0.5, null], "fit_error": 0.04"#;

    #[test]
    fn a_chosen_lobe_is_read_where_it_is_used_and_a_wrong_one_is_named() {
        let with = |anisotropy: &str| {
            read(&format!(r#"{{{BASIS}, "anisotropy": {anisotropy}}}"#))
                .unwrap()
                .chosen_lobe()
        };
        let lobe = r#"{"diffuse": [0.02, 0.02, 0.02], "specular": [0.9, 0.9, 0.9], "axis": [0, 1, 0], "alpha_t": 0.24, "alpha_b": 0.06}"#;
        // Absent, or compared and not chosen: the model relights.
        assert_eq!(
            read(&format!("{{{BASIS}}}")).unwrap().chosen_lobe(),
            Ok(None)
        );
        assert_eq!(
            with(&format!(r#"{{"chosen": false, "lobe": {lobe}}}"#)),
            Ok(None)
        );
        assert_eq!(with(r#"{"isotropic_misfit": 0.2}"#), Ok(None));
        let l = with(&format!(r#"{{"chosen": true, "lobe": {lobe}}}"#))
            .unwrap()
            .unwrap();
        assert_eq!((l.alpha_t, l.alpha_b), (0.24, 0.06));
        // A bad lobe fails where it is used, by its field; the rest of the file still reads.
        let e = with(r#"{"chosen": true}"#).unwrap_err();
        assert!(e.contains("`lobe` it chose is missing"), "{e}");
        let e = with(&format!(
            r#"{{"chosen": true, "lobe": {}}}"#,
            lobe.replace("0.24", "0")
        ))
        .unwrap_err();
        assert!(
            e.contains("anisotropy.lobe") && e.contains("alpha_t"),
            "{e}"
        );
        let e = with(r#"{"chosen": true, "lobe": {"diffuse": 1}}"#).unwrap_err();
        assert!(e.contains("field `anisotropy.lobe`"), "{e}");
        let e = with(r#"{"chosen": "yes"}"#).unwrap_err();
        assert!(e.contains("anisotropy.chosen"), "{e}");
        let e = with("[]").unwrap_err();
        assert!(e.contains("field `anisotropy` is []"), "{e}");
    }

    #[test]
    fn a_stored_result_is_read_back_typed_and_a_wrong_one_is_named() {
        let r = read(&format!(
            r#"{{"format": "{COEFFICIENTS_FORMAT}", "format_version": 1, "model": "basis", {BASIS}}}"#
        ))
        .unwrap();
        assert_eq!(r.columns, ["c0", "c1"]);
        assert_eq!(r.coefficients, [Some(0.5), None]);
        assert!(r.coefficient_values()[1].is_nan());
        assert_eq!(r.fit_error, Some(0.04));
        assert!(r.exports.is_none());
        // A file from before the format was named, or the models were, is the basis's.
        assert_eq!(read(&format!("{{{BASIS}}}")).unwrap().model, "basis");
        let other = read(&format!(r#"{{"format": "other", {BASIS}}}"#)).unwrap_err();
        assert!(matches!(other, ReadResultError::Format { .. }), "{other}");
        let newer = read(&format!(
            r#"{{"format": "{COEFFICIENTS_FORMAT}", "format_version": 2, {BASIS}}}"#
        ))
        .unwrap_err();
        assert!(newer.to_string().contains("version 2"), "{newer}");
        // A field of the wrong type is named, with the file.
        let bad = read(r#"{"basis_id": "b1", "columns": "c0", "coefficients": []}"#).unwrap_err();
        assert!(
            matches!(bad, ReadResultError::Parse { .. })
                && bad.to_string().contains("coefficients.json"),
            "{bad}"
        );
        // Serde's words are the source, said once after the file's name.
        let truncated = read(&format!("{{{BASIS}")).unwrap_err();
        let source = std::error::Error::source(&truncated).map(|s| s.to_string());
        assert!(
            source.as_deref().is_some_and(|s| s.contains("EOF"))
                && !truncated.to_string().contains("EOF"),
            "{truncated}: {source:?}"
        );
    }
}
