//! How sure an estimate is: each coefficient's spread and the BRDF's 1-σ band, for every model.
//!
//! Both models resample the pixels they solved from (a bootstrap, seeded) and solve again with
//! everything else fixed; the spread of the rebuilt BRDF says whether the pixels pin it down.
//! The analytic model also has the linearised covariance of its weights and the curvature of
//! its misfit along each roughness ([`super::analytic`]); the basis model's covariance is the
//! bootstrap's.

use serde::Serialize;

use super::error::Result;
use super::geometry::{Camera, GeomPixel, PixelGeometry, Shape};

/// Resamples of the pixels (with replacement) for the bootstrap.
pub const BOOTSTRAP_RESAMPLES: usize = 32;
/// Seed of the bootstrap's resamples: the same photo gives the same spread.
pub const BOOTSTRAP_SEED: u64 = 0x5eed;

/// The bootstrap's [`BOOTSTRAP_RESAMPLES`] resamples of `n` pixels (indices, with
/// replacement), drawn in order from [`BOOTSTRAP_SEED`]: every model resamples alike, and
/// solving them side by side leaves them the same.
pub fn resamples(n: usize) -> Vec<Vec<usize>> {
    use rand::{Rng, SeedableRng};
    let mut rng = rand::rngs::StdRng::seed_from_u64(BOOTSTRAP_SEED);
    (0..BOOTSTRAP_RESAMPLES)
        .map(|_| (0..n).map(|_| rng.random_range(0..n)).collect())
        .collect()
}

/// How sure an estimate is.
#[derive(Clone, Debug, Serialize)]
pub struct Uncertainty {
    /// 1-σ of each coefficient, in the order of the estimate's coefficients.
    pub std: Vec<f64>,
    /// The coefficients' covariance, row-major, in the same order.
    pub covariance: Vec<f64>,
    /// How the covariance was found: `linearised` (the analytic model: the weights' σ²(XᵀX)⁻¹
    /// with σ² the residual's variance, each α's variance from the misfit's curvature) or
    /// `bootstrap` (the basis model: the spread over the resamples).
    pub covariance_from: &'static str,
    /// How much the estimate's relit sphere moves over [`BOOTSTRAP_RESAMPLES`] resamples of the
    /// pixels (`image_spread`).
    pub bootstrap_spread: f64,
    /// Resamples used (a resample with fewer distinct pixels than unknowns per channel system
    /// is left out).
    pub resamples: usize,
    /// Each grid value's bootstrap standard deviation (the 1-σ band), channel-planar like
    /// [`super::bivariate::Bivariate::values`].
    #[serde(skip)]
    pub band: Vec<f64>,
}

/// Per value, the standard deviation over `samples` (one vector per resample).
pub fn band(samples: &[Vec<f64>]) -> Vec<f64> {
    let n = samples.len() as f64;
    let len = samples.first().map_or(0, Vec::len);
    (0..len)
        .map(|k| {
            if samples.len() < 2 {
                return f64::INFINITY;
            }
            let mean = samples.iter().map(|s| s[k]).sum::<f64>() / n;
            let var = samples.iter().map(|s| (s[k] - mean).powi(2)).sum::<f64>() / (n - 1.0);
            var.sqrt()
        })
        .collect()
}

/// How much the relit sphere moves over the resamples: the RMS over its pixels and channels of
/// each value's standard deviation over `images`, relative to the RMS of `fitted` (the image
/// of the estimate itself).
///
/// Why an image and not the BRDF's cells: a cell's error matters as much as light reaches it.
/// The analytic lobe's values near θd = 90° run to 10⁴ 1/sr and are barely measured, so a
/// per-cell measure is all grazing noise, while an image weighs every cell by what it shows.
pub(crate) fn image_spread(images: &[Vec<f64>], fitted: &[f64]) -> f64 {
    let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt();
    rms(&band(images)) / rms(fitted).max(f64::MIN_POSITIVE)
}

/// Size of the sphere `image_spread` is measured on (orthographic, every normal facing the
/// camera), relit under the estimate's own lights.
pub const SPREAD_SPHERE: usize = 48;

/// The pixels of the [`SPREAD_SPHERE`] sphere.
pub(crate) fn spread_sphere() -> Result<Vec<GeomPixel>> {
    Ok(PixelGeometry::rasterize(
        &Camera::eval_orthographic(SPREAD_SPHERE),
        &Shape::unit_sphere(),
    )?
    .pixels)
}

/// The sample covariance (row-major) of coefficient vectors.
pub(crate) fn sample_covariance(samples: &[Vec<f64>]) -> Vec<f64> {
    let m = samples.first().map_or(0, Vec::len);
    let n = samples.len() as f64;
    let mean: Vec<f64> = (0..m)
        .map(|j| samples.iter().map(|s| s[j]).sum::<f64>() / n)
        .collect();
    let mut cov = vec![0.0; m * m];
    for s in samples {
        for i in 0..m {
            for j in 0..m {
                cov[i * m + j] += (s[i] - mean[i]) * (s[j] - mean[j]) / (n - 1.0).max(1.0);
            }
        }
    }
    cov
}

/// The square roots of a row-major covariance's diagonal.
pub(crate) fn std_of(covariance: &[f64], m: usize) -> Vec<f64> {
    (0..m)
        .map(|i| covariance[i * m + i].max(0.0).sqrt())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn band_and_covariance_of_known_samples() {
        // Two coefficients: the second is twice the first plus 1; samples 0, 1, 2.
        let samples: Vec<Vec<f64>> = (0..3)
            .map(|i| vec![i as f64, 2.0 * i as f64 + 1.0])
            .collect();
        let cov = sample_covariance(&samples);
        // Var(x) = 1, Var(2x+1) = 4, Cov = 2 (unbiased, n − 1 = 2).
        assert_eq!(cov, vec![1.0, 2.0, 2.0, 4.0]);
        assert_eq!(std_of(&cov, 2), vec![1.0, 2.0]);
        assert_eq!(band(&samples), vec![1.0, 2.0]);
        // RMS of the band (1, 2) over RMS of the fitted (1, 3).
        let spread = image_spread(&samples, &[1.0, 3.0]);
        assert!((spread - (2.5f64 / 5.0).sqrt()).abs() < 1e-12);
    }
}
