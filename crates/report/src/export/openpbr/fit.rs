//! OpenPBR's own parameters fitted to the estimate's renders: its metalness, and each
//! channel's base colour and specular colour.
//!
//! A glTF fit does not read part for part into OpenPBR where their BRDFs differ most:
//!
//! - glTF's specular weight q holds a dielectric's Fresnel to q·(F₀ + (1 − F₀)·w), dim at
//!   grazing too, where OpenPBR's dielectric rises to 1 whatever its IOR. OpenPBR dims it by
//!   `specular_color`, which multiplies it (and leaves the diffuse's albedo scaling to the
//!   untinted dielectric);
//! - OpenPBR compensates its lobes for multiple scattering, which brightens a rough metal, and
//!   reads `specular_color` as the metal's F82 tint as well.
//!
//! With the roughness, the IOR and the coat set, OpenPBR's image is a sum of eleven images
//! whose weights are polynomials in the metalness M and each channel's base colour c and
//! specular colour T (`specular_weight` 1):
//!
//! ```text
//! base = (1 − M)·[T·(F·S + κ·F²·S) + c·(1 − E_spec)/π] + M·(F82·S + κ·F82²·S)
//! F82 = c·(1 − w) + w − β·g,   β = (1 − T)·(c·(1 − w̄) + w̄)/ḡ
//! ```
//!
//! with κ = (1 − E₁)/E₁ of the compensation, w = (1 − μ)⁵, g = μ(1 − μ)⁶ and w̄, ḡ their values
//! at μ̄ = 1/7 ([`super::OpenPbrBrdf`]): the dielectric's lobe, the diffuse, the metal's three
//! terms and its six products, each seen through the coat, then the coat itself. OpenPBR's BRDF
//! clamps F82 at 0, which a tint below about a half reaches at middle angles on a dark metal;
//! the search keeps to the colours whose F82 stays above 0 at every θd of the grid, where the
//! sum is the BRDF's tables exactly. So a candidate's misfit is a quadratic form in those
//! weights over the Gram matrix of the eleven images and the target, formed once: no image is
//! rendered in the search. M is searched on a grid refined about its best, and for each M every
//! channel's (c, T) on a grid of [0, 1]² refined the same way, at each of five IORs around the
//! glTF fit's (its F₀ times 0.5 to 2), keeping the glTF fit's roughness and coat (OpenPBR's
//! lobe is glTF's GGX/Smith, and its roughness under the coat is set to the fit's).

use brdfd_core::bivariate::{Bivariate, Grid};
use brdfd_core::geometry::PixelGeometry;
use brdfd_core::raster::Raster;

use super::{f82_b, fresnel_dielectric, Lobe, Lobes, OpenPbrBrdf, OpenPbrMaterial, MAX_F0};
use crate::export::fit::{ior_of_f0, view_cosine, Fitted};

/// The normal-incidence reflectances tried, as multiples of the glTF fit's (at full weight):
/// OpenPBR's exact Fresnel and its albedo-scaled diffuse move the best IOR a little from
/// glTF's Schlick and weighted one.
const F0_STEPS: [f64; IORS] = [0.5, 0.71, 1.0, 1.41, 2.0];
const IORS: usize = 5;
/// Below this F₀ (an IOR of 1.2) a dielectric's highlight is too faint to tell IORs apart.
const MIN_F0: f64 = 0.01;

/// The weighted images, in this order: the dielectric's lobe, the diffuse, the metal's
/// F82 terms (1 − w, w, g) and their products ((1 − w)², w², g², (1 − w)w, (1 − w)g, wg).
const TERMS: usize = 11;
/// The tables shared by every IOR: the diffuse, the metal's nine, the coat's two.
const SHARED: usize = 12;
/// The search's grids: steps on [0, 1] of the coarse grid, then the points either side of
/// the best at each finer level (each a `REFINE`th of the step before), and how many levels.
const COARSE_STEPS: usize = 10;
const COLOUR_COARSE_STEPS: usize = 25;
const REFINE: usize = 8;
const LEVELS: usize = 3;

/// OpenPBR's base at each IOR tried, as the tables its images are rendered from.
pub struct OpenPbrFit {
    /// The material each IOR's fit starts from: metalness 0, colours white, the glTF fit's
    /// roughness and coat.
    grey: Vec<OpenPbrMaterial>,
    /// Its BRDF, for the factors of the view.
    brdfs: Vec<OpenPbrBrdf>,
    /// The shared tables ([`SHARED`]; without a coat its two are left out), then each IOR's
    /// dielectric lobe through F and through F².
    tables: Vec<Bivariate>,
    coated: bool,
}

impl OpenPbrFit {
    /// The fit for the glTF fit `f`: its roughness and coat, at IORs around its dielectric's.
    pub fn new(f: &Fitted, grid: Grid) -> OpenPbrFit {
        use rayon::prelude::*;
        // Kept where every step stays between the least and the largest F₀, so that the
        // IORs differ.
        let start = f
            .f0_max()
            .clamp(MIN_F0 / F0_STEPS[0], MAX_F0 / F0_STEPS[IORS - 1]);
        let grey: Vec<OpenPbrMaterial> = F0_STEPS
            .iter()
            .map(|s| {
                OpenPbrMaterial {
                    base_color: [1.0; 3],
                    base_metalness: 0.0,
                    specular_weight: 1.0,
                    specular_color: [1.0; 3],
                    specular_roughness: 0.0,
                    specular_ior: ior_of_f0((s * start).clamp(MIN_F0, MAX_F0)),
                    coat_weight: f.coat,
                    coat_roughness: f.coat_alpha.sqrt().clamp(0.0, 1.0),
                    specular_roughness_anisotropy: 0.0,
                }
                .with_base_roughness(f.alpha.sqrt())
                .with_base_ior_under_coat()
            })
            .collect();
        let brdfs: Vec<OpenPbrBrdf> = grey.par_iter().map(OpenPbrBrdf::new).collect();
        // Every IOR has the same roughness and coat: the first's lobes serve all.
        let first = &brdfs[0];
        let lobes = Lobes::reduce(
            first.alpha,
            (f.coat > 0.0).then_some(first.coat_alpha),
            grid,
        );
        let mut kinds = [Lobe::Base; SHARED + 2 * IORS];
        (kinds[0], kinds[10], kinds[11]) = (Lobe::One, Lobe::Coat, Lobe::Coat);
        let all = lobes.scaled(
            |mu| {
                let (w, g) = (
                    (1.0 - mu).clamp(0.0, 1.0).powi(5),
                    mu * (1.0 - mu).clamp(0.0, 1.0).powi(6),
                );
                let metal = [1.0 - w, w, g];
                let f_c = fresnel_dielectric(mu, super::COAT_IOR);
                let mut v = [0.0; SHARED + 2 * IORS];
                v[0] = 1.0 / std::f64::consts::PI;
                for (i, (a, b)) in PRODUCTS.iter().enumerate() {
                    v[1 + i] = metal[*a] * b.map_or(1.0, |b| metal[b]);
                }
                (v[10], v[11]) = (f.coat * f_c, f.coat * f_c * f_c);
                for (j, brdf) in brdfs.iter().enumerate() {
                    let f_d = fresnel_dielectric(mu, brdf.eta);
                    (v[SHARED + 2 * j], v[SHARED + 2 * j + 1]) = (f_d, f_d * f_d);
                }
                v.map(|x| [x; 3])
            },
            kinds,
        );
        let coated = f.coat > 0.0;
        let tables = all
            .into_iter()
            .enumerate()
            .filter(|(i, _)| coated || !(10..SHARED).contains(i))
            .map(|(_, t)| t)
            .collect();
        OpenPbrFit {
            grey,
            brdfs,
            tables,
            coated,
        }
    }

    /// The tables to render, in one pass with others.
    pub fn parts(&self) -> impl Iterator<Item = &Bivariate> {
        self.tables.iter()
    }

    /// The fit from the renders of [`OpenPbrFit::parts`] under each map (`renders[m]`, in
    /// their order) and the target's (`targets[m]`) on `geometry`: the closest material and
    /// its mean relative RMSE over the maps.
    pub fn solve(
        &self,
        geometry: &PixelGeometry,
        renders: &[Vec<Raster>],
        targets: &[Raster],
    ) -> (OpenPbrMaterial, f64) {
        use rayon::prelude::*;
        (0..self.grey.len())
            .into_par_iter()
            .map(|j| {
                let images: Vec<Images> = renders
                    .iter()
                    .map(|r| self.images(geometry, r, j))
                    .collect();
                let grams: [Gram; 3] = std::array::from_fn(|k| Gram::of(&images, targets, k));
                let (metalness, colours) = search(&grams);
                let m = OpenPbrMaterial {
                    base_color: colours.map(|c| c.0),
                    specular_color: colours.map(|c| c.1),
                    base_metalness: metalness,
                    ..self.grey[j]
                };
                let error = images
                    .iter()
                    .zip(targets)
                    .map(|(im, t)| im.image(metalness, &colours).relative_rmse(t))
                    .sum::<f64>()
                    / targets.len() as f64;
                (m, error)
            })
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .expect("an IOR")
    }

    /// IOR `j`'s eleven images and the coat's, from the parts' renders under one map.
    fn images(&self, geometry: &PixelGeometry, parts: &[Raster], j: usize) -> Images {
        let shared = if self.coated { SHARED } else { SHARED - 2 };
        let (d1, d2) = (&parts[shared + 2 * j], &parts[shared + 2 * j + 1]);
        let mut terms: [Raster; TERMS] =
            std::array::from_fn(|_| Raster::black(geometry.width, geometry.height));
        let mut coat = Raster::black(geometry.width, geometry.height);
        for px in &geometry.pixels {
            let i = px.y as usize * geometry.width + px.x as usize;
            let f = self.brdfs[j].factors(view_cosine(px));
            let at = |r: &Raster| r.pixels[i].map(f64::from);
            let (d1, d2, diffuse) = (at(d1), at(d2), at(&parts[0]));
            let metal: [[f64; 3]; 9] = std::array::from_fn(|t| at(&parts[1 + t]));
            for k in 0..3 {
                let through = f.coat_through;
                terms[0].pixels[i][k] = (through * (d1[k] + f.compensation * d2[k])) as f32;
                terms[1].pixels[i][k] = (through * f.diffuse * diffuse[k]) as f32;
                for (t, m) in metal.iter().enumerate() {
                    // The products are F82², which the compensation multiplies.
                    let comp = if t < 3 { 1.0 } else { f.compensation };
                    terms[2 + t].pixels[i][k] = (through * comp * m[k]) as f32;
                }
                if self.coated {
                    coat.pixels[i][k] =
                        (at(&parts[10])[k] + f.coat_compensation * at(&parts[11])[k]) as f32;
                }
            }
        }
        Images { terms, coat }
    }
}

/// The metal's tables: F82's three terms, then their products (pairs of terms).
const PRODUCTS: [(usize, Option<usize>); 9] = [
    (0, None),
    (1, None),
    (2, None),
    (0, Some(0)),
    (1, Some(1)),
    (2, Some(2)),
    (0, Some(1)),
    (0, Some(2)),
    (1, Some(2)),
];

/// One map's images of one IOR's material.
struct Images {
    terms: [Raster; TERMS],
    coat: Raster,
}

impl Images {
    /// The material's image for metalness `m` and each channel's (c, T).
    fn image(&self, m: f64, colours: &[(f64, f64); 3]) -> Raster {
        let weights: [[f64; TERMS]; 3] =
            std::array::from_fn(|k| weights(m, colours[k].0, colours[k].1));
        let mut out = self.coat.clone();
        for (i, p) in out.pixels.iter_mut().enumerate() {
            for k in 0..3 {
                let sum: f64 = (0..TERMS)
                    .map(|t| weights[k][t] * f64::from(self.terms[t].pixels[i][k]))
                    .sum();
                p[k] += sum as f32;
            }
        }
        out
    }
}

/// The images' weights for metalness `m`, base colour `c` and specular colour `t` (one
/// channel): F82 = c·(1 − w) + w − β·g, and its square through the products.
fn weights(m: f64, c: f64, t: f64) -> [f64; TERMS] {
    let x = [c, 1.0, -f82_b(c, t)];
    let mut e = [0.0; TERMS];
    e[0] = (1.0 - m) * t;
    e[1] = (1.0 - m) * c;
    for (i, (a, b)) in PRODUCTS.iter().enumerate() {
        e[2 + i] = m * match b {
            None => x[*a],
            Some(b) if b == a => x[*a] * x[*a],
            Some(b) => 2.0 * x[*a] * x[*b],
        };
    }
    e
}

/// One channel's Gram matrix of the eleven images and the target less the coat, each map
/// weighed by its target's squared norm, so that each counts alike (the sum of the maps'
/// squared relative RMSEs, where the error reported is their mean): the misfit of weights e
/// is e·G·e − 2·e·b + (a constant).
struct Gram {
    g: [[f64; TERMS]; TERMS],
    b: [f64; TERMS],
}

impl Gram {
    fn of(images: &[Images], targets: &[Raster], k: usize) -> Gram {
        let mut gram = Gram {
            g: [[0.0; TERMS]; TERMS],
            b: [0.0; TERMS],
        };
        for (im, t) in images.iter().zip(targets) {
            let norm: f64 = t
                .pixels
                .iter()
                .flat_map(|p| p.iter().map(|v| f64::from(*v).powi(2)))
                .sum();
            let w = 1.0 / norm.max(f64::MIN_POSITIVE);
            for i in 0..t.pixels.len() {
                let v: [f64; TERMS] = std::array::from_fn(|a| f64::from(im.terms[a].pixels[i][k]));
                let y = f64::from(t.pixels[i][k]) - f64::from(im.coat.pixels[i][k]);
                for a in 0..TERMS {
                    gram.b[a] += w * v[a] * y;
                    for b in a..TERMS {
                        gram.g[a][b] += w * v[a] * v[b];
                    }
                }
            }
        }
        for a in 0..TERMS {
            for b in 0..a {
                gram.g[a][b] = gram.g[b][a];
            }
        }
        gram
    }

    fn misfit(&self, e: &[f64; TERMS]) -> f64 {
        let mut sum = 0.0;
        for a in 0..TERMS {
            let row: f64 = (0..TERMS).map(|b| self.g[a][b] * e[b]).sum();
            sum += e[a] * (row - 2.0 * self.b[a]);
        }
        sum
    }
}

/// The metalness and each channel's (c, T) of least misfit: the metalness on a grid refined
/// about its best, each channel's colours likewise for each metalness tried.
fn search(grams: &[Gram; 3]) -> (f64, [(f64, f64); 3]) {
    let at = |m: f64| {
        let colours: [((f64, f64), f64); 3] = std::array::from_fn(|k| colours(&grams[k], m));
        (
            colours.iter().map(|c| c.1).sum::<f64>(),
            colours.map(|c| c.0),
        )
    };
    let mut best = (0.0, (f64::INFINITY, [(0.0, 0.0); 3]));
    let mut step = 1.0 / COARSE_STEPS as f64;
    let mut points: Vec<f64> = (0..=COARSE_STEPS).map(|i| i as f64 * step).collect();
    for _ in 0..LEVELS {
        for m in points {
            let here = at(m);
            if here.0 < best.1 .0 {
                best = (m, here);
            }
        }
        step /= REFINE as f64;
        points = around(best.0, step);
    }
    (best.0, best.1 .1)
}

/// One channel's (c, T) of least misfit at metalness `m`, with the misfit, among those whose
/// F82 stays above 0 ([`least_tint`]) when there is a metal.
fn colours(gram: &Gram, m: f64) -> ((f64, f64), f64) {
    let coarse: Vec<f64> = (0..=COLOUR_COARSE_STEPS)
        .map(|i| i as f64 / COLOUR_COARSE_STEPS as f64)
        .collect();
    let mut best = ((0.0, 0.0), f64::INFINITY);
    let (mut cs, mut ts) = (coarse.clone(), coarse);
    let mut step = 1.0 / COLOUR_COARSE_STEPS as f64;
    for _ in 0..LEVELS {
        for &c in &cs {
            let least = if m > 0.0 { least_tint(c) } else { 0.0 };
            for &t in ts.iter().filter(|t| **t >= least) {
                let e = gram.misfit(&weights(m, c, t));
                if e < best.1 {
                    best = ((c, t), e);
                }
            }
        }
        step /= REFINE as f64;
        (cs, ts) = (around(best.0 .0, step), around(best.0 .1, step));
    }
    best
}

/// The least specular colour T for which F82 = c·(1 − w) + w − β·g stays above 0 at every θd
/// centre of the grid with base colour `c`: β ≤ (c·(1 − w) + w)/g at each, β being
/// (1 − T) times its value at T = 0.
fn least_tint(c: f64) -> f64 {
    use std::sync::OnceLock;
    // (1 − w)/g and w/g at each θd centre.
    static RATIOS: OnceLock<Vec<(f64, f64)>> = OnceLock::new();
    let ratios = RATIOS.get_or_init(|| {
        (0..brdfd_core::bivariate::N_THETA_D)
            .map(|jd| {
                let mu = brdfd_core::merl::theta_d_center(jd).cos();
                let (w, g) = ((1.0 - mu).powi(5), mu * (1.0 - mu).powi(6));
                ((1.0 - w) / g, w / g)
            })
            .collect()
    });
    let most = ratios
        .iter()
        .map(|(a, b)| c * a + b)
        .fold(f64::INFINITY, f64::min);
    (1.0 - most / f82_b(c, 0.0)).max(0.0)
}

/// The points `step` apart within one coarser step (`REFINE` steps) either side of `x`, on
/// [0, 1].
fn around(x: f64, step: f64) -> Vec<f64> {
    let r = REFINE as i64;
    (-r..=r)
        .map(|i| x + i as f64 * step)
        .filter(|v| (0.0..=1.0).contains(v))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::super::MU_BAR;
    use super::*;
    use brdfd_core::geometry::{Camera, Shape};
    use brdfd_core::render::render_bivariates;

    /// `truth`, rendered with OpenPBR's own BRDF under two maps, fitted from the glTF fit
    /// `start`: the fit found, and its error.
    fn refit(truth: &OpenPbrMaterial, start: &Fitted) -> (OpenPbrMaterial, f64) {
        let grid = Grid::default();
        let sphere =
            PixelGeometry::rasterize(&Camera::eval_orthographic(32), &Shape::unit_sphere())
                .unwrap();
        let maps = crate::export::maps::reference_maps().unwrap();
        let lights: Vec<_> = maps[..2]
            .iter()
            .map(|(_, m)| m.compressed(1024, 0.0))
            .collect();
        let true_tables = OpenPbrBrdf::new(truth).tables(grid);
        let fit = OpenPbrFit::new(start, grid);
        let parts: Vec<&Bivariate> = fit.parts().collect();
        let targets: Vec<Raster> = lights
            .iter()
            .map(|l| true_tables.render_beside(&sphere, l, &[]).0)
            .collect();
        let renders: Vec<Vec<Raster>> = lights
            .iter()
            .map(|l| render_bivariates(&sphere, l, &parts))
            .collect();
        fit.solve(&sphere, &renders, &targets)
    }

    /// A glTF fit with F₀ 0.04 (IOR 1.5) at GGX α 0.16, with a coat of weight `coat`.
    fn start(coat: f64) -> Fitted {
        Fitted {
            base_color: [0.0; 3],
            metallic: 0.0,
            specular: 1.0,
            f0: [0.04; 3],
            alpha: 0.16,
            coat,
            coat_alpha: 0.01,
            fit_error: 0.0,
        }
    }

    #[test]
    fn the_least_tint_keeps_f82_just_above_zero() {
        // F82 by the BRDF's own definition (its b from the tint), at the grid's θd centres.
        let f82 = |c: f64, t: f64, mu: f64| {
            let schlick = |mu: f64| c + (1.0 - c) * (1.0 - mu).powi(5);
            let b = schlick(MU_BAR) * (1.0 - t) / (MU_BAR * (1.0 - MU_BAR).powi(6));
            schlick(mu) - b * mu * (1.0 - mu).powi(6)
        };
        let lowest = |c: f64, t: f64| {
            (0..brdfd_core::bivariate::N_THETA_D)
                .map(|jd| f82(c, t, brdfd_core::merl::theta_d_center(jd).cos()))
                .fold(f64::INFINITY, f64::min)
        };
        for c in [0.0, 0.05, 0.2, 0.5, 0.9] {
            let t = least_tint(c);
            assert!(lowest(c, t) > -1e-12, "c {c}: T {t}");
            if t > 0.0 {
                assert!(lowest(c, t - 0.01) < 0.0, "c {c}: T {t}");
            }
        }
        // A dark metal cannot take a tint much below a half; a bright one takes nearly any.
        assert!(least_tint(0.0) > 0.4, "{}", least_tint(0.0));
        assert!(least_tint(0.9) < 0.01, "{}", least_tint(0.9));
    }

    #[test]
    fn a_dim_dielectric_and_a_tinted_metallic_mix_are_recovered_from_their_renders() {
        // Made with OpenPBR's own BRDF at the IOR and roughness the fit starts from: a coated
        // red plastic whose specular colour dims its Fresnel to a third (what a paint's glTF
        // fit with a dim specular weight reads as), and a half-metallic gold with an F82 tint.
        // The fit finds each again, to its grids' steps (measured: colours within 0.0013,
        // relight 7e-4 and 9e-4).
        for (coat, metalness, base_color, specular_color) in [
            (0.5, 0.0, [0.5, 0.1, 0.08], [0.35, 0.3, 0.3]),
            (0.0, 0.45, [0.9, 0.6, 0.2], [0.95, 0.85, 0.7]),
        ] {
            let start = start(coat);
            // The candidate at the start's own IOR (F₀ 0.04), with its roughness and IOR
            // under the coat, coloured.
            let truth = OpenPbrMaterial {
                base_color,
                specular_color,
                base_metalness: metalness,
                ..OpenPbrFit::new(&start, Grid::default()).grey[2]
            };
            let (found, error) = refit(&truth, &start);
            eprintln!("{error:.2e}: {found:?}");
            assert!(error < 2e-3, "{error}: {found:?}");
            assert!(
                (found.specular_ior - truth.specular_ior).abs() < 1e-9,
                "{found:?}"
            );
            assert!((found.base_metalness - metalness).abs() < 0.01, "{found:?}");
            for k in 0..3 {
                assert!(
                    (found.base_color[k] - base_color[k]).abs() < 0.01,
                    "{found:?}"
                );
                assert!(
                    (found.specular_color[k] - specular_color[k]).abs() < 0.01,
                    "{found:?}"
                );
            }
        }
    }
}
