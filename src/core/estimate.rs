//! The estimate from measurements: photo + lights + geometry + basis → coefficients.
//! Used by `brdfd estimate`, the evaluation and the capture flow alike.

use std::time::{Duration, Instant};

use serde::Serialize;

use super::basis::Basis;
use super::bivariate::Bivariate;
use super::envmap::LightSet;
use super::error::{CoreError, Result};
use super::geometry::{GeomPixel, PixelGeometry};
use super::raster::Raster;
use super::render::RenderingMatrix;
use super::select::{self, Blocks, Selection, SwapParams};
use super::solve::{channel_coefficients, Colour, ColourChoice, Solution, Solver};

/// Chosen pixels whose rows are rebuilt with the view's finer lights at most (see
/// [`chosen_rows`]): 20 pixels under 65,536 lights cost about as much as 320 under the
/// default 4,096, so this bounds the rebuild near the cost of the candidates' matrix. Above
/// it (an "all pixels" estimate), the solve keeps the candidates' rows: over thousands of
/// rows, compression errors of single pixels average out.
pub const MAX_CHOSEN_ROWS: usize = 2_000;

/// Candidate pixels considered at most: a 16-megapixel photo holds millions of object pixels,
/// and conditioning saturates long before this many (see README, "Speed").
pub const DEFAULT_MAX_CANDIDATES: usize = 50_000;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum SelectionMethod {
    /// The paper's swap search.
    Paper,
    /// Our exchange search (default).
    Fast,
}

/// What to estimate with.
#[derive(Clone, Debug)]
pub struct EstimateOptions {
    /// Pixels to use; `None` for every candidate.
    pub pixel_count: Option<usize>,
    pub method: SelectionMethod,
    pub swap: SwapParams,
    pub max_candidates: usize,
    pub solver: Solver,
    pub colour: ColourChoice,
    /// The photo's white level, if it has one: a value at or above it was clipped, so it is
    /// only a lower bound on the radiance. Pixels with a clipped channel are not candidates.
    /// 8-bit photos have one (1.0 after decoding); an HDR merge or a linear EXR usually not.
    pub white: Option<f32>,
}

impl Default for EstimateOptions {
    fn default() -> Self {
        EstimateOptions {
            pixel_count: Some(20),
            method: SelectionMethod::Fast,
            swap: SwapParams::default(),
            max_candidates: DEFAULT_MAX_CANDIDATES,
            solver: Solver::default(),
            colour: ColourChoice::default(),
            white: None,
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
}

/// The result, as written to `coefficients.json` (plus the basis id the caller adds).
#[derive(Clone, Debug)]
pub struct Estimate {
    /// Names of the solution's coefficients (per channel for [`Colour::PerChannel`]).
    pub names: Vec<String>,
    pub solution: Solution,
    pub solver: Solver,
    /// The model that gave this estimate (with [`ColourChoice::Auto`], the better fit).
    pub colour: Colour,
    /// Each model tried, with its fit ([`Estimate::fit_error`]); one unless the choice was
    /// [`ColourChoice::Auto`].
    pub colour_fits: Vec<(Colour, f64)>,
    pub selection: Selection,
    /// Image positions (x, y) of the chosen pixels.
    pub chosen: Vec<(u32, u32)>,
    /// Which view (0 for the first) each chosen pixel is from.
    pub chosen_views: Vec<usize>,
    pub candidates: usize,
    /// Object pixels left out because a channel was clipped (see [`EstimateOptions::white`]).
    pub clipped: usize,
    /// ‖A·c − y‖ / ‖y‖ over every candidate pixel, not only the chosen ones: how well the
    /// estimate re-renders the photo, with no ground truth needed.
    pub fit_error: f64,
    pub lights: usize,
    /// Lights the chosen pixels' rows were rebuilt with (first view); 0 if they kept the
    /// candidates' rows.
    pub chosen_lights: usize,
    pub timings: Timings,
}

/// How much better (in [`Estimate::fit_error`], a relative RMSE) a colour model with more
/// unknowns must re-render the photo to be kept over one with fewer. Below 0.1% of the
/// photo's RMS the fits agree: an in-span joint BRDF fits both to rounding, and the model
/// with fewer unknowns, the paper's, should win that tie rather than rounding deciding it.
pub const COLOUR_FIT_MARGIN: f64 = 1e-3;

/// The rule `auto` chooses by, for estimates offered in order of increasing unknowns, each
/// with its fit: the `candidate` replaces the `kept` one only if it fits better by more than
/// [`COLOUR_FIT_MARGIN`]. The evaluation's `prior-auto` uses it too.
pub fn keep_better_fit<T>(kept: Option<(T, f64)>, candidate: (T, f64)) -> Option<(T, f64)> {
    match kept {
        Some(k) if candidate.1 >= k.1 - COLOUR_FIT_MARGIN => Some(k),
        _ => Some(candidate),
    }
}

/// Spreads `max` picks evenly over `0..n` (deterministic, keeps the image's coverage).
pub fn spread(n: usize, max: usize) -> Vec<usize> {
    if n <= max {
        return (0..n).collect();
    }
    (0..max).map(|i| i * n / max).collect()
}

fn secs(d: Duration) -> f64 {
    d.as_secs_f64()
}

/// Builds A for the candidate pixels of `geometry` under `lights`: pixels the photo saw with
/// finite, non-negative values, below `white` if given. Also returns how many were clipped.
pub fn candidate_matrix(
    basis: &Basis,
    geometry: &PixelGeometry,
    lights: &LightSet,
    photo: &Raster,
    max_candidates: usize,
    white: Option<f32>,
) -> Result<(RenderingMatrix, Vec<[f64; 3]>, usize)> {
    if (photo.width, photo.height) != (geometry.width, geometry.height) {
        return Err(CoreError::Invalid(format!(
            "the photo is {}×{} but the geometry is {}×{}",
            photo.width, photo.height, geometry.width, geometry.height
        )));
    }
    let measured: Vec<_> = geometry
        .pixels
        .iter()
        .filter(|p| {
            photo
                .get(p.x as usize, p.y as usize)
                .iter()
                .all(|v| v.is_finite() && *v >= 0.0)
        })
        .copied()
        .collect();
    let unclipped = |p: &GeomPixel| {
        white.is_none_or(|w| photo.get(p.x as usize, p.y as usize).iter().all(|v| *v < w))
    };
    let usable: Vec<_> = measured.iter().filter(|p| unclipped(p)).copied().collect();
    let clipped = measured.len() - usable.len();
    if usable.is_empty() {
        return Err(CoreError::Invalid(if clipped > 0 {
            format!("every object pixel of the photo is clipped ({clipped} at or above the white level {}); use a shorter exposure", white.unwrap_or(0.0))
        } else {
            "no object pixel of the photo is usable (mask empty, or all values negative/NaN)".into()
        }));
    }
    let picked: Vec<_> = spread(usable.len(), max_candidates)
        .into_iter()
        .map(|i| usable[i])
        .collect();
    let a = basis.rendering_matrix(&picked, lights);
    let observed = picked
        .iter()
        .map(|p| photo.get(p.x as usize, p.y as usize).map(|v| v as f64))
        .collect();
    Ok((a, observed, clipped))
}

/// The pixels `options` asks for, chosen on a prepared rendering matrix for a solve with
/// `colour`: selection conditions the systems that solve will use, one joint system or one
/// per channel (see [`Blocks`]).
pub fn select_pixels(
    basis: &Basis,
    a: &RenderingMatrix,
    options: &EstimateOptions,
    colour: Colour,
) -> Selection {
    let blocks = Blocks::for_colour(a, &basis.column_scales(), colour);
    match options.pixel_count {
        None => select::all_pixels(&blocks),
        Some(l) => match options.method {
            SelectionMethod::Paper => select::paper_swap(&blocks, l, &options.swap),
            SelectionMethod::Fast => select::fast_exchange(&blocks, l),
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
        let pixels: Vec<GeomPixel> = members.iter().map(|&i| rows.pixels[i]).collect();
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

/// Selection, the chosen rows ([`chosen_rows`]) and the solve with `colour`, on a prepared
/// rendering matrix.
pub fn estimate_from_matrix<'l>(
    basis: &Basis,
    a: &RenderingMatrix,
    observed: &[[f64; 3]],
    options: &EstimateOptions,
    colour: Colour,
    lights_of: impl Fn(usize) -> Option<&'l LightSet>,
) -> Result<(Selection, Solution, Timings)> {
    let mut timings = Timings::default();
    let t = Instant::now();
    let selection = select_pixels(basis, a, options, colour);
    timings.selection_s = secs(t.elapsed());
    let t = Instant::now();
    let rows = chosen_rows(basis, a, &selection.pixels, lights_of);
    let chosen_observed: Vec<[f64; 3]> = selection.pixels.iter().map(|&p| observed[p]).collect();
    timings.chosen_rows_s = secs(t.elapsed());
    let t = Instant::now();
    let all_rows: Vec<usize> = (0..rows.pixels.len()).collect();
    let solution = options.solver.solve_colour(
        colour,
        &rows,
        &all_rows,
        &chosen_observed,
        &basis.column_prior(),
    )?;
    timings.solve_s = secs(t.elapsed());
    Ok((selection, solution, timings))
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

/// The whole estimate from several views: each view's candidate rows are stacked, so the
/// pixel selection chooses among the normals of every view and one solve uses them all.
/// The candidate budget is shared evenly between the views.
pub fn estimate_views(
    basis: &Basis,
    views: &[View],
    options: &EstimateOptions,
) -> Result<Estimate> {
    let t = Instant::now();
    let per_view = (options.max_candidates / views.len().max(1)).max(1);
    let mut stacked: Option<(RenderingMatrix, Vec<[f64; 3]>)> = None;
    let mut view_of_pixel = Vec::new();
    let mut clipped = 0;
    for (i, v) in views.iter().enumerate() {
        let (a, observed, c) = candidate_matrix(
            basis,
            v.geometry,
            v.lights,
            v.photo,
            per_view,
            options.white,
        )
        .map_err(|e| CoreError::Invalid(format!("view {}: {e}", i + 1)))?;
        clipped += c;
        view_of_pixel.extend(std::iter::repeat_n(i, a.pixels.len()));
        stacked = Some(match stacked {
            None => (a, observed),
            Some((mut all, mut all_observed)) => {
                all.append(a).map_err(CoreError::Invalid)?;
                all_observed.extend(observed);
                (all, all_observed)
            }
        });
    }
    let (a, observed) =
        stacked.ok_or_else(|| CoreError::Invalid("no views to estimate from".into()))?;
    let matrix_s = secs(t.elapsed());
    // Each model the choice names, fewer unknowns first, keeping the one that re-renders the
    // photo best ([`keep_better_fit`]). A model that cannot solve (say, least squares per channel
    // on fewer pixels than unknowns) is left out while another remains.
    let mut timings = Timings {
        rendering_matrix_s: matrix_s,
        ..Timings::default()
    };
    let mut best: Option<((Colour, Selection, Solution), f64)> = None;
    let mut colour_fits = Vec::new();
    let mut failure = None;
    for &colour in options.colour.models() {
        let tried = estimate_from_matrix(basis, &a, &observed, options, colour, |p| {
            views[view_of_pixel[p]].chosen_lights
        });
        let (selection, solution, t) = match tried {
            Ok(done) => done,
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
        let fit = relative_misfit(&a.predict_per_channel(per_channel), &observed);
        colour_fits.push((colour, fit));
        best = keep_better_fit(best, ((colour, selection, solution), fit));
    }
    let Some(((colour, selection, solution), fit_error)) = best else {
        return Err(failure.expect("every colour choice names a model"));
    };
    let chosen_lights = views
        .first()
        .and_then(|v| v.chosen_lights)
        .filter(|_| rebuilds_rows(selection.pixels.len()))
        .map_or(0, |l| l.len());
    let chosen = selection
        .pixels
        .iter()
        .map(|&p| (a.pixels[p].x, a.pixels[p].y))
        .collect();
    let chosen_views = selection.pixels.iter().map(|&p| view_of_pixel[p]).collect();
    Ok(Estimate {
        names: colour.names(&basis.model().names),
        solution,
        solver: options.solver,
        colour,
        colour_fits,
        selection,
        chosen,
        chosen_views,
        candidates: a.pixels.len(),
        clipped,
        fit_error,
        lights: views.first().map_or(0, |v| v.lights.len()),
        chosen_lights,
        timings,
    })
}

/// ‖predicted − observed‖ / ‖observed‖ over every pixel and channel.
pub fn relative_misfit(predicted: &[f64], observed: &[[f64; 3]]) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    for (p, o) in predicted.chunks_exact(3).zip(observed) {
        for c in 0..3 {
            num += (p[c] - o[c]).powi(2);
            den += o[c] * o[c];
        }
    }
    (num / den.max(f64::MIN_POSITIVE)).sqrt()
}

impl Estimate {
    /// The colour model for a person to read, and when several were tried, why this one.
    pub fn colour_text(&self) -> String {
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
                "colour {} (the better fit to the photo: {:.4} against {})",
                self.colour.name(),
                self.fit_error,
                others.join(", ")
            )
        }
    }

    pub fn brdf(&self, basis: &Basis) -> Bivariate {
        basis
            .reconstruct_solution(&self.solution.coefficients)
            .expect("an estimate's coefficients fit its basis")
    }
}
