//! Fitting a renderer's material model to the whole estimate, by how it relights.
//!
//! The target is the estimate itself (analytic lobes and measured mix together), rendered on a
//! sphere under several maps; the fitted material is the one whose own BRDF, rendered the same
//! way, comes closest in relative RMSE, each map counting alike. Both formats brdfd writes
//! share one structure (glTF 2.0 appendix B with `KHR_materials_specular`,
//! `KHR_materials_ior` and `KHR_materials_clearcoat`; OpenPBR's base and coat), per colour
//! channel k:
//!
//! ```text
//! f_k = (1 − k_c·Fc)·base_k + k_c·Fc·S_c
//! base_k = (1 − m)·[(1 − q·F)·c_k/π + q·Fr_k·S]  +  m·(c_k + (1 − c_k)·w)·S
//! Fr_k = F₀_k + (1 − F₀_k)·w,   F = max over k of Fr_k,   w = (1 − cos θd)⁵,
//! Fc = 0.04 + 0.96·(1 − N·V)⁵,   S = D·V (GGX/Smith, roughness α), S_c the same at α_c
//! ```
//!
//! with base colour c, metalness m, specular weight q, the dielectric's F₀ per channel (the
//! largest from the IOR, the others through the specular colour), and a clear coat of weight
//! k_c and roughness α_c. The coat holds what one lobe cannot: a sharp varnish over a broad
//! metallic paint, or a haze around a mirror.
//!
//! Rendering is linear in the BRDF, so a render is a sum of nine images per pair of
//! roughnesses: Lambert `L`, Lambert·w `Lw`, `S(1 − w)` and `S·w`; the same four seen through
//! the coat's Fresnel; and the coat's lobe. Fc hangs on N·V, which a pixel fixes whatever the
//! light, so an image seen through it is the image times each pixel's Fc: only the lobes are
//! rendered, and the Gram matrix weighs their inner products by Fc and Fc². For fixed (α, α_c, m, q, largest F₀, k_c) the
//! render is linear in each channel's c_k and F₀_k, which are solved exactly on their box;
//! (m, q, largest F₀) are searched on a grid and refined, all through the 10 × 10 Gram matrix
//! of the nine images and the target (no image is formed in the search). The roughnesses are
//! searched on a log grid (every pair for a coat, its weight refined from the uncoated best)
//! under some of the maps ([`Coarse`]), then on finer grids with new renders under all.
//!
//! Not here: the formats' writers ([`super::gltf`], [`super::openpbr`]), and measuring the
//! result under maps the fit did not see ([`super::write_exports`]).

use rayon::prelude::*;

use brdfd_core::analytic::{coat_fresnel, columns, lambert_column, schlick_weight};
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
/// Finer grids of α after the coarse grid, each of this many points rendered in one pass
/// ([`finer`]).
const FINER_GRIDS: usize = 2;
const FINER_POINTS: usize = 6;
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
/// The coarse grid's pairs of roughnesses stop refining sooner: they only pick the pair the
/// finer grids start from.
const COARSE_LAST_STEP: f64 = 2e-3;
/// A coat's weight where its search starts, from the uncoated best at the base's roughness.
const COAT_START: f64 = 0.5;
/// A coat is kept only when it lowers the squared misfit by this share (its relative RMSE by
/// 1%): a coat that changes nothing visible is one more extension for a renderer to get wrong.
const COAT_GAIN: f64 = 0.02;

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
    /// The clear coat's weight in [0, 1] (glTF's `clearcoatFactor`; 0 is no coat).
    pub coat: f64,
    /// The coat's GGX α.
    pub coat_alpha: f64,
    /// The relative RMSE of the fit over the fit maps (each counting alike).
    pub fit_error: f64,
}

impl Fitted {
    /// The largest channel's dielectric F₀: the IOR's.
    pub fn f0_max(&self) -> f64 {
        self.f0.iter().copied().fold(0.0, f64::max)
    }

    /// The IOR whose normal-incidence reflectance is the largest F₀.
    pub fn ior(&self) -> f64 {
        ior_of_f0(self.f0_max().clamp(0.0, 0.99))
    }

    /// The specular colour, each channel's F₀ relative to the IOR's (the largest is 1).
    pub fn specular_color(&self) -> [f64; 3] {
        let top = self.f0_max();
        self.f0.map(|f| if top > 0.0 { f / top } else { 1.0 })
    }
}

/// The IOR η whose normal-incidence reflectance ((η − 1)/(η + 1))² is `f0` (below 1).
pub fn ior_of_f0(f0: f64) -> f64 {
    let r = f0.sqrt();
    (1.0 + r) / (1.0 - r)
}

/// The terms in the Gram matrix's order: the base's four (L, Lw, S0, S1), the same four seen
/// through the coat's Fresnel, the coat's lobe, then the target.
const TERMS: usize = 9;
const TARGET: usize = 9;
type Gram = [[f64; 10]; 10];

/// An image the Gram matrix is made of: the α-free ones (L, Lw, the target), the base lobe's
/// (S0, S1), or the coat's lobe (S), with the power of the coat's Fresnel it is seen through.
#[derive(Clone, Copy)]
enum Source {
    Fixed(usize),
    Base(usize),
    Coat,
}
const SOURCES: [(Source, usize); TERMS + 1] = [
    (Source::Fixed(0), 0),
    (Source::Fixed(1), 0),
    (Source::Base(0), 0),
    (Source::Base(1), 0),
    (Source::Fixed(0), 1),
    (Source::Fixed(1), 1),
    (Source::Base(0), 1),
    (Source::Base(1), 1),
    (Source::Coat, 1),
    (Source::Fixed(2), 0),
];

/// Weights of the terms in an image.
type Terms = [f64; TERMS];

/// The (m, q, F, k) part of the search; F bounds every channel's F₀ and is the largest of
/// them, k is the clear coat's weight.
#[derive(Clone, Copy, Debug)]
struct Shape {
    m: f64,
    q: f64,
    f: f64,
    k: f64,
}

impl Shape {
    /// The weights of the terms that multiply c (A), that multiply the channel's F₀ (P), and
    /// the rest (B). The diffuse's weight uses F, the largest F₀ (the ratified
    /// `KHR_materials_specular` takes the maximum over the channels there). Under a coat of
    /// weight k the base loses k·Fc of itself and the coat's lobe adds k·Fc·S.
    fn weights(self) -> (Terms, Terms, Terms) {
        let Shape { m, q, f, k } = self;
        let d = 1.0 - m;
        let coated = |base: [f64; 4], coat: f64| -> Terms {
            let mut t = [0.0; TERMS];
            for i in 0..4 {
                t[i] = base[i];
                t[4 + i] = -k * base[i];
            }
            t[8] = coat;
            t
        };
        (
            coated([d * (1.0 - q * f), -d * q * (1.0 - f), m, 0.0], 0.0),
            coated([0.0, 0.0, d * q, 0.0], 0.0),
            coated([0.0, 0.0, 0.0, d * q + m], k),
        )
    }

    fn clamped(self) -> Shape {
        Shape {
            m: self.m.clamp(0.0, 1.0),
            q: self.q.clamp(0.0, 1.0),
            f: self.f.clamp(0.0, 0.99),
            k: self.k.clamp(0.0, 1.0),
        }
    }
}

fn quad(g: &Gram, a: &Terms, b: &Terms) -> f64 {
    (0..TERMS)
        .filter(|i| a[*i] != 0.0)
        .map(|i| a[i] * (0..TERMS).map(|j| g[i][j] * b[j]).sum::<f64>())
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

/// The best shape without a coat: the grid of (m, q, F), then a pattern search from its best
/// point.
fn best_shape(grams: &[Gram; 3]) -> (Shape, f64) {
    let steps = (0..=UNIT_STEPS).map(|i| i as f64 / UNIT_STEPS as f64);
    let mut best = (
        Shape {
            m: 0.0,
            q: 0.0,
            f: 0.0,
            k: 0.0,
        },
        f64::INFINITY,
    );
    for m in steps.clone() {
        for q in steps.clone() {
            for f in F0_GRID {
                let s = Shape { m, q, f, k: 0.0 };
                let (e, ..) = cost(grams, s);
                if e < best.1 {
                    best = (s, e);
                }
            }
        }
    }
    refine(grams, best.0, false, REFINE_LAST_STEP)
}

/// A pattern search over (m, q, F), and the coat's weight when `coat`, from `start`, until
/// its step is below `last_step`.
fn refine(grams: &[Gram; 3], start: Shape, coat: bool, last_step: f64) -> (Shape, f64) {
    let mut best = (start, cost(grams, start).0);
    let axes: &[[f64; 4]] = &[
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0, 0.0],
        // F₀ moves on a finer scale: it lives near 0.04.
        [0.0, 0.0, 0.2, 0.0],
        [0.0, 0.0, 0.0, 1.0],
    ];
    let axes = if coat { axes } else { &axes[..3] };
    let mut step = REFINE_FIRST_STEP;
    while step >= last_step {
        let mut moved = false;
        for axis in axes {
            for sign in [1.0, -1.0] {
                let s = best.0;
                let d = axis.map(|a| a * sign * step);
                let t = Shape {
                    m: s.m + d[0],
                    q: s.q + d[1],
                    f: s.f + d[2],
                    k: s.k + d[3],
                }
                .clamped();
                let (e, ..) = cost(grams, t);
                if e < best.1 {
                    best = (t, e);
                    moved = true;
                }
            }
        }
        if !moved {
            step /= 2.0;
        }
    }
    best
}

/// Per-channel inner products of two images (rows of 3 channels per pixel), weighted by the
/// coat's Fresnel of each row's pixel to the powers 0, 1 and 2.
fn dots(a: &[f64], b: &[f64], fresnel: &[f64]) -> Dots {
    let mut s = [[0.0; 3]; 3];
    for ((x, y), f) in a
        .chunks_exact(3)
        .zip(b.chunks_exact(3))
        .zip(fresnel.iter().cycle())
    {
        for c in 0..3 {
            let v = x[c] * y[c];
            s[0][c] += v;
            s[1][c] += v * f;
            s[2][c] += v * f * f;
        }
    }
    s
}

/// Inner products per power of the coat's Fresnel (0, 1, 2), then per channel.
type Dots = [[f64; 3]; 3];

/// One roughness's lobe images under each of its scenes' maps (the coarse search's five, or
/// all the fit's), S0, S1 and their sum S (the lobe as a coat), with their inner products
/// with the α-free images and with each other.
struct Lobe {
    alpha: f64,
    images: [Vec<f64>; 3],
    with_fixed: [[Dots; 3]; 3],
    own: [[Dots; 3]; 3],
}

/// The images a fit compares: the target and the α-free terms (L, Lw), each map's rows scaled
/// so that the target has unit norm there, every map's rows one after another.
///
/// glTF's coat hangs on N·V, which a pixel fixes whatever the light: the render of a term seen
/// through the coat's Fresnel is the term's render times the pixel's Fresnel, exactly. So no
/// image is rendered for the coat; the Gram matrix weighs the inner products by the Fresnel.
pub struct Scenes<'a> {
    pixels: &'a [GeomPixel],
    maps: Vec<&'a LightSet>,
    grid: Grid,
    /// L, Lw and the target.
    fixed: [Vec<f64>; 3],
    fixed_dots: [[Dots; 3]; 3],
    /// The coat's Fresnel at each pixel's N·V.
    fresnel: Vec<f64>,
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
        let mut fixed: [Vec<f64>; 3] = Default::default();
        let mut scale = Vec::with_capacity(maps.len());
        let maps: Vec<&LightSet> = maps.iter().collect();
        for a in RenderingMatrix::build_under(pixels, &maps, &cols, None, grid.theta_h_binning) {
            let rows = pixels.len() * 3;
            let norm = (0..rows)
                .map(|r| (a.row(r)[2] as f64).powi(2))
                .sum::<f64>()
                .sqrt();
            if !(norm.is_finite() && norm > 0.0) {
                return Err(CoreError::Invalid(
                    "the estimate renders black (or not a number) under a reference map: \
                     there is nothing for an export to match"
                        .into(),
                ));
            }
            let s = 1.0 / norm;
            for (j, image) in fixed.iter_mut().enumerate() {
                image.extend((0..rows).map(|r| a.row(r)[j] as f64 * s));
            }
            scale.push(s);
        }
        let fresnel: Vec<f64> = pixels.iter().map(coat_fresnel_at).collect();
        let fixed_dots =
            std::array::from_fn(|i| std::array::from_fn(|j| dots(&fixed[i], &fixed[j], &fresnel)));
        Ok(Scenes {
            pixels,
            maps,
            grid,
            fixed,
            fixed_dots,
            fresnel,
            scale,
        })
    }

    /// The same scenes under `maps` alone (indices into this one's maps, ascending): their
    /// rows of the images, already rendered, and the inner products over them.
    fn only(&self, maps: &[usize]) -> Scenes<'a> {
        let rows = self.pixels.len() * 3;
        let fixed: [Vec<f64>; 3] = std::array::from_fn(|j| {
            maps.iter()
                .flat_map(|m| &self.fixed[j][m * rows..(m + 1) * rows])
                .copied()
                .collect()
        });
        let fixed_dots = std::array::from_fn(|i| {
            std::array::from_fn(|j| dots(&fixed[i], &fixed[j], &self.fresnel))
        });
        Scenes {
            pixels: self.pixels,
            maps: maps.iter().map(|m| self.maps[*m]).collect(),
            grid: self.grid,
            fixed,
            fixed_dots,
            fresnel: self.fresnel.clone(),
            scale: maps.iter().map(|m| self.scale[*m]).collect(),
        }
    }

    /// The lobe images at each of `alphas`.
    fn lobes(&self, alphas: &[f64]) -> Vec<Lobe> {
        self.lobes_from(
            alphas,
            &render_lobes(self.pixels, &self.maps, self.grid, alphas),
        )
    }

    /// The lobes of `alphas` from their unscaled images ([`render_lobes`]).
    fn lobes_from(&self, alphas: &[f64], raw: &[[Vec<f64>; 2]]) -> Vec<Lobe> {
        let rows = self.pixels.len() * 3;
        let images: Vec<[Vec<f64>; 3]> = raw
            .iter()
            .map(|[s0, s1]| {
                let scaled = |x: &[f64]| -> Vec<f64> {
                    x.iter()
                        .enumerate()
                        .map(|(r, v)| v * self.scale[r / rows])
                        .collect()
                };
                let (s0, s1) = (scaled(s0), scaled(s1));
                let sum = s0.iter().zip(&s1).map(|(a, b)| a + b).collect();
                [s0, s1, sum]
            })
            .collect();
        alphas
            .par_iter()
            .zip(images)
            .map(|(alpha, images)| {
                let d = |x: &[f64], y: &[f64]| dots(x, y, &self.fresnel);
                Lobe {
                    alpha: *alpha,
                    with_fixed: std::array::from_fn(|i| {
                        std::array::from_fn(|j| d(&images[i], &self.fixed[j]))
                    }),
                    own: std::array::from_fn(|i| {
                        std::array::from_fn(|j| d(&images[i], &images[j]))
                    }),
                    images,
                }
            })
            .collect()
    }

    /// The per-channel Gram matrices of the terms and the target with `base` as the base's
    /// lobe and `coat` as the coat's.
    fn gram(&self, base: &Lobe, coat: &Lobe) -> [Gram; 3] {
        let same = std::ptr::eq(base, coat);
        let cross: [Dots; 2] = std::array::from_fn(|i| {
            if same {
                base.own[i][2]
            } else {
                dots(&base.images[i], &coat.images[2], &self.fresnel)
            }
        });
        let dot = |x: Source, y: Source| -> Dots {
            use Source::*;
            match (x, y) {
                (Fixed(i), Fixed(j)) => self.fixed_dots[i][j],
                (Fixed(j), Base(i)) | (Base(i), Fixed(j)) => base.with_fixed[i][j],
                (Base(i), Base(j)) => base.own[i][j],
                (Fixed(j), Coat) | (Coat, Fixed(j)) => coat.with_fixed[2][j],
                (Base(i), Coat) | (Coat, Base(i)) => cross[i],
                (Coat, Coat) => coat.own[2][2],
            }
        };
        let mut out = [[[0.0; TERMS + 1]; TERMS + 1]; 3];
        for (x, (sx, px)) in SOURCES.iter().enumerate() {
            for (y, (sy, py)) in SOURCES.iter().enumerate().skip(x) {
                let d = dot(*sx, *sy)[px + py];
                for c in 0..3 {
                    out[c][x][y] = d[c];
                    out[c][y][x] = d[c];
                }
            }
        }
        out
    }

    /// The best material without a coat at the base's roughness.
    fn plain(&self, base: &Lobe) -> Candidate {
        let grams = self.gram(base, base);
        Candidate::of(base.alpha, 0.0, &grams, best_shape(&grams).0)
    }

    /// The best coated material from `start` with these lobes.
    fn coated(&self, base: &Lobe, coat: &Lobe, start: Shape, last_step: f64) -> Candidate {
        let grams = self.gram(base, coat);
        let (shape, _) = refine(&grams, start, true, last_step);
        Candidate::of(base.alpha, coat.alpha, &grams, shape)
    }

    /// Fits the shared model to the target: every coarse roughness without a coat, and every
    /// pair of them with one, under the coarse search's maps ([`Coarse`]); then finer grids
    /// about the best's roughnesses under every map.
    pub fn fit(&self, coarse: &Coarse) -> Fitted {
        // Renders of other scenes (another grid, say) are no use: the grid is rendered
        // again, under every map, rather than the capture failing on it.
        let rendered;
        let coarse = if coarse.is_for(self) {
            coarse
        } else {
            rendered = Coarse::under(
                self.pixels,
                &self.maps,
                (0..self.maps.len()).collect(),
                self.grid,
            );
            &rendered
        };
        let alphas = coarse_alphas();
        let searched = self.only(&coarse.maps);
        let lobes = searched.lobes_from(&alphas, &coarse.images);
        let plain: Vec<Candidate> = lobes.par_iter().map(|l| searched.plain(l)).collect();
        let pairs: Vec<(usize, usize)> = (0..COARSE_ALPHAS)
            .flat_map(|b| (0..COARSE_ALPHAS).map(move |c| (b, c)))
            .collect();
        let coated: Vec<Candidate> = pairs
            .par_iter()
            .map(|&(b, c)| {
                let start = Shape {
                    k: COAT_START,
                    ..plain[b].shape
                };
                searched.coated(&lobes[b], &lobes[c], start, COARSE_LAST_STEP)
            })
            .collect();
        let best = |c: &[Candidate]| {
            (0..c.len())
                .min_by(|a, b| c[*a].misfit.total_cmp(&c[*b].misfit))
                .unwrap_or(0)
        };
        let (best_plain, best_coated) = (best(&plain), best(&coated));
        let bracket = |i: usize| {
            (
                alphas[i.saturating_sub(1)],
                alphas[(i + 1).min(COARSE_ALPHAS - 1)],
            )
        };
        let plain_found = finer(
            bracket(best_plain),
            alphas[best_plain],
            |c| c.alpha,
            |alphas| {
                self.lobes(alphas)
                    .par_iter()
                    .map(|l| self.plain(l))
                    .collect()
            },
        );
        let found = if coated[best_coated].misfit < plain[best_plain].misfit * (1.0 - COAT_GAIN) {
            let (b, c) = pairs[best_coated];
            let start = coated[best_coated].shape;
            let coat = self.lobes(&[alphas[c]]).remove(0);
            let found = finer(
                bracket(b),
                alphas[b],
                |c| c.alpha,
                |alphas| {
                    let lobes = self.lobes(alphas);
                    lobes
                        .par_iter()
                        .map(|l| self.coated(l, &coat, start, REFINE_LAST_STEP))
                        .collect()
                },
            );
            let base = self.lobes(&[found.alpha]).remove(0);
            let found = finer(
                bracket(c),
                found.coat_alpha,
                |c| c.coat_alpha,
                |alphas| {
                    let lobes = self.lobes(alphas);
                    lobes
                        .par_iter()
                        .map(|l| self.coated(&base, l, found.shape, REFINE_LAST_STEP))
                        .collect()
                },
            );
            // The finer grids may have found a coat that no longer pays for itself.
            if found.misfit < plain_found.misfit * (1.0 - COAT_GAIN) {
                found
            } else {
                plain_found
            }
        } else {
            plain_found
        };
        Fitted {
            base_color: found.colour,
            metallic: found.shape.m,
            specular: found.shape.q,
            f0: found.f0,
            alpha: found.alpha,
            coat: found.shape.k,
            coat_alpha: found.coat_alpha,
            fit_error: (found.misfit / self.maps.len() as f64).sqrt(),
        }
    }
}

/// The coarse grid of roughnesses: log-spaced from [`ALPHA_MIN`] to [`ALPHA_MAX`].
fn coarse_alphas() -> Vec<f64> {
    let ratio = (ALPHA_MAX / ALPHA_MIN).powf(1.0 / (COARSE_ALPHAS - 1) as f64);
    (0..COARSE_ALPHAS)
        .map(|i| ALPHA_MIN * ratio.powi(i as i32))
        .collect()
}

/// Each of `alphas`' lobe images, S(1 − w) and S·w, unscaled, under every one of `maps` in
/// turn: renders of the formats' own lobe alone, the same whatever the estimate.
fn render_lobes(
    pixels: &[GeomPixel],
    maps: &[&LightSet],
    grid: Grid,
    alphas: &[f64],
) -> Vec<[Vec<f64>; 2]> {
    let cols: Vec<[Vec<f64>; 3]> = alphas.par_iter().map(|a| columns(grid, *a)).collect();
    let rows = pixels.len() * 3;
    let mut images: Vec<[Vec<f64>; 2]> = (0..alphas.len())
        .map(|_| std::array::from_fn(|_| Vec::with_capacity(rows * maps.len())))
        .collect();
    let per_pass = PASS_COLUMNS / 2;
    // A chunk's lobes under every map, map after map: each lobe's images stay in the maps'
    // order, and the maps' turns share the chunk's table.
    for (p, chunk) in cols.chunks(per_pass).enumerate() {
        let refs: Vec<&[f64]> = chunk.iter().flat_map(|c| [&c[1][..], &c[2][..]]).collect();
        for a in RenderingMatrix::build_under(pixels, maps, &refs, None, grid.theta_h_binning) {
            for (i, lobe) in images[p * per_pass..p * per_pass + chunk.len()]
                .iter_mut()
                .enumerate()
            {
                for r in 0..rows {
                    let row = a.row(r);
                    lobe[0].push(row[2 * i] as f64);
                    lobe[1].push(row[2 * i + 1] as f64);
                }
            }
        }
    }
    images
}

/// The coarse grid's lobe images for a fit's sphere and grid, under some of its maps: the
/// fit's largest render, and one that needs no estimate. A capture renders it while the camera
/// shoots. The coarse grid only brackets the roughnesses, and the finer grids then see every
/// map: rendered under all thirteen of a capture's fit maps, it took as much of the cores as
/// the capture's estimate, and under five of them (each map's first turn and the capture's)
/// the MERL test materials' exports relit as closely (with 256 lights a map, glTF median
/// 0.108 and `.mtlx` 0.102 against 0.108 and 0.098 under all thirteen).
pub struct Coarse {
    pixels: usize,
    /// Which of the fit's maps it is rendered under, ascending, and how many the fit has.
    maps: Vec<usize>,
    of: usize,
    grid: Grid,
    images: Vec<[Vec<f64>; 2]>,
}

impl Coarse {
    /// The coarse grid on `pixels` under those of `maps` that `searched` names.
    pub fn render(
        pixels: &[GeomPixel],
        maps: &[LightSet],
        searched: Vec<usize>,
        grid: Grid,
    ) -> Coarse {
        Coarse::under(pixels, &maps.iter().collect::<Vec<_>>(), searched, grid)
    }

    fn under(pixels: &[GeomPixel], maps: &[&LightSet], searched: Vec<usize>, grid: Grid) -> Coarse {
        let lit: Vec<&LightSet> = searched.iter().map(|m| maps[*m]).collect();
        Coarse {
            pixels: pixels.len(),
            of: maps.len(),
            grid,
            images: render_lobes(pixels, &lit, grid, &coarse_alphas()),
            maps: searched,
        }
    }

    /// Whether these are renders of `scenes`: the same grid and as many pixels and maps (the
    /// caller keeps the sphere and the maps themselves the same).
    fn is_for(&self, scenes: &Scenes) -> bool {
        self.grid == scenes.grid
            && self.pixels == scenes.pixels.len()
            && self.of == scenes.maps.len()
    }
}

/// The best of finer grids of one roughness within `bracket`: each grid's points, evenly
/// spaced in log α and rendered in one pass by `at`, then a grid between the best point's
/// neighbours. The first grid holds the coarse grid's best, `centre`, too: the coarse
/// search saw fewer maps, so its candidate is measured again beside the others. Two grids
/// of [`FINER_POINTS`] place α within 1.3% of the best. `of` reads the roughness searched
/// from a candidate.
fn finer(
    bracket: (f64, f64),
    centre: f64,
    of: fn(&Candidate) -> f64,
    at: impl Fn(&[f64]) -> Vec<Candidate>,
) -> Candidate {
    let bounds = (bracket.0.ln(), bracket.1.ln());
    let (mut lo, mut hi) = bounds;
    let mut found: Option<Candidate> = None;
    for grid in 0..FINER_GRIDS {
        let step = (hi - lo) / (FINER_POINTS + 1) as f64;
        let mut alphas: Vec<f64> = (1..=FINER_POINTS)
            .map(|i| (lo + step * i as f64).exp())
            .collect();
        if grid == 0 {
            alphas.push(centre);
        }
        for c in at(&alphas) {
            if found.is_none_or(|f| c.misfit < f.misfit) {
                found = Some(c);
            }
        }
        let best = of(&found.expect("a grid has points")).ln();
        (lo, hi) = ((best - step).max(bounds.0), (best + step).min(bounds.1));
    }
    found.expect("a grid has points")
}

/// The coat's Fresnel at a pixel: at its N·V.
pub fn coat_fresnel_at(px: &GeomPixel) -> f64 {
    coat_fresnel(view_cosine(px))
}

/// N·V at a pixel, in [0, 1]: what the formats' factors of the view hang on.
pub fn view_cosine(px: &GeomPixel) -> f64 {
    let d: f32 = (0..3).map(|k| px.normal[k] * px.view[k]).sum();
    f64::from(d).clamp(0.0, 1.0)
}

/// One material's roughnesses, shape, colours and squared misfit.
#[derive(Clone, Copy)]
struct Candidate {
    alpha: f64,
    coat_alpha: f64,
    shape: Shape,
    colour: [f64; 3],
    f0: [f64; 3],
    misfit: f64,
}

impl Candidate {
    fn of(alpha: f64, coat_alpha: f64, grams: &[Gram; 3], shape: Shape) -> Candidate {
        let (misfit, colour, f0) = cost(grams, shape);
        Candidate {
            alpha,
            coat_alpha,
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

    /// The scenes under some of their maps are the scenes made under those maps alone: the
    /// same images, scales and inner products, so the coarse search's misfits are those.
    #[test]
    fn scenes_under_some_of_their_maps_are_those_maps_own() {
        let sphere = crate::export::sphere(16).unwrap();
        let maps: Vec<LightSet> = crate::export::maps::reference_maps()
            .unwrap()
            .iter()
            .flat_map(|(_, m)| [m.compressed(32, 0.0), m.compressed(32, 1.0)])
            .collect();
        let target = brdfd_core::analytic::Microfacet::one_lobe(
            [0.2, 0.1, 0.05],
            [0.9, 0.6, 0.3],
            [1.0; 3],
            0.1,
        )
        .bivariate(Grid::default());
        let all = Scenes::new(&sphere.pixels, &maps, &target).unwrap();
        let picked = [1, 4, 6];
        let alone: Vec<LightSet> = picked.iter().map(|m| maps[*m].clone()).collect();
        let own = Scenes::new(&sphere.pixels, &alone, &target).unwrap();
        let only = all.only(&picked);
        assert_eq!(only.scale, own.scale);
        assert_eq!(only.fixed, own.fixed);
        assert_eq!(only.fixed_dots, own.fixed_dots);
        assert_eq!(only.maps.len(), 3);
    }

    #[test]
    fn a_channel_recovers_a_known_colour_and_f0_from_its_gram() {
        // Terms as orthonormal images and a target made of them with c = 0.3 and F₀ = 0.04
        // under a coated dielectric (m = 0.2, q = 0.8, F = 0.05, coat 0.3): the closed form
        // returns both and a zero misfit.
        let shape = Shape {
            m: 0.2,
            q: 0.8,
            f: 0.05,
            k: 0.3,
        };
        let (a, p, b) = shape.weights();
        let target: Vec<f64> = (0..TERMS)
            .map(|i| 0.3 * a[i] + 0.04 * p[i] + b[i])
            .collect();
        let mut g = [[0.0; TERMS + 1]; TERMS + 1];
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
