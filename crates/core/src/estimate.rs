//! The estimate from measurements: photo + lights + geometry + basis → coefficients.
//! Used by `brdfd estimate`, the evaluation and the capture flow alike.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use serde::Serialize;

use super::analytic::{self, Microfacet, ViewPixels};
use super::anisotropic::AnisotropicLobe;
use super::anisotropy::{self, Anisotropy, ViewSamples};
use super::basis::channel_coefficients;
use super::basis::{Basis, LinearModel};
use super::bivariate::Bivariate;
use super::bounce::Paths;
use super::brdf::{tangent_frame, IsotropicBrdf};
use super::envmap::LightSet;
use super::error::{CoreError, Result};
use super::geometry::{GeomPixel, PixelGeometry};
use super::hybrid::{self, MixWeight};
use super::raster::Raster;
use super::registration::{self, Registration};
use super::render::{RenderingMatrix, SpherePicture};
use super::select::spread;
use super::select::{self, Blocks, Selection, SwapParams};
use super::solve::{relative_misfit, Colour, ColourChoice, Solution, Solver};
use super::stop::Stop;
use super::uncertainty::{self, Uncertainty};

/// Chosen pixels whose rows are rebuilt with the view's finer lights at most (see
/// [`chosen_rows`]): 20 pixels under 65,536 lights cost about as much as 320 under the
/// default 4,096, so this bounds the rebuild near the cost of the candidates' matrix. Above
/// it (an "all pixels" estimate), the solve keeps the candidates' rows: over thousands of
/// rows, compression errors of single pixels average out.
pub const MAX_CHOSEN_ROWS: usize = 2_000;

/// Candidate pixels considered at most: a 16-megapixel photo holds millions of object pixels,
/// and conditioning saturates long before this many (see docs/evaluation.md, "Speed").
pub const DEFAULT_MAX_CANDIDATES: usize = 50_000;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum SelectionMethod {
    /// The paper's swap search.
    Paper,
    /// Our exchange search (default).
    Fast,
}

/// The BRDF model an estimate fits: the seam between the estimate's shared steps (candidate
/// pixels, the fit to the photo, the result) and each model's own fit.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, serde::Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[serde(rename_all = "kebab-case")]
pub enum Model {
    /// The paper's: coefficients of the data-driven PCA basis, from selected pixels.
    Basis,
    /// Lambert plus one or two GGX/Smith lobes, fitted to every candidate pixel
    /// ([`analytic`]): the baseline a graphics user would fit by hand.
    Analytic,
    /// The analytic model's Lambert and lobes plus a non-negative mix of the measured
    /// materials the basis was trained on, fitted jointly on 4,000 pixels spread over the
    /// object ([`super::hybrid`]). The default: relit under maps the estimate never saw, it is
    /// the most accurate model brdfd has (`brdfd eval --relight`; docs/evaluation.md): median
    /// relight error 0.107 on the MERL test materials with two lobes, against 0.136 for the
    /// analytic model, 0.243 for the basis with every pixel and 0.435 for the paper's method.
    #[default]
    Hybrid,
}

impl Model {
    pub fn name(self) -> &'static str {
        match self {
            Model::Basis => "basis",
            Model::Analytic => "analytic",
            Model::Hybrid => "hybrid",
        }
    }
}

/// Lobes of the analytic and hybrid models unless told otherwise: two cover a clear coat
/// over a rougher base, or a metal's core and halo (measured: docs/evaluation.md).
pub const DEFAULT_LOBES: usize = 2;

/// What to estimate with: the model, with its own settings, and what every model shares (the
/// candidates, the checks, the bounce, the split into materials).
#[derive(Clone, Debug)]
pub struct EstimateOptions {
    pub model: ModelOptions,
    /// Candidate pixels considered at most, shared evenly between the views.
    pub max_candidates: usize,
    /// The photo's white level, if it has one: a value at or above it was clipped, so it is
    /// only a lower bound on the radiance. Pixels with a clipped channel are not candidates.
    /// 8-bit photos have one (1.0 after decoding); an HDR merge or a linear EXR usually not.
    pub white: Option<f32>,
    /// Check the model's assumptions on the photo: compare an isotropic and an anisotropic
    /// lobe ([`crate::anisotropy`], [`Estimate::anisotropy`]) and, when the fit is not good,
    /// the light turned about the vertical ([`crate::registration`],
    /// [`Estimate::registration`]). On for an estimate a person reads; off for the
    /// evaluation, which scores the BRDF alone and runs hundreds.
    pub checks: bool,
    /// Whether the light a concave mesh throws on itself is taken out of the photo before the
    /// fit, which is then made again, twice ([`crate::bounce`], up to two bounces); off, every pixel is
    /// fitted as if it saw only the room.
    pub bounce: bool,
    /// Whether [`crate::materials::estimate_materials`] may split a part whose photo's colour
    /// departs from one BRDF's from place to place into two materials, each estimated on its
    /// own pixels; off, one BRDF is fitted to the whole part. Only with
    /// [`EstimateOptions::checks`], as the split is itself a check of the photo.
    pub materials: bool,
    /// Checked in the estimate's long loops: once requested, the estimate ends with
    /// [`CoreError::Stopped`] within about a second.
    pub stop: Stop,
}

impl Default for EstimateOptions {
    fn default() -> Self {
        EstimateOptions {
            model: ModelOptions::default(),
            max_candidates: DEFAULT_MAX_CANDIDATES,
            white: None,
            checks: true,
            bounce: true,
            materials: true,
            stop: Stop::default(),
        }
    }
}

/// The model an estimate fits, with the settings only that model has (after kornia-rs's
/// `PnPMethod`): a combination no model reads, say a pixel count for the hybrid, cannot be
/// written.
#[derive(Clone, Debug, PartialEq)]
pub enum ModelOptions {
    /// [`Model::Basis`]: the paper's pixel selection and solve.
    Basis(BasisOptions),
    /// [`Model::Analytic`], with this many specular lobes (1 or 2).
    Analytic { lobes: usize },
    /// [`Model::Hybrid`], with this many specular lobes (1 or 2).
    Hybrid { lobes: usize },
}

impl Default for ModelOptions {
    fn default() -> Self {
        ModelOptions::of(Model::default())
    }
}

impl ModelOptions {
    /// `model` with its default settings.
    pub fn of(model: Model) -> Self {
        match model {
            Model::Basis => ModelOptions::Basis(BasisOptions::default()),
            Model::Analytic => ModelOptions::Analytic {
                lobes: DEFAULT_LOBES,
            },
            Model::Hybrid => ModelOptions::Hybrid {
                lobes: DEFAULT_LOBES,
            },
        }
    }

    /// The model these settings are of.
    pub fn model(&self) -> Model {
        match self {
            ModelOptions::Basis(_) => Model::Basis,
            ModelOptions::Analytic { .. } => Model::Analytic,
            ModelOptions::Hybrid { .. } => Model::Hybrid,
        }
    }
}

/// The basis model's settings: how its pixels are chosen and how its coefficients are solved.
#[derive(Clone, Debug, PartialEq)]
pub struct BasisOptions {
    /// Pixels to use; `None` for every candidate.
    pub pixel_count: Option<usize>,
    pub method: SelectionMethod,
    pub swap: SwapParams,
    pub solver: Solver,
    pub colour: ColourChoice,
    /// Keep the BRDF ≥ 0 in every cell, in the solve (the default). Off only for the paper's
    /// method exactly as published (`--allow-negative`), whose least squares can leave cells
    /// negative. The other models are non-negative by construction.
    pub nonnegative: bool,
}

impl Default for BasisOptions {
    fn default() -> Self {
        BasisOptions {
            pixel_count: Some(20),
            method: SelectionMethod::Fast,
            swap: SwapParams::default(),
            solver: Solver::default(),
            colour: ColourChoice::default(),
            nonnegative: true,
        }
    }
}

#[derive(Clone, Debug, Default, Serialize)]
pub struct Timings {
    pub rendering_matrix_s: f64,
    pub selection_s: f64,
    /// Rebuilding the chosen pixels' rows with the finer lights ([`chosen_rows`]).
    pub chosen_rows_s: f64,
    pub solve_s: f64,
    /// Whether renders made before the photo arrived were used ([`Shared::prepare`]): then
    /// the times above leave them out.
    pub prepared: bool,
}

/// The result, as written to `coefficients.json` (plus the basis id the caller adds): what every
/// model gives, and what only its model gives in [`Estimate::outcome`].
#[derive(Clone, Debug)]
pub struct Estimate {
    /// The estimated BRDF, reduced to the bivariate grid.
    pub brdf: Bivariate,
    /// What only the fitted model gives, and so which model it was.
    pub outcome: Outcome,
    /// How sure the estimate is (its coefficients' spread and the BRDF's 1-σ band).
    pub uncertainty: Uncertainty,
    /// Names of the solution's coefficients (per channel for [`Colour::PerChannel`]).
    pub names: Vec<String>,
    pub solution: Solution,
    pub candidates: usize,
    /// Pixels the model's weights were solved on: the chosen ones (basis), every candidate
    /// (analytic), or the roughness search's spread pixels (hybrid).
    pub solved: usize,
    /// Object pixels left out because a channel was clipped (see [`EstimateOptions::white`]).
    pub clipped: usize,
    /// ‖A·c − y‖ / ‖y‖ over every candidate pixel, not only the chosen ones: how well the
    /// estimate re-renders the photo, with no ground truth needed. Of the anisotropic lobe
    /// when the estimate chose one ([`Anisotropy::chosen`]): of what it relights with. With a
    /// bounce taken out ([`Estimate::bounce`]), the render A·c has its bounce added back, and
    /// y is the whole photo.
    pub fit_error: f64,
    /// The model's own fit, as [`Estimate::fit_error`] measured it when the model was fitted:
    /// to the photo less the bounce when one is taken out, and of the model, not of a lobe
    /// chosen over it. What `coefficients.json`'s `colour_fits` records for the analytic and
    /// hybrid models (the basis model's are in its [`BasisOutcome::colour_fits`]).
    pub model_fit: f64,
    /// What the estimate renders at each candidate pixel, beside what the photo measured
    /// there: the re-render [`Estimate::fit_error`] is measured on, every view's in turn (the
    /// chosen anisotropic lobe's, when there is one).
    pub rerender: Vec<Rerendered>,
    pub lights: usize,
    pub timings: Timings,
    /// Whether an anisotropic lobe re-renders the photo closer than an isotropic one
    /// ([`crate::anisotropy`]); `None` with too few pixels or a black photo, and when
    /// [`EstimateOptions::checks`] is off.
    pub anisotropy: Option<Anisotropy>,
    /// Whether the photo fits much closer with the light turned about the vertical
    /// ([`crate::registration`]); `None` when the fit is good (the check is not run), with
    /// too few pixels, and when [`EstimateOptions::checks`] is off.
    pub registration: Option<Registration>,
    /// The light the part throws on itself, taken out of the photo before the fit; `None`
    /// off a mesh, on a convex one, and when [`EstimateOptions::bounce`] is off.
    pub bounce: Option<BounceFit>,
}

/// What one model's estimate gives beside the shared result.
#[derive(Clone, Debug)]
pub enum Outcome {
    /// The basis model's chosen pixels and its solve.
    Basis(BasisOutcome),
    /// The analytic model's parameters.
    Analytic(Microfacet),
    /// The hybrid model's analytic part and the measured materials mixed into it, with their
    /// weights.
    Hybrid {
        analytic: Microfacet,
        mixture: Vec<MixWeight>,
    },
}

/// What the basis model chose and solved with.
#[derive(Clone, Debug)]
pub struct BasisOutcome {
    pub solver: Solver,
    /// The colour model that gave this estimate (with [`ColourChoice::Auto`], the better fit).
    pub colour: Colour,
    /// Each colour model tried, with its fit ([`Estimate::fit_error`]); one unless the choice
    /// was [`ColourChoice::Auto`].
    pub colour_fits: Vec<(Colour, f64)>,
    pub selection: Selection,
    /// Image positions (x, y) of the chosen pixels.
    pub chosen: Vec<(u32, u32)>,
    /// Which view (0 for the first) each chosen pixel is from.
    pub chosen_views: Vec<usize>,
    /// Lights the chosen pixels' rows were rebuilt with (first view); 0 if they kept the
    /// candidates' rows.
    pub chosen_lights: usize,
}

impl Outcome {
    /// The model fitted.
    pub fn model(&self) -> Model {
        match self {
            Outcome::Basis(_) => Model::Basis,
            Outcome::Analytic(_) => Model::Analytic,
            Outcome::Hybrid { .. } => Model::Hybrid,
        }
    }

    /// The analytic model's parameters, or the hybrid's analytic part.
    pub fn analytic(&self) -> Option<&Microfacet> {
        match self {
            Outcome::Analytic(m) | Outcome::Hybrid { analytic: m, .. } => Some(m),
            Outcome::Basis(_) => None,
        }
    }

    /// The hybrid model's measured materials and their weights.
    pub fn mixture(&self) -> Option<&[MixWeight]> {
        match self {
            Outcome::Hybrid { mixture, .. } => Some(mixture),
            _ => None,
        }
    }

    /// The basis model's pixels and solve.
    pub fn basis(&self) -> Option<&BasisOutcome> {
        match self {
            Outcome::Basis(b) => Some(b),
            _ => None,
        }
    }
}

/// What the bounces ([`crate::bounce`]) took out of the photo before the fit.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct BounceFit {
    /// Hidden directions followed from the candidates, and the cells they ended in, with
    /// those the cells' own hidden directions end in.
    pub directions: usize,
    pub cells: usize,
    /// The share of all the light the candidates measured (sum over pixels and channels)
    /// that was taken out as bounced before the final fit.
    pub share: f64,
    /// Candidates that receive any bounced light.
    pub pixels: usize,
    /// The first fit, made with the bounce left in the photo: what `--no-bounce` fits.
    pub fit_without: f64,
}

/// One candidate pixel of the re-render: where it is, what the estimate renders there and
/// what the photo measured (linear RGB).
#[derive(Clone, Copy, Debug)]
pub struct Rerendered {
    /// The view (0 for the first).
    pub view: usize,
    pub x: u32,
    pub y: u32,
    pub predicted: [f32; 3],
    pub observed: [f32; 3],
}

/// The re-render of every candidate from `predicted` (three values per candidate, in the
/// candidates' order).
fn rerendered(candidates: &[Candidates], predicted: &[f64]) -> Vec<Rerendered> {
    debug_assert_eq!(
        predicted.len(),
        3 * candidates.iter().map(|c| c.pixels.len()).sum::<usize>(),
        "one prediction per candidate and channel"
    );
    let pixels = candidates.iter().enumerate().flat_map(|(view, c)| {
        c.pixels
            .iter()
            .zip(&c.observed)
            .map(move |(p, o)| (view, p, o))
    });
    pixels
        .zip(predicted.chunks_exact(3))
        .map(|((view, p, o), rgb)| Rerendered {
            view,
            x: p.x,
            y: p.y,
            predicted: [rgb[0] as f32, rgb[1] as f32, rgb[2] as f32],
            observed: [o[0] as f32, o[1] as f32, o[2] as f32],
        })
        .collect()
}

/// How much better (in [`Estimate::fit_error`], a relative RMSE) a colour model with more
/// unknowns must re-render the photo to be kept over one with fewer. Below 0.1% of the
/// photo's RMS the fits agree: an in-span joint BRDF fits both to rounding, and the model
/// with fewer unknowns, the paper's, should win that tie rather than rounding deciding it.
pub const COLOUR_FIT_MARGIN: f64 = 1e-3;

/// The rule `auto` chooses by, for estimates offered in order of increasing unknowns, each
/// with its fit: the `candidate` replaces the `kept` one only if it fits better by more than
/// [`COLOUR_FIT_MARGIN`]. The evaluation's `prior-auto` uses it too.
pub(crate) fn keep_better_fit<T>(kept: Option<(T, f64)>, candidate: (T, f64)) -> Option<(T, f64)> {
    match kept {
        Some(k) if candidate.1 >= k.1 - COLOUR_FIT_MARGIN => Some(k),
        _ => Some(candidate),
    }
}

fn secs(d: Duration) -> f64 {
    d.as_secs_f64()
}

/// At most `max` of `pixels`, spread evenly over them: the candidates of a view whose usable
/// pixels these are.
fn spread_pixels<P: std::borrow::Borrow<GeomPixel>>(pixels: &[P], max: usize) -> Vec<GeomPixel> {
    spread(pixels.len(), max)
        .into_iter()
        .map(|i| pixels[i].borrow().clone())
        .collect()
}

/// Each view's share of the candidate budget.
fn candidates_per_view(options: &EstimateOptions, views: usize) -> usize {
    (options.max_candidates / views.max(1)).max(1)
}

/// The candidate pixels of `geometry` in `photo`: pixels the photo saw with finite,
/// non-negative values, below `white` if given, spread to at most `max_candidates`. Returns
/// them, what they measured, and how many object pixels were clipped.
pub(crate) fn candidate_pixels(
    geometry: &PixelGeometry,
    photo: &Raster,
    max_candidates: usize,
    white: Option<f32>,
) -> Result<(Vec<GeomPixel>, Vec<[f64; 3]>, usize)> {
    if (photo.width, photo.height) != (geometry.width, geometry.height) {
        return Err(CoreError::Invalid(format!(
            "the photo is {}×{} but the geometry is {}×{}",
            photo.width, photo.height, geometry.width, geometry.height
        )));
    }
    // References, not copies: a 16-megapixel photo's object holds millions of pixels, of
    // which `max_candidates` are kept; two full copies of them cost the end-to-end estimate
    // about a third of a second of page faults, on one thread.
    let mut clipped = 0;
    let usable: Vec<&GeomPixel> = geometry
        .pixels
        .iter()
        .filter(|p| {
            let v = photo.get(p.x as usize, p.y as usize);
            if !v.iter().all(|v| v.is_finite() && *v >= 0.0) {
                return false;
            }
            let unclipped = white.is_none_or(|w| v.iter().all(|v| *v < w));
            clipped += usize::from(!unclipped);
            unclipped
        })
        .collect();
    if usable.is_empty() {
        return Err(CoreError::Invalid(if clipped > 0 {
            format!("every object pixel of the photo is clipped ({clipped} at or above the white level {}); use a shorter exposure", white.unwrap_or(0.0))
        } else {
            "no object pixel of the photo is usable (mask empty, or all values negative/NaN)".into()
        }));
    }
    let picked = spread_pixels(&usable, max_candidates);
    let observed = picked
        .iter()
        .map(|p| photo.get(p.x as usize, p.y as usize).map(|v| v as f64))
        .collect();
    Ok((picked, observed, clipped))
}

/// The pixels `options` asks for, chosen on a prepared rendering matrix for a solve with
/// `colour`: selection conditions the systems that solve will use, one joint system or one
/// per channel (see [`Blocks`]).
pub(crate) fn select_pixels(
    basis: &Basis,
    a: &RenderingMatrix,
    options: &BasisOptions,
    colour: Colour,
    stop: &Stop,
) -> Result<Selection> {
    let blocks = Blocks::for_colour(a, &basis.column_scales(), colour);
    match options.pixel_count {
        None => Ok(select::all_pixels(&blocks)),
        Some(l) => match options.method {
            SelectionMethod::Paper => select::paper_swap(&blocks, l, &options.swap, stop),
            SelectionMethod::Fast => select::fast_exchange(&blocks, l, stop),
        },
    }
}

/// The rows of the `chosen` pixels of `a`, each rebuilt under `lights_of(pixel)` (its view's
/// finer lights) where that is given; the others keep their rows of `a`.
///
/// Why: `a` is built with compressed lights so that every candidate is affordable, and
/// compression leaves an error in each row. It is small on average but not for every pixel:
/// a mirror-like material under a broad, textured sky changes by 20% in places. Selection
/// only needs the rows' conditioning, which that error hardly moves; the solve needs their
/// values, and with 20 pixels one bad row moves the estimate. Rebuilding 20 rows costs little.
pub fn chosen_rows<'l>(
    basis: &Basis,
    a: &RenderingMatrix,
    chosen: &[usize],
    lights_of: impl Fn(usize) -> Option<&'l LightSet>,
) -> RenderingMatrix {
    let mut rows = a.subset(chosen);
    if !rebuilds_rows(chosen.len()) {
        return rows;
    }
    // One build per light set (one per view), not per pixel: a build prepares its lights.
    let mut groups: Vec<(&LightSet, Vec<usize>)> = Vec::new();
    for (i, &p) in chosen.iter().enumerate() {
        let Some(lights) = lights_of(p) else { continue };
        match groups.iter_mut().find(|(l, _)| std::ptr::eq(*l, lights)) {
            Some((_, members)) => members.push(i),
            None => groups.push((lights, vec![i])),
        }
    }
    for (lights, members) in groups {
        let pixels: Vec<GeomPixel> = members.iter().map(|&i| rows.pixels[i].clone()).collect();
        let fine = basis.rendering_matrix(&pixels, lights);
        for (j, &i) in members.iter().enumerate() {
            rows.replace_pixel(i, &fine, j);
        }
    }
    rows
}

/// Whether [`chosen_rows`] rebuilds the rows of this many chosen pixels.
fn rebuilds_rows(chosen: usize) -> bool {
    chosen <= MAX_CHOSEN_ROWS
}

/// Selection (`select`: [`select_pixels`], or a selection made before on the same matrix), the
/// chosen rows ([`chosen_rows`]), the solve with `colour` and its uncertainty (with the sphere
/// of [`Uncertainty::bootstrap_spread`] relit under `lights`), on a prepared rendering matrix.
#[allow(clippy::too_many_arguments)]
fn estimate_from_matrix<'l>(
    basis: &Basis,
    a: &RenderingMatrix,
    observed: &[[f64; 3]],
    options: &BasisOptions,
    colour: Colour,
    lights: &LightSet,
    lights_of: impl Fn(usize) -> Option<&'l LightSet>,
    select: impl FnOnce() -> Result<Selection>,
) -> Result<(Selection, Solution, Uncertainty, Timings)> {
    let mut timings = Timings::default();
    let t = Instant::now();
    let selection = select()?;
    timings.selection_s = secs(t.elapsed());
    let t = Instant::now();
    let rows = chosen_rows(basis, a, &selection.pixels, lights_of);
    let chosen_observed: Vec<[f64; 3]> = selection.pixels.iter().map(|&p| observed[p]).collect();
    timings.chosen_rows_s = secs(t.elapsed());
    let t = Instant::now();
    let all_rows: Vec<usize> = (0..rows.pixels.len()).collect();
    let model = basis.model();
    let nonnegative = options.nonnegative.then_some(&model);
    let solution = options.solver.solve_colour(
        colour,
        &rows,
        &all_rows,
        &chosen_observed,
        &basis.column_prior(),
        nonnegative,
    )?;
    let uncertainty = basis_uncertainty(
        basis,
        &rows,
        &chosen_observed,
        (options.solver, nonnegative),
        colour,
        &solution,
        lights,
    )?;
    timings.solve_s = secs(t.elapsed());
    Ok((selection, solution, uncertainty, timings))
}

/// The basis estimate's [`Uncertainty`]: its pixels resampled with replacement and solved
/// again, the same way; the coefficients' covariance and the BRDF's band are the resamples'.
/// With 20 pixels this is what says whether those 20 pin the BRDF down.
fn basis_uncertainty(
    basis: &Basis,
    rows: &RenderingMatrix,
    observed: &[[f64; 3]],
    (solver, nonnegative): (Solver, Option<&LinearModel>),
    colour: Colour,
    solution: &Solution,
    lights: &LightSet,
) -> Result<Uncertainty> {
    let n = rows.pixels.len();
    let prior = basis.column_prior();
    // The sphere relit under the first view's candidate lights, linear in the coefficients.
    let sphere = basis.rendering_matrix(&uncertainty::spread_sphere()?, lights);
    let image = |c: &[f64]| -> Result<Vec<f64>> {
        Ok(sphere.predict_per_channel(channel_coefficients(c, sphere.columns)?))
    };
    let mut coefficients = Vec::new();
    let (mut brdfs, mut images) = (Vec::new(), Vec::new());
    for picks in uncertainty::resamples(n) {
        // A resample with fewer distinct pixels than a channel system has unknowns is left
        // out: least squares would solve it through a pseudo-inverse, a spread of its own.
        let mut distinct = picks.clone();
        distinct.sort_unstable();
        distinct.dedup();
        if distinct.len() < rows.columns {
            continue;
        }
        if let Ok(s) = solver.solve_colour(colour, rows, &picks, observed, &prior, nonnegative) {
            brdfs.push(basis.reconstruct_solution(&s.coefficients)?.values);
            images.push(image(&s.coefficients)?);
            coefficients.push(s.coefficients);
        }
    }
    let band = uncertainty::band(&brdfs);
    let bootstrap_spread = uncertainty::image_spread(&images, &image(&solution.coefficients)?);
    let m = solution.coefficients.len();
    let covariance = if coefficients.len() > 1 {
        uncertainty::sample_covariance(&coefficients)
    } else {
        vec![f64::INFINITY; m * m]
    };
    Ok(Uncertainty {
        std: uncertainty::std_of(&covariance, m),
        covariance,
        covariance_from: "bootstrap",
        bootstrap_spread,
        resamples: coefficients.len(),
        band,
    })
}

/// One view of the object: its per-pixel geometry, the lights in the same (object) frame,
/// and the photo. Several views come from a turntable (see `Camera::turned_about_y`).
pub struct View<'a> {
    pub geometry: &'a PixelGeometry,
    /// The lights every candidate's row is built with (compressed, e.g. to
    /// [`super::envmap::DEFAULT_LIGHTS`]).
    pub lights: &'a LightSet,
    /// Finer lights of the same map for the chosen pixels' rows ([`chosen_rows`]), e.g.
    /// [`super::envmap::CHOSEN_LIGHTS`]; `None` keeps the candidates' rows.
    pub chosen_lights: Option<&'a LightSet>,
    pub photo: &'a Raster,
}

/// The whole estimate from one view.
pub fn estimate(basis: &Basis, view: View, options: &EstimateOptions) -> Result<Estimate> {
    estimate_views(basis, &[view], options)
}

/// Work that estimates of the same scene share: the basis model's rendering matrix for a set
/// of candidates, and each selection made on it. The evaluation estimates every material,
/// with several settings, from photos of one scene; it passes one `Shared` to all of them
/// ([`estimate_views_shared`]) and so builds each matrix and makes each selection once, as the
/// paper's protocol does (selection depends on the rows, not on what the pixels measured).
/// The estimate is the same with or without it.
///
/// Entries are keyed by what they were built from, compared by value: the basis, and each
/// view's candidate pixels (position, normal, view vector) and lights.
#[derive(Default)]
pub struct Shared {
    matrices: Mutex<Vec<(MatrixKey, Arc<RenderingMatrix>)>>,
    selections: Mutex<Vec<(SelectionKey, Selection)>>,
    /// The hybrid model's renders made before the photo ([`Shared::prepare`]).
    hybrid: Mutex<Option<Arc<hybrid::Prepared>>>,
}

/// What a stacked candidate matrix was built from.
struct MatrixKey {
    basis: String,
    views: Vec<(Vec<GeomPixel>, LightSet)>,
}

impl MatrixKey {
    /// Whether this key is of `basis` (its [`basis_tag`]) and these views' pixels and lights:
    /// compared in place, so that a lookup copies nothing.
    fn is(&self, basis: &str, views: &[(&[GeomPixel], &LightSet)]) -> bool {
        self.basis == basis
            && self.views.len() == views.len()
            && self
                .views
                .iter()
                .zip(views)
                .all(|((p, l), (q, m))| p.as_slice() == *q && l == *m)
    }
}

/// The basis as far as its rendering matrix depends on it: the id names the training data,
/// the settings change the model's columns.
fn basis_tag(basis: &Basis) -> String {
    let h = &basis.header;
    format!(
        "{} {:?} {:?} {}",
        h.id, h.normalisation, h.cell_weight, h.mean
    )
}

/// A selection's settings, on the matrix `matrix` (an index into [`Shared::matrices`]).
#[derive(PartialEq)]
struct SelectionKey {
    matrix: usize,
    colour: Colour,
    pixel_count: Option<usize>,
    method: SelectionMethod,
    swap: SwapParams,
}

impl Shared {
    /// The stacked matrix of `candidates` (built by `build` the first time) and its index.
    fn matrix(
        &self,
        basis: &Basis,
        candidates: &[Candidates],
        build: impl FnOnce() -> Result<RenderingMatrix>,
    ) -> Result<(usize, Arc<RenderingMatrix>)> {
        let tag = basis_tag(basis);
        let views: Vec<(&[GeomPixel], &LightSet)> = candidates
            .iter()
            .map(|c| (c.pixels.as_slice(), c.view.lights))
            .collect();
        {
            let matrices = self.matrices.lock().expect("not poisoned");
            if let Some(i) = matrices.iter().position(|(k, _)| k.is(&tag, &views)) {
                return Ok((i, matrices[i].1.clone()));
            }
        }
        // Built without the lock (the build runs on rayon); a race builds twice, harmlessly.
        let a = Arc::new(build()?);
        Ok((self.insert(tag, &views, a.clone()), a))
    }

    /// Keeps `a` as the matrix of `views`; its index.
    fn insert(
        &self,
        basis: String,
        views: &[(&[GeomPixel], &LightSet)],
        a: Arc<RenderingMatrix>,
    ) -> usize {
        let key = MatrixKey {
            basis,
            views: views
                .iter()
                .map(|(p, l)| (p.to_vec(), (*l).clone()))
                .collect(),
        };
        let mut matrices = self.matrices.lock().expect("not poisoned");
        matrices.push((key, a));
        matrices.len() - 1
    }

    /// Gives the basis's rendering matrix `a`, already built for one view's `pixels` under
    /// `lights`, to the estimates that share this: an estimate whose candidates are those
    /// pixels (every object pixel of a photo with none clipped, under the candidate cap)
    /// uses it rather than building it again.
    pub fn seed(
        &self,
        basis: &Basis,
        pixels: &[GeomPixel],
        lights: &LightSet,
        a: Arc<RenderingMatrix>,
    ) {
        self.insert(basis_tag(basis), &[(pixels, lights)], a);
    }

    /// Renders, before the views' photos arrive, what an estimate with `options` will need
    /// of them, taking each view's candidates to be all its pixels (the usual case: no pixel
    /// clipped or unmeasured). An estimate whose candidates turn out to be others renders its
    /// own. Only the hybrid model has such work.
    pub fn prepare(
        &self,
        basis: &Basis,
        views: &[(&PixelGeometry, &LightSet)],
        options: &EstimateOptions,
    ) -> Result<()> {
        if options.model.model() != Model::Hybrid || views.is_empty() {
            return Ok(());
        }
        let per_view = candidates_per_view(options, views.len());
        let candidates: Vec<(Vec<GeomPixel>, &LightSet)> = views
            .iter()
            .map(|(g, lights)| (spread_pixels(&g.pixels, per_view), *lights))
            .collect();
        let views: Vec<(&[GeomPixel], &LightSet)> =
            candidates.iter().map(|(p, l)| (p.as_slice(), *l)).collect();
        let prepared = hybrid::Prepared::new(&views, basis, &options.stop)?;
        *self.hybrid.lock().expect("not poisoned") = Some(Arc::new(prepared));
        Ok(())
    }

    fn hybrid(&self) -> Option<Arc<hybrid::Prepared>> {
        self.hybrid.lock().expect("not poisoned").clone()
    }

    /// [`select_pixels`] on matrix `matrix`, made once per setting.
    fn selection(
        &self,
        matrix: usize,
        basis: &Basis,
        a: &RenderingMatrix,
        options: &BasisOptions,
        colour: Colour,
        stop: &Stop,
    ) -> Result<Selection> {
        let key = SelectionKey {
            matrix,
            colour,
            pixel_count: options.pixel_count,
            method: options.method,
            swap: options.swap.clone(),
        };
        {
            let selections = self.selections.lock().expect("not poisoned");
            if let Some((_, s)) = selections.iter().find(|(k, _)| *k == key) {
                return Ok(s.clone());
            }
        }
        let s = select_pixels(basis, a, options, colour, stop)?;
        self.selections
            .lock()
            .expect("not poisoned")
            .push((key, s.clone()));
        Ok(s)
    }
}

/// One view's candidate pixels ([`candidate_pixels`]) and the view they came from.
struct Candidates<'v, 'a> {
    view: &'v View<'a>,
    pixels: Vec<GeomPixel>,
    observed: Vec<[f64; 3]>,
}

/// The whole estimate from several views, with the model `options` names. Every model sees
/// the same candidates: each view's usable pixels, the candidate budget shared evenly between
/// the views.
pub fn estimate_views(
    basis: &Basis,
    views: &[View],
    options: &EstimateOptions,
) -> Result<Estimate> {
    estimate_views_shared(basis, views, options, &Shared::default())
}

/// [`estimate_views`], sharing work with other estimates of the same scene ([`Shared`]).
pub fn estimate_views_shared(
    basis: &Basis,
    views: &[View],
    options: &EstimateOptions,
    shared: &Shared,
) -> Result<Estimate> {
    if views.is_empty() {
        return Err(CoreError::Invalid("no views to estimate from".into()));
    }
    let per_view = candidates_per_view(options, views.len());
    let mut candidates = Vec::with_capacity(views.len());
    let mut clipped = 0;
    for (i, view) in views.iter().enumerate() {
        let (pixels, observed, c) =
            candidate_pixels(view.geometry, view.photo, per_view, options.white)
                .map_err(|e| CoreError::Invalid(format!("view {}: {e}", i + 1)))?;
        clipped += c;
        candidates.push(Candidates {
            view,
            pixels,
            observed,
        });
    }
    // The anisotropy check reads only the photo: it runs beside the model's fit, which
    // leaves a core idle in its serial steps.
    let (estimate, anisotropy) = rayon::join(
        || model_estimate(basis, &candidates, options, shared),
        || {
            options
                .checks
                .then(|| anisotropy_check(&candidates, &options.stop))
        },
    );
    let mut estimate = estimate?;
    options.stop.check()?;
    let bounced = if options.bounce {
        bounce_refit(basis, &mut candidates, options, shared, &mut estimate)?
    } else {
        None
    };
    // The checks after this judge what the model is asked to fit: with a bounce taken out,
    // the photo less it, which the anisotropy check, made beside the first fit, did not see.
    let anisotropy = match &bounced {
        Some(_) => options
            .checks
            .then(|| anisotropy_check(&candidates, &options.stop)),
        None => anisotropy,
    };
    estimate.clipped = clipped;
    // Turned light first, on the model's own fit (against the whole photo, as it is
    // reported): a lobe chosen under the wrong light would fit a turn it cannot tell from a
    // grain.
    let fit = bounced.as_ref().map_or(estimate.fit_error, |b| b.whole_fit);
    let not_good = fit.is_nan() || fit > CHECK_TURN_ABOVE;
    if options.checks && not_good {
        estimate.registration = registration::check(&view_samples(&candidates), &options.stop);
        options.stop.check()?;
    }
    let turned = estimate.registration.as_ref().is_some_and(|r| r.asks());
    if let Some(mut found) = anisotropy.flatten() {
        if found.asks() && !turned {
            choose_lobe(&mut estimate, &candidates, &mut found);
        }
        estimate.anisotropy = Some(found);
    }
    if let Some(bounced) = bounced {
        put_back_bounce(&mut estimate, &candidates, &bounced);
    }
    Ok(estimate)
}

/// Fits the model again to the photo less the light the part throws on itself, in two
/// rounds. The first fit, made to the whole photo, took the bounce for the material's own and
/// came out too bright by about the bounce's share of the light: the bounce lit through it is
/// scaled down by that share, per channel, a first-order correction, and the model fitted to
/// the photo less it. The second round lights the bounce through that fit, made to direct
/// light, and fits again to the photo less it. On brdfd's Mitsuba set the second round took
/// groove-gold from 0.070 to 0.058 and groove-plastic from 0.108 to 0.097
/// (docs/evaluation.md). The candidates keep the photo less the last bounce, so that the
/// checks after it judge what the model is asked to fit; what is needed to put the photo and
/// the bounce back ([`put_back_bounce`]) is returned: that bounce, the one the final fit was
/// made against. `None` when no view is of a concave mesh, or the first fit lights it with a
/// value that is not a number.
fn bounce_refit(
    basis: &Basis,
    candidates: &mut [Candidates],
    options: &EstimateOptions,
    shared: &Shared,
    estimate: &mut Estimate,
) -> Result<Option<Bounced>> {
    let t = Instant::now();
    let mut paths = Vec::with_capacity(candidates.len());
    for c in candidates.iter() {
        paths.push(Paths::new(&c.pixels, &options.stop)?);
    }
    if paths.iter().all(Option::is_none) {
        return Ok(None);
    }
    let followed = t.elapsed();
    let photo: Vec<[f64; 3]> = candidates
        .iter()
        .flat_map(|c| c.observed.iter().copied())
        .collect();
    let sum = |v: &[[f64; 3]], k: usize| v.iter().map(|x| x[k]).sum::<f64>();
    let brdf = &estimate.brdf;
    let mut bounce = lit(candidates, &paths, tangent_frame, |wi, wo| {
        brdf.eval_dirs(wi, wo)
    });
    if !bounce.iter().flatten().all(|v| v.is_finite()) {
        tracing::warn!("the first fit lights the part's bounce with a value that is not a number: fitted without the bounce");
        return Ok(None);
    }
    let share: [f64; 3] =
        std::array::from_fn(|k| (sum(&bounce, k) / sum(&photo, k).max(f64::MIN_POSITIVE)).min(1.0));
    for b in &mut bounce {
        for k in 0..3 {
            b[k] *= 1.0 - share[k];
        }
    }
    let fit_without = estimate.fit_error;
    // Time spent lighting the bounce and fitting again, over the rounds.
    let (mut lighting, mut fitting, mut mark) = (Duration::ZERO, Duration::ZERO, followed);
    for round in 0..2 {
        if round > 0 {
            let brdf = &estimate.brdf;
            let next = lit(candidates, &paths, tangent_frame, |wi, wo| {
                brdf.eval_dirs(wi, wo)
            });
            if !next.iter().flatten().all(|v| v.is_finite()) {
                // The first round's fit stands, made against a bounce that was a number.
                tracing::warn!("the first round's fit lights the part's bounce with a value that is not a number: kept the first round");
                break;
            }
            bounce = next;
        }
        let lit_at = t.elapsed();
        let mut b = bounce.iter().zip(&photo);
        for c in candidates.iter_mut() {
            for o in c.observed.iter_mut() {
                let (b, y) = b.next().expect("a bounce per candidate");
                *o = std::array::from_fn(|k| (y[k] - b[k]).max(0.0));
            }
        }
        *estimate = model_estimate(basis, candidates, options, shared)?;
        options.stop.check()?;
        lighting += lit_at - mark;
        mark = t.elapsed();
        fitting += mark - lit_at;
    }
    let total: f64 = (0..3).map(|k| sum(&photo, k)).sum();
    estimate.bounce = Some(BounceFit {
        directions: paths.iter().flatten().map(Paths::len).sum(),
        cells: paths.iter().flatten().map(Paths::cells).sum(),
        share: (0..3).map(|k| sum(&bounce, k)).sum::<f64>() / total.max(f64::MIN_POSITIVE),
        pixels: bounce.iter().filter(|b| b.iter().any(|&v| v > 0.0)).count(),
        fit_without,
    });
    tracing::debug!(
        "bounce: paths followed in {:.2} s; lit in {:.2} s and refitted in {:.2} s over the rounds",
        followed.as_secs_f64(),
        lighting.as_secs_f64(),
        fitting.as_secs_f64(),
    );
    let whole_fit = whole_photo_fit(&estimate.rerender, &photo, &bounce);
    Ok(Some(Bounced {
        paths,
        photo,
        rendered: bounce,
        whole_fit,
    }))
}

/// The bounce of every candidate, in order, through the BRDF `eval` in the frames `frame`
/// lays ([`Paths::radiance`]); none off the views' paths.
fn lit(
    candidates: &[Candidates],
    paths: &[Option<Paths>],
    frame: impl Fn([f64; 3]) -> ([f64; 3], [f64; 3]) + Sync + Copy,
    eval: impl Fn([f64; 3], [f64; 3]) -> [f64; 3] + Sync + Copy,
) -> Vec<[f64; 3]> {
    candidates
        .iter()
        .zip(paths)
        .flat_map(|(c, p)| match p {
            Some(p) => p.radiance(&c.pixels, c.view.lights, frame, eval),
            None => vec![[0.0; 3]; c.pixels.len()],
        })
        .collect()
}

/// What [`bounce_refit`] leaves to put back: each view's paths, the photo as measured and the
/// bounce the final fit was made against (lit through the fit before it), per candidate in
/// order, and the final fit with that bounce against the photo.
struct Bounced {
    paths: Vec<Option<Paths>>,
    photo: Vec<[f64; 3]>,
    rendered: Vec<[f64; 3]>,
    /// The model's re-render, with its bounce, against the whole photo.
    whole_fit: f64,
}

/// ‖predicted + bounce − photo‖ / ‖photo‖ over the candidates, `rerender`'s predictions being
/// of direct light.
fn whole_photo_fit(rerender: &[Rerendered], photo: &[[f64; 3]], bounce: &[[f64; 3]]) -> f64 {
    assert_eq!(rerender.len(), photo.len(), "a re-render per candidate");
    let predicted: Vec<f64> = rerender
        .iter()
        .zip(bounce)
        .flat_map(|(r, b)| std::array::from_fn::<f64, 3, _>(|c| r.predicted[c] as f64 + b[c]))
        .collect();
    relative_misfit(&predicted, photo)
}

/// The bounce put back into the estimate's re-render: the photo as measured, and the
/// estimate's render with the bounce its fit was made against (lit through the round before
/// it, which the final fit moved little), or, when it chose an anisotropic lobe, lit through
/// that lobe, as `brdfd render` lights it. The fit is then measured against the whole photo,
/// as without a bounce.
fn put_back_bounce(estimate: &mut Estimate, candidates: &[Candidates], bounced: &Bounced) {
    let lobe_bounce;
    let rendered = match estimate.chosen_lobe() {
        Some(lobe) => {
            let lobe = lobe.clone();
            lobe_bounce = lit(
                candidates,
                &bounced.paths,
                |n| lobe.frame(n),
                |wi, wo| lobe.eval_local(wi, wo),
            );
            &lobe_bounce
        }
        None => &bounced.rendered,
    };
    estimate.fit_error = whole_photo_fit(&estimate.rerender, &bounced.photo, rendered);
    for ((r, y), b) in estimate
        .rerender
        .iter_mut()
        .zip(&bounced.photo)
        .zip(rendered)
    {
        for c in 0..3 {
            r.predicted[c] += b[c] as f32;
            r.observed[c] = y[c] as f32;
        }
    }
}

/// A fit above this (or not a number) is checked for turned light ([`crate::registration`]):
/// a good fit leaves no turn worth finding, and the check costs about 0.6 s on 2 cores.
const CHECK_TURN_ABOVE: f64 = GOOD_FIT;

/// When the photo asks for anisotropy: the lobe, its weights solved again on every
/// candidate, is chosen over the model if it re-renders the photo closer than the model does
/// (a stretched highlight the measured mix already follows needs no other model). Then the
/// estimate's re-render and fit are the lobe's: the photo is compared with what the estimate
/// relights with.
fn choose_lobe(estimate: &mut Estimate, candidates: &[Candidates], found: &mut Anisotropy) {
    let (lobe, predicted) = anisotropy::refit(&view_samples(candidates), &found.lobe);
    let observed: Vec<[f64; 3]> = candidates
        .iter()
        .flat_map(|c| c.observed.iter().copied())
        .collect();
    let fit = relative_misfit(&predicted, &observed);
    tracing::debug!(
        "anisotropic lobe refitted: {fit} against the model's {}",
        estimate.fit_error
    );
    found.chosen = fit < estimate.fit_error;
    if found.chosen {
        found.lobe = lobe;
        estimate.fit_error = fit;
        estimate.rerender = rerendered(candidates, &predicted);
    }
}

/// The estimate of the model `options` name, on these candidates.
fn model_estimate(
    basis: &Basis,
    candidates: &[Candidates],
    options: &EstimateOptions,
    shared: &Shared,
) -> Result<Estimate> {
    let stop = &options.stop;
    match &options.model {
        ModelOptions::Basis(b) => basis_estimate(basis, candidates, b, shared, stop),
        &ModelOptions::Analytic { lobes } => analytic_estimate(basis, candidates, lobes, stop),
        &ModelOptions::Hybrid { lobes } => {
            let prepared = shared.hybrid();
            hybrid_estimate(basis, candidates, lobes, prepared.as_deref(), stop)
        }
    }
}

/// Whether an anisotropic lobe fits the candidates better than an isotropic one
/// ([`anisotropy::compare`]).
fn anisotropy_check(candidates: &[Candidates], stop: &Stop) -> Option<Anisotropy> {
    let t = Instant::now();
    let found = anisotropy::compare(&view_samples(candidates), stop);
    tracing::debug!("anisotropy {found:?} in {:?}", t.elapsed());
    found
}

/// The candidates as the photo's checks read them.
fn view_samples<'c>(candidates: &'c [Candidates]) -> Vec<ViewSamples<'c>> {
    candidates
        .iter()
        .map(|c| ViewSamples {
            pixels: &c.pixels,
            observed: &c.observed,
            lights: c.view.lights,
        })
        .collect()
}

fn view_pixels<'c>(candidates: &'c [Candidates]) -> Vec<ViewPixels<'c>> {
    candidates
        .iter()
        .map(|c| ViewPixels {
            pixels: &c.pixels,
            observed: &c.observed,
            lights: c.view.lights,
        })
        .collect()
}

/// The hybrid model ([`hybrid::fit`]) on every candidate.
fn hybrid_estimate(
    basis: &Basis,
    candidates: &[Candidates],
    lobes: usize,
    prepared: Option<&hybrid::Prepared>,
    stop: &Stop,
) -> Result<Estimate> {
    let t = Instant::now();
    let fit = hybrid::fit(&view_pixels(candidates), basis, lobes, prepared, stop)?;
    let n = fit.candidates;
    Ok(Estimate {
        brdf: fit.brdf,
        outcome: Outcome::Hybrid {
            analytic: fit.analytic,
            mixture: fit.mixture,
        },
        uncertainty: fit.uncertainty,
        names: fit.names,
        solution: Solution {
            coefficients: fit.coefficients,
            residual_rms: {
                let y2: f64 = candidates
                    .iter()
                    .flat_map(|c| c.observed.iter().flatten())
                    .map(|v| v * v)
                    .sum();
                fit.fit_error * (y2 / (3 * n).max(1) as f64).sqrt()
            },
            relative_residual: fit.solved_misfit,
            condition: fit.condition,
        },
        candidates: n,
        solved: fit.solved,
        clipped: 0,
        fit_error: fit.fit_error,
        model_fit: fit.fit_error,
        rerender: rerendered(candidates, &fit.predicted),
        lights: candidates.first().map_or(0, |c| c.view.lights.len()),
        timings: Timings {
            solve_s: secs(t.elapsed()),
            prepared: fit.prepared,
            ..Timings::default()
        },
        anisotropy: None,
        registration: None,
        bounce: None,
    })
}

/// The analytic model ([`analytic::fit`]) on every candidate.
fn analytic_estimate(
    basis: &Basis,
    candidates: &[Candidates],
    lobes: usize,
    stop: &Stop,
) -> Result<Estimate> {
    let t = Instant::now();
    let grid = basis.header.grid;
    let fit = analytic::fit(&view_pixels(candidates), grid, lobes, stop)?;
    let predicted = fit.predicted();
    let fit_error = relative_misfit(&predicted, &fit.observed);
    let n = fit.observed.len();
    let rows = (3 * n).max(1) as f64;
    let y2: f64 = fit.observed.iter().flatten().map(|v| v * v).sum();
    let residual = fit_error * y2.sqrt();
    Ok(Estimate {
        brdf: fit.model.bivariate(grid),
        names: fit.model.names(),
        solution: Solution {
            coefficients: fit.model.values(),
            residual_rms: residual / rows.sqrt(),
            relative_residual: fit_error,
            condition: fit.condition,
        },
        outcome: Outcome::Analytic(fit.model),
        uncertainty: fit.uncertainty,
        // Every candidate is used: no pixel is singled out.
        candidates: n,
        solved: n,
        clipped: 0,
        fit_error,
        model_fit: fit_error,
        rerender: rerendered(candidates, &predicted),
        lights: candidates.first().map_or(0, |c| c.view.lights.len()),
        timings: Timings {
            solve_s: secs(t.elapsed()),
            ..Timings::default()
        },
        anisotropy: None,
        registration: None,
        bounce: None,
    })
}

/// The paper's model: the basis's rendering matrix over the stacked candidates, selection,
/// and the solve, for each colour model the choice names.
fn basis_estimate(
    basis: &Basis,
    candidates: &[Candidates],
    options: &BasisOptions,
    shared: &Shared,
    stop: &Stop,
) -> Result<Estimate> {
    let t = Instant::now();
    let mut observed = Vec::new();
    let mut view_of_pixel = Vec::new();
    for (i, c) in candidates.iter().enumerate() {
        view_of_pixel.extend(std::iter::repeat_n(i, c.pixels.len()));
        observed.extend_from_slice(&c.observed);
    }
    let (matrix, a) = shared.matrix(basis, candidates, || {
        stacked_matrix(basis, candidates, stop)
    })?;
    let matrix_s = secs(t.elapsed());
    // Each model the choice names, fewer unknowns first, keeping the one that re-renders the
    // photo best ([`keep_better_fit`]). A model that cannot solve (say, least squares per channel
    // on fewer pixels than unknowns) is left out while another remains.
    let mut timings = Timings {
        rendering_matrix_s: matrix_s,
        ..Timings::default()
    };
    type Tried = (Colour, Selection, Solution, Uncertainty, Vec<f64>);
    let mut best: Option<(Tried, f64)> = None;
    let mut colour_fits = Vec::new();
    let mut failure = None;
    for &colour in options.colour.models() {
        stop.check()?;
        let lights = candidates[0].view.lights;
        let tried = estimate_from_matrix(
            basis,
            &a,
            &observed,
            options,
            colour,
            lights,
            |p| candidates[view_of_pixel[p]].view.chosen_lights,
            || shared.selection(matrix, basis, &a, options, colour, stop),
        );
        let (selection, solution, uncertainty, t) = match tried {
            Ok(done) => done,
            Err(CoreError::Stopped) => return Err(CoreError::Stopped),
            Err(e) => {
                if options.colour.models().len() > 1 {
                    tracing::warn!(colour = colour.name(), "colour model left out: {e}");
                }
                failure = Some(e);
                continue;
            }
        };
        timings.selection_s += t.selection_s;
        timings.chosen_rows_s += t.chosen_rows_s;
        timings.solve_s += t.solve_s;
        let per_channel = channel_coefficients(&solution.coefficients, a.columns)?;
        let predicted = a.predict_per_channel(per_channel);
        let fit = relative_misfit(&predicted, &observed);
        colour_fits.push((colour, fit));
        let tried = (colour, selection, solution, uncertainty, predicted);
        best = keep_better_fit(best, (tried, fit));
    }
    let Some(((colour, selection, solution, uncertainty, predicted), fit_error)) = best else {
        return Err(failure.expect("every colour choice names a model"));
    };
    let chosen_lights = candidates
        .first()
        .and_then(|c| c.view.chosen_lights)
        .filter(|_| rebuilds_rows(selection.pixels.len()))
        .map_or(0, |l| l.len());
    let chosen = selection
        .pixels
        .iter()
        .map(|&p| (a.pixels[p].x, a.pixels[p].y))
        .collect();
    let chosen_views = selection.pixels.iter().map(|&p| view_of_pixel[p]).collect();
    Ok(Estimate {
        brdf: basis.reconstruct_solution(&solution.coefficients)?,
        uncertainty,
        names: colour.names(&basis.model().names),
        solution,
        candidates: a.pixels.len(),
        solved: selection.pixels.len(),
        outcome: Outcome::Basis(BasisOutcome {
            solver: options.solver,
            colour,
            colour_fits,
            selection,
            chosen,
            chosen_views,
            chosen_lights,
        }),
        clipped: 0,
        fit_error,
        model_fit: fit_error,
        rerender: rerendered(candidates, &predicted),
        lights: candidates.first().map_or(0, |c| c.view.lights.len()),
        timings,
        anisotropy: None,
        registration: None,
        bounce: None,
    })
}

/// The basis's rendering matrix over every view's candidates, stacked in view order.
fn stacked_matrix(
    basis: &Basis,
    candidates: &[Candidates],
    stop: &Stop,
) -> Result<RenderingMatrix> {
    let mut stacked: Option<RenderingMatrix> = None;
    for c in candidates {
        stop.check()?;
        let a = basis.rendering_matrix(&c.pixels, c.view.lights);
        stacked = Some(match stacked {
            None => a,
            Some(mut all) => {
                all.append(a).map_err(CoreError::Invalid)?;
                all
            }
        });
    }
    stacked.ok_or_else(|| CoreError::Invalid("no views to estimate from".into()))
}

/// A fit to the photo ([`Estimate::fit_error`]) at or below this is called good: the estimate
/// re-renders the photo about as well as the best model of a real material does (measured:
/// the analytic model fits the MERL test materials' photos to a median 0.055, the basis with
/// every pixel to 0.075; `brdfd eval --relight`).
pub const GOOD_FIT: f64 = 0.10;
/// Above this the fit is called poor: the estimate does not look like the photo, and it
/// should not be trusted under other light (the paper's 20-pixel method's median was 0.27).
pub const POOR_FIT: f64 = 0.25;

/// Above this bootstrap spread ([`Uncertainty::bootstrap_spread`]) an estimate is called
/// unsteady: resampling its pixels moves its relit sphere by more than 5% RMS, so the pixels do
/// not pin it down. Measured on the README's main command's files: the default 0.5%, the basis
/// with every pixel 0.5%, with 20 pixels 39% (the paper's least squares: 34%).
pub const UNSTEADY_SPREAD: f64 = 0.05;

/// The verdict in words on a fit to the photo, with the thresholds it was judged by.
pub fn fit_verdict(fit: f64) -> String {
    let (word, bounds) = fit_judged(fit);
    format!("{word}: {bounds}")
}

/// The threshold a fit to the photo was judged by, and what to do when it is not good: the
/// words after [`fit_verdict`]'s grade, for lines that already lead with it (so a good fit's
/// threshold says what it is the threshold of).
pub fn fit_bounds(fit: f64) -> String {
    match fit_judged(fit) {
        ("good", bounds) => format!("{bounds} is good"),
        (_, bounds) => bounds,
    }
}

/// A fit's grade word and the words that follow it in [`fit_verdict`].
fn fit_judged(fit: f64) -> (&'static str, String) {
    if !fit.is_finite() {
        ("no verdict", "the fit is not a number".into())
    } else if fit <= GOOD_FIT {
        ("good", format!("at most {GOOD_FIT}"))
    } else if fit <= POOR_FIT {
        (
            "fair",
            format!("above {GOOD_FIT}; compare the preview with the photo"),
        )
    } else {
        ("poor", format!("above {POOR_FIT}, the estimate does not reproduce the photo; check the geometry, the exposure and the light map"))
    }
}

impl Estimate {
    /// The anisotropic lobe the estimate relights with, when it chose one over its model
    /// ([`Anisotropy::chosen`]).
    pub fn chosen_lobe(&self) -> Option<&AnisotropicLobe> {
        self.anisotropy
            .as_ref()
            .filter(|a| a.chosen)
            .map(|a| &a.lobe)
    }

    /// The estimate on a `size` × `size` sphere under `lights`: its chosen lobe when it chose
    /// one, else its BRDF.
    pub fn sphere_picture(&self, lights: &LightSet, size: usize) -> Result<SpherePicture> {
        match self.chosen_lobe() {
            Some(lobe) => SpherePicture::render_lobe(lobe, lights, size),
            None => SpherePicture::render(&self.brdf, lights, size),
        }
    }

    /// The model fitted.
    pub fn model(&self) -> Model {
        self.outcome.model()
    }

    /// The condition number the estimate reports: of the chosen pixels' system for the basis
    /// model (its selection's criterion; the prior's own solve is underdetermined by design),
    /// of the weights' solve for the others.
    pub fn condition(&self) -> f64 {
        match &self.outcome {
            Outcome::Basis(b) => b.selection.condition,
            _ => self.solution.condition,
        }
    }

    /// The pixels the estimate used: the basis model's chosen ones; every candidate for the
    /// analytic and hybrid models, which single none out.
    pub fn pixel_count(&self) -> usize {
        self.outcome
            .basis()
            .map_or(self.candidates, |b| b.selection.pixels.len())
    }

    /// [`Estimate::condition`] for a person to read.
    pub fn condition_text(&self) -> String {
        select::condition_text(self.condition())
    }

    /// The colour model of the coefficients: the basis model's choice; the other models
    /// weigh each channel on its own.
    pub fn colour(&self) -> Colour {
        self.outcome
            .basis()
            .map_or(Colour::PerChannel, |b| b.colour)
    }

    /// The model and its settings, for a person to read.
    pub fn method_text(&self) -> String {
        let alphas = |m: &Microfacet| {
            let alphas: Vec<String> = m.lobes.iter().map(|l| format!("{:.4}", l.alpha)).collect();
            format!(
                "Lambert + {} GGX lobe{}, roughness α {}",
                m.lobes.len(),
                if m.lobes.len() == 1 { "" } else { "s" },
                alphas.join(" and ")
            )
        };
        match &self.outcome {
            Outcome::Analytic(m) => format!(
                "model analytic ({}), every one of {} pixels",
                alphas(m),
                self.candidates
            ),
            Outcome::Hybrid { analytic, mixture } => {
                // The measured atoms are not what the object is made of (a gold estimate
                // may mix in a walnut's table): they are counted, not named.
                let atoms = mixture.len();
                format!(
                    "model hybrid ({}, and {} measured atom{} of the MERL database), solved on {} pixels spread over all {}",
                    alphas(analytic),
                    atoms,
                    if atoms == 1 { "" } else { "s" },
                    self.solved,
                    self.candidates
                )
            }
            Outcome::Basis(b) => format!(
                "model basis, {} of {} pixels, solver {}, {}",
                b.selection.pixels.len(),
                self.candidates,
                b.solver.name(),
                b.colour_text(self.fit_error)
            ),
        }
    }

    /// How sure the estimate is, in words, where it was measured; and whether to distrust it.
    pub fn certainty_text(&self) -> (String, bool) {
        let u = &self.uncertainty;
        let unsteady = u.bootstrap_spread > UNSTEADY_SPREAD;
        // A fit that is not a number is as untrustworthy as a poor one.
        let poor = self.fit_error.is_nan() || self.fit_error > POOR_FIT;
        let text = format!(
            "resampling the pixels {} times moves the estimate's relit sphere by {:.1}% RMS ({} {:.0}%){}",
            u.resamples,
            100.0 * u.bootstrap_spread,
            if unsteady {
                "unsteady: above"
            } else {
                "steady: at most"
            },
            100.0 * UNSTEADY_SPREAD,
            if poor || unsteady {
                "; do not trust this estimate under other light"
            } else {
                ""
            }
        );
        (text, poor || unsteady)
    }
}

impl BasisOutcome {
    /// The colour model for a person to read, and when several were tried, why this one
    /// (`fit` being the kept model's).
    fn colour_text(&self, fit: f64) -> String {
        let others: Vec<String> = self
            .colour_fits
            .iter()
            .filter(|(c, _)| *c != self.colour)
            .map(|(c, fit)| format!("{} {fit:.4}", c.name()))
            .collect();
        if others.is_empty() {
            format!("colour {}", self.colour.name())
        } else {
            format!(
                "colour {} (the better fit to the photo: {fit:.4} against {})",
                self.colour.name(),
                others.join(", ")
            )
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_fits_grade_is_said_once() {
        assert_eq!(fit_verdict(0.05), "good: at most 0.1");
        assert_eq!(fit_bounds(0.05), "at most 0.1 is good");
        assert!(fit_verdict(0.2).starts_with("fair: above 0.1; "));
        assert!(fit_bounds(0.2).starts_with("above 0.1; "));
        assert!(fit_verdict(0.3).starts_with("poor: above 0.25, "));
        assert_eq!(fit_verdict(f64::NAN), "no verdict: the fit is not a number");
        for fit in [0.05, 0.2, 0.3, f64::NAN] {
            let (verdict, bounds) = (fit_verdict(fit), fit_bounds(fit));
            assert!(verdict.matches("good").count() <= 1, "{verdict}");
            assert!(
                !bounds.starts_with("good")
                    && !bounds.starts_with("fair")
                    && !bounds.starts_with("poor"),
                "{bounds}"
            );
        }
    }
}
