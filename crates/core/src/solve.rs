//! Solving for the coefficients on the chosen rows: plain least squares (the paper's), and a
//! maximum a posteriori solve whose prior is the spread of the PCA scores over the training set.

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

use super::basis::LinearModel;
use super::bivariate::{GRID_CELLS, VALUES};
use super::error::{CoreError, Result};
use super::nnls::least_distance;
use super::render::RenderingMatrix;

/// How coefficients are solved from the chosen rows.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[serde(rename_all = "kebab-case")]
pub enum Solver {
    /// Least squares, as in the paper.
    LeastSquares,
    /// Least squares with the training set's prior (`with_prior_system`); the default, measured in
    /// docs/evaluation.md.
    #[default]
    Prior,
}

impl Solver {
    pub fn name(self) -> &'static str {
        match self {
            Solver::LeastSquares => "least-squares",
            Solver::Prior => "prior",
        }
    }

    /// Solves for one set of coefficients for all three channels. With `nonnegative`, the
    /// model whose coefficients these are, the BRDF they reconstruct is kept ≥ 0 in every cell
    /// (the constrained optimum, not a clamp); without, the solve is unconstrained (the
    /// paper's).
    pub fn solve(
        self,
        a: &RenderingMatrix,
        pixels: &[usize],
        observed: &[[f64; 3]],
        prior: &[Option<f64>],
        nonnegative: Option<&LinearModel>,
    ) -> Result<Solution> {
        let (x, y) = system(a, pixels, observed);
        let cells = nonnegative.map(|model| Cells::new(model, 0..VALUES));
        self.solve_system(pixels.len(), x, y, prior, cells)
    }

    fn solve_system(
        self,
        pixels: usize,
        x: DMatrix<f64>,
        y: DVector<f64>,
        prior: &[Option<f64>],
        cells: Option<Cells>,
    ) -> Result<Solution> {
        match self {
            Solver::LeastSquares => least_squares_system(pixels, x, y, cells),
            Solver::Prior => with_prior_system(pixels, x, y, prior, cells),
        }
    }

    /// Solves with the given colour model: [`Colour::Joint`] is [`Solver::solve`];
    /// [`Colour::PerChannel`] solves each channel from its own rows, and the coefficients are
    /// the three channels' in turn (R, G, B; see [`channel_coefficients`](super::basis::channel_coefficients)), each channel's
    /// BRDF kept ≥ 0 with `nonnegative` as in [`Solver::solve`].
    pub(crate) fn solve_colour(
        self,
        colour: Colour,
        a: &RenderingMatrix,
        pixels: &[usize],
        observed: &[[f64; 3]],
        prior: &[Option<f64>],
        nonnegative: Option<&LinearModel>,
    ) -> Result<Solution> {
        if colour == Colour::Joint {
            return self.solve(a, pixels, observed, prior, nonnegative);
        }
        let mut coefficients = Vec::with_capacity(3 * a.columns);
        let (mut residual2, mut observed2, mut condition) = (0.0, 0.0, 0.0f64);
        for c in 0..3 {
            let (x, y) = system_of(a, pixels, observed, &[c]);
            let rows = y.len() as f64;
            observed2 += y.norm_squared();
            let cells =
                nonnegative.map(|model| Cells::new(model, c * GRID_CELLS..(c + 1) * GRID_CELLS));
            let sol = self
                .solve_system(pixels.len(), x, y, prior, cells)
                .map_err(|e| CoreError::Invalid(format!("{} channel: {e}", CHANNELS[c])))?;
            // The channel's squared residual, back from its RMS over its rows.
            residual2 += sol.residual_rms.powi(2) * rows;
            condition = condition.max(sol.condition);
            coefficients.extend(sol.coefficients);
        }
        let rows = (3 * pixels.len()).max(1) as f64;
        Ok(Solution {
            coefficients,
            residual_rms: (residual2 / rows).sqrt(),
            relative_residual: (residual2 / observed2.max(f64::MIN_POSITIVE)).sqrt(),
            condition,
        })
    }
}

/// Channel names, in the order of the rendering matrix's rows.
pub const CHANNELS: [&str; 3] = ["R", "G", "B"];

/// How colour is modelled.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Colour {
    /// One set of coefficients for all three channels, as in the paper: each basis vector is
    /// an RGB pattern, so an estimate's colour is a blend of the training set's component
    /// colours (gold can come out red, chrome green).
    Joint,
    /// One set of coefficients per channel: channel c is the basis's channel-c planes combined
    /// with its own coefficients, so colour is free. Three times the unknowns, each channel
    /// solved from its own rows of the same pixels.
    PerChannel,
}

impl Colour {
    pub fn name(self) -> &'static str {
        match self {
            Colour::Joint => "joint",
            Colour::PerChannel => "per-channel",
        }
    }

    /// Column names of the solution: the model's, or each of them per channel (`pc1.R`).
    pub fn names(self, model: &[String]) -> Vec<String> {
        match self {
            Colour::Joint => model.to_vec(),
            Colour::PerChannel => CHANNELS
                .iter()
                .flat_map(|c| model.iter().map(move |n| format!("{n}.{c}")))
                .collect(),
        }
    }
}

/// The colour model an estimate is asked for (`--colour`, a preset's `colour`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[serde(rename_all = "kebab-case")]
pub enum ColourChoice {
    Joint,
    PerChannel,
    /// Both, keeping the estimate that re-renders the photo better over every candidate
    /// pixel (not only the chosen ones, so the per-channel model's three times as many
    /// unknowns cannot win by fitting its own pixels). The default: per channel fixes the
    /// colour of coloured materials, but tints mirrors, whose joint estimate fits better
    /// (docs/method.md, "Colour").
    #[default]
    Auto,
}

impl ColourChoice {
    /// The models an estimate tries.
    pub fn models(self) -> &'static [Colour] {
        match self {
            ColourChoice::Joint => &[Colour::Joint],
            ColourChoice::PerChannel => &[Colour::PerChannel],
            ColourChoice::Auto => &[Colour::Joint, Colour::PerChannel],
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            ColourChoice::Joint => "joint",
            ColourChoice::PerChannel => "per-channel",
            ColourChoice::Auto => "auto",
        }
    }
}

/// ‖predicted − observed‖ / ‖observed‖ over every pixel and channel.
pub(crate) fn relative_misfit(predicted: &[f64], observed: &[[f64; 3]]) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    for (p, o) in predicted.chunks_exact(3).zip(observed) {
        for c in 0..3 {
            num += (p[c] - o[c]).powi(2);
            den += o[c] * o[c];
        }
    }
    (num / den.max(f64::MIN_POSITIVE)).sqrt()
}

#[derive(Clone, Debug)]
pub struct Solution {
    pub coefficients: Vec<f64>,
    /// RMS of y − A·c over the rows used.
    pub residual_rms: f64,
    /// ‖y − A·c‖ / ‖y‖ over the rows used.
    pub relative_residual: f64,
    /// κ of the rows used.
    pub condition: f64,
}

/// Stacks the rows of `pixels` (indices into `a`) and the matching observations.
/// `observed[p]` is the linear RGB that pixel `a.pixels[p]` measured.
fn system(
    a: &RenderingMatrix,
    pixels: &[usize],
    observed: &[[f64; 3]],
) -> (DMatrix<f64>, DVector<f64>) {
    system_of(a, pixels, observed, &[0, 1, 2])
}

/// [`system`] with only the rows of `channels`.
fn system_of(
    a: &RenderingMatrix,
    pixels: &[usize],
    observed: &[[f64; 3]],
    channels: &[usize],
) -> (DMatrix<f64>, DVector<f64>) {
    let m = a.columns;
    let n = channels.len();
    let rows = pixels.len() * n;
    let mut x = DMatrix::zeros(rows, m);
    let mut y = DVector::zeros(rows);
    for (i, &p) in pixels.iter().enumerate() {
        for (ci, &c) in channels.iter().enumerate() {
            let r = 3 * p + c;
            for (j, v) in a.row(r).iter().enumerate() {
                x[(n * i + ci, j)] = *v as f64;
            }
            y[n * i + ci] = observed[p][c] - a.offset.as_ref().map_or(0.0, |o| o[r] as f64);
        }
    }
    (x, y)
}

fn finish(x: &DMatrix<f64>, y: &DVector<f64>, c: DVector<f64>) -> Solution {
    let r = y - x * &c;
    let sv = x.singular_values();
    let max = sv.max();
    let min = sv.min();
    Solution {
        coefficients: c.iter().copied().collect(),
        residual_rms: (r.norm_squared() / y.len().max(1) as f64).sqrt(),
        relative_residual: r.norm() / y.norm().max(f64::MIN_POSITIVE),
        condition: if min > 0.0 { max / min } else { f64::INFINITY },
    }
}

fn least_squares_system(
    pixels: usize,
    x: DMatrix<f64>,
    y: DVector<f64>,
    cells: Option<Cells>,
) -> Result<Solution> {
    if x.nrows() < x.ncols() {
        let per_pixel = (x.nrows() / pixels.max(1)).max(1);
        return Err(CoreError::Invalid(format!(
            "{} pixels give {} equations for {} unknowns; choose at least {} pixels",
            pixels,
            x.nrows(),
            x.ncols(),
            x.ncols().div_ceil(per_pixel)
        )));
    }
    let svd = x.clone().svd(true, true);
    let c = svd
        .solve(&y, 1e-14 * svd.singular_values.max())
        .map_err(|e| CoreError::Invalid(e.to_string()))?;
    let c = match cells {
        Some(cells) if !cells.hold(&c) => {
            let (xtx, rhs) = (x.tr_mul(&x), x.tr_mul(&y));
            cells.constrained(&with_ridge(xtx), &rhs)?
        }
        _ => c,
    };
    Ok(finish(&x, &y, c))
}

/// `h` with a negligible ridge, so that its Cholesky exists when rows are fewer than unknowns
/// or a column sees no light.
fn with_ridge(mut h: DMatrix<f64>) -> DMatrix<f64> {
    let m = h.ncols();
    let tiny = (1e-12 * h.trace() / m.max(1) as f64).max(f64::MIN_POSITIVE);
    (0..m).for_each(|k| h[(k, k)] += tiny);
    h
}

/// The values of a model's BRDF a solve must keep ≥ 0: `values` (indices into its three
/// planes, [`VALUES`]) of `offset + Σₖ cₖ·columnₖ`. Cells that no column reaches are left out.
struct Cells {
    /// One row per cell: the columns' values there.
    g: DMatrix<f64>,
    /// The offset's value at each cell (zero without one).
    offset: DVector<f64>,
}

impl Cells {
    fn new(model: &LinearModel, values: std::ops::Range<usize>) -> Cells {
        let cells: Vec<usize> = values
            .filter(|&v| model.columns.iter().any(|col| col[v] != 0.0))
            .collect();
        Cells {
            g: DMatrix::from_fn(cells.len(), model.columns.len(), |i, k| {
                model.columns[k][cells[i]]
            }),
            offset: DVector::from_fn(cells.len(), |i, _| {
                model.offset.map_or(0.0, |o| o[cells[i]])
            }),
        }
    }

    /// The BRDF's value at every cell for coefficients `c`.
    fn values(&self, c: &DVector<f64>) -> DVector<f64> {
        &self.g * c + &self.offset
    }

    /// Whether every value is ≥ 0 for `c`.
    fn hold(&self, c: &DVector<f64>) -> bool {
        self.values(c).iter().all(|v| *v >= 0.0)
    }

    /// min ½cᵀHc − rhsᵀc subject to every value ≥ 0 (H positive definite).
    ///
    /// With H = LLᵀ and c₀ = H⁻¹rhs, c = c₀ + L⁻ᵀz turns this into the shortest z with
    /// (G·L⁻ᵀ) z ≥ −offset − G·c₀ (G: the columns' values, one row per cell), a least-distance
    /// problem (`least_distance`): the exact constrained optimum, not a clamp.
    ///
    /// Only the cells that bind matter, and they are few, so the rows are cutting planes: the
    /// cells negative at c₀ first, then, after each solve, any cell that the answer leaves
    /// negative, until none is. The answer then holds on every cell and is optimal on a
    /// subset of them, so it is the optimum over all.
    fn constrained(&self, h: &DMatrix<f64>, rhs: &DVector<f64>) -> Result<DVector<f64>> {
        // A ridge of 1e-10 of H's mean eigenvalue: where the pixels leave a direction of c
        // (almost) free, L⁻¹ would amplify the reduction's rounding past any margin; the ridge
        // bounds that, and moves a determined solution by a negligible amount.
        let mut h = h.clone();
        let ridge = 1e-10 * h.trace() / h.ncols().max(1) as f64;
        (0..h.ncols()).for_each(|k| h[(k, k)] += ridge);
        let factor = h
            .cholesky()
            .ok_or_else(|| CoreError::Invalid("the chosen pixels see no light".into()))?;
        let c0 = factor.solve(rhs);
        let l = factor.l();

        let values0 = self.values(&c0);
        // The margin's scale: the BRDF's peak where the unconstrained answer is positive.
        let largest = values0.max().max(0.0);
        let mut working = Vec::new();
        let mut in_working = vec![false; values0.len()];
        let mut hairs = HAIRS.iter();
        let mut hair = hairs.next().expect("hairs");
        let mut c = c0.clone();
        for _ in 0..MAX_CUTS {
            // The bound is raised by a hair, so that rounding (amplified by L⁻¹ where the
            // pixels pin the BRDF down poorly) cannot leave a value just below zero; a larger
            // hair if it did. Each is far below anything a render shows.
            let bound = hair * largest;
            let values = self.values(&c);
            let before = working.len();
            for (i, v) in values.iter().enumerate() {
                if !in_working[i] && *v < bound {
                    in_working[i] = true;
                    working.push(i);
                }
            }
            if working.len() == before {
                if values.min() >= 0.0 {
                    return Ok(c);
                }
                match hairs.next() {
                    Some(h) => hair = h,
                    None => break,
                }
            }
            c = self.nearest(&l, &c0, &values0, &working, hair * largest)?;
        }
        Err(CoreError::Invalid(
            "the non-negative solve did not converge".into(),
        ))
    }

    /// The least-distance step of [`Cells::constrained`] on the cells `working`, each held at
    /// `bound` or above; `values0` are the values at c₀.
    fn nearest(
        &self,
        l: &DMatrix<f64>,
        c0: &DVector<f64>,
        values0: &DVector<f64>,
        working: &[usize],
        bound: f64,
    ) -> Result<DVector<f64>> {
        let g = self.g.select_rows(working);
        // Eᵀ = L⁻¹Gᵀ, each row of E (and its bound) scaled to unit length: the feasible set
        // stays as it is, and the reduction's tolerances keep their meaning.
        let mut et = l
            .solve_lower_triangular(&g.transpose())
            .expect("a Cholesky factor is invertible");
        let mut f = DVector::from_fn(working.len(), |i, _| bound - values0[working[i]]);
        for i in 0..working.len() {
            let norm = et.column(i).norm();
            if norm > 0.0 {
                et.column_mut(i).unscale_mut(norm);
                f[i] /= norm;
            }
        }
        let z = least_distance(&et.transpose(), &f).ok_or_else(|| {
            CoreError::Invalid("no BRDF of the model is non-negative in every cell".into())
        })?;
        let step = l
            .transpose()
            .solve_upper_triangular(&z)
            .expect("a Cholesky factor is invertible");
        Ok(c0 + step)
    }
}

/// Margins of [`Cells::constrained`], relative to the BRDF's peak, tried in turn: far below
/// the smallest value a render shows (a diffuse floor 10⁴ times below a metal's peak is
/// still 100 times above the largest).
const HAIRS: [f64; 4] = [1e-9, 1e-8, 1e-7, 1e-6];

/// Rounds of cutting planes in [`Cells::constrained`] at most; a handful are needed.
const MAX_CUTS: usize = 64;

/// Iterations of `with_prior_system`; it settles in a handful (the change is checked each time).
const PRIOR_ITERATIONS: usize = 50;

fn with_prior_system(
    pixels: usize,
    x: DMatrix<f64>,
    y: DVector<f64>,
    prior: &[Option<f64>],
    cells: Option<Cells>,
) -> Result<Solution> {
    let m = x.ncols();
    if pixels == 0 {
        return Err(CoreError::Invalid("no pixels to solve from".into()));
    }
    let xtx = x.transpose() * &x;
    let rhs = x.transpose() * &y;
    let scale_column = prior.iter().position(|p| p.is_none());
    // Least squares to start, made definite by a negligible ridge when rows are fewer than
    // unknowns.
    let mut lhs = with_ridge(xtx.clone());
    let mut c = lhs
        .clone()
        .cholesky()
        .map(|ch| ch.solve(&rhs))
        .ok_or_else(|| CoreError::Invalid("the chosen pixels see no light".into()))?;
    let dof = (x.nrows() as f64 - m as f64).max(1.0);
    for _ in 0..PRIOR_ITERATIONS {
        let scale = scale_column.map_or(1.0, |f| c[f].abs());
        let misfit = (&y - &x * &c).norm_squared() / dof;
        if !(scale > 0.0 && misfit > 0.0) {
            // Data fit exactly, or a zero scale: nothing for the prior to weigh against.
            break;
        }
        let mut next_lhs = xtx.clone();
        for k in 0..m {
            if let Some(Some(sigma)) = prior.get(k) {
                next_lhs[(k, k)] += misfit / (scale * sigma).powi(2);
            }
        }
        let Some(ch) = next_lhs.clone().cholesky() else {
            break;
        };
        let next = ch.solve(&rhs);
        let settled = (&next - &c).norm() <= 1e-10 * next.norm();
        (c, lhs) = (next, next_lhs);
        if settled {
            break;
        }
    }
    // The prior's weights settle without the constraint; the last step's quadratic is then
    // solved with it. (Constraining every step would cost a constrained solve per step for
    // weights that hardly move.)
    if let Some(cells) = cells {
        if !cells.hold(&c) {
            c = cells.constrained(&lhs, &rhs)?;
        }
    }
    Ok(finish(&x, &y, c))
}
