//! Fitting a renderer's material model to the whole estimate, by how it relights.
//!
//! The target is the estimate itself (analytic lobes and measured mix together), rendered on a
//! sphere under several maps; the fitted material is the one whose own BRDF, rendered the same
//! way, comes closest in relative RMSE, each map counting alike. Both formats brdfd writes
//! share one structure (glTF 2.0 appendix B with `KHR_materials_specular`/`KHR_materials_ior`;
//! OpenPBR's base layer), per colour channel k:
//!
//! ```text
//! f_k = (1 − m)·[(1 − q·F)·c_k/π + q·Fr_k·S]  +  m·(c_k + (1 − c_k)·w)·S
//! Fr_k = F₀_k + (1 − F₀_k)·w,   F = max over k of Fr_k,   w = (1 − cos θd)⁵,
//! S = D·V (GGX/Smith, roughness α)
//! ```
//!
//! with base colour c, metalness m, specular weight q and the dielectric's F₀ per channel (the
//! largest from the IOR, the others through the specular colour). Rendering is linear in the
//! BRDF, so a render is a sum of four images per α: Lambert `L`, Lambert·w `Lw`, `S(1 − w)`
//! and `S·w`. For fixed (α, m, q, largest F₀) the render is linear in each channel's c_k and
//! F₀_k, which are solved exactly on their box; (m, q, largest F₀) are searched on a grid and
//! refined, all through the 5 × 5 Gram matrix of the four images and the target (no image is
//! formed in the search). α is searched on a log grid, then by golden section with new
//! renders.
//!
//! Not here: the formats' writers ([`super::gltf`], [`super::openpbr`]), and measuring the
//! result under maps the fit did not see ([`super::write_exports`]).

use rayon::prelude::*;

use brdfd_core::analytic::{columns, lambert_column, schlick_weight};
use brdfd_core::bivariate::{Bivariate, Grid, GRID_CELLS, N_THETA_D};
use brdfd_core::envmap::LightSet;
use brdfd_core::geometry::GeomPixel;
use brdfd_core::merl::theta_d_center;
use brdfd_core::render::{RenderingMatrix, PASS_COLUMNS};
use brdfd_core::{CoreError, Result};

/// Roughness (GGX α) searched: glTF roughness 0.02 (a polished mirror; below it the sphere's
/// pixels cannot tell α apart) to 1.
pub const ALPHA_MIN: f64 = 4e-4;
pub const ALPHA_MAX: f64 = 1.0;
/// Log-spaced α of the coarse search: neighbours differ by 1.36×.
const COARSE_ALPHAS: usize = 26;
/// Golden-section steps on log α after the coarse grid: the bracket of two grid steps
/// shrinks to 0.618⁸ = 2% of itself, about 1% in α.
const GOLDEN_STEPS: usize = 8;
/// The dielectric F₀ values the grid search starts from (IOR 1.0 to 5.8): plastics and
/// paints sit near 0.04, coatings and glazes up to 0.1, the rest lets a dim metal-like
/// dielectric (black obsidian) be expressed.
const F0_GRID: [f64; 12] = [
    0.0, 0.02, 0.03, 0.04, 0.05, 0.06, 0.08, 0.1, 0.15, 0.2, 0.3, 0.5,
];
/// Steps of metalness and specular weight on the search grid.
const UNIT_STEPS: usize = 10;
/// Pattern-search refinement of (m, q, F): the first step and the smallest.
const REFINE_FIRST_STEP: f64 = 0.05;
const REFINE_LAST_STEP: f64 = 1e-4;

/// The four terms and the target, in the Gram matrix's order.
const TERMS: usize = 4;
const TARGET: usize = 4;
type Gram = [[f64; 5]; 5];

/// The shared model's parameters: what every format holds in its own fields.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fitted {
    /// Base colour c per channel, in [0, 1].
    pub base_color: [f64; 3],
    /// Metalness m in [0, 1].
    pub metallic: f64,
    /// Specular weight q of the dielectric in [0, 1] (glTF's `specularFactor`).
    pub specular: f64,
    /// The dielectric's F₀ at full weight per channel, in [0, 1): the largest is the IOR's,
    /// the others that times the specular colour.
    pub f0: [f64; 3],
    /// GGX α.
    pub alpha: f64,
    /// The relative RMSE of the fit over the fit maps (each counting alike).
    pub fit_error: f64,
}

impl Fitted {
    fn f0_max(&self) -> f64 {
        self.f0.iter().copied().fold(0.0, f64::max)
    }

    /// The IOR whose normal-incidence reflectance is the largest F₀: ((η − 1)/(η + 1))² = F.
    pub fn ior(&self) -> f64 {
        let r = self.f0_max().clamp(0.0, 0.99).sqrt();
        (1.0 + r) / (1.0 - r)
    }

    /// The specular colour, each channel's F₀ relative to the IOR's (the largest is 1).
    pub fn specular_color(&self) -> [f64; 3] {
        let top = self.f0_max();
        self.f0.map(|f| if top > 0.0 { f / top } else { 1.0 })
    }
}

/// The (m, q, F) part of the search; F bounds every channel's F₀ and is the largest of them.
#[derive(Clone, Copy, Debug)]
struct Shape {
    m: f64,
    q: f64,
    f: f64,
}

/// Weights of (L, Lw, S0, S1) in an image.
type Terms = [f64; TERMS];

impl Shape {
    /// The weights of (L, Lw, S0, S1) that multiply c (A), that multiply the channel's F₀
    /// (P), and the rest (B). The diffuse's weight uses F, the largest F₀ (the ratified
    /// `KHR_materials_specular` takes the maximum over the channels there).
    fn weights(self) -> (Terms, Terms, Terms) {
        let Shape { m, q, f } = self;
        let d = 1.0 - m;
        (
            [d * (1.0 - q * f), -d * q * (1.0 - f), m, 0.0],
            [0.0, 0.0, d * q, 0.0],
            [0.0, 0.0, 0.0, d * q + m],
        )
    }

    fn clamped(self) -> Shape {
        Shape {
            m: self.m.clamp(0.0, 1.0),
            q: self.q.clamp(0.0, 1.0),
            f: self.f.clamp(0.0, 0.99),
        }
    }
}

fn quad(g: &Gram, a: &Terms, b: &Terms) -> f64 {
    (0..TERMS)
        .map(|i| (0..TERMS).map(|j| a[i] * g[i][j] * b[j]).sum::<f64>())
        .sum()
}

fn with_target(g: &Gram, a: &Terms) -> f64 {
    (0..TERMS).map(|i| a[i] * g[i][TARGET]).sum()
}

/// ‖x·u + y·v + b − t‖² for one channel, from its Gram matrix, as a quadratic in (x, y).
struct Quadratic {
    uu: f64,
    uv: f64,
    vv: f64,
    /// ⟨u, t − b⟩ and ⟨v, t − b⟩.
    ut: f64,
    vt: f64,
    /// ‖t − b‖².
    tt: f64,
}

impl Quadratic {
    fn new(g: &Gram, u: &Terms, v: &Terms, b: &Terms) -> Quadratic {
        Quadratic {
            uu: quad(g, u, u),
            uv: quad(g, u, v),
            vv: quad(g, v, v),
            ut: with_target(g, u) - quad(g, u, b),
            vt: with_target(g, v) - quad(g, v, b),
            tt: quad(g, b, b) - 2.0 * with_target(g, b) + g[TARGET][TARGET],
        }
    }

    fn at(&self, x: f64, y: f64) -> f64 {
        x * x * self.uu + 2.0 * x * y * self.uv + y * y * self.vv
            - 2.0 * x * self.ut
            - 2.0 * y * self.vt
            + self.tt
    }

    /// The best x in [0, x_max] for a fixed y.
    fn best_x(&self, y: f64, x_max: f64) -> f64 {
        if self.uu > 0.0 {
            ((self.ut - y * self.uv) / self.uu).clamp(0.0, x_max)
        } else {
            0.0
        }
    }

    fn best_y(&self, x: f64, y_max: f64) -> f64 {
        if self.vv > 0.0 {
            ((self.vt - x * self.uv) / self.vv).clamp(0.0, y_max)
        } else {
            0.0
        }
    }

    /// The minimum over the box [0, x_max] × [0, y_max]: the free minimum if it lies inside,
    /// else the best point on the box's edges.
    fn box_min(&self, x_max: f64, y_max: f64) -> (f64, f64) {
        let det = self.uu * self.vv - self.uv * self.uv;
        if det > 1e-300 {
            let x = (self.ut * self.vv - self.vt * self.uv) / det;
            let y = (self.vt * self.uu - self.ut * self.uv) / det;
            if (0.0..=x_max).contains(&x) && (0.0..=y_max).contains(&y) {
                return (x, y);
            }
        }
        let candidates = [
            (self.best_x(0.0, x_max), 0.0),
            (self.best_x(y_max, x_max), y_max),
            (0.0, self.best_y(0.0, y_max)),
            (x_max, self.best_y(x_max, y_max)),
        ];
        candidates
            .into_iter()
            .min_by(|a, b| self.at(a.0, a.1).total_cmp(&self.at(b.0, b.1)))
            .unwrap_or((0.0, 0.0))
    }
}

/// The best base colour and F₀ of every channel for a shape, and the squared misfit. The
/// channel whose F₀ comes out largest is then held at F, so that F is the largest F₀ as the
/// model says.
fn cost(grams: &[Gram; 3], shape: Shape) -> (f64, [f64; 3], [f64; 3]) {
    let (a, p, b) = shape.weights();
    let quads: Vec<Quadratic> = grams
        .iter()
        .map(|g| Quadratic::new(g, &a, &p, &b))
        .collect();
    let mut colour = [0.0; 3];
    let mut f0 = [0.0; 3];
    for k in 0..3 {
        (colour[k], f0[k]) = quads[k].box_min(1.0, shape.f);
    }
    let top = (0..3).max_by(|i, j| f0[*i].total_cmp(&f0[*j])).unwrap_or(0);
    f0[top] = shape.f;
    colour[top] = quads[top].best_x(shape.f, 1.0);
    let total = (0..3).map(|k| quads[k].at(colour[k], f0[k]).max(0.0)).sum();
    (total, colour, f0)
}

/// The best shape at one α: the grid, then a pattern search from its best point.
fn best_shape(grams: &[Gram; 3]) -> (Shape, f64) {
    let steps = (0..=UNIT_STEPS).map(|i| i as f64 / UNIT_STEPS as f64);
    let mut best = (
        Shape {
            m: 0.0,
            q: 0.0,
            f: 0.0,
        },
        f64::INFINITY,
    );
    for m in steps.clone() {
        for q in steps.clone() {
            for f in F0_GRID {
                let s = Shape { m, q, f };
                let (e, ..) = cost(grams, s);
                if e < best.1 {
                    best = (s, e);
                }
            }
        }
    }
    let mut step = REFINE_FIRST_STEP;
    while step >= REFINE_LAST_STEP {
        let mut moved = false;
        for (dm, dq, df) in [
            (1.0, 0.0, 0.0),
            (-1.0, 0.0, 0.0),
            (0.0, 1.0, 0.0),
            (0.0, -1.0, 0.0),
            (0.0, 0.0, 1.0),
            (0.0, 0.0, -1.0),
        ] {
            let (s, _) = best;
            let t = Shape {
                m: s.m + dm * step,
                q: s.q + dq * step,
                // F₀ moves on a finer scale: it lives near 0.04.
                f: s.f + df * step * 0.2,
            }
            .clamped();
            let (e, ..) = cost(grams, t);
            if e < best.1 {
                best = (t, e);
                moved = true;
            }
        }
        if !moved {
            step /= 2.0;
        }
    }
    best
}

/// The images a fit compares: the target and the α-free terms (L, Lw) per map, each map's
/// rows scaled so that the target has unit norm there.
pub struct Scenes<'a> {
    pixels: &'a [GeomPixel],
    maps: &'a [LightSet],
    grid: Grid,
    /// Per map: rows (3 per pixel) of L, Lw and the target, each scaled by the map's weight.
    fixed: Vec<[Vec<f64>; 3]>,
    scale: Vec<f64>,
}

/// Lambert × Schlick's weight, grey.
fn lambert_w_column(grid: Grid) -> Vec<f64> {
    let lambert = lambert_column(grid);
    lambert
        .iter()
        .enumerate()
        .map(|(i, l)| l * schlick_weight(theta_d_center((i % GRID_CELLS) % N_THETA_D).cos()))
        .collect()
}

impl<'a> Scenes<'a> {
    /// Renders `target` and the α-free terms on `pixels` under each of `maps`.
    pub fn new(pixels: &'a [GeomPixel], maps: &'a [LightSet], target: &Bivariate) -> Result<Self> {
        let grid = target.grid;
        let lambert = lambert_column(grid);
        let lambert_w = lambert_w_column(grid);
        let cols: [&[f64]; 3] = [&lambert, &lambert_w, &target.values];
        let mut fixed = Vec::with_capacity(maps.len());
        let mut scale = Vec::with_capacity(maps.len());
        for lights in maps {
            let a = RenderingMatrix::build(pixels, lights, &cols, None, grid.theta_h_binning);
            let column = |j: usize| -> Vec<f64> {
                (0..pixels.len() * 3).map(|r| a.row(r)[j] as f64).collect()
            };
            let t = column(2);
            let norm = t.iter().map(|v| v * v).sum::<f64>().sqrt();
            if !(norm.is_finite() && norm > 0.0) {
                return Err(CoreError::Invalid(
                    "the estimate renders black (or not a number) under a reference map: \
                     there is nothing for an export to match"
                        .into(),
                ));
            }
            let s = 1.0 / norm;
            fixed.push([column(0), column(1), t].map(|v| v.into_iter().map(|x| x * s).collect()));
            scale.push(s);
        }
        Ok(Scenes {
            pixels,
            maps,
            grid,
            fixed,
            scale,
        })
    }

    /// The per-channel Gram matrices of (L, Lw, S0, S1, target) at each of `alphas`, summed
    /// over the maps.
    fn grams(&self, alphas: &[f64]) -> Vec<[Gram; 3]> {
        let cols: Vec<[Vec<f64>; 3]> = alphas.par_iter().map(|a| columns(self.grid, *a)).collect();
        let mut out = vec![[[[0.0; 5]; 5]; 3]; alphas.len()];
        let per_pass = PASS_COLUMNS / 2;
        for (m, lights) in self.maps.iter().enumerate() {
            let [l, lw, t] = &self.fixed[m];
            for (p, chunk) in cols.chunks(per_pass).enumerate() {
                let refs: Vec<&[f64]> = chunk.iter().flat_map(|c| [&c[1][..], &c[2][..]]).collect();
                let a = RenderingMatrix::build(
                    self.pixels,
                    lights,
                    &refs,
                    None,
                    self.grid.theta_h_binning,
                );
                let s = self.scale[m];
                for (i, g) in out[p * per_pass..p * per_pass + chunk.len()]
                    .iter_mut()
                    .enumerate()
                {
                    for r in 0..self.pixels.len() * 3 {
                        let row = a.row(r);
                        let v = [
                            l[r],
                            lw[r],
                            row[2 * i] as f64 * s,
                            row[2 * i + 1] as f64 * s,
                            t[r],
                        ];
                        let k = &mut g[r % 3];
                        for x in 0..5 {
                            for y in x..5 {
                                k[x][y] += v[x] * v[y];
                            }
                        }
                    }
                }
            }
        }
        for g in out.iter_mut().flatten() {
            for x in 0..5 {
                for y in 0..x {
                    g[x][y] = g[y][x];
                }
            }
        }
        out
    }

    /// The best shape and base colour at one α, and its squared misfit.
    fn at(&self, alpha: f64) -> Candidate {
        let grams = self.grams(&[alpha]).remove(0);
        Candidate::of(alpha, &grams, best_shape(&grams).0)
    }

    /// Fits the shared model to the target.
    pub fn fit(&self) -> Fitted {
        let ratio = (ALPHA_MAX / ALPHA_MIN).powf(1.0 / (COARSE_ALPHAS - 1) as f64);
        let alphas: Vec<f64> = (0..COARSE_ALPHAS)
            .map(|i| ALPHA_MIN * ratio.powi(i as i32))
            .collect();
        let grams = self.grams(&alphas);
        let coarse: Vec<Candidate> = grams
            .par_iter()
            .zip(&alphas)
            .map(|(g, a)| Candidate::of(*a, g, best_shape(g).0))
            .collect();
        let best = (0..COARSE_ALPHAS)
            .min_by(|a, b| coarse[*a].misfit.total_cmp(&coarse[*b].misfit))
            .unwrap_or(0);
        let mut found = coarse[best];
        // Golden section on log α over the two grid steps around the best.
        let (mut lo, mut hi) = (
            alphas[best.saturating_sub(1)].ln(),
            alphas[(best + 1).min(COARSE_ALPHAS - 1)].ln(),
        );
        let phi = (5f64.sqrt() - 1.0) / 2.0;
        let mut x1 = hi - phi * (hi - lo);
        let mut x2 = lo + phi * (hi - lo);
        let mut f1 = self.at(x1.exp());
        let mut f2 = self.at(x2.exp());
        for _ in 0..GOLDEN_STEPS {
            if f1.misfit < f2.misfit {
                hi = x2;
                x2 = x1;
                f2 = f1;
                x1 = hi - phi * (hi - lo);
                f1 = self.at(x1.exp());
            } else {
                lo = x1;
                x1 = x2;
                f1 = f2;
                x2 = lo + phi * (hi - lo);
                f2 = self.at(x2.exp());
            }
        }
        for f in [f1, f2] {
            if f.misfit < found.misfit {
                found = f;
            }
        }
        Fitted {
            base_color: found.colour,
            metallic: found.shape.m,
            specular: found.shape.q,
            f0: found.f0,
            alpha: found.alpha,
            fit_error: (found.misfit / self.maps.len() as f64).sqrt(),
        }
    }
}

/// One roughness's best material and its squared misfit.
#[derive(Clone, Copy)]
struct Candidate {
    alpha: f64,
    shape: Shape,
    colour: [f64; 3],
    f0: [f64; 3],
    misfit: f64,
}

impl Candidate {
    fn of(alpha: f64, grams: &[Gram; 3], shape: Shape) -> Candidate {
        let (misfit, colour, f0) = cost(grams, shape);
        Candidate {
            alpha,
            shape,
            colour,
            f0,
            misfit,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_channel_recovers_a_known_colour_and_f0_from_its_gram() {
        // Terms as orthonormal images and a target made of them with c = 0.3 and F₀ = 0.04
        // under a dielectric (m = 0.2, q = 0.8, F = 0.05): the closed form returns both and a
        // zero misfit.
        let shape = Shape {
            m: 0.2,
            q: 0.8,
            f: 0.05,
        };
        let (a, p, b) = shape.weights();
        let target: Vec<f64> = (0..TERMS)
            .map(|i| 0.3 * a[i] + 0.04 * p[i] + b[i])
            .collect();
        let mut g = [[0.0; 5]; 5];
        for i in 0..TERMS {
            g[i][i] = 1.0;
            g[i][TARGET] = target[i];
            g[TARGET][i] = target[i];
        }
        g[TARGET][TARGET] = target.iter().map(|t| t * t).sum();
        let q = Quadratic::new(&g, &a, &p, &b);
        let (c, f0) = q.box_min(1.0, shape.f);
        assert!(
            (c - 0.3).abs() < 1e-9 && (f0 - 0.04).abs() < 1e-9,
            "{c} {f0}"
        );
        assert!(q.at(c, f0).abs() < 1e-15);
    }
}
