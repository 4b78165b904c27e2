//! Solving for the coefficients on the chosen rows: plain least squares (the paper's), and a
//! maximum a posteriori solve whose prior is the spread of the PCA scores over the training set.

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

use super::error::{CoreError, Result};
use super::render::RenderingMatrix;

/// How coefficients are solved from the chosen rows.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Solver {
    /// Least squares, as in the paper.
    LeastSquares,
    /// Least squares with the training set's prior ([`with_prior`]); the default, measured in
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

    pub fn solve(
        self,
        a: &RenderingMatrix,
        pixels: &[usize],
        observed: &[[f64; 3]],
        prior: &[Option<f64>],
    ) -> Result<Solution> {
        match self {
            Solver::LeastSquares => least_squares(a, pixels, observed),
            Solver::Prior => with_prior(a, pixels, observed, prior),
        }
    }

    /// Solves with the given colour model: [`Colour::Joint`] is [`Solver::solve`];
    /// [`Colour::PerChannel`] solves each channel from its own rows, and the coefficients are
    /// the three channels' in turn (R, G, B; see [`channel_coefficients`]).
    pub fn solve_colour(
        self,
        colour: Colour,
        a: &RenderingMatrix,
        pixels: &[usize],
        observed: &[[f64; 3]],
        prior: &[Option<f64>],
    ) -> Result<Solution> {
        if colour == Colour::Joint {
            return self.solve(a, pixels, observed, prior);
        }
        let mut coefficients = Vec::with_capacity(3 * a.columns);
        let (mut residual2, mut observed2, mut condition) = (0.0, 0.0, 0.0f64);
        for c in 0..3 {
            let (x, y) = system_of(a, pixels, observed, &[c]);
            let rows = y.len() as f64;
            observed2 += y.norm_squared();
            let sol = match self {
                Solver::LeastSquares => least_squares_system(pixels.len(), x, y),
                Solver::Prior => with_prior_system(pixels.len(), x, y, prior),
            }
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

/// Each channel's coefficients from a solution with `m` model columns: the same slice three
/// times for a joint solution (length m), the channel's third for a per-channel one (3m).
pub fn channel_coefficients(coefficients: &[f64], m: usize) -> Result<[&[f64]; 3]> {
    if coefficients.len() == m {
        Ok([coefficients; 3])
    } else if coefficients.len() == 3 * m {
        Ok([
            &coefficients[..m],
            &coefficients[m..2 * m],
            &coefficients[2 * m..],
        ])
    } else {
        Err(CoreError::Invalid(format!(
            "{} coefficients for a model of {m} columns: expected {m} (joint colour) or {} (per channel)",
            coefficients.len(),
            3 * m
        )))
    }
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

/// Ordinary least squares via SVD.
pub fn least_squares(
    a: &RenderingMatrix,
    pixels: &[usize],
    observed: &[[f64; 3]],
) -> Result<Solution> {
    let (x, y) = system(a, pixels, observed);
    least_squares_system(pixels.len(), x, y)
}

fn least_squares_system(pixels: usize, x: DMatrix<f64>, y: DVector<f64>) -> Result<Solution> {
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
    Ok(finish(&x, &y, c))
}

/// Iterations of [`with_prior`]; it settles in a handful (the change is checked each time).
const PRIOR_ITERATIONS: usize = 50;

/// Maximum a posteriori coefficients under the training set's prior, with nothing to tune.
///
/// An RMS-normalised basis models a material as s·(b₀ + Σₖ zₖ bₖ): scale s (the free mean
/// coefficient c₀) times a normalised shape whose scores zₖ spread over the training set with
/// standard deviation σₖ (`prior[k]`). So cₖ = s·zₖ, and the prior on cₖ is N(0, (c₀σₖ)²).
/// The misfit variance σ² is estimated from the residual (model error dominates it, not
/// sensor noise, so it cannot be known in advance). Each step solves
///
///   min ‖Xc − y‖² + Σₖ (σ / (c₀σₖ))² cₖ²
///
/// with c₀ and σ from the step before, starting from least squares.
///
/// Why: with 5 to 20 pixels, least squares follows the model error into coefficients far
/// outside anything in the training set; the prior keeps them plausible. With every pixel the
/// data term dominates and the answer is close to least squares. A column with `prior[k] =
/// None` (the scale) is free; with no such column, the scale is taken as 1.
pub fn with_prior(
    a: &RenderingMatrix,
    pixels: &[usize],
    observed: &[[f64; 3]],
    prior: &[Option<f64>],
) -> Result<Solution> {
    let (x, y) = system(a, pixels, observed);
    with_prior_system(pixels.len(), x, y, prior)
}

fn with_prior_system(
    pixels: usize,
    x: DMatrix<f64>,
    y: DVector<f64>,
    prior: &[Option<f64>],
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
    let mut c = {
        let mut lhs = xtx.clone();
        let tiny = 1e-12 * xtx.trace() / m as f64;
        (0..m).for_each(|k| lhs[(k, k)] += tiny);
        lhs.cholesky()
            .map(|ch| ch.solve(&rhs))
            .ok_or_else(|| CoreError::Invalid("the chosen pixels see no light".into()))?
    };
    let dof = (x.nrows() as f64 - m as f64).max(1.0);
    for _ in 0..PRIOR_ITERATIONS {
        let scale = scale_column.map_or(1.0, |f| c[f].abs());
        let misfit = (&y - &x * &c).norm_squared() / dof;
        if !(scale > 0.0 && misfit > 0.0) {
            // Data fit exactly, or a zero scale: nothing for the prior to weigh against.
            break;
        }
        let mut lhs = xtx.clone();
        for k in 0..m {
            if let Some(Some(sigma)) = prior.get(k) {
                lhs[(k, k)] += misfit / (scale * sigma).powi(2);
            }
        }
        let Some(ch) = lhs.cholesky() else { break };
        let next = ch.solve(&rhs);
        let settled = (&next - &c).norm() <= 1e-10 * next.norm();
        c = next;
        if settled {
            break;
        }
    }
    Ok(finish(&x, &y, c))
}
