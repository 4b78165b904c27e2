//! Solving for the coefficients on the chosen rows: plain least squares, and a Tikhonov variant
//! whose prior comes from the spread of the PCA scores over the training set.

use nalgebra::{DMatrix, DVector};

use super::error::{CoreError, Result};
use super::render::RenderingMatrix;

/// Default strength of the regularised solve, relative to the data term (see [`regularised`]).
pub const DEFAULT_RIDGE: f64 = 1e-3;

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
    let m = a.columns;
    let rows = pixels.len() * 3;
    let mut x = DMatrix::zeros(rows, m);
    let mut y = DVector::zeros(rows);
    for (i, &p) in pixels.iter().enumerate() {
        for c in 0..3 {
            let r = 3 * p + c;
            for (j, v) in a.row(r).iter().enumerate() {
                x[(3 * i + c, j)] = *v as f64;
            }
            y[3 * i + c] = observed[p][c] - a.offset.as_ref().map_or(0.0, |o| o[r] as f64);
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
    if x.nrows() < x.ncols() {
        return Err(CoreError::Invalid(format!(
            "{} pixels give {} equations for {} unknowns; choose at least {} pixels",
            pixels.len(),
            x.nrows(),
            x.ncols(),
            x.ncols().div_ceil(3)
        )));
    }
    let svd = x.clone().svd(true, true);
    let c = svd
        .solve(&y, 1e-14 * svd.singular_values.max())
        .map_err(|e| CoreError::Invalid(e.to_string()))?;
    Ok(finish(&x, &y, c))
}

/// Tikhonov: minimise ‖Xc − y‖² + Σₖ λₖ cₖ², with λₖ = ridge · tr(XᵀX)/m · (σ̄/σₖ)², where σₖ is
/// the training spread of coefficient k and σ̄ their geometric mean. Components that vary
/// little over real materials are pulled harder toward zero. `prior[k] = None` leaves a
/// coefficient free (the scale of an RMS-normalised basis).
pub fn regularised(
    a: &RenderingMatrix,
    pixels: &[usize],
    observed: &[[f64; 3]],
    prior: &[Option<f64>],
    ridge: f64,
) -> Result<Solution> {
    let (x, y) = system(a, pixels, observed);
    let m = x.ncols();
    let xtx = x.transpose() * &x;
    let scale = xtx.trace() / m as f64;
    let sigmas: Vec<f64> = prior
        .iter()
        .flatten()
        .copied()
        .filter(|s| *s > 0.0)
        .collect();
    let geo = (sigmas.iter().map(|s| s.ln()).sum::<f64>() / sigmas.len().max(1) as f64).exp();
    let mut lhs = xtx;
    for k in 0..m {
        if let Some(Some(s)) = prior.get(k) {
            lhs[(k, k)] += ridge * scale * (geo / s.max(f64::MIN_POSITIVE)).powi(2);
        }
    }
    let rhs = x.transpose() * &y;
    let c = lhs
        .cholesky()
        .ok_or_else(|| {
            CoreError::Invalid(
                "the regularised system is singular; add pixels or raise the ridge".into(),
            )
        })?
        .solve(&rhs);
    Ok(finish(&x, &y, c))
}
