//! The analytic estimate as materials a renderer reads: a glTF 2.0 material (metallic-roughness
//! with `KHR_materials_specular` and `KHR_materials_ior`) and an OpenPBR Surface in MaterialX.
//!
//! Both hold one specular lobe: with two, the lobe carrying more light is exported. How much
//! the mapping loses is measured, not assumed: the material's own BRDF ([`GltfBrdf`], glTF's
//! published one) is rendered beside the estimate under a map neither was fitted to, and the
//! relative RMSE is written beside the files ([`Export::relight_error`]).
//!
//! Not here: exporting a basis estimate (it has no analytic form), and a measured OpenPBR
//! mapping: the `.mtlx` puts the glTF material's numbers into OpenPBR's nearest inputs (base
//! colour and metalness, specular weight, colour capped at 1, roughness, IOR). OpenPBR's model
//! differs in its details (energy compensation, F82 tint), and `relight_error` is the glTF's.

use std::fmt::Write as _;
use std::path::Path;

use serde::Serialize;

use crate::bench::studio_envmap;
use crate::core::analytic::{schlick_weight, Lobe, Microfacet};
use crate::core::bivariate::{Bivariate, Grid};
use crate::core::brdf::{from_rusinkiewicz, IsotropicBrdf};
use crate::core::geometry::{Camera, PixelGeometry, Shape};
use crate::core::render::render_bivariate;
use crate::core::{CoreError, Result};

/// F₀ of glTF's default dielectric (IOR 1.5).
const DIELECTRIC_F0: f64 = 0.04;
/// The smallest specular factor the specular colour is divided by (a lobe with no grazing
/// reflection would otherwise divide by zero).
const MIN_SPECULAR: f64 = 1e-3;
/// The map and sphere the export's loss is measured on: the procedural studio turned 120°,
/// which no capture is fitted under.
const CHECK_YAW_DEG: f64 = 120.0;
const CHECK_SIZE: usize = 64;
const CHECK_LIGHTS: usize = 4096;

/// A glTF metallic-roughness material with the specular and IOR extensions.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct GltfMaterial {
    pub base_color: [f64; 3],
    pub metallic: f64,
    /// glTF's roughness: √α.
    pub roughness: f64,
    pub specular: f64,
    pub specular_color: [f64; 3],
    pub ior: f64,
}

/// What [`write_exports`] wrote, and how far the exported material relights from the estimate.
#[derive(Clone, Debug, Serialize)]
pub struct Export {
    pub gltf: String,
    pub mtlx: String,
    pub material: GltfMaterial,
    /// ‖render(exported) − render(estimate)‖ / ‖render(estimate)‖ on a sphere under the studio
    /// map turned 120°: what the renderer's material loses against brdfd's estimate.
    pub relight_error: f64,
}

/// The lobe carrying the most light (the mean of F₀ and F₉₀ stands for its weight).
fn main_lobe(m: &Microfacet) -> Option<Lobe> {
    let weight = |l: &Lobe| (0..3).map(|c| l.f0[c] + l.f90[c]).sum::<f64>();
    m.lobes
        .iter()
        .copied()
        .max_by(|a, b| weight(a).total_cmp(&weight(b)))
}

impl GltfMaterial {
    /// Maps the analytic model's parameters to glTF's. An estimate whose lobe reflects more at
    /// normal incidence than its diffuse term (mean F₀ above mean kd) is a metal, which takes
    /// F₀ as its base colour (a dim dielectric with no diffuse, such as black plastic, is the
    /// same BRDF as a metal of that F₀). Otherwise a dielectric keeps the diffuse albedo as
    /// base colour and carries F₀ in the specular colour (relative to IOR 1.5) and F₉₀ in the
    /// specular factor.
    pub fn from_estimate(m: &Microfacet) -> Option<GltfMaterial> {
        let lobe = main_lobe(m)?;
        let mean = |v: [f64; 3]| v.iter().sum::<f64>() / 3.0;
        let roughness = lobe.alpha.sqrt().clamp(0.0, 1.0);
        let specular = mean(lobe.f90).clamp(0.0, 1.0);
        Some(if mean(lobe.f0) > mean(m.diffuse) {
            GltfMaterial {
                base_color: lobe.f0.map(|v| v.clamp(0.0, 1.0)),
                metallic: 1.0,
                roughness,
                specular: 1.0,
                specular_color: [1.0; 3],
                ior: 1.5,
            }
        } else {
            GltfMaterial {
                base_color: m.diffuse.map(|v| v.clamp(0.0, 1.0)),
                metallic: 0.0,
                roughness,
                specular,
                // glTF's dielectric F₀ is 0.04 · specularColor · specularFactor.
                specular_color: lobe
                    .f0
                    .map(|v| (v / (DIELECTRIC_F0 * specular.max(MIN_SPECULAR))).max(0.0)),
                ior: 1.5,
            }
        })
    }

    fn gltf_json(&self, name: &str) -> String {
        let json = serde_json::json!({
            "asset": { "version": "2.0", "generator": concat!("brdfd ", env!("CARGO_PKG_VERSION")) },
            "extensionsUsed": ["KHR_materials_specular", "KHR_materials_ior"],
            "materials": [{
                "name": name,
                "pbrMetallicRoughness": {
                    "baseColorFactor": [self.base_color[0], self.base_color[1], self.base_color[2], 1.0],
                    "metallicFactor": self.metallic,
                    "roughnessFactor": self.roughness,
                },
                "extensions": {
                    "KHR_materials_specular": {
                        "specularFactor": self.specular,
                        "specularColorFactor": self.specular_color,
                    },
                    "KHR_materials_ior": { "ior": self.ior },
                },
            }],
        });
        serde_json::to_string_pretty(&json).expect("a material serialises")
    }

    fn mtlx(&self, name: &str) -> String {
        let c3 = |v: [f64; 3]| format!("{:.6}, {:.6}, {:.6}", v[0], v[1], v[2]);
        let mut s = String::from(
            "<?xml version=\"1.0\"?>\n<materialx version=\"1.39\" colorspace=\"lin_rec709\">\n",
        );
        let _ = writeln!(
            s,
            "  <open_pbr_surface name=\"SR_{name}\" type=\"surfaceshader\">"
        );
        let inputs = [
            ("base_weight", "float", "1.0".to_string()),
            ("base_color", "color3", c3(self.base_color)),
            ("base_metalness", "float", format!("{:.6}", self.metallic)),
            ("specular_weight", "float", format!("{:.6}", self.specular)),
            (
                "specular_color",
                "color3",
                c3(self.specular_color.map(|v| v.min(1.0))),
            ),
            (
                "specular_roughness",
                "float",
                format!("{:.6}", self.roughness),
            ),
            ("specular_ior", "float", format!("{:.6}", self.ior)),
        ];
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

/// glTF's metallic-roughness BRDF with the specular extension (glTF 2.0 appendix B and
/// `KHR_materials_specular`): a Lambert term weighted by (1 − F), and a GGX/Smith lobe with
/// Schlick's Fresnel between F₀ and F₉₀.
pub struct GltfBrdf(pub GltfMaterial);

impl IsotropicBrdf for GltfBrdf {
    fn eval_angles(&self, theta_h: f64, theta_d: f64, phi_d: f64) -> [f64; 3] {
        let m = &self.0;
        let (wi, wo) = from_rusinkiewicz(theta_h, theta_d, phi_d);
        if wi[2] <= 0.0 || wo[2] <= 0.0 {
            return [0.0; 3];
        }
        let alpha = m.roughness * m.roughness;
        let specular = Microfacet::one_lobe([0.0; 3], [1.0; 3], [1.0; 3], alpha)
            .eval_angles(theta_h, theta_d, phi_d)[0];
        let w = schlick_weight(theta_d.cos());
        let ior_f0 = ((m.ior - 1.0) / (m.ior + 1.0)).powi(2);
        std::array::from_fn(|c| {
            let dielectric_f0 = (ior_f0 * m.specular_color[c]).min(1.0) * m.specular;
            let dielectric_f = dielectric_f0 + (m.specular - dielectric_f0) * w;
            let metal_f = m.base_color[c] + (1.0 - m.base_color[c]) * w;
            let dielectric = (1.0 - dielectric_f) * m.base_color[c] / std::f64::consts::PI
                + dielectric_f * specular;
            let metal = metal_f * specular;
            (1.0 - m.metallic) * dielectric + m.metallic * metal
        })
    }
}

/// Writes `material.gltf` and `material.mtlx` into `dir` for an analytic estimate, and
/// measures how far they relight from it. `None` if the estimate has no lobe.
pub fn write_exports(
    dir: &Path,
    name: &str,
    estimate: &Microfacet,
    estimate_brdf: &Bivariate,
    grid: Grid,
) -> Result<Option<Export>> {
    let Some(material) = GltfMaterial::from_estimate(estimate) else {
        return Ok(None);
    };
    let gltf = dir.join("material.gltf");
    let mtlx = dir.join("material.mtlx");
    std::fs::write(&gltf, material.gltf_json(name)).map_err(|e| CoreError::io(&gltf, e))?;
    std::fs::write(&mtlx, material.mtlx(name)).map_err(|e| CoreError::io(&mtlx, e))?;
    let sphere = PixelGeometry::rasterize(
        &Camera::eval_orthographic(CHECK_SIZE),
        &Shape::unit_sphere(),
    )?;
    let lights = studio_envmap(256).compressed(CHECK_LIGHTS, CHECK_YAW_DEG.to_radians());
    let reference = render_bivariate(&sphere, &lights, estimate_brdf);
    let exported = render_bivariate(
        &sphere,
        &lights,
        &Bivariate::reduce(&GltfBrdf(material), grid),
    );
    Ok(Some(Export {
        gltf: "material.gltf".into(),
        mtlx: "material.mtlx".into(),
        material,
        relight_error: exported.relative_rmse(&reference),
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_metal_and_a_plastic_map_to_gltf_and_relight_close_to_the_estimate() {
        // A conductor with F₉₀ = 1 is exactly glTF's metal, and a plastic with F₀ 0.04 and
        // F₉₀ 1 is glTF's dielectric but for the (1 − F) on its diffuse term, which dims the
        // rim: they relight within 1% and 5% of the estimate (measured 0.0 and 3.2%).
        let grid = Grid::default();
        let dir = tempfile::tempdir().unwrap();
        for (m, metallic) in [
            (
                Microfacet::one_lobe([0.0; 3], [0.95, 0.64, 0.54], [1.0; 3], 0.1),
                1.0,
            ),
            (
                Microfacet::one_lobe([0.5, 0.1, 0.1], [0.04; 3], [1.0; 3], 0.2),
                0.0,
            ),
            // A weaker grazing reflection (F₉₀ 0.5): glTF's F₀ is 0.04 · colour · factor.
            (
                Microfacet::one_lobe([0.5, 0.1, 0.1], [0.04; 3], [0.5; 3], 0.2),
                0.0,
            ),
        ] {
            let e = write_exports(dir.path(), "test", &m, &m.bivariate(grid), grid)
                .unwrap()
                .unwrap();
            assert_eq!(e.material.metallic, metallic);
            let tolerance = if metallic == 1.0 { 0.01 } else { 0.05 };
            assert!(e.relight_error < tolerance, "{e:?}");
            let text = std::fs::read_to_string(dir.path().join("material.gltf")).unwrap();
            let json: serde_json::Value = serde_json::from_str(&text).unwrap();
            assert_eq!(json["asset"]["version"], "2.0");
            let mtlx = std::fs::read_to_string(dir.path().join("material.mtlx")).unwrap();
            assert!(mtlx.contains("<open_pbr_surface") && mtlx.contains("specular_roughness"));
        }
    }
}
