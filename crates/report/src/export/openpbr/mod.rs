//! `material.mtlx`: the fitted material as an OpenPBR Surface (MaterialX 1.39), and OpenPBR's
//! own BRDF for the inputs brdfd writes ([`OpenPbrBrdf`]), which chooses the `.mtlx` and
//! measures how it relights.
//!
//! The `.mtlx` is OpenPBR's own parameters fitted to the estimate ([`OpenPbrFit`], in [`fit`]):
//! its metalness and each channel's base and specular colours, at IORs around the glTF fit's,
//! with the glTF fit's roughness and coat (the roughness and IOR the base needs for the coat to
//! leave it the fit's: OpenPBR roughens a coated base and measures its IOR against the
//! coat's), and the coat's weight, roughness and IOR (1.5, glTF's). Its `specular_weight` is
//! 1, which leaves out a metal whose grazing reflectance stays below 1; so the glTF fit's
//! specular read as such a metal ([`OpenPbrMaterial::specular_as_metal`]) is the other
//! candidate, and the one OpenPBR's BRDF renders closer to the estimate under the fit's maps is
//! written, and measured under the maps the fit did not see:
//! [`super::Export::mtlx_relight_error`].
//! `coat_darkening` is 0: glTF's coat dims the base by its Fresnel alone, not by light trapped
//! inside the coat.
//!
//! An anisotropic lobe the estimate chose goes into `specular_roughness_anisotropy`, with
//! OpenPBR's own mapping (αt = r²·√(2/(1 + (1 − a)²)) along the geometry's tangent,
//! αb = (1 − a)·αt across it): the highlight stretches along the tangent, so the mesh's
//! tangents must run across the grain, as `material.gltf`'s `TANGENT` does.

use std::fmt::Write as _;

use brdfd_core::analytic::{ggx_d, ggx_lobe};
use brdfd_core::anisotropic::AnisotropicLobe;
use brdfd_core::bivariate::{Bivariate, Grid};
use brdfd_core::brdf::{Cosines, IsotropicBrdf};
use brdfd_core::envmap::LightSet;
use brdfd_core::geometry::PixelGeometry;
use brdfd_core::raster::Raster;

use super::fit::{view_cosine, Fitted};

pub mod fit;
pub use fit::OpenPbrFit;

/// An OpenPBR Surface's base and specular inputs.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct OpenPbrMaterial {
    pub base_color: [f64; 3],
    pub base_metalness: f64,
    pub specular_weight: f64,
    /// The dielectric's Fresnel tint, and the metal's F82 tint (its reflectivity near 82°
    /// as a share of Schlick's).
    pub specular_color: [f64; 3],
    pub specular_roughness: f64,
    pub specular_ior: f64,
    pub coat_weight: f64,
    pub coat_roughness: f64,
    /// 0: isotropic (and not written).
    pub specular_roughness_anisotropy: f64,
}

/// The coat's IOR: glTF's `KHR_materials_clearcoat` fixes 1.5 (F₀ 0.04).
const COAT_IOR: f64 = 1.5;
/// The largest dielectric reflectance written (an IOR of about 400): above it the IOR is no
/// longer a number a renderer handles well.
const MAX_F0: f64 = 0.99;

impl OpenPbrMaterial {
    /// The fit's dielectric specular as OpenPBR's metal, its base colour the dielectric's F₀
    /// and `specular_weight` glTF's: glTF's weighted dielectric Fresnel q·(F₀ + (1 − F₀)·w)
    /// rises to q at grazing, as OpenPBR's weighted metal does, where OpenPBR's dielectric
    /// rises to 1 whatever its IOR. What a fit with no diffuse to speak of (a metal that glTF
    /// held as a dim dielectric) is closest to; its diffuse and metal parts are left out.
    /// [`OpenPbrFit`] holds metals with `specular_weight` 1 alone, so this is the candidate
    /// [`super::write_exports`] weighs it against (chrome's estimate is closer so).
    pub fn specular_as_metal(f: &Fitted) -> OpenPbrMaterial {
        OpenPbrMaterial {
            base_color: f.f0,
            base_metalness: 1.0,
            specular_weight: f.specular,
            specular_color: [1.0; 3],
            specular_roughness: 0.0,
            specular_ior: 1.5,
            coat_weight: f.coat,
            coat_roughness: f.coat_alpha.sqrt().clamp(0.0, 1.0),
            specular_roughness_anisotropy: 0.0,
        }
        .with_base_roughness(f.alpha.sqrt())
    }

    /// The material with the `specular_ior` whose ratio to the coat's, as OpenPBR takes it
    /// under a coat of weight C (mix(η, η/η_c, C)), is the IOR it has now, where that ratio
    /// stays above 1: the dielectric keeps the reflectance the fit gave it.
    fn with_base_ior_under_coat(self) -> OpenPbrMaterial {
        let c = self.coat_weight;
        let ior = self.specular_ior / (1.0 - c + c / COAT_IOR);
        if c > 0.0 && ior > COAT_IOR {
            OpenPbrMaterial {
                specular_ior: ior,
                ..self
            }
        } else {
            self
        }
    }

    /// The material with the `specular_roughness` whose roughness under the coat is `r`
    /// where it can be: OpenPBR roughens the base under a coat, to
    /// (1 − C)·r + C·min(1, 2r_c⁴ + r⁴)^¼, which grows with r, so it is inverted by
    /// bisection; a base smoother than the coat allows gets roughness 0.
    fn with_base_roughness(self, r: f64) -> OpenPbrMaterial {
        let target = r.clamp(0.0, 1.0);
        let mut lo_hi = (0.0f64, 1.0f64);
        for _ in 0..60 {
            let mid = 0.5 * (lo_hi.0 + lo_hi.1);
            if effective_roughness(mid, self.coat_roughness, self.coat_weight) < target {
                lo_hi.0 = mid;
            } else {
                lo_hi.1 = mid;
            }
        }
        OpenPbrMaterial {
            specular_roughness: 0.5 * (lo_hi.0 + lo_hi.1),
            ..self
        }
    }

    /// The material with the roughnesses of an anisotropic lobe, through OpenPBR's mapping,
    /// the roughness being the one the base needs under the coat, as for an isotropic one.
    pub fn with_lobe(self, lobe: &AnisotropicLobe) -> OpenPbrMaterial {
        let (smooth, rough) = lobe.smooth_and_rough();
        let a = (1.0 - smooth / rough).clamp(0.0, 1.0);
        let r2 = rough / (2.0 / (1.0 + (1.0 - a) * (1.0 - a))).sqrt();
        OpenPbrMaterial {
            specular_roughness_anisotropy: a,
            ..self
        }
        .with_base_roughness(r2.sqrt())
    }

    /// The document: one `open_pbr_surface` and the `surfacematerial` that uses it.
    pub fn document(&self, name: &str) -> String {
        let c3 = |v: [f64; 3]| format!("{:.6}, {:.6}, {:.6}", v[0], v[1], v[2]);
        let mut s = String::from(
            "<?xml version=\"1.0\"?>\n<materialx version=\"1.39\" colorspace=\"lin_rec709\">\n",
        );
        let _ = writeln!(
            s,
            "  <open_pbr_surface name=\"SR_{name}\" type=\"surfaceshader\">"
        );
        let mut inputs = vec![
            ("base_weight", "float", "1.0".to_string()),
            ("base_color", "color3", c3(self.base_color)),
            (
                "base_metalness",
                "float",
                format!("{:.6}", self.base_metalness),
            ),
            (
                "specular_weight",
                "float",
                format!("{:.6}", self.specular_weight),
            ),
            ("specular_color", "color3", c3(self.specular_color)),
            (
                "specular_roughness",
                "float",
                format!("{:.6}", self.specular_roughness),
            ),
            ("specular_ior", "float", format!("{:.6}", self.specular_ior)),
        ];
        if self.specular_roughness_anisotropy > 0.0 {
            inputs.push((
                "specular_roughness_anisotropy",
                "float",
                format!("{:.6}", self.specular_roughness_anisotropy),
            ));
        }
        if self.coat_weight > 0.0 {
            inputs.extend([
                ("coat_weight", "float", format!("{:.6}", self.coat_weight)),
                (
                    "coat_roughness",
                    "float",
                    format!("{:.6}", self.coat_roughness),
                ),
                ("coat_ior", "float", format!("{COAT_IOR:.6}")),
                ("coat_darkening", "float", "0.0".to_string()),
            ]);
        }
        for (n, t, v) in inputs {
            let _ = writeln!(s, "    <input name=\"{n}\" type=\"{t}\" value=\"{v}\" />");
        }
        let _ = writeln!(s, "  </open_pbr_surface>");
        let _ = writeln!(
            s,
            "  <surfacematerial name=\"{name}\" type=\"material\">\n    <input name=\"surfaceshader\" type=\"surfaceshader\" nodename=\"SR_{name}\" />\n  </surfacematerial>\n</materialx>"
        );
        s
    }
}

/// OpenPBR Surface's BRDF for what brdfd writes: an opaque base (no transmission,
/// subsurface, fuzz, thin film or emission), a Lambertian diffuse (`base_diffuse_roughness`
/// 0), a colourless coat without darkening, and isotropic roughness. After the specification
/// (1.1) and its reference MaterialX graph:
///
/// ```text
/// f = C·f_coat + (1 − C·E_coat(ω_o))·base,    f_coat = F(μ, η_c)·S_c·comp_c
/// base = (1 − M)·[T·F(μ, η′)·S·comp + (1 − E_spec(ω_o))·c/π] + M·F82(μ)·S·comp
/// F82 = ξ·(F_s(μ) − b·μ(1 − μ)⁶),  F_s = c + (1 − c)(1 − μ)⁵,  b = F_s(1/7)(1 − T)/((1/7)(6/7)⁶)
/// ```
///
/// with μ = cos θd, S = D·V the GGX/Smith lobe (α the square of the roughness, which the coat
/// raises to ((1 − C)·r + C·min(1, 2r_c⁴ + r⁴)^¼)²), F the exact dielectric Fresnel, η′ the
/// IOR (over the coat's, when coated) modulated by ξ = `specular_weight`, T =
/// `specular_color`, and comp = 1 + F·(1 − E₁)/E₁ the multiple-scattering compensation of
/// Turquin (2019) that MaterialX applies, E₁ being the lobe's albedo with F = 1. E_spec and
/// E_coat, the directional albedos of the untinted compensated dielectric and coat lobes, are
/// integrated numerically where MaterialX fits them with a polynomial. The view is the second
/// direction: the albedo scaling makes the BRDF non-reciprocal, as the specification says.
#[derive(Clone)]
pub struct OpenPbrBrdf {
    m: OpenPbrMaterial,
    alpha: f64,
    /// The dielectric's IOR ratio after the coat and `specular_weight`.
    eta: f64,
    coat_alpha: f64,
    /// The F82 term's b per channel.
    f82_b: [f64; 3],
    /// Albedos against cos θ_o: the specular lobe with F = 1, the compensated dielectric
    /// reflection, the coat's lobe with F = 1 and the compensated coat.
    lobe_one: Albedo,
    dielectric: Albedo,
    coat_one: Albedo,
    coat: Albedo,
}

/// The base's roughness under a coat of weight `c` and roughness `rc` (the reference graph's
/// `effective_specular_roughness`): light through a rough coat sees a rougher base.
pub(super) fn effective_roughness(r: f64, rc: f64, c: f64) -> f64 {
    let coated = (2.0 * rc.powi(4) + r.powi(4)).min(1.0).powf(0.25);
    (1.0 - c) * r + c * coated
}

/// The F82-tint model's μ̄: the cosine near 82° at which `specular_color` is the metal's
/// reflectivity as a share of Schlick's.
const MU_BAR: f64 = 1.0 / 7.0;

/// The F82-tint model's b for base colour `c` and tint `t` (one channel): F82 = F_s(μ) −
/// b·μ(1 − μ)⁶ is t·F_s at μ̄, so b = F_s(μ̄)·(1 − t)/(μ̄(1 − μ̄)⁶). The fit
/// ([`fit::OpenPbrFit`]) writes F82 with the same b.
fn f82_b(c: f64, t: f64) -> f64 {
    let schlick = c + (1.0 - c) * (1.0 - MU_BAR).powi(5);
    schlick * (1.0 - t) / (MU_BAR * (1.0 - MU_BAR).powi(6))
}

impl OpenPbrBrdf {
    pub fn new(m: &OpenPbrMaterial) -> OpenPbrBrdf {
        let r_eff = effective_roughness(m.specular_roughness, m.coat_roughness, m.coat_weight);
        let alpha = (r_eff * r_eff).max(ALPHA_FLOOR);
        let coat_alpha = (m.coat_roughness * m.coat_roughness).max(ALPHA_FLOOR);
        let c = m.coat_weight;
        // The specular IOR relative to what lies above it: the coat's, when coated, inverted
        // when below 1 (the reference graph's fix for total internal reflection).
        let under_coat = m.specular_ior / COAT_IOR;
        let under_coat = if under_coat > 1.0 {
            under_coat
        } else {
            1.0 / under_coat
        };
        let eta_s = (1.0 - c) * m.specular_ior + c * under_coat;
        let f_s = ((eta_s - 1.0) / (eta_s + 1.0)).powi(2);
        let eps = (eta_s - 1.0).signum() * (m.specular_weight * f_s).clamp(0.0, 0.99999).sqrt();
        let eta = (1.0 + eps) / (1.0 - eps);
        let f82_b = std::array::from_fn(|k| f82_b(m.base_color[k], m.specular_color[k]));
        let lobe_one = Albedo::of(alpha, |_| 1.0, None);
        let dielectric = Albedo::of(alpha, |mu| fresnel_dielectric(mu, eta), Some(&lobe_one));
        let coat_one = Albedo::of(coat_alpha, |_| 1.0, None);
        let coat = Albedo::of(
            coat_alpha,
            |mu| fresnel_dielectric(mu, COAT_IOR),
            Some(&coat_one),
        );
        OpenPbrBrdf {
            m: *m,
            alpha,
            eta,
            coat_alpha,
            f82_b,
            lobe_one,
            dielectric,
            coat_one,
            coat,
        }
    }

    fn eval_cosines(&self, c: Cosines) -> [f64; 3] {
        let p = self.parts(c);
        let f = self.factors(c.o);
        std::array::from_fn(|k| {
            let (s, s2) = p.specular[k];
            f.combine([s, s2, p.diffuse[k], p.coat.0, p.coat.1])
        })
    }

    /// The BRDF's parts at `c` that are functions of (θh, θd) and the directions' cosines
    /// through the lobes alone; what multiplies them depends on the view's cosine only
    /// ([`OpenPbrBrdf::factors`]).
    fn parts(&self, c: Cosines) -> Parts {
        let f = self.by_theta_d(c.d);
        let lobe = ggx_lobe(c.h, c.i, c.o, self.alpha);
        let coat = if self.m.coat_weight > 0.0 {
            ggx_lobe(c.h, c.i, c.o, self.coat_alpha)
        } else {
            0.0
        };
        Parts {
            specular: f.specular.map(|(a, b)| (a * lobe, b * lobe)),
            diffuse: f.diffuse,
            coat: (f.coat.0 * coat, f.coat.1 * coat),
        }
    }

    /// The parts as functions of cos θd, each to be multiplied by its lobe: the base's for the
    /// specular, the coat's for the coat (the diffuse's is 1). So a table of the parts is a
    /// table of the lobes times functions of θd, which a cell's φd average leaves alone.
    fn by_theta_d(&self, mu: f64) -> Parts {
        let m = &self.m;
        let f_d = fresnel_dielectric(mu, self.eta);
        let w = (1.0 - mu).clamp(0.0, 1.0).powi(5);
        let g = mu * (1.0 - mu).clamp(0.0, 1.0).powi(6);
        let mut p = Parts::default();
        for k in 0..3 {
            let schlick = m.base_color[k] + (1.0 - m.base_color[k]) * w;
            // The weight scales the metal's lobe after its compensation, which is of the
            // unweighted Fresnel (as MaterialX's generalized Schlick BSDF has it).
            let f82 = (schlick - self.f82_b[k] * g).clamp(0.0, 1.0);
            let (dielectric, metal) = (m.specular_color[k] * f_d, m.specular_weight * f82);
            let (d, mt) = (1.0 - m.base_metalness, m.base_metalness);
            p.specular[k] = (
                d * dielectric + mt * metal,
                d * dielectric * f_d + mt * metal * f82,
            );
            p.diffuse[k] = d * m.base_color[k] / std::f64::consts::PI;
        }
        if m.coat_weight > 0.0 {
            let f_c = fresnel_dielectric(mu, COAT_IOR);
            p.coat = (m.coat_weight * f_c, m.coat_weight * f_c * f_c);
        }
        p
    }

    /// What multiplies the parts at a view of cosine `mu`.
    fn factors(&self, mu: f64) -> Factors {
        let e1 = self.lobe_one.at(mu);
        let (coat_compensation, coat_through) = if self.m.coat_weight > 0.0 {
            let e1 = self.coat_one.at(mu);
            ((1.0 - e1) / e1, 1.0 - self.m.coat_weight * self.coat.at(mu))
        } else {
            (0.0, 1.0)
        };
        Factors {
            compensation: (1.0 - e1) / e1,
            diffuse: 1.0 - self.dielectric.at(mu),
            coat_compensation,
            coat_through,
        }
    }

    /// The material as bivariate tables of its parts, for rendering as brdfd renders the
    /// estimate ([`OpenPbrTables::render_beside`]).
    pub fn tables(&self, grid: Grid) -> OpenPbrTables {
        let coat_alpha = (self.m.coat_weight > 0.0).then_some(self.coat_alpha);
        let lobes = Lobes::reduce(self.alpha, coat_alpha, grid);
        let parts = |mu: f64| {
            let p = self.by_theta_d(mu);
            [
                p.specular.map(|s| s.0),
                p.specular.map(|s| s.1),
                p.diffuse,
                [p.coat.0; 3],
                [p.coat.1; 3],
            ]
        };
        let [s, s2, diffuse, coat, coat2] = lobes.scaled(
            parts,
            [Lobe::Base, Lobe::Base, Lobe::One, Lobe::Coat, Lobe::Coat],
        );
        // Without a coat its two parts are zero, and not rendered.
        let mut tables = vec![s, s2, diffuse];
        if self.m.coat_weight > 0.0 {
            tables.extend([coat, coat2]);
        }
        OpenPbrTables {
            brdf: self.clone(),
            tables,
        }
    }
}

/// Which lobe a part multiplies: the base's, the coat's, or none (the diffuse).
#[derive(Clone, Copy)]
enum Lobe {
    One,
    Base,
    Coat,
}

/// The lobes the tables of OpenPBR's parts are made of, each reduced to the grid once
/// ([`brdfd_core::analytic::lobe_plane`]): every other factor of a part is a function of θd
/// ([`OpenPbrBrdf::by_theta_d`]), constant over a cell's φd average, so a part's table is its
/// lobe's times that function at the cell's θd.
struct Lobes {
    grid: Grid,
    /// Whether a cell has a φd above both horizons.
    valid: Vec<bool>,
    base: Vec<f64>,
    /// The coat's, when there is one.
    coat: Option<Vec<f64>>,
}

impl Lobes {
    /// The lobes of roughness `alpha` and, with a coat, `coat_alpha`.
    fn reduce(alpha: f64, coat_alpha: Option<f64>, grid: Grid) -> Lobes {
        use brdfd_core::analytic::{lambert_column, lobe_plane};
        use brdfd_core::bivariate::GRID_CELLS;
        Lobes {
            grid,
            valid: lambert_column(grid)[..GRID_CELLS]
                .iter()
                .map(|v| *v > 0.0)
                .collect(),
            base: lobe_plane(grid, alpha),
            coat: coat_alpha.map(|a| lobe_plane(grid, a)),
        }
    }

    /// `N` tables, part n being `parts(cos θd)[n]` per channel times the lobe `lobes[n]`.
    fn scaled<const N: usize>(
        &self,
        parts: impl Fn(f64) -> [[f64; 3]; N],
        lobes: [Lobe; N],
    ) -> [Bivariate; N] {
        use brdfd_core::bivariate::{GRID_CELLS, N_THETA_D};
        let by_theta_d: Vec<[[f64; 3]; N]> = (0..N_THETA_D)
            .map(|jd| parts(brdfd_core::merl::theta_d_center(jd).cos()))
            .collect();
        std::array::from_fn(|n| {
            let lobe = |g: usize| match lobes[n] {
                Lobe::One if self.valid[g] => 1.0,
                Lobe::One => 0.0,
                Lobe::Base => self.base[g],
                Lobe::Coat => self.coat.as_ref().map_or(0.0, |c| c[g]),
            };
            let mut values = vec![0.0; 3 * GRID_CELLS];
            for g in 0..GRID_CELLS {
                let (l, f) = (lobe(g), by_theta_d[g % N_THETA_D][n]);
                for c in 0..3 {
                    values[c * GRID_CELLS + g] = l * f[c];
                }
            }
            Bivariate::from_values(self.grid, values, self.valid.clone())
        })
    }
}

/// The parts of [`OpenPbrBrdf`] at one pair of directions, per channel: the base's specular
/// lobe (dielectric and metal, each through its Fresnel F) and the same through F², which the
/// compensation 1 + F·(1 − E₁)/E₁ adds; the diffuse before its albedo scaling; and the coat's
/// lobe and its F² term (grey).
#[derive(Default)]
struct Parts {
    specular: [(f64, f64); 3],
    diffuse: [f64; 3],
    coat: (f64, f64),
}

/// What multiplies [`Parts`] at one view: (1 − E₁)/E₁ of the base's lobe and of the coat's,
/// 1 − E_spec and 1 − C·E_coat.
struct Factors {
    compensation: f64,
    diffuse: f64,
    coat_compensation: f64,
    coat_through: f64,
}

impl Factors {
    /// One channel from its parts: the base's lobe and its F² term, the diffuse, the coat's
    /// lobe and its F² term.
    fn combine(&self, [s, s2, diffuse, coat, coat2]: [f64; 5]) -> f64 {
        let base = s + self.compensation * s2 + self.diffuse * diffuse;
        coat + self.coat_compensation * coat2 + self.coat_through * base
    }
}

/// An [`OpenPbrBrdf`] reduced to bivariate tables of its parts; each pixel's view gives what
/// multiplies them.
pub struct OpenPbrTables {
    brdf: OpenPbrBrdf,
    /// The base's lobe and its F² term, the diffuse, and with a coat, its lobe and F² term.
    tables: Vec<Bivariate>,
}

impl OpenPbrTables {
    /// The tables of the parts, to render in one pass with others
    /// ([`brdfd_core::render::render_bivariates`]).
    pub fn parts(&self) -> impl Iterator<Item = &Bivariate> {
        self.tables.iter()
    }

    /// The material rendered on `geometry` under `lights`, and each of `others` in the same
    /// pass.
    pub fn render_beside(
        &self,
        geometry: &PixelGeometry,
        lights: &LightSet,
        others: &[&Bivariate],
    ) -> (Raster, Vec<Raster>) {
        let (own, rest) = super::render_with(geometry, lights, self.parts().collect(), others);
        (self.combine(geometry, &own), rest)
    }

    /// The material's image from its parts' renders on `geometry` (in [`OpenPbrTables::parts`]'
    /// order): each pixel's view gives what multiplies them.
    pub fn combine(&self, geometry: &PixelGeometry, parts: &[Raster]) -> Raster {
        assert_eq!(parts.len(), self.tables.len(), "a render per part");
        let mut image = Raster::black(geometry.width, geometry.height);
        for px in &geometry.pixels {
            let i = px.y as usize * image.width + px.x as usize;
            let f = self.brdf.factors(view_cosine(px));
            image.pixels[i] = std::array::from_fn(|k| {
                f.combine(std::array::from_fn(|t| {
                    parts.get(t).map_or(0.0, |p| f64::from(p.pixels[i][k]))
                })) as f32
            });
        }
        image
    }
}

impl IsotropicBrdf for OpenPbrBrdf {
    fn eval_angles(&self, theta_h: f64, theta_d: f64, phi_d: f64) -> [f64; 3] {
        Cosines::of_angles(theta_h, theta_d, phi_d).map_or([0.0; 3], |c| self.eval_cosines(c))
    }

    fn eval_dirs(&self, wi: [f64; 3], wo: [f64; 3]) -> [f64; 3] {
        Cosines::of_dirs(wi, wo).map_or([0.0; 3], |c| self.eval_cosines(c))
    }
}

/// The smallest GGX α the albedos are integrated for: a sharper lobe is a mirror to them.
const ALPHA_FLOOR: f64 = 1e-6;
/// View cosines the albedos are tabulated at, evenly spaced from 0 to 1.
const ALBEDO_COSINES: usize = 33;
/// Quadrature points per dimension of the half-vector's distribution.
const QUADRATURE: usize = 32;

/// A GGX lobe's directional albedo against the view's cosine, tabulated.
#[derive(Clone)]
struct Albedo {
    at: [f64; ALBEDO_COSINES],
}

impl Albedo {
    /// The albedo E(μ_o) = ∫ F(ω_o·h)·D·V·comp·cos θ_i dω_i of the lobe of roughness `alpha`
    /// with Fresnel `fresnel` (of the cosine between the view and the half vector), and with
    /// the compensation 1 + F·(1 − E₁)/E₁ when `one`, the lobe's albedo with F = 1, is given.
    /// The half vector is drawn from D·cos θh by its inverse distribution (tan² θh =
    /// α²·u/(1 − u)), so that a sharp lobe is integrated as finely as a broad one.
    fn of(alpha: f64, fresnel: impl Fn(f64) -> f64, one: Option<&Albedo>) -> Albedo {
        let n = QUADRATURE;
        let mut at = [0.0; ALBEDO_COSINES];
        for (j, e) in at.iter_mut().enumerate() {
            let mu = (j as f64 / (ALBEDO_COSINES - 1) as f64).max(1e-3);
            let o = [(1.0 - mu * mu).max(0.0).sqrt(), 0.0, mu];
            let e1 = one.map(|a| a.at(mu));
            let mut sum = 0.0;
            for a in 0..n {
                let u = (a as f64 + 0.5) / n as f64;
                let tan2 = alpha * alpha * u / (1.0 - u);
                let cos_h = 1.0 / (1.0 + tan2).sqrt();
                let sin_h = (1.0 - cos_h * cos_h).max(0.0).sqrt();
                for b in 0..n {
                    let phi = 2.0 * std::f64::consts::PI * (b as f64 + 0.5) / n as f64;
                    let h = [sin_h * phi.cos(), sin_h * phi.sin(), cos_h];
                    let oh = o[0] * h[0] + o[2] * h[2];
                    let cos_i = 2.0 * oh * h[2] - o[2];
                    if oh <= 0.0 || cos_i <= 0.0 {
                        continue;
                    }
                    let f = fresnel(oh);
                    let comp = e1.map_or(1.0, |e1| 1.0 + f * (1.0 - e1) / e1);
                    // f·cos θi over the density of ω_i, D·cos θh / (4 ω_o·h).
                    let value = f * comp * ggx_lobe(cos_h, cos_i, mu, alpha) * cos_i;
                    sum += value * 4.0 * oh / (ggx_d(cos_h, alpha) * cos_h);
                }
            }
            *e = (sum / (n * n) as f64).clamp(1e-6, 1.0);
        }
        Albedo { at }
    }

    /// The albedo at the view's cosine `mu`, interpolated.
    fn at(&self, mu: f64) -> f64 {
        let x = mu.clamp(0.0, 1.0) * (ALBEDO_COSINES - 1) as f64;
        let j = (x.floor() as usize).min(ALBEDO_COSINES - 2);
        let t = x - j as f64;
        self.at[j] * (1.0 - t) + self.at[j + 1] * t
    }
}

/// The unpolarised Fresnel reflectance of a dielectric of relative IOR `eta` at an angle of
/// cosine `cos` from outside (1 under total internal reflection, for `eta` below 1).
pub fn fresnel_dielectric(cos: f64, eta: f64) -> f64 {
    let c = cos.clamp(0.0, 1.0);
    let g2 = eta * eta - 1.0 + c * c;
    if g2 <= 0.0 {
        return 1.0;
    }
    let g = g2.sqrt();
    let a = (g - c) / (g + c);
    let b = (c * (g + c) - 1.0) / (c * (g - c) + 1.0);
    0.5 * a * a * (1.0 + b * b)
}

#[cfg(test)]
mod tests {
    use super::*;
    use brdfd_core::geometry::{Camera, Shape};

    fn material(base_color: [f64; 3], metalness: f64, roughness: f64) -> OpenPbrMaterial {
        OpenPbrMaterial {
            base_color,
            base_metalness: metalness,
            specular_weight: 1.0,
            specular_color: [1.0; 3],
            specular_roughness: roughness,
            specular_ior: 1.5,
            coat_weight: 0.0,
            coat_roughness: 0.0,
            specular_roughness_anisotropy: 0.0,
        }
    }

    /// ∫ f(ω_i, ω_o)·cos θi dω_i at a view of cosine `mu`, by the midpoint rule in (cos θi, φ).
    fn albedo(brdf: &OpenPbrBrdf, mu: f64) -> [f64; 3] {
        let o = [(1.0 - mu * mu).sqrt(), 0.0, mu];
        let n = 400;
        let mut sum = [0.0; 3];
        for a in 0..n {
            // cos θi² uniform: cos θi dω_i = ½ d(cos² θi) dφ.
            let c = ((a as f64 + 0.5) / n as f64).sqrt();
            let s = (1.0 - c * c).sqrt();
            for b in 0..n {
                let phi = 2.0 * std::f64::consts::PI * (b as f64 + 0.5) / n as f64;
                let f = brdf.eval_dirs([s * phi.cos(), s * phi.sin(), c], o);
                for k in 0..3 {
                    sum[k] += f[k] * std::f64::consts::PI / (n * n) as f64;
                }
            }
        }
        sum
    }

    #[test]
    fn a_white_dielectric_and_a_white_coat_keep_all_the_light() {
        // The albedo scaling makes a white base under its specular, and under a coat, reflect
        // everything that reaches it: OpenPBR's furnace test, at every view. Measured within
        // 0.3% (the quadrature's, at grazing views).
        let plastic = material([1.0; 3], 0.0, 0.5);
        let coated = OpenPbrMaterial {
            coat_weight: 1.0,
            coat_roughness: 0.3,
            ..plastic
        };
        for m in [plastic, coated] {
            let brdf = OpenPbrBrdf::new(&m);
            for mu in [0.2, 0.5, 0.9] {
                let e = albedo(&brdf, mu);
                assert!((e[0] - 1.0).abs() < 0.01, "{m:?} at μ {mu}: {e:?}");
            }
        }
    }

    #[test]
    fn the_metal_is_schlick_s_with_a_white_tint_and_dips_at_82_degrees_with_a_tint() {
        let gold = [1.0, 0.78, 0.34];
        let schlick = |c: f64, mu: f64| c + (1.0 - c) * (1.0 - mu).powi(5);
        // White: b is 0, F82 is Schlick's.
        let white = OpenPbrBrdf::new(&material(gold, 1.0, 0.3));
        assert_eq!(white.f82_b, [0.0; 3]);
        // Tinted: at μ̄ the reflectivity is the tint's share of Schlick's.
        let tint = [0.9, 0.8, 0.5];
        let tinted = OpenPbrBrdf::new(&OpenPbrMaterial {
            specular_color: tint,
            ..material(gold, 1.0, 0.3)
        });
        for k in 0..3 {
            let s = schlick(gold[k], MU_BAR);
            let f82 = s - tinted.f82_b[k] * MU_BAR * (1.0 - MU_BAR).powi(6);
            assert!((f82 - tint[k] * s).abs() < 1e-12, "{k}: {f82}");
        }
    }

    #[test]
    fn the_dielectric_fresnel_is_the_ior_s() {
        assert!((fresnel_dielectric(1.0, 1.5) - 0.04).abs() < 1e-12);
        assert!((fresnel_dielectric(0.0, 1.5) - 1.0).abs() < 1e-9);
        // specular_weight scales the normal-incidence reflectance through the IOR.
        let half = OpenPbrBrdf::new(&OpenPbrMaterial {
            specular_weight: 0.5,
            ..material([0.5; 3], 0.0, 0.3)
        });
        assert!((fresnel_dielectric(1.0, half.eta) - 0.02).abs() < 1e-9);
    }

    #[test]
    fn its_tables_are_its_parts_reduced_to_the_grid() {
        // The tables are made as the lobes' tables times functions of θd; the parts reduced
        // to the grid sample by sample must give the same, for a coated and an uncoated
        // material on both θh binnings (measured equal to about 1e-15, the sums' order).
        use brdfd_core::bivariate::{PhiReduction, ThetaHBinning};
        let plain = material([0.8, 0.5, 0.2], 0.6, 0.5);
        let coated = OpenPbrMaterial {
            coat_weight: 0.8,
            coat_roughness: 0.2,
            specular_color: [0.9, 0.9, 0.8],
            ..plain
        };
        for m in [plain, coated] {
            let brdf = OpenPbrBrdf::new(&m);
            for binning in [ThetaHBinning::Sqrt, ThetaHBinning::Uniform] {
                let grid = Grid {
                    theta_h_binning: binning,
                    phi_reduction: PhiReduction::ValidMean,
                };
                let reduced = Bivariate::reduce_parts(grid, |th, td, pd| {
                    let p = brdf.parts(Cosines::of_angles(th, td, pd)?);
                    Some([
                        p.specular.map(|s| s.0),
                        p.specular.map(|s| s.1),
                        p.diffuse,
                        [p.coat.0; 3],
                        [p.coat.1; 3],
                    ])
                });
                let tables = brdf.tables(grid);
                let kept = if m.coat_weight > 0.0 { 5 } else { 3 };
                assert_eq!(tables.parts().count(), kept);
                for (t, r) in tables.parts().zip(&reduced) {
                    assert_eq!(t.valid, r.valid);
                    for (a, b) in t.values.iter().zip(&r.values) {
                        assert!(
                            (a - b).abs() <= 1e-10 * b.abs(),
                            "{binning:?}: {a} against {b}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn its_tables_render_what_its_directions_do() {
        // The parts' tables times each pixel's factors, against the BRDF evaluated for every
        // pixel and light: a coated metallic paint.
        let m = OpenPbrMaterial {
            coat_weight: 0.8,
            coat_roughness: 0.2,
            specular_color: [0.9, 0.9, 0.8],
            ..material([0.8, 0.5, 0.2], 0.6, 0.5)
        };
        let brdf = OpenPbrBrdf::new(&m);
        let sphere =
            PixelGeometry::rasterize(&Camera::eval_orthographic(32), &Shape::unit_sphere())
                .unwrap();
        let lights = super::super::maps::reference_maps().unwrap()[0]
            .1
            .compressed(1024, 0.0);
        let (tabled, _) = brdf
            .tables(Grid::default())
            .render_beside(&sphere, &lights, &[]);
        let direct = brdfd_core::render::render_full(&sphere, &lights, &brdf);
        let e = tabled.relative_rmse(&direct);
        // The same two renders of glTF's BRDF for the uncoated material, which is a table of
        // (θh, θd) with no factor of the view: what the φd average and the two renderers
        // leave between them.
        let gltf = super::super::GltfBrdf(super::super::GltfMaterial {
            base_color: m.base_color,
            metallic: m.base_metalness,
            roughness: m.specular_roughness,
            specular: 1.0,
            specular_color: [1.0; 3],
            ior: 1.5,
            clearcoat: 0.0,
            clearcoat_roughness: 0.0,
            anisotropy: None,
        });
        let table = Bivariate::reduce(&gltf, Grid::default());
        let g = brdfd_core::render::render_bivariate(&sphere, &lights, &table)
            .relative_rmse(&brdfd_core::render::render_full(&sphere, &lights, &gltf));
        eprintln!("tables against directions: OpenPBR {e:.4}, glTF {g:.4}");
        // Measured 0.0263 and 0.0259: the factors of the view add nothing the renderers'
        // own gap does not have.
        assert!(e < g + 0.003, "OpenPBR {e}, glTF {g}");
    }
}
