//! OpenPBR's own parameters fitted to the estimate's renders, where they differ from glTF's:
//! its dielectric.
//!
//! A glTF fit of a paint or a plastic often has a dim specular: glTF's specular weight q holds
//! the Fresnel to q·(F₀ + (1 − F₀)·w), dim at grazing too. Read part for part, OpenPBR's
//! dielectric keeps its full Fresnel, which rises to 1 at grazing whatever the IOR, and adds a
//! bright rim the estimate does not have. OpenPBR dims a dielectric's Fresnel by its
//! `specular_color` instead, which multiplies it (and leaves the diffuse's albedo scaling to
//! the untinted dielectric). With metalness 0 and the roughness, IOR and coat set, OpenPBR's
//! image is linear in each channel's base colour c and specular colour T:
//!
//! ```text
//! image_k = T_k·specular + c_k·diffuse + coat
//! ```
//!
//! the three images being the grey material's parts as they leave it
//! ([`super::OpenPbrTables::split`]). So the colours are solved exactly on their box [0, 1]²
//! for each IOR of a short list around the glTF fit's, keeping the glTF fit's roughness and
//! coat (OpenPBR's lobe is glTF's GGX/Smith, and its roughness under the coat is set to the
//! fit's), and the IOR whose solve comes closest is the fit.

use brdfd_core::bivariate::{Bivariate, Grid};
use brdfd_core::geometry::PixelGeometry;
use brdfd_core::raster::Raster;

use super::{OpenPbrBrdf, OpenPbrMaterial, OpenPbrTables, MAX_F0};
use crate::export::fit::Fitted;

/// The normal-incidence reflectances tried, as multiples of the glTF fit's (at full weight):
/// OpenPBR's exact Fresnel and its albedo-scaled diffuse move the best IOR a little from
/// glTF's Schlick and weighted one.
const F0_STEPS: [f64; 5] = [0.5, 0.71, 1.0, 1.41, 2.0];
/// Below this F₀ (an IOR of 1.2) a dielectric's highlight is too faint to tell IORs apart.
const MIN_F0: f64 = 0.01;

/// OpenPBR's dielectric at each IOR tried, as grey tables (base and specular colours white)
/// whose renders the colours are solved from.
pub struct DielectricFit {
    candidates: Vec<(OpenPbrMaterial, OpenPbrTables)>,
}

impl DielectricFit {
    /// The dielectrics to try for the glTF fit `f`: its roughness and coat, metalness 0, at
    /// IORs around its dielectric's.
    pub fn new(f: &Fitted, grid: Grid) -> DielectricFit {
        use rayon::prelude::*;
        let start = f.f0_max().max(MIN_F0);
        let mut f0s: Vec<f64> = F0_STEPS
            .iter()
            .map(|s| (s * start).clamp(MIN_F0, MAX_F0))
            .collect();
        f0s.dedup();
        let candidates = f0s
            .par_iter()
            .map(|&f0| {
                let r = f0.sqrt();
                let grey = OpenPbrMaterial {
                    base_color: [1.0; 3],
                    base_metalness: 0.0,
                    specular_weight: 1.0,
                    specular_color: [1.0; 3],
                    specular_roughness: 0.0,
                    specular_ior: (1.0 + r) / (1.0 - r),
                    coat_weight: f.coat,
                    coat_roughness: f.coat_alpha.sqrt().clamp(0.0, 1.0),
                    specular_roughness_anisotropy: 0.0,
                }
                .with_base_roughness(f.alpha.sqrt())
                .with_base_ior_under_coat();
                (grey, OpenPbrBrdf::new(&grey).tables(grid))
            })
            .collect();
        DielectricFit { candidates }
    }

    /// Every candidate's tables, to render in one pass with others.
    pub fn parts(&self) -> impl Iterator<Item = &Bivariate> {
        self.candidates.iter().flat_map(|(_, t)| t.parts())
    }

    /// The fit from the renders of [`DielectricFit::parts`] under each map (`renders[m]`, in
    /// their order) and the target's (`targets[m]`) on `geometry`: the material with each
    /// IOR's colours solved, the closest, and its mean relative RMSE over the maps.
    pub fn solve(
        &self,
        geometry: &PixelGeometry,
        renders: &[Vec<Raster>],
        targets: &[Raster],
    ) -> Option<(OpenPbrMaterial, f64)> {
        let mut best: Option<(OpenPbrMaterial, f64)> = None;
        let mut next = 0;
        for (grey, tables) in &self.candidates {
            let n = tables.parts().count();
            let split: Vec<[Raster; 3]> = renders
                .iter()
                .map(|r| tables.split(geometry, &r[next..next + n]))
                .collect();
            next += n;
            let colours: [(f64, f64); 3] =
                std::array::from_fn(|k| solve_channel(&split, targets, k));
            let m = OpenPbrMaterial {
                base_color: colours.map(|c| c.1),
                specular_color: colours.map(|c| c.0),
                ..*grey
            };
            let error = split
                .iter()
                .zip(targets)
                .map(|([s, d, c], t)| image(s, d, c, &colours).relative_rmse(t))
                .sum::<f64>()
                / targets.len() as f64;
            if best.is_none_or(|b| error < b.1) {
                best = Some((m, error));
            }
        }
        best
    }
}

/// The image T_k·specular + c_k·diffuse + coat per channel, for each channel's (T, c).
fn image(specular: &Raster, diffuse: &Raster, coat: &Raster, colours: &[(f64, f64); 3]) -> Raster {
    let mut out = specular.clone();
    for (i, p) in out.pixels.iter_mut().enumerate() {
        *p = std::array::from_fn(|k| {
            let (t, c) = colours[k];
            (t * f64::from(specular.pixels[i][k])
                + c * f64::from(diffuse.pixels[i][k])
                + f64::from(coat.pixels[i][k])) as f32
        });
    }
    out
}

/// Channel `k`'s (T, c) on [0, 1]² that minimise Σ over maps of ‖T·s + c·d + coat − target‖²
/// over the map's ‖target‖² (each map counting alike, as the mean relative RMSE does).
fn solve_channel(split: &[[Raster; 3]], targets: &[Raster], k: usize) -> (f64, f64) {
    // The normal equations' sums: [ss, sd, dd] and [s·y, d·y], y the target less the coat.
    let (mut g, mut b) = ([0.0f64; 3], [0.0f64; 2]);
    for ([s, d, c], t) in split.iter().zip(targets) {
        let norm: f64 = t
            .pixels
            .iter()
            .flat_map(|p| p.iter().map(|v| f64::from(*v).powi(2)))
            .sum();
        let w = 1.0 / norm.max(f64::MIN_POSITIVE);
        for i in 0..t.pixels.len() {
            let (sv, dv) = (f64::from(s.pixels[i][k]), f64::from(d.pixels[i][k]));
            let y = f64::from(t.pixels[i][k]) - f64::from(c.pixels[i][k]);
            g[0] += w * sv * sv;
            g[1] += w * sv * dv;
            g[2] += w * dv * dv;
            b[0] += w * sv * y;
            b[1] += w * dv * y;
        }
    }
    box_least_squares(g, b)
}

/// The (x, y) on [0, 1]² that minimise the quadratic x·x·g₀ + 2·x·y·g₁ + y·y·g₂ − 2·(x·b₀ +
/// y·b₁): the unconstrained minimum when it lies in the box, else the best on its edges.
fn box_least_squares(g: [f64; 3], b: [f64; 2]) -> (f64, f64) {
    let cost = |(x, y): (f64, f64)| {
        x * x * g[0] + 2.0 * x * y * g[1] + y * y * g[2] - 2.0 * (x * b[0] + y * b[1])
    };
    let det = g[0] * g[2] - g[1] * g[1];
    if det > 1e-12 * g[0] * g[2] {
        let (x, y) = (
            (b[0] * g[2] - b[1] * g[1]) / det,
            (b[1] * g[0] - b[0] * g[1]) / det,
        );
        if (0.0..=1.0).contains(&x) && (0.0..=1.0).contains(&y) {
            return (x, y);
        }
    }
    // On an edge one variable is fixed at 0 or 1 and the other minimises along it, clamped.
    let along = |fixed: f64, gg: f64, cross: f64, bb: f64| {
        if gg > 0.0 {
            ((bb - cross * fixed) / gg).clamp(0.0, 1.0)
        } else {
            0.0
        }
    };
    [0.0, 1.0]
        .into_iter()
        .flat_map(|fixed| {
            [
                (fixed, along(fixed, g[2], g[1], b[1])),
                (along(fixed, g[0], g[1], b[0]), fixed),
            ]
        })
        .min_by(|p, q| cost(*p).total_cmp(&cost(*q)))
        .expect("four edges")
}

#[cfg(test)]
mod tests {
    use super::*;
    use brdfd_core::geometry::{Camera, Shape};
    use brdfd_core::render::render_bivariates;

    #[test]
    fn a_dim_dielectric_made_with_openpbr_s_brdf_is_recovered_from_its_renders() {
        // A red plastic whose specular colour dims its Fresnel to a third (what a paint's glTF
        // fit with a dim specular weight reads as), with a clear coat, rendered with
        // OpenPBR's own BRDF under two maps: the fit at its IOR and roughness finds its colours
        // again and renders it to float precision.
        // The glTF fit the dielectrics are tried around: its F₀ (IOR 1.5's) and roughnesses.
        let start = Fitted {
            base_color: [0.0; 3],
            metallic: 0.0,
            specular: 1.0,
            f0: [0.04; 3],
            alpha: 0.16,
            coat: 0.5,
            coat_alpha: 0.01,
            fit_error: 0.0,
        };
        let grid = Grid::default();
        let fit = DielectricFit::new(&start, grid);
        // The candidate at the start's own IOR (F₀ 0.04), with its roughness and IOR under the
        // coat, coloured.
        let truth = OpenPbrMaterial {
            base_color: [0.5, 0.1, 0.08],
            specular_color: [0.35, 0.3, 0.3],
            ..fit.candidates[2].0
        };
        let sphere =
            PixelGeometry::rasterize(&Camera::eval_orthographic(32), &Shape::unit_sphere())
                .unwrap();
        let maps = crate::export::maps::reference_maps().unwrap();
        let lights: Vec<_> = maps[..2]
            .iter()
            .map(|(_, m)| m.compressed(1024, 0.0))
            .collect();
        let true_tables = OpenPbrBrdf::new(&truth).tables(grid);
        let parts: Vec<&Bivariate> = fit.parts().collect();
        let targets: Vec<Raster> = lights
            .iter()
            .map(|l| true_tables.render_beside(&sphere, l, &[]).0)
            .collect();
        let renders: Vec<Vec<Raster>> = lights
            .iter()
            .map(|l| render_bivariates(&sphere, l, &parts))
            .collect();
        let (found, error) = fit.solve(&sphere, &renders, &targets).unwrap();
        assert!(error < 1e-4, "{error}: {found:?}");
        assert!(
            (found.specular_ior - truth.specular_ior).abs() < 1e-9,
            "{found:?}"
        );
        for k in 0..3 {
            assert!(
                (found.base_color[k] - truth.base_color[k]).abs() < 1e-3,
                "{found:?}"
            );
            assert!(
                (found.specular_color[k] - truth.specular_color[k]).abs() < 1e-3,
                "{found:?}"
            );
        }
    }

    #[test]
    fn the_box_solve_finds_interior_and_edge_minima() {
        // x² + y² − 2(0.3x + 0.6y): the minimum (0.3, 0.6) is inside.
        assert_eq!(box_least_squares([1.0, 0.0, 1.0], [0.3, 0.6]), (0.3, 0.6));
        // The same towards (1.5, −0.2): the box's nearest point (1, 0).
        let (x, y) = box_least_squares([1.0, 0.0, 1.0], [1.5, -0.2]);
        assert!((x - 1.0).abs() < 1e-12 && y.abs() < 1e-12, "{x} {y}");
        // (x + y)² − 4(x + y) is least on the line x + y = 2, which meets the box at (1, 1).
        let (x, y) = box_least_squares([1.0, 1.0, 1.0], [2.0, 2.0]);
        assert!(
            (x - 1.0).abs() < 1e-12 && (y - 1.0).abs() < 1e-12,
            "{x} {y}"
        );
    }
}
