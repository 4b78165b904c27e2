//! An analytic BRDF model: Lambert plus one or two GGX/Smith microfacet lobes with Schlick's
//! Fresnel, the model a graphics user would otherwise fit by hand. It is fitted to the photo
//! through the same rendering matrix as the PCA basis, so both are compared on equal terms.
//!
//! ```text
//! f = kd/π + Σₗ D(θh; αₗ) · G₂(θi, θo; αₗ) / (4 cos θi cos θo) · (F₀ₗ (1 − w) + F₉₀ₗ w),
//! w = (1 − cos θd)⁵
//! ```
//!
//! per colour channel, with kd, F₀ₗ, F₉₀ₗ ≥ 0 per channel and one roughness αₗ per lobe. For
//! fixed roughnesses the BRDF is linear in the weights, so the fit is a variable projection:
//! the weights are solved exactly (non-negative least squares) for each set of αₗ, and only the
//! αₗ are searched. The model is non-negative and reciprocal by construction.
//!
//! Not here: anisotropy, and the full (θh, θd, φd) dependence in the estimate (like every
//! model of the estimate, the lobes are used through their bivariate reduction; the
//! [`Microfacet`] itself is a full BRDF, which tabulates analytic test materials).

use std::sync::{Arc, Mutex, OnceLock};

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::bivariate::{Bivariate, Grid, PhiReduction, GRID_CELLS, N_THETA_D, N_THETA_H, VALUES};
use super::brdf::{from_rusinkiewicz, Cosines, IsotropicBrdf};
use super::envmap::LightSet;
use super::error::{CoreError, Result};
use super::geometry::GeomPixel;
use super::merl;
use super::nnls::nnls;
use super::render::{RenderingMatrix, PASS_COLUMNS};
use super::stop::Stop;
use super::uncertainty::{band, image_spread, resamples, spread_sphere, std_of, Uncertainty};

/// Roughness (GGX α) searched: from a near mirror to a nearly diffuse lobe.
pub const ALPHA_MIN: f64 = 0.004;
pub const ALPHA_MAX: f64 = 1.0;
/// Log-spaced α values of the coarse search. Neighbours differ by a factor of 1.34, so the
/// refinement below starts within 16% of the best α.
const COARSE_ALPHAS: usize = 20;
/// Points per refinement round: a round's new roughnesses (two columns each) are rendered in
/// one pass over the pixels.
const REFINE_POINTS: usize = 4;
/// Refinement rounds: each narrows the bracket to 2/5, so three leave it within 2% of α.
const REFINE_ROUNDS: usize = 3;
/// Pixels the α search fits (spread over the candidates); the analytic model's final weights
/// use every candidate, the hybrid model's these pixels.
pub const SEARCH_PIXELS: usize = 4_000;
/// Lobes at most (two cover a clear coat over a rougher base, or a metal's core and halo).
pub const MAX_LOBES: usize = 2;

/// One GGX/Smith lobe with Schlick's Fresnel.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Lobe {
    /// Specular reflectance at normal incidence, per channel.
    pub f0: [f64; 3],
    /// Specular reflectance at grazing incidence (1 for a physical surface; free in the fit,
    /// which lets it absorb the lobe's overall scale).
    pub f90: [f64; 3],
    /// GGX roughness α (the square of the "perceptual" roughness of glTF and OpenPBR).
    pub alpha: f64,
}

/// Lambert + GGX/Smith lobes with Schlick's Fresnel, per-channel weights (module header).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Microfacet {
    /// Diffuse albedo kd per channel (the Lambert term is kd/π).
    pub diffuse: [f64; 3],
    /// The specular lobes, sharpest first.
    pub lobes: Vec<Lobe>,
}

impl Microfacet {
    /// Checks parameters that came from a file: weights finite and ≥ 0, each α finite within
    /// [`ALPHA_MIN`] … [`ALPHA_MAX`] (the range the fit searches; α = 0 has no GGX lobe).
    pub fn check(&self) -> std::result::Result<(), String> {
        let weights = self
            .diffuse
            .iter()
            .chain(self.lobes.iter().flat_map(|l| l.f0.iter().chain(&l.f90)));
        if let Some(w) = weights.into_iter().find(|w| !(w.is_finite() && **w >= 0.0)) {
            return Err(format!(
                "a weight is {w}; weights are finite and at least 0"
            ));
        }
        match self
            .lobes
            .iter()
            .find(|l| !(ALPHA_MIN..=ALPHA_MAX).contains(&l.alpha))
        {
            Some(l) => Err(format!(
                "a lobe's alpha is {}; it is between {ALPHA_MIN} and {ALPHA_MAX}",
                l.alpha
            )),
            None => Ok(()),
        }
    }

    /// Lambert and one lobe.
    pub fn one_lobe(diffuse: [f64; 3], f0: [f64; 3], f90: [f64; 3], alpha: f64) -> Microfacet {
        Microfacet {
            diffuse,
            lobes: vec![Lobe { f0, f90, alpha }],
        }
    }
}

/// GGX (Trowbridge–Reitz) normal distribution for cos θh.
pub fn ggx_d(cos_h: f64, alpha: f64) -> f64 {
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
pub fn schlick_weight(cos_d: f64) -> f64 {
    (1.0 - cos_d).clamp(0.0, 1.0).powi(5)
}

impl IsotropicBrdf for Microfacet {
    fn eval_angles(&self, theta_h: f64, theta_d: f64, phi_d: f64) -> [f64; 3] {
        Cosines::of_angles(theta_h, theta_d, phi_d).map_or([0.0; 3], |c| self.eval_cosines(c))
    }

    /// From the halfway vector, without the angles ([`Cosines::of_dirs`] says why).
    fn eval_dirs(&self, wi: [f64; 3], wo: [f64; 3]) -> [f64; 3] {
        Cosines::of_dirs(wi, wo).map_or([0.0; 3], |c| self.eval_cosines(c))
    }
}

impl Microfacet {
    fn eval_cosines(&self, c: Cosines) -> [f64; 3] {
        let w = schlick_weight(c.d);
        let mut out = self.diffuse.map(|kd| kd / std::f64::consts::PI);
        for l in &self.lobes {
            let lobe = ggx_lobe(c.h, c.i, c.o, l.alpha);
            for c in 0..3 {
                out[c] += lobe * (l.f0[c] * (1.0 - w) + l.f90[c] * w);
            }
        }
        out
    }
}

/// One GGX lobe without its Fresnel, D · G₂ / (4 cos θi cos θo), at cos θh and the
/// directions' cosines to the normal (both positive).
pub fn ggx_lobe(cos_h: f64, cos_i: f64, cos_o: f64, alpha: f64) -> f64 {
    ggx_d(cos_h, alpha) * visibility(cos_i, cos_o, alpha)
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

/// Each grid's samples, made once per process (a process uses one or two grids).
type SampleCache = Mutex<Vec<(Grid, Arc<CellSamples>)>>;

/// The samples of `grid`, from the [`SampleCache`].
fn cell_samples(grid: Grid) -> Arc<CellSamples> {
    static SAMPLES: OnceLock<SampleCache> = OnceLock::new();
    let cache = SAMPLES.get_or_init(|| Mutex::new(Vec::new()));
    // A poisoned lock only means another thread panicked while making samples; the list itself
    // is still whole.
    let found = |made: &[(Grid, Arc<CellSamples>)]| {
        made.iter()
            .find(|(g, _)| *g == grid)
            .map(|(_, s)| Arc::clone(s))
    };
    if let Some(s) = found(&cache.lock().unwrap_or_else(|e| e.into_inner())) {
        return s;
    }
    // Made unlocked: the samples are made on rayon's pool, and a worker that waited on the
    // lock while another made them could hold, further down its own stack, a job the maker
    // waits for (an estimate hung so in CI). Two threads may both make them; the first kept
    // is shared.
    let s = Arc::new(CellSamples::new(grid));
    let mut made = cache.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(first) = found(&made) {
        return first;
    }
    made.push((grid, Arc::clone(&s)));
    s
}

impl CellSamples {
    fn new(grid: Grid) -> CellSamples {
        // φd as the grid's reduction samples it: over [0, π/2) (reciprocity and the mirror
        // symmetry of an isotropic BRDF cover the rest), or the φd = 90° slice alone.
        let phis: Vec<f64> = match grid.phi_reduction {
            PhiReduction::ValidMean => (0..merl::PHI_D_BINS / 2).map(merl::phi_d_center).collect(),
            PhiReduction::Slice90 => vec![std::f64::consts::FRAC_PI_2],
        };
        let per_cell: Vec<Vec<(f64, f64)>> = (0..GRID_CELLS)
            .into_par_iter()
            .map(|g| {
                let (th, td) = cell_angles(grid, g);
                phis.iter()
                    .filter_map(|&phi| {
                        let (wi, wo) = from_rusinkiewicz(th, td, phi);
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

/// The normal-incidence reflectance of a clear coat of IOR 1.5, as glTF's
/// `KHR_materials_clearcoat` fixes it.
pub const COAT_F0: f64 = 0.04;

/// Schlick's Fresnel of that coat at a view with cosine `cos_v` to the normal. glTF hangs the
/// coat's weight (and the base's loss under it) on N·V, not on θd: a coated material is not a
/// function of (θh, θd) alone, but on an image a pixel fixes N·V whatever the light.
pub fn coat_fresnel(cos_v: f64) -> f64 {
    COAT_F0 + (1.0 - COAT_F0) * schlick_weight(cos_v)
}

/// Lambert's column (1/π where the grid has a cell), the first of [`columns`].
pub fn lambert_column(grid: Grid) -> Vec<f64> {
    let s = cell_samples(grid);
    let plane: Vec<f64> = (0..GRID_CELLS)
        .map(|g| {
            if s.valid(g) {
                std::f64::consts::FRAC_1_PI
            } else {
                0.0
            }
        })
        .collect();
    plane.iter().chain(&plane).chain(&plane).copied().collect()
}

/// [`ggx_lobe`] of roughness α reduced to `grid` as [`Bivariate::reduce`] reduces a BRDF,
/// one plane (`GRID_CELLS` long, 0 where a cell has no sample): D hangs on θh alone, so a
/// cell's mean is D at its θh times the mean of G₂/(4 cos θi cos θo) over its samples.
pub fn lobe_plane(grid: Grid, alpha: f64) -> Vec<f64> {
    let s = cell_samples(grid);
    (0..GRID_CELLS)
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
        .collect()
}

/// The model's columns for roughness α, each a grey bivariate vector (the same in R, G and B):
/// Lambert (1/π), the lobe weighted by (1 − w), and by w. A BRDF is Σ weightᵢ · columnᵢ per
/// channel.
pub fn columns(grid: Grid, alpha: f64) -> [Vec<f64>; 3] {
    let s = cell_samples(grid);
    let lobe = lobe_plane(grid, alpha);
    let grey = |f: &dyn Fn(usize) -> f64| -> Vec<f64> {
        let plane: Vec<f64> = (0..GRID_CELLS).map(f).collect();
        plane.iter().chain(&plane).chain(&plane).copied().collect()
    };
    let lambert = lambert_column(grid);
    let f0 = grey(&|g| lobe[g] * (1.0 - schlick_weight(s.cos_d[g])));
    let f90 = grey(&|g| lobe[g] * schlick_weight(s.cos_d[g]));
    [lambert, f0, f90]
}

impl Microfacet {
    /// The model of per-channel weights in the column order of the fit (Lambert, then each
    /// lobe's F₀ and F₉₀; further columns are not read) at roughnesses `alphas`.
    pub(crate) fn from_weights(w: &[DVector<f64>; 3], alphas: &[f64]) -> Microfacet {
        Microfacet {
            diffuse: std::array::from_fn(|c| w[c][0]),
            lobes: alphas
                .iter()
                .enumerate()
                .map(|(i, alpha)| Lobe {
                    f0: std::array::from_fn(|c| w[c][1 + 2 * i]),
                    f90: std::array::from_fn(|c| w[c][2 + 2 * i]),
                    alpha: *alpha,
                })
                .collect(),
        }
    }

    /// The model's bivariate reduction (what the estimate renders and writes).
    pub fn bivariate(&self, grid: Grid) -> Bivariate {
        let mut values = vec![0.0; VALUES];
        let mut add = |col: &[f64], w: [f64; 3]| {
            for c in 0..3 {
                let plane = c * GRID_CELLS..(c + 1) * GRID_CELLS;
                for (v, b) in values[plane.clone()].iter_mut().zip(&col[plane]) {
                    *v += w[c] * b;
                }
            }
        };
        let s = cell_samples(grid);
        let lambert: Vec<f64> = (0..3)
            .flat_map(|_| {
                (0..GRID_CELLS).map(|g| {
                    if s.valid(g) {
                        std::f64::consts::FRAC_1_PI
                    } else {
                        0.0
                    }
                })
            })
            .collect();
        add(&lambert, self.diffuse);
        for l in &self.lobes {
            let [_, f0, f90] = columns(grid, l.alpha);
            add(&f0, l.f0);
            add(&f90, l.f90);
        }
        let valid = (0..GRID_CELLS).map(|g| s.valid(g)).collect();
        Bivariate::from_values(grid, values, valid)
    }

    /// The parameters as one vector, in the order of [`Microfacet::names`]: kd per channel,
    /// then per lobe F₀ and F₉₀ per channel and α.
    pub fn values(&self) -> Vec<f64> {
        let mut out = self.diffuse.to_vec();
        for l in &self.lobes {
            out.extend(l.f0);
            out.extend(l.f90);
            out.push(l.alpha);
        }
        out
    }

    /// `diffuse.R`, …, then `lobe1.f0.R`, …, `lobe1.f90.B`, `lobe1.alpha`, and so on.
    pub fn names(&self) -> Vec<String> {
        let channels = super::solve::CHANNELS;
        let mut out: Vec<String> = channels.iter().map(|c| format!("diffuse.{c}")).collect();
        for i in 1..=self.lobes.len() {
            for part in ["f0", "f90"] {
                out.extend(channels.iter().map(|c| format!("lobe{i}.{part}.{c}")));
            }
            out.push(format!("lobe{i}.alpha"));
        }
        out
    }
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
    /// The rendering matrix of the fitted model's columns over every candidate: Lambert, then
    /// (F₀, F₉₀) of each lobe.
    pub matrix: RenderingMatrix,
    /// The observations stacked in the matrix's pixel order.
    pub observed: Vec<[f64; 3]>,
    /// Roughness sets tried (the αₗ) and their relative misfit on the search pixels.
    pub search: Vec<(Vec<f64>, f64)>,
    /// κ of the final per-channel systems (the worst channel's), columns scaled to unit norm.
    pub condition: f64,
    pub uncertainty: Uncertainty,
}

/// Step in log α of the misfit profile's curvature (10%).
const PROFILE_STEP: f64 = 0.1;

/// Builds the matrix of several α over every candidate: Lambert, then (F₀, F₉₀) columns of
/// each α. One pass over the (pixel, light) pairs serves every α.
fn matrix_for(views: &[ViewPixels], grid: Grid, alphas: &[f64]) -> RenderingMatrix {
    let cols: Vec<[Vec<f64>; 3]> = alphas.iter().map(|a| columns(grid, *a)).collect();
    let mut refs: Vec<&[f64]> = vec![&cols[0][0]];
    for c in &cols {
        refs.push(&c[1]);
        refs.push(&c[2]);
    }
    let mut out: Option<RenderingMatrix> = None;
    for v in views {
        let a = RenderingMatrix::build(v.pixels, v.lights, &refs, None, grid.theta_h_binning);
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

/// How many roughnesses each pass of [`Search::render`] renders, for `missing` of them (two
/// columns each) and Lambert first if `lambert`: as few passes as [`PASS_COLUMNS`] allows,
/// evenly filled. Empty if there is nothing to render.
fn passes(missing: usize, lambert: bool) -> Vec<usize> {
    if missing == 0 {
        return if lambert { vec![0] } else { Vec::new() };
    }
    // Lambert takes one column of the first pass.
    let first = (PASS_COLUMNS - usize::from(lambert)) / 2;
    let full = PASS_COLUMNS / 2;
    let n = 1 + missing.saturating_sub(first).div_ceil(full);
    // Evenly spread, the first pass (with Lambert) taking a smaller share if any.
    let (base, extra) = (missing / n, missing % n);
    (0..n).map(|k| base + usize::from(k >= n - extra)).collect()
}

/// The columns of [`matrix_for`]'s matrix that model Lambert and the lobes at `lobes`
/// (positions in its α list).
fn lobe_columns(lobes: &[usize]) -> Vec<usize> {
    let mut cols = vec![0];
    for &i in lobes {
        cols.extend([1 + 2 * i, 2 + 2 * i]);
    }
    cols
}

fn search_subset(n: usize, views: usize) -> Vec<usize> {
    super::select::spread(n, (SEARCH_PIXELS / views.max(1)).max(1))
}

/// The normal equations of `rows` rows of m unknowns: G = XᵀX, b = Xᵀy and yᵀy. `row(r, x)`
/// writes row r of X into `x` and returns its observation. Only G's lower half is summed.
pub(crate) fn normal_equations(
    m: usize,
    rows: usize,
    mut row: impl FnMut(usize, &mut [f64]) -> f64,
) -> (DMatrix<f64>, DVector<f64>, f64) {
    let mut g = DMatrix::zeros(m, m);
    // The right-hand side's sums and the Gram matrix's are apart: summed in one pass over
    // the rows, each in its own order.
    let (b, yy) = right_hand_side(m, rows, |r, x| {
        let y = row(r, x);
        for i in 0..m {
            for j in 0..=i {
                g[(i, j)] += x[i] * x[j];
            }
        }
        y
    });
    for i in 0..m {
        for j in 0..i {
            g[(j, i)] = g[(i, j)];
        }
    }
    (g, b, yy)
}

/// The right-hand side of [`normal_equations`] alone, b = Xᵀy and yᵀy, summed in the same
/// order (so the same to the bit): for a system whose Gram matrix was worked out beforehand.
pub(crate) fn right_hand_side(
    m: usize,
    rows: usize,
    mut row: impl FnMut(usize, &mut [f64]) -> f64,
) -> (DVector<f64>, f64) {
    let mut b = DVector::zeros(m);
    let mut yy = 0.0;
    let mut x = vec![0.0; m];
    for r in 0..rows {
        let y = row(r, &mut x);
        yy += y * y;
        for i in 0..m {
            b[i] += x[i] * y;
        }
    }
    (b, yy)
}

/// Per channel, the Gram blocks of the columns `cols` of `a` against the observations.
fn channel_systems(
    a: &RenderingMatrix,
    observed: &[[f64; 3]],
    cols: &[usize],
) -> [(DMatrix<f64>, DVector<f64>, f64); 3] {
    std::array::from_fn(|c| {
        normal_equations(cols.len(), observed.len(), |p, x| {
            let row = a.row(3 * p + c);
            for (xi, &k) in x.iter_mut().zip(cols) {
                *xi = row[k] as f64;
            }
            observed[p][c]
        })
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

/// How the roughness search scores a set of roughnesses: given the search pixels' matrix and
/// the columns of the lobes tried (Lambert first, then each lobe's F₀ and F₉₀), the
/// relative misfit of the best non-negative weights. The analytic model solves the lobes'
/// weights alone; the hybrid model solves them beside its measured materials.
pub type Scorer<'f> = Box<dyn Fn(&RenderingMatrix, &[usize]) -> f64 + Sync + 'f>;

/// The α search on the search pixels: every misfit it computes is recorded.
struct Search<'v, 'a> {
    views: &'v [ViewPixels<'a>],
    grid: Grid,
    observed: Vec<[f64; 3]>,
    score: Scorer<'v>,
    tried: Vec<(Vec<f64>, f64)>,
    /// Each view's search pixels ([`search_pixels`]).
    view_pixels: Vec<Vec<GeomPixel>>,
    /// The same, every view's in turn: the rows of [`Search::columns`].
    pixels: Vec<GeomPixel>,
    /// The search pixels' rendered columns, each computed once: a set of roughnesses tried
    /// shares Lambert and its fixed lobes with every other set, so only a new α costs a pass
    /// over the (pixel, light) pairs.
    columns: SearchColumns,
    /// Checked before each pass over the pixels, the search's unit of work.
    stop: Stop,
}

/// Where the search renders: each view's search pixels under its lights, on a grid.
struct SearchPixels<'s> {
    view_pixels: &'s [Vec<GeomPixel>],
    lights: &'s [&'s LightSet],
    grid: Grid,
}

impl SearchPixels<'_> {
    /// Renders into `out` the αs it lacks (and Lambert, the first time), as many per
    /// pass over the pixels as [`PASS_COLUMNS`] allows, the passes evenly filled.
    fn render(&self, out: &mut SearchColumns, alphas: &[f64], stop: &Stop) -> Result<()> {
        let mut missing: Vec<f64> = Vec::new();
        for a in alphas {
            if !out.lobes.contains_key(&a.to_bits())
                && !missing.iter().any(|m| m.to_bits() == a.to_bits())
            {
                missing.push(*a);
            }
        }
        let need_lambert = out.lambert.is_empty();
        let mut rest = missing.as_slice();
        for (k, count) in passes(missing.len(), need_lambert).into_iter().enumerate() {
            stop.check()?;
            let (chunk, after) = rest.split_at(count);
            rest = after;
            let lambert = need_lambert && k == 0;
            let cols: Vec<[Vec<f64>; 3]> = chunk.iter().map(|a| columns(self.grid, *a)).collect();
            let lambert_col = lambert.then(|| lambert_column(self.grid));
            let mut refs: Vec<&[f64]> = lambert_col.iter().map(|c| c.as_slice()).collect();
            for c in &cols {
                refs.push(&c[1]);
                refs.push(&c[2]);
            }
            let m = refs.len();
            let pixels: usize = self.view_pixels.iter().map(Vec::len).sum();
            let mut rows: Vec<f32> = Vec::with_capacity(3 * pixels * m);
            for (lights, pixels) in self.lights.iter().zip(self.view_pixels) {
                let binning = self.grid.theta_h_binning;
                rows.extend(RenderingMatrix::build(pixels, lights, &refs, None, binning).rows);
            }
            let column = |j: usize| -> Vec<f32> { rows.chunks(m).map(|r| r[j]).collect() };
            let first = usize::from(lambert);
            if lambert {
                out.lambert = column(0);
            }
            for (i, a) in chunk.iter().enumerate() {
                let pair = [column(first + 2 * i), column(first + 2 * i + 1)];
                out.lobes.insert(a.to_bits(), pair);
            }
        }
        Ok(())
    }
}

/// The search's renders that need no photo: Lambert and the coarse grid's lobes on each
/// view's search pixels. A capture makes them while its camera shoots, from the pixels the
/// estimate will take if the photo has none to leave out; the search uses them when its
/// pixels and lights turn out to be those.
#[derive(Clone)]
pub struct CoarseRenders {
    view_pixels: Vec<Vec<GeomPixel>>,
    lights: Vec<LightSet>,
    grid: Grid,
    columns: SearchColumns,
}

impl CoarseRenders {
    /// For views with these candidate pixels under these lights.
    pub fn new(views: &[(&[GeomPixel], &LightSet)], grid: Grid, stop: &Stop) -> Result<Self> {
        let view_pixels: Vec<Vec<GeomPixel>> = views
            .iter()
            .map(|(pixels, _)| search_pixels_of(pixels, views.len()))
            .collect();
        let lights: Vec<&LightSet> = views.iter().map(|(_, l)| *l).collect();
        let mut columns = SearchColumns::default();
        let at = SearchPixels {
            view_pixels: &view_pixels,
            lights: &lights,
            grid,
        };
        at.render(&mut columns, &coarse_grid(), stop)?;
        Ok(CoarseRenders {
            view_pixels,
            lights: lights.into_iter().cloned().collect(),
            grid,
            columns,
        })
    }

    /// Each view's search pixels.
    pub(crate) fn view_pixels(&self) -> &[Vec<GeomPixel>] {
        &self.view_pixels
    }

    /// Whether these are the renders of these search pixels under these lights.
    pub(crate) fn is_for(
        &self,
        view_pixels: &[Vec<GeomPixel>],
        views: &[ViewPixels],
        grid: Grid,
    ) -> bool {
        self.grid == grid
            && self.view_pixels == view_pixels
            && self.lights.len() == views.len()
            && self.lights.iter().zip(views).all(|(l, v)| l == v.lights)
    }
}

/// Rendered columns of the search pixels: Lambert, and (F₀, F₉₀) per α, each as rows
/// `3·p + c`.
#[derive(Default, Clone)]
struct SearchColumns {
    lambert: Vec<f32>,
    /// By α's bits: the F₀ column's rows, then the F₉₀ column's.
    lobes: std::collections::HashMap<u64, [Vec<f32>; 2]>,
}

impl Search<'_, '_> {
    /// Renders the columns of the αs not rendered yet (and Lambert, the first time).
    fn render(&mut self, alphas: &[f64]) -> Result<()> {
        let lights: Vec<&LightSet> = self.views.iter().map(|v| v.lights).collect();
        let at = SearchPixels {
            view_pixels: &self.view_pixels,
            lights: &lights,
            grid: self.grid,
        };
        at.render(&mut self.columns, alphas, &self.stop)
    }

    /// The search pixels' matrix of the model with these lobes: Lambert, then (F₀, F₉₀) of
    /// each α (all rendered by [`Search::render`]).
    fn matrix(&self, alphas: &[f64]) -> RenderingMatrix {
        let mut cols: Vec<&[f32]> = vec![&self.columns.lambert];
        for a in alphas {
            let [f0, f90] = &self.columns.lobes[&a.to_bits()];
            cols.push(f0);
            cols.push(f90);
        }
        let rows = (0..self.columns.lambert.len())
            .flat_map(|r| cols.iter().map(move |c| c[r]))
            .collect();
        RenderingMatrix {
            columns: cols.len(),
            pixels: self.pixels.clone(),
            rows,
            offset: None,
        }
    }

    /// The misfit of each candidate α as one more lobe beside the `fixed` ones.
    fn misfits(&mut self, fixed: &[f64], candidates: &[f64]) -> Result<Vec<f64>> {
        use rayon::prelude::*;
        self.render(&[fixed, candidates].concat())?;
        let cols: Vec<usize> = (0..1 + 2 * (fixed.len() + 1)).collect();
        let sets: Vec<Vec<f64>> = candidates
            .iter()
            .map(|alpha| [fixed, &[*alpha]].concat())
            .collect();
        // Each set's solve needs nothing of the others': they run side by side (a round's
        // solves are serial work as long as its render is parallel).
        let search = &*self;
        let misfits: Vec<f64> = sets
            .par_iter()
            .map(|set| (search.score)(&search.matrix(set), &cols))
            .collect();
        self.tried
            .extend(sets.into_iter().zip(misfits.iter().copied()));
        Ok(misfits)
    }

    /// The best α for one more lobe beside `fixed`: the coarse grid, then the refinement
    /// ([`Search::refine`]) between the best grid point's neighbours.
    fn best_lobe(&mut self, fixed: &[f64]) -> Result<f64> {
        let coarse = coarse_grid();
        let misfits = self.misfits(fixed, &coarse)?;
        let best = (0..coarse.len())
            .min_by(|&i, &j| misfits[i].total_cmp(&misfits[j]))
            .expect("a coarse grid");
        self.refine(
            fixed,
            coarse[best.saturating_sub(1)],
            coarse[(best + 1).min(coarse.len() - 1)],
            (coarse[best], misfits[best]),
        )
    }

    /// Refines one more lobe's α in [lo, hi] (log scale): [`REFINE_ROUNDS`] rounds of
    /// [`REFINE_POINTS`] evenly spaced points, each round narrowed to the best point's
    /// neighbours. A round's points share one matrix build, which costs far more than the
    /// solves, so this is three builds where a golden-section search of the same precision
    /// takes ten. Never returns worse than `start` (an α and its misfit).
    fn refine(&mut self, fixed: &[f64], lo: f64, hi: f64, start: (f64, f64)) -> Result<f64> {
        let mut best = start;
        let (mut lo, mut hi) = (lo.ln(), hi.ln());
        for _ in 0..REFINE_ROUNDS {
            let step = (hi - lo) / (REFINE_POINTS + 1) as f64;
            let points: Vec<f64> = (1..=REFINE_POINTS)
                .map(|i| (lo + step * i as f64).exp())
                .collect();
            let misfits = self.misfits(fixed, &points)?;
            for (alpha, misfit) in points.into_iter().zip(misfits) {
                if misfit < best.1 {
                    best = (alpha, misfit);
                }
            }
            // Within the searched range: a bracket at the grid's end (a mirror, a nearly
            // diffuse lobe) must not step past it.
            (lo, hi) = (
                (best.0.ln() - step).max(ALPHA_MIN.ln()),
                (best.0.ln() + step).min(ALPHA_MAX.ln()),
            );
        }
        Ok(best.0)
    }
}

/// The coarse grid of α: [`COARSE_ALPHAS`] values, log-spaced over the searched range.
fn coarse_grid() -> Vec<f64> {
    let log_span = (ALPHA_MAX / ALPHA_MIN).ln();
    (0..COARSE_ALPHAS)
        .map(|i| ALPHA_MIN * (log_span * i as f64 / (COARSE_ALPHAS - 1) as f64).exp())
        .collect()
}

/// The factor either side of the first lobe's α that it is searched again over once the
/// second lobe is in place: fitted alone, the first lobe also covered what the second now does.
const RESEARCH_SPAN: f64 = 1.8;

/// The roughness search of [`fit`] on the search pixels: the roughnesses found, sorted, and the
/// search (with every misfit it computed).
fn search_roughness<'v, 'a>(
    views: &'v [ViewPixels<'a>],
    grid: Grid,
    lobes: usize,
    score: Option<Scorer<'v>>,
    coarse: Option<&CoarseRenders>,
    stop: &Stop,
) -> Result<(Search<'v, 'a>, Vec<f64>)> {
    if views.iter().all(|v| v.pixels.is_empty()) {
        return Err(CoreError::Invalid(
            "no pixels to fit the model's lobes to".into(),
        ));
    }
    if !(1..=MAX_LOBES).contains(&lobes) {
        return Err(CoreError::Invalid(format!(
            "the model has 1 to {MAX_LOBES} lobes, not {lobes}"
        )));
    }
    let observed = observed_of(views, true);
    let score = score.unwrap_or_else(|| {
        let observed = observed.clone();
        Box::new(move |a: &RenderingMatrix, cols: &[usize]| solve_weights(a, &observed, cols).1)
    });
    let (view_pixels, _) = search_pixels(views);
    let mut search = Search {
        views,
        grid,
        observed,
        score,
        tried: Vec::new(),
        pixels: view_pixels.concat(),
        view_pixels,
        columns: SearchColumns::default(),
        stop: stop.clone(),
    };
    if let Some(c) = coarse.filter(|c| c.is_for(&search.view_pixels, views, grid)) {
        search.columns = c.columns.clone();
    }
    let mut alphas = vec![search.best_lobe(&[])?];
    if lobes == 2 {
        let second = search.best_lobe(&alphas)?;
        let current = search.misfits(&[second], &[alphas[0]])?[0];
        let first = search.refine(
            &[second],
            (alphas[0] / RESEARCH_SPAN).max(ALPHA_MIN),
            (alphas[0] * RESEARCH_SPAN).min(ALPHA_MAX),
            (alphas[0], current),
        )?;
        alphas = vec![first, second];
        alphas.sort_by(f64::total_cmp);
    }
    Ok((search, alphas))
}

/// The observations of every view's candidates, or of its search pixels (`subset`).
fn observed_of(views: &[ViewPixels], subset: bool) -> Vec<[f64; 3]> {
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
}

/// The search pixels of every view (spread over its candidates, [`SEARCH_PIXELS`] in all) and
/// what they measured, in the order the search's matrices hold them.
pub(crate) fn search_pixels(views: &[ViewPixels]) -> (Vec<Vec<GeomPixel>>, Vec<[f64; 3]>) {
    let pixels = views
        .iter()
        .map(|v| search_pixels_of(v.pixels, views.len()))
        .collect();
    (pixels, observed_of(views, true))
}

/// One view's search pixels, of `views` sharing [`SEARCH_PIXELS`].
fn search_pixels_of(candidates: &[GeomPixel], views: usize) -> Vec<GeomPixel> {
    search_subset(candidates.len(), views)
        .into_iter()
        .map(|i| candidates[i].clone())
        .collect()
}

/// The roughnesses [`fit`]'s search finds with the given `score` (the analytic model's own if
/// `None`), each with its 1-σ from the misfit's profile, without the fit's weights over every
/// candidate: for a model that solves its own weights beside the lobes ([`super::hybrid`]).
/// The search starts from `coarse`'s renders where they are of its pixels and lights.
pub fn roughnesses<'v>(
    views: &'v [ViewPixels],
    grid: Grid,
    lobes: usize,
    score: Option<Scorer<'v>>,
    coarse: Option<&CoarseRenders>,
    stop: &Stop,
) -> Result<Roughnesses> {
    let (mut search, alphas) = search_roughness(views, grid, lobes, score, coarse, stop)?;
    let lobes = (0..alphas.len())
        .map(|l| Ok((alphas[l], profile_std(&mut search, &alphas, l)?)))
        .collect::<Result<_>>()?;
    // The search rendered these roughnesses' columns on its pixels already.
    let rows = search
        .matrix(&alphas)
        .rows
        .iter()
        .map(|v| *v as f64)
        .collect();
    Ok(Roughnesses { lobes, rows })
}

/// What [`roughnesses`] finds: each lobe's α with its 1-σ, and the search pixels' dense rows
/// of the model at those roughnesses (row 3·p + c: Lambert, then each lobe's F₀ and F₉₀), as
/// the search rendered them.
pub struct Roughnesses {
    pub lobes: Vec<(f64, f64)>,
    pub rows: Vec<f64>,
}

/// Fits the model with `lobes` lobes (1 or 2) to the candidates of every view, by variable
/// projection on a spread of [`SEARCH_PIXELS`] pixels: the first lobe's α over a coarse grid
/// and a refinement around the best; then the second lobe's the same way beside it, and the
/// first searched again beside the second. The weights of the best roughnesses then come from
/// every candidate.
pub fn fit(views: &[ViewPixels], grid: Grid, lobes: usize, stop: &Stop) -> Result<AnalyticFit> {
    let (mut search, alphas) = search_roughness(views, grid, lobes, None, None, stop)?;
    let observed = observed_of(views, false);
    let matrix = matrix_for(views, grid, &alphas);
    stop.check()?;
    let cols = lobe_columns(&(0..alphas.len()).collect::<Vec<_>>());
    let (w, _) = solve_weights(&matrix, &observed, &cols);
    let systems = channel_systems(&matrix, &observed, &cols);
    let condition = systems
        .iter()
        .map(|(g, _, _)| scaled_condition(g))
        .fold(0.0, f64::max);
    let alpha_std: Vec<f64> = (0..alphas.len())
        .map(|l| profile_std(&mut search, &alphas, l))
        .collect::<Result<_>>()?;
    let lobes: Vec<(f64, f64)> = alphas.iter().copied().zip(alpha_std).collect();
    let uncertainty = uncertainty(
        &matrix,
        &observed,
        &systems,
        &w,
        &lobes,
        grid,
        views[0].lights,
    )?;
    let model = Microfacet::from_weights(&w, &alphas);
    Ok(AnalyticFit {
        model,
        matrix,
        observed,
        search: search.tried,
        condition,
        uncertainty,
    })
}

/// 1-σ of lobe `l`'s α from the curvature of the residual sum of squares along log α on the
/// search pixels, the other lobes fixed: RSS(u) ≈ RSS* + a (u − u*)², σᵤ = √(σ² / a). It is
/// measured on the [`SEARCH_PIXELS`] search pixels, not every candidate, so it is the wider of
/// the two (by up to √(candidates / search pixels)): a bound, not a tight figure.
fn profile_std(search: &mut Search, alphas: &[f64], l: usize) -> Result<f64> {
    let fixed: Vec<f64> = alphas
        .iter()
        .enumerate()
        .filter(|(i, _)| *i != l)
        .map(|(_, a)| *a)
        .collect();
    let a = alphas[l];
    let m = search.misfits(
        &fixed,
        &[a * (-PROFILE_STEP).exp(), a, a * PROFILE_STEP.exp()],
    )?;
    let y2: f64 = search.observed.iter().flatten().map(|v| v * v).sum();
    let rss: Vec<f64> = m.iter().map(|m| m * m * y2).collect();
    let curvature = (rss[0] - 2.0 * rss[1] + rss[2]) / (2.0 * PROFILE_STEP * PROFILE_STEP);
    // Unknowns: kd per channel, and per lobe F₀ and F₉₀ per channel and α.
    let dof = (3 * search.observed.len())
        .saturating_sub(3 + 7 * alphas.len())
        .max(1);
    let variance = rss[1] / dof as f64;
    Ok(if curvature > 0.0 {
        a * (variance / curvature).sqrt()
    } else {
        // Flat or concave: the photo does not pin this roughness down.
        f64::INFINITY
    })
}

/// The analytic fit's [`Uncertainty`]: the weights' covariance at the fitted roughnesses,
/// σ²(XᵀX)⁻¹ over the weights the fit keeps (a weight held at zero by its bound gets 0), with
/// σ² the residual's variance, so model error counts as noise and a poor fit is reported as
/// unsure; each α's variance from the misfit's profile ([`profile_std`]); and the bootstrap
/// band with the roughnesses fixed. `lobes` holds each lobe's α and its 1-σ.
fn uncertainty(
    matrix: &RenderingMatrix,
    observed: &[[f64; 3]],
    systems: &[(DMatrix<f64>, DVector<f64>, f64); 3],
    weights: &[DVector<f64>; 3],
    lobes: &[(f64, f64)],
    grid: Grid,
    lights: &LightSet,
) -> Result<Uncertainty> {
    let alphas: Vec<f64> = lobes.iter().map(|l| l.0).collect();
    let p = weights[0].len();
    let n = observed.len();
    let per_channel: [DMatrix<f64>; 3] = std::array::from_fn(|c| {
        let (g, b, yy) = &systems[c];
        linearised_covariance(g, b, *yy, &weights[c], n)
    });
    // Into the order of `Microfacet::values`: kd of R, G, B; then per lobe F₀ of R, G, B, F₉₀
    // of R, G, B, α. Channels are solved apart, so their blocks do not mix.
    let m = 3 + 7 * alphas.len();
    let position = |c: usize, k: usize| -> usize {
        if k == 0 {
            c
        } else {
            let (lobe, part) = ((k - 1) / 2, (k - 1) % 2);
            3 + 7 * lobe + 3 * part + c
        }
    };
    let mut covariance = vec![0.0; m * m];
    for (c, cov) in per_channel.iter().enumerate() {
        for i in 0..p {
            for j in 0..p {
                covariance[position(c, i) * m + position(c, j)] = cov[(i, j)];
            }
        }
    }
    for (l, (_, s)) in lobes.iter().enumerate() {
        let k = 9 + 7 * l;
        covariance[k * m + k] = s * s;
    }
    // Bootstrap: the pixels resampled with replacement, the weights solved again at the fitted
    // roughnesses, the BRDF rebuilt from them.
    let cols: Vec<[Vec<f64>; 3]> = alphas.iter().map(|a| columns(grid, *a)).collect();
    let rebuild = |w: &[DVector<f64>; 3]| -> Vec<f64> {
        let mut values = vec![0.0; VALUES];
        for c in 0..3 {
            let plane = c * GRID_CELLS..(c + 1) * GRID_CELLS;
            for (k, col) in std::iter::once(&cols[0][0])
                .chain(cols.iter().flat_map(|l| [&l[1], &l[2]]))
                .enumerate()
            {
                for (v, x) in values[plane.clone()].iter_mut().zip(&col[plane.clone()]) {
                    *v += w[c][k] * x;
                }
            }
        }
        values
    };
    // The sphere relit under the estimate's lights, linear in the weights.
    let refs: Vec<&[f64]> = std::iter::once(cols[0][0].as_slice())
        .chain(cols.iter().flat_map(|l| [l[1].as_slice(), l[2].as_slice()]))
        .collect();
    let sphere =
        RenderingMatrix::build(&spread_sphere()?, lights, &refs, None, grid.theta_h_binning);
    let image = |w: &[DVector<f64>; 3]| {
        sphere.predict_per_channel([w[0].as_slice(), w[1].as_slice(), w[2].as_slice()])
    };
    let full: Vec<usize> = (0..p).collect();
    // Drawn in order from one seed, solved side by side.
    let (brdfs, images): (Vec<Vec<f64>>, Vec<Vec<f64>>) = resamples(n)
        .par_iter()
        .map(|picks| {
            let obs: Vec<[f64; 3]> = picks.iter().map(|&i| observed[i]).collect();
            let w = solve_weights(&matrix.subset(picks), &obs, &full).0;
            (rebuild(&w), image(&w))
        })
        .unzip();
    Ok(Uncertainty {
        std: std_of(&covariance, m),
        covariance,
        covariance_from: "linearised",
        bootstrap_spread: image_spread(&images, &image(weights)),
        resamples: images.len(),
        band: band(&brdfs),
    })
}

/// The covariance σ²(XᵀX)⁻¹ of non-negative least-squares weights `w` (given G = XᵀX,
/// b = Xᵀy and yᵀy, over `n` observations), over the weights the fit keeps: a weight held at
/// zero by its bound gets 0. σ² is the residual's variance, so model error counts as noise and
/// a poor fit is reported as unsure.
pub(crate) fn linearised_covariance(
    g: &DMatrix<f64>,
    b: &DVector<f64>,
    yy: f64,
    w: &DVector<f64>,
    n: usize,
) -> DMatrix<f64> {
    let p = w.len();
    let rss = ((w.transpose() * g * w)[0] - 2.0 * w.dot(b) + yy).max(0.0);
    let free: Vec<usize> = (0..p).filter(|&k| w[k] > 0.0).collect();
    let variance = rss / n.saturating_sub(free.len()).max(1) as f64;
    let sub = DMatrix::from_fn(free.len(), free.len(), |i, j| g[(free[i], free[j])]);
    let inv = sub
        .try_inverse()
        .unwrap_or_else(|| DMatrix::from_element(free.len(), free.len(), f64::INFINITY));
    let mut cov = DMatrix::zeros(p, p);
    for (i, &a) in free.iter().enumerate() {
        for (j, &b) in free.iter().enumerate() {
            cov[(a, b)] = variance * inv[(i, j)];
        }
    }
    cov
}

/// κ of X from its Gram matrix G = XᵀX, with X's columns scaled to unit norm first (the
/// columns' units differ; their overlap is what matters).
pub(crate) fn scaled_condition(g: &DMatrix<f64>) -> f64 {
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
    /// The per-channel weights in the matrix's column order, for prediction.
    pub fn per_channel(&self) -> [Vec<f64>; 3] {
        let m = &self.model;
        std::array::from_fn(|c| {
            let mut w = vec![m.diffuse[c]];
            for l in &m.lobes {
                w.extend([l.f0[c], l.f90[c]]);
            }
            w
        })
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
    fn search_passes_hold_every_roughness_and_never_overflow() {
        for lambert in [false, true] {
            for missing in 0..=100 {
                let p = passes(missing, lambert);
                assert_eq!(p.iter().sum::<usize>(), missing, "{missing} {lambert}");
                for (k, n) in p.iter().enumerate() {
                    let columns = 2 * n + usize::from(lambert && k == 0);
                    assert!(columns <= PASS_COLUMNS, "{missing} {lambert}: {p:?}");
                }
                // As few passes as the columns need: one fewer could not hold them.
                let first = (PASS_COLUMNS - usize::from(lambert)) / 2;
                if p.len() > 1 {
                    let fewer = first + (p.len() - 2) * (PASS_COLUMNS / 2);
                    assert!(fewer < missing, "{missing} {lambert}: {p:?}");
                }
                assert_eq!(p.is_empty(), missing == 0 && !lambert);
            }
        }
        // The coarse grid with Lambert: 41 columns in two passes of ten roughnesses.
        assert_eq!(passes(COARSE_ALPHAS, true), vec![10, 10]);
    }

    #[test]
    fn a_white_lobe_reflects_at_most_all_light() {
        // With F₀ = F₉₀ = 1, a single-scattering GGX lobe loses only what its masking loses:
        // about 1% at α 0.02 seen from the normal, more for rough lobes and at grazing views.
        // The albedo must stay ≤ 1 (plus the quadrature's 0.5%) and near 1 for a sharp lobe.
        use crate::brdf::directional_albedo;
        let sharp = Microfacet::one_lobe([0.0; 3], [1.0; 3], [1.0; 3], 0.02);
        let a = directional_albedo(&sharp, 0.0)[0];
        assert!(a > 0.97 && a < 1.005, "α 0.02 at normal view: {a}");
        for alpha in [0.1, 0.5] {
            let m = Microfacet::one_lobe([0.0; 3], [1.0; 3], [1.0; 3], alpha);
            for theta in [0.0, 0.8, 1.3] {
                let a = directional_albedo(&m, theta)[0];
                assert!(a < 1.005, "α {alpha} at {theta}: {a}");
            }
        }
    }

    #[test]
    fn lobe_columns_match_the_reduction_of_the_full_model() {
        // The fast column path and Bivariate::reduce of the full BRDF must agree: same
        // samples, same formula, summed in another order (tolerance 1e-9 relative).
        let grid = Grid::default();
        let mut m = Microfacet::one_lobe([0.2, 0.3, 0.4], [0.9, 0.6, 0.3], [1.0; 3], 0.1);
        m.lobes.push(Lobe {
            f0: [0.1, 0.2, 0.3],
            f90: [0.5; 3],
            alpha: 0.4,
        });
        let fast = m.bivariate(grid);
        let slow = Bivariate::reduce(&m, grid);
        for (a, b) in fast.values.iter().zip(&slow.values) {
            assert!((a - b).abs() <= 1e-9 * (1.0 + b.abs()), "{a} vs {b}");
        }
        assert_eq!(fast.valid, slow.valid);
    }
}
