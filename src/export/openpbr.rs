//! `material.mtlx`: the fitted material as an OpenPBR Surface (MaterialX 1.39).
//!
//! The shared model's parameters go into OpenPBR's nearest inputs: base colour and
//! metalness, specular weight, white specular colour, roughness (√α) and IOR. OpenPBR's own
//! BRDF differs from glTF's in its details (the dielectric's exact Fresnel instead of
//! Schlick's, albedo-scaled layering of the specular over the diffuse, F82 tint), so the
//! relight error written beside the file is the glTF material's, and says so.

use std::fmt::Write as _;

use super::fit::Fitted;

/// An OpenPBR Surface's base and specular inputs.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct OpenPbrMaterial {
    pub base_color: [f64; 3],
    pub base_metalness: f64,
    pub specular_weight: f64,
    pub specular_roughness: f64,
    pub specular_ior: f64,
}

impl OpenPbrMaterial {
    pub fn from_fit(f: &Fitted) -> OpenPbrMaterial {
        OpenPbrMaterial {
            base_color: f.base_color,
            base_metalness: f.metallic,
            specular_weight: f.specular,
            specular_roughness: f.alpha.sqrt().clamp(0.0, 1.0),
            specular_ior: f.ior(),
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
        let inputs = [
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
