//! `material.mtlx`: the fitted material as an OpenPBR Surface (MaterialX 1.39).
//!
//! The shared model's parameters go into OpenPBR's nearest inputs: base colour and
//! metalness, specular weight, white specular colour, roughness (√α) and IOR, and the clear
//! coat's weight, roughness and IOR (1.5, glTF's). OpenPBR's own BRDF differs from glTF's in
//! its details (the dielectric's exact Fresnel instead of Schlick's, albedo-scaled layering of
//! the specular over the diffuse and of the coat over the base, F82 tint), so the relight error
//! written beside the file is the glTF material's, and says so. `coat_darkening` is 0: glTF's
//! coat dims the base by its Fresnel alone, not by light trapped inside the coat.
//!
//! An anisotropic lobe the estimate chose goes into `specular_roughness_anisotropy`, with
//! OpenPBR's own mapping (αt = r²·√(2/(1 + (1 − a)²)) along the geometry's tangent,
//! αb = (1 − a)·αt across it): the highlight stretches along the tangent, so the mesh's
//! tangents must run across the grain, as `material.gltf`'s `TANGENT` does.

use std::fmt::Write as _;

use brdfd_core::anisotropic::AnisotropicLobe;

use super::fit::Fitted;

/// An OpenPBR Surface's base and specular inputs.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct OpenPbrMaterial {
    pub base_color: [f64; 3],
    pub base_metalness: f64,
    pub specular_weight: f64,
    pub specular_roughness: f64,
    pub specular_ior: f64,
    pub coat_weight: f64,
    pub coat_roughness: f64,
    /// 0: isotropic (and not written).
    pub specular_roughness_anisotropy: f64,
}

/// The coat's IOR: glTF's `KHR_materials_clearcoat` fixes 1.5 (F₀ 0.04).
const COAT_IOR: f64 = 1.5;

impl OpenPbrMaterial {
    pub fn from_fit(f: &Fitted) -> OpenPbrMaterial {
        OpenPbrMaterial {
            base_color: f.base_color,
            base_metalness: f.metallic,
            specular_weight: f.specular,
            specular_roughness: f.alpha.sqrt().clamp(0.0, 1.0),
            specular_ior: f.ior(),
            coat_weight: f.coat,
            coat_roughness: f.coat_alpha.sqrt().clamp(0.0, 1.0),
            specular_roughness_anisotropy: 0.0,
        }
    }

    /// The material with the roughnesses of an anisotropic lobe, through OpenPBR's mapping.
    pub fn with_lobe(self, lobe: &AnisotropicLobe) -> OpenPbrMaterial {
        let (smooth, rough) = lobe.smooth_and_rough();
        let a = (1.0 - smooth / rough).clamp(0.0, 1.0);
        let r2 = rough / (2.0 / (1.0 + (1.0 - a) * (1.0 - a))).sqrt();
        OpenPbrMaterial {
            specular_roughness: r2.sqrt().clamp(0.0, 1.0),
            specular_roughness_anisotropy: a,
            ..self
        }
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
            ("specular_color", "color3", c3([1.0; 3])),
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
