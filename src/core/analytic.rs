//! The analytic model: Lambert plus one GGX/Smith microfacet lobe with Schlick's Fresnel, the
//! model a graphics user would otherwise fit by hand. It is fitted to the photo through the
//! same rendering matrix as the PCA basis, so both are compared on equal terms.
//!
//! ```text
//! f = kd/π + D(θh; α) · G₂(θi, θo; α) / (4 cos θi cos θo) · (F₀ (1 − w) + F₉₀ w),
//! w = (1 − cos θd)⁵
//! ```
//!
//! per colour channel, with kd, F₀, F₉₀ ≥ 0 per channel and one roughness α. For a fixed α the
//! BRDF is linear in the nine weights, so the fit is a variable projection: the weights are
//! solved exactly (non-negative least squares) for each α, and only α is searched. The model is
//! non-negative and reciprocal by construction.
//!
//! Not here: anisotropy, several lobes, and the full (θh, θd, φd) dependence in the estimate
//! (like every model of the estimate, the lobe is used through its bivariate reduction; the
//! [`Microfacet`] itself is a full BRDF, which tabulates analytic test materials).

use std::sync::OnceLock;

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::bivariate::{Bivariate, Grid, GRID_CELLS, N_THETA_D, N_THETA_H, VALUES};
use super::brdf::{from_rusinkiewicz, IsotropicBrdf};
use super::envmap::LightSet;
use super::error::{CoreError, Result};
use super::geometry::GeomPixel;
use super::merl;
use super::render::{RenderingMatrix, MAX_COLUMNS};

/// Roughness (GGX α) searched: from a near mirror to a nearly diffuse lobe.
pub const ALPHA_MIN: f64 = 0.004;
pub const ALPHA_MAX: f64 = 1.0;
/// Log-spaced α values of the coarse search. Neighbours differ by a factor of 1.34, so the
/// refinement below starts within 16% of the best α.
const COARSE_ALPHAS: usize = 20;
/// Golden-section steps on log α between the coarse search's neighbours: each shrinks the
/// bracket by 0.618, so eight leave it within 2% of α.
const REFINE_STEPS: usize = 8;
/// Pixels the α search fits (spread over the candidates); the final weights use every one.
pub const SEARCH_PIXELS: usize = 4_000;
/// Unknowns per channel: kd, F₀, F₉₀.
pub const WEIGHTS: usize = 3;
/// Names of the weights, per channel, and of the roughness, as written to `coefficients.json`.
pub const WEIGHT_NAMES: [&str; WEIGHTS] = ["diffuse", "f0", "f90"];

/// Lambert + GGX/Smith with Schlick's Fresnel, per-channel weights (module header).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Microfacet {
    /// Diffuse albedo kd per channel (the Lambert term is kd/π).
    pub diffuse: [f64; 3],
    /// Specular reflectance at normal incidence.
    pub f0: [f64; 3],
    /// Specular reflectance at grazing incidence (1 for a physical surface; free in the fit,
    /// which lets it absorb the lobe's overall scale).
    pub f90: [f64; 3],
    /// GGX roughness α (the square of the "perceptual" roughness of glTF and OpenPBR).
    pub alpha: f64,
}

/// GGX (Trowbridge–Reitz) normal distribution for cos θh.
fn ggx_d(cos_h: f64, alpha: f64) -> f64 {
    let a2 = alpha * alpha;
    let t = (a2 - 1.0) * cos_h * cos_h + 1.0;
    a2 / (std::f64::consts::PI * t * t)
}

/// Smith's Λ for GGX at a direction with cosine `c` to the normal.
fn smith_lambda(c: f64, alpha: f64) -> f64 {
    let c2 = (c * c).max(1e-12);
    let tan2 = (1.0 - c2) / c2;
    0.5 * ((1.0 + alpha * alpha * tan2).sqrt() - 1.0)
}

/// The height-correlated Smith masking-shadowing term over 4 cos θi cos θo.
fn visibility(ci: f64, co: f64, alpha: f64) -> f64 {
    1.0 / ((1.0 + smith_lambda(ci, alpha) + smith_lambda(co, alpha)) * 4.0 * ci * co)
}

/// Schlick's weight w = (1 − cos θd)⁵.
fn schlick_weight(cos_d: f64) -> f64 {
    (1.0 - cos_d).clamp(0.0, 1.0).powi(5)
}

impl IsotropicBrdf for Microfacet {
    fn eval_angles(&self, theta_h: f64, theta_d: f64, phi_d: f64) -> [f64; 3] {
        let (wi, wo) = from_rusinkiewicz(theta_h, theta_d, phi_d);
        if wi[2] <= 0.0 || wo[2] <= 0.0 {
            return [0.0; 3];
        }
        let lobe = ggx_d(theta_h.cos(), self.alpha) * visibility(wi[2], wo[2], self.alpha);
        let w = schlick_weight(theta_d.cos());
        std::array::from_fn(|c| {
            self.diffuse[c] / std::f64::consts::PI
                + lobe * (self.f0[c] * (1.0 - w) + self.f90[c] * w)
        })
    }
}

/// The (cos θi, cos θo) of every φd sample of every grid cell that is above both horizons,
/// exactly the samples [`Bivariate::reduce`] averages over. They do not depend on α, so they
/// are computed once per process.
struct CellSamples {
    /// `start[g]..start[g + 1]` are cell g's samples.
    start: Vec<usize>,
    cosines: Vec<(f64, f64)>,
    cos_h: Vec<f64>,
    cos_d: Vec<f64>,
}

fn cell_samples(grid: Grid) -> &'static CellSamples {
    static SAMPLES: OnceLock<(Grid, CellSamples)> = OnceLock::new();
    let (made_for, samples) = SAMPLES.get_or_init(|| (grid, CellSamples::new(grid)));
    assert_eq!(*made_for, grid, "one grid per process");
    samples
}

impl CellSamples {
    fn new(grid: Grid) -> CellSamples {
        // φd over [0, π/2): the reduction's samples (reciprocity and the mirror symmetry of an
        // isotropic BRDF cover the rest).
        let phis = merl::PHI_D_BINS / 2;
        let per_cell: Vec<Vec<(f64, f64)>> = (0..GRID_CELLS)
            .into_par_iter()
            .map(|g| {
                let (th, td) = cell_angles(grid, g);
                (0..phis)
                    .filter_map(|k| {
                        let (wi, wo) = from_rusinkiewicz(th, td, merl::phi_d_center(k));
                        (wi[2] > 0.0 && wo[2] > 0.0).then_some((wi[2], wo[2]))
                    })
                    .collect()
            })
            .collect();
        let mut start = Vec::with_capacity(GRID_CELLS + 1);
        let mut cosines = Vec::new();
        for cell in &per_cell {
            start.push(cosines.len());
            cosines.extend_from_slice(cell);
        }
        start.push(cosines.len());
        let (cos_h, cos_d) = (0..GRID_CELLS)
            .map(|g| {
                let (th, td) = cell_angles(grid, g);
                (th.cos(), td.cos())
            })
            .unzip();
        CellSamples {
            start,
            cosines,
            cos_h,
            cos_d,
        }
    }

    fn valid(&self, g: usize) -> bool {
        self.start[g + 1] > self.start[g]
    }
}

fn cell_angles(grid: Grid, g: usize) -> (f64, f64) {
    let (ih, jd) = (g / N_THETA_D, g % N_THETA_D);
    debug_assert!(ih < N_THETA_H);
    (grid.theta_h_binning.center(ih), merl::theta_d_center(jd))
}

/// The model's columns for roughness α, each a grey bivariate vector (the same in R, G and B):
/// Lambert (1/π), the lobe weighted by (1 − w), and by w. A BRDF is Σ weightᵢ · columnᵢ per
/// channel.
pub fn columns(grid: Grid, alpha: f64) -> [Vec<f64>; WEIGHTS] {
    let s = cell_samples(grid);
    let lobe: Vec<f64> = (0..GRID_CELLS)
        .into_par_iter()
        .map(|g| {
            let cell = &s.cosines[s.start[g]..s.start[g + 1]];
            if cell.is_empty() {
                return 0.0;
            }
            let mean_v = cell
                .iter()
                .map(|&(ci, co)| visibility(ci, co, alpha))
                .sum::<f64>()
                / cell.len() as f64;
            ggx_d(s.cos_h[g], alpha) * mean_v
        })
        .collect();
    let grey = |f: &dyn Fn(usize) -> f64| -> Vec<f64> {
        let plane: Vec<f64> = (0..GRID_CELLS).map(f).collect();
        plane.iter().chain(&plane).chain(&plane).copied().collect()
    };
    let lambert = grey(&|g| {
        if s.valid(g) {
            std::f64::consts::FRAC_1_PI
        } else {
            0.0
        }
    });
    let f0 = grey(&|g| lobe[g] * (1.0 - schlick_weight(s.cos_d[g])));
    let f90 = grey(&|g| lobe[g] * schlick_weight(s.cos_d[g]));
    [lambert, f0, f90]
}

impl Microfacet {
    /// The model's bivariate reduction (what the estimate renders and writes).
    pub fn bivariate(&self, grid: Grid) -> Bivariate {
        let cols = columns(grid, self.alpha);
        let weights = [self.diffuse, self.f0, self.f90];
        let mut values = vec![0.0; VALUES];
        for c in 0..3 {
            for (col, w) in cols.iter().zip(&weights) {
                let plane = c * GRID_CELLS..(c + 1) * GRID_CELLS;
                for (v, b) in values[plane.clone()].iter_mut().zip(&col[plane]) {
                    *v += w[c] * b;
                }
            }
        }
        let s = cell_samples(grid);
        let valid = (0..GRID_CELLS).map(|g| s.valid(g)).collect();
        Bivariate::from_values(grid, values, valid)
    }

    /// The weights as one vector, per channel in turn (kd, F₀, F₉₀ of R, then of G, then of
    /// B), then α: the order of [`Microfacet::names`].
    pub fn values(&self) -> Vec<f64> {
        let mut out: Vec<f64> = (0..3)
            .flat_map(|c| [self.diffuse[c], self.f0[c], self.f90[c]])
            .collect();
        out.push(self.alpha);
        out
    }

    pub fn names() -> Vec<String> {
        let mut out: Vec<String> = super::solve::CHANNELS
            .iter()
            .flat_map(|c| WEIGHT_NAMES.iter().map(move |n| format!("{n}.{c}")))
            .collect();
        out.push("alpha".into());
        out
    }
}

/// Non-negative least squares on the normal equations (Lawson–Hanson active set): minimises
/// ‖Xc − y‖² subject to c ≥ 0, given G = XᵀX and b = Xᵀy. Small systems only (a dozen
/// unknowns); returns c and the squared residual up to the constant ‖y‖².
pub fn nnls(g: &DMatrix<f64>, b: &DVector<f64>) -> DVector<f64> {
    let m = b.len();
    let mut c = DVector::zeros(m);
    let mut passive = vec![false; m];
    // Each outer step frees one variable, each inner step fixes at least one: bounded well
    // within this for m ≤ 12.
    for _ in 0..(4 * m + 8) {
        let grad = b - g * &c;
        let next = (0..m)
            .filter(|&j| !passive[j] && grad[j] > 1e-12 * (1.0 + b[j].abs()))
            .max_by(|&i, &j| grad[i].total_cmp(&grad[j]));
        let Some(j) = next else { break };
        passive[j] = true;
        loop {
            let z = solve_passive(g, b, &passive);
            if (0..m).all(|k| !passive[k] || z[k] > 0.0) {
                c = z;
                break;
            }
            // Step from c towards z until the first passive variable reaches zero.
            let mut step = 1.0f64;
            for k in 0..m {
                if passive[k] && z[k] <= 0.0 {
                    step = step.min(c[k] / (c[k] - z[k]).max(f64::MIN_POSITIVE));
                }
            }
            c = &c + (&z - &c) * step;
            for k in 0..m {
                if passive[k] && c[k] <= 1e-15 {
                    passive[k] = false;
                    c[k] = 0.0;
                }
            }
            if !passive.iter().any(|p| *p) {
                break;
            }
        }
    }
    c
}

/// The unconstrained solution over the passive variables (the others zero).
fn solve_passive(g: &DMatrix<f64>, b: &DVector<f64>, passive: &[bool]) -> DVector<f64> {
    let idx: Vec<usize> = (0..b.len()).filter(|&k| passive[k]).collect();
    let n = idx.len();
    let mut sub = DMatrix::from_fn(n, n, |i, j| g[(idx[i], idx[j])]);
    let rhs = DVector::from_fn(n, |i, _| b[idx[i]]);
    // A negligible ridge keeps the Cholesky defined for a column that sees no light.
    let tiny = 1e-13 * (0..n).map(|i| sub[(i, i)]).fold(0.0, f64::max);
    (0..n).for_each(|i| sub[(i, i)] += tiny.max(f64::MIN_POSITIVE));
    let z = sub
        .clone()
        .cholesky()
        .map(|ch| ch.solve(&rhs))
        .unwrap_or_else(|| DVector::zeros(n));
    let mut out = DVector::zeros(b.len());
    for (i, &k) in idx.iter().enumerate() {
        out[k] = z[i];
    }
    out
}

/// One view's candidates: pixels, what they measured, and the view's lights.
pub struct ViewPixels<'a> {
    pub pixels: &'a [GeomPixel],
    pub observed: &'a [[f64; 3]],
    pub lights: &'a LightSet,
}

/// The fit of [`fit`].
#[derive(Clone, Debug)]
pub struct AnalyticFit {
    pub model: Microfacet,
    /// The rendering matrix of the fitted α's three columns over every candidate.
    pub matrix: RenderingMatrix,
    /// The observations stacked in the matrix's pixel order.
    pub observed: Vec<[f64; 3]>,
    /// (α, relative misfit on the search pixels) of every α tried, in order tried.
    pub search: Vec<(f64, f64)>,
    /// κ of the final per-channel systems (the worst channel's), columns scaled to unit norm.
    pub condition: f64,
}

/// Builds the matrix of several α at once: Lambert, then (F₀, F₉₀) columns of each α. One
/// pass over the (pixel, light) pairs serves every α.
fn matrix_for(views: &[ViewPixels], grid: Grid, alphas: &[f64], subset: bool) -> RenderingMatrix {
    let cols: Vec<[Vec<f64>; WEIGHTS]> = alphas.iter().map(|a| columns(grid, *a)).collect();
    let mut refs: Vec<&[f64]> = vec![&cols[0][0]];
    for c in &cols {
        refs.push(&c[1]);
        refs.push(&c[2]);
    }
    let mut out: Option<RenderingMatrix> = None;
    for v in views {
        let pixels: Vec<GeomPixel> = if subset {
            search_subset(v.pixels.len(), views.len())
                .into_iter()
                .map(|i| v.pixels[i])
                .collect()
        } else {
            v.pixels.to_vec()
        };
        let a = RenderingMatrix::build(&pixels, v.lights, &refs, None, grid.theta_h_binning);
        out = Some(match out {
            None => a,
            Some(mut all) => {
                all.append(a).expect("same columns");
                all
            }
        });
    }
    out.expect("at least one view")
}

fn search_subset(n: usize, views: usize) -> Vec<usize> {
    super::estimate::spread(n, (SEARCH_PIXELS / views.max(1)).max(1))
}

/// Per channel, the Gram blocks of the columns `cols` of `a` against the observations.
fn channel_systems(
    a: &RenderingMatrix,
    observed: &[[f64; 3]],
    cols: &[usize],
) -> [(DMatrix<f64>, DVector<f64>, f64); 3] {
    std::array::from_fn(|c| {
        let n = cols.len();
        let mut g = DMatrix::zeros(n, n);
        let mut b = DVector::zeros(n);
        let mut yy = 0.0;
        for (p, obs) in observed.iter().enumerate() {
            let row = a.row(3 * p + c);
            let y = obs[c];
            yy += y * y;
            for i in 0..n {
                let xi = row[cols[i]] as f64;
                b[i] += xi * y;
                for j in 0..=i {
                    g[(i, j)] += xi * row[cols[j]] as f64;
                }
            }
        }
        for i in 0..n {
            for j in 0..i {
                g[(j, i)] = g[(i, j)];
            }
        }
        (g, b, yy)
    })
}

/// Solves the non-negative weights per channel for the columns `cols` of `a`; returns them
/// (per channel) and the relative misfit ‖Ac − y‖/‖y‖ over every channel.
fn solve_weights(
    a: &RenderingMatrix,
    observed: &[[f64; 3]],
    cols: &[usize],
) -> ([DVector<f64>; 3], f64) {
    let systems = channel_systems(a, observed, cols);
    let (mut r2, mut y2) = (0.0, 0.0);
    let weights = systems.map(|(g, b, yy)| {
        let c = nnls(&g, &b);
        // ‖Xc − y‖² = cᵀGc − 2cᵀb + yᵀy.
        r2 += ((c.transpose() * &g * &c)[0] - 2.0 * c.dot(&b) + yy).max(0.0);
        y2 += yy;
        c
    });
    (weights, (r2 / y2.max(f64::MIN_POSITIVE)).sqrt())
}

/// Fits the model to the candidates of every view: a coarse search over α on a spread of
/// [`SEARCH_PIXELS`] pixels, golden-section refinement on log α, then the weights for the
/// best α from every candidate.
pub fn fit(views: &[ViewPixels], grid: Grid) -> Result<AnalyticFit> {
    if views.iter().all(|v| v.pixels.is_empty()) {
        return Err(CoreError::Invalid(
            "no pixels to fit the analytic model to".into(),
        ));
    }
    let observed_of = |subset: bool| -> Vec<[f64; 3]> {
        views
            .iter()
            .flat_map(|v| {
                let idx: Vec<usize> = if subset {
                    search_subset(v.pixels.len(), views.len())
                } else {
                    (0..v.pixels.len()).collect()
                };
                idx.into_iter().map(|i| v.observed[i]).collect::<Vec<_>>()
            })
            .collect()
    };
    let search_y = observed_of(true);
    let mut search: Vec<(f64, f64)> = Vec::new();
    let log_span = (ALPHA_MAX / ALPHA_MIN).ln();
    let coarse: Vec<f64> = (0..COARSE_ALPHAS)
        .map(|i| ALPHA_MIN * (log_span * i as f64 / (COARSE_ALPHAS - 1) as f64).exp())
        .collect();
    // Lambert plus two columns per α: as many α per matrix as the column limit allows.
    let per_build = (MAX_COLUMNS - 1) / 2;
    for chunk in coarse.chunks(per_build) {
        let a = matrix_for(views, grid, chunk, true);
        for (i, alpha) in chunk.iter().enumerate() {
            let (_, misfit) = solve_weights(&a, &search_y, &[0, 1 + 2 * i, 2 + 2 * i]);
            search.push((*alpha, misfit));
        }
    }
    let best = (0..coarse.len())
        .min_by(|&i, &j| search[i].1.total_cmp(&search[j].1))
        .expect("a coarse search");
    let misfit_at = |alpha: f64, search: &mut Vec<(f64, f64)>| -> f64 {
        let a = matrix_for(views, grid, &[alpha], true);
        let (_, misfit) = solve_weights(&a, &search_y, &[0, 1, 2]);
        search.push((alpha, misfit));
        misfit
    };
    // Golden-section search on log α over the best coarse α's neighbours.
    let (mut lo, mut hi) = (
        coarse[best.saturating_sub(1)].ln(),
        coarse[(best + 1).min(coarse.len() - 1)].ln(),
    );
    let ratio = (5f64.sqrt() - 1.0) / 2.0;
    let mut x1 = hi - ratio * (hi - lo);
    let mut x2 = lo + ratio * (hi - lo);
    let mut f1 = misfit_at(x1.exp(), &mut search);
    let mut f2 = misfit_at(x2.exp(), &mut search);
    for _ in 0..REFINE_STEPS {
        if f1 <= f2 {
            hi = x2;
            (x2, f2) = (x1, f1);
            x1 = hi - ratio * (hi - lo);
            f1 = misfit_at(x1.exp(), &mut search);
        } else {
            lo = x1;
            (x1, f1) = (x2, f2);
            x2 = lo + ratio * (hi - lo);
            f2 = misfit_at(x2.exp(), &mut search);
        }
    }
    let alpha = search
        .iter()
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(a, _)| *a)
        .expect("a search");
    let matrix = matrix_for(views, grid, &[alpha], false);
    let observed = observed_of(false);
    let (w, _) = solve_weights(&matrix, &observed, &[0, 1, 2]);
    let condition = channel_systems(&matrix, &observed, &[0, 1, 2])
        .iter()
        .map(|(g, _, _)| scaled_condition(g))
        .fold(0.0, f64::max);
    let model = Microfacet {
        diffuse: std::array::from_fn(|c| w[c][0]),
        f0: std::array::from_fn(|c| w[c][1]),
        f90: std::array::from_fn(|c| w[c][2]),
        alpha,
    };
    Ok(AnalyticFit {
        model,
        matrix,
        observed,
        search,
        condition,
    })
}

/// κ of X from its Gram matrix G = XᵀX, with X's columns scaled to unit norm first (the
/// columns' units differ; their overlap is what matters).
fn scaled_condition(g: &DMatrix<f64>) -> f64 {
    let n = g.nrows();
    let d: Vec<f64> = (0..n)
        .map(|i| g[(i, i)].max(f64::MIN_POSITIVE).sqrt())
        .collect();
    let scaled = DMatrix::from_fn(n, n, |i, j| g[(i, j)] / (d[i] * d[j]));
    let eig = scaled.symmetric_eigenvalues();
    let (lo, hi) = (eig.min(), eig.max());
    if lo > 0.0 {
        (hi / lo).sqrt()
    } else {
        f64::INFINITY
    }
}

impl AnalyticFit {
    /// The per-channel weights as the rendering matrix's coefficients, for prediction.
    pub fn per_channel(&self) -> [[f64; WEIGHTS]; 3] {
        let m = &self.model;
        std::array::from_fn(|c| [m.diffuse[c], m.f0[c], m.f90[c]])
    }

    /// The photo this fit predicts, per candidate pixel and channel.
    pub fn predicted(&self) -> Vec<f64> {
        let w = self.per_channel();
        self.matrix.predict_per_channel([&w[0], &w[1], &w[2]])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nnls_matches_enumeration_of_active_sets() {
        // Against the brute-force answer: every subset of free variables, solved and checked.
        // Tolerance 1e-9 relative: both are f64 Cholesky solves of the same small systems.
        use rand::{Rng, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        for _ in 0..200 {
            let (rows, m) = (12, 4);
            let x = DMatrix::from_fn(rows, m, |_, _| rng.random_range(-1.0..1.0));
            let y = DVector::from_fn(rows, |_, _| rng.random_range(-1.0..1.0));
            let g = x.transpose() * &x;
            let b = x.transpose() * &y;
            let c = nnls(&g, &b);
            let cost = |c: &DVector<f64>| (&x * c - &y).norm_squared();
            let mut best = f64::INFINITY;
            for mask in 0..(1u32 << m) {
                let passive: Vec<bool> = (0..m).map(|k| mask & (1 << k) != 0).collect();
                let z = solve_passive(&g, &b, &passive);
                if z.iter().all(|v| *v >= 0.0) {
                    best = best.min(cost(&z));
                }
            }
            assert!(c.iter().all(|v| *v >= 0.0));
            assert!(
                cost(&c) <= best * (1.0 + 1e-9) + 1e-12,
                "{} > {best}",
                cost(&c)
            );
        }
    }

    #[test]
    fn lobe_columns_match_the_reduction_of_the_full_model() {
        // The fast column path and Bivariate::reduce of the full BRDF must agree: same
        // samples, same formula, summed in another order (tolerance 1e-9 relative).
        let grid = Grid::default();
        let m = Microfacet {
            diffuse: [0.2, 0.3, 0.4],
            f0: [0.9, 0.6, 0.3],
            f90: [1.0, 1.0, 1.0],
            alpha: 0.1,
        };
        let fast = m.bivariate(grid);
        let slow = Bivariate::reduce(&m, grid);
        for (a, b) in fast.values.iter().zip(&slow.values) {
            assert!((a - b).abs() <= 1e-9 * (1.0 + b.abs()), "{a} vs {b}");
        }
        assert_eq!(fast.valid, slow.valid);
    }
}
