//! Neural BRDF fits (Sztrajman et al. 2021) of the MERL materials, as stored in
//! `merl_nbrdf.json`: a 6→21→21→3 MLP per material.
//!
//! Input x = (h, d): the half vector (sin θh, 0, cos θh) and the difference vector
//! (sin θd cos φd, sin θd sin φd, cos θd). Output rgb = exp(mlp(x)) − 1, in 1/sr with MERL's
//! channel scales already applied. Weight matrices are stored `[in][out]` (Keras kernels).

use std::collections::BTreeMap;
use std::path::Path;

use serde::Deserialize;

use super::brdf::IsotropicBrdf;
use super::error::{CoreError, Result};

const IN: usize = 6;
const HIDDEN: usize = 21;
const OUT: usize = 3;

#[derive(Deserialize)]
struct File {
    materials: BTreeMap<String, RawMaterial>,
}

#[derive(Deserialize)]
#[serde(rename_all = "UPPERCASE")]
struct RawMaterial {
    w1: Vec<Vec<f64>>,
    #[serde(rename = "b1")]
    b1: Vec<f64>,
    w2: Vec<Vec<f64>>,
    #[serde(rename = "b2")]
    b2: Vec<f64>,
    w3: Vec<Vec<f64>>,
    #[serde(rename = "b3")]
    b3: Vec<f64>,
}

/// One material's fitted network, with weights transposed to `[out][in]` for the dot products.
#[derive(Clone)]
pub struct NbrdfMaterial {
    pub name: String,
    w1: [[f32; IN]; HIDDEN],
    b1: [f32; HIDDEN],
    w2: [[f32; HIDDEN]; HIDDEN],
    b2: [f32; HIDDEN],
    w3: [[f32; HIDDEN]; OUT],
    b3: [f32; OUT],
}

/// All materials of an NBRDF file, by name.
pub struct NbrdfSet {
    pub materials: BTreeMap<String, NbrdfMaterial>,
}

fn transpose<const I: usize, const O: usize>(
    m: &[Vec<f64>],
    what: &str,
    field: &str,
) -> Result<[[f32; I]; O]> {
    if m.len() != I || m.iter().any(|row| row.len() != O) {
        return Err(CoreError::format(
            what,
            format!("field {field} must be {I}×{O}"),
        ));
    }
    let mut out = [[0f32; I]; O];
    for (i, row) in m.iter().enumerate() {
        for (o, v) in row.iter().enumerate() {
            out[o][i] = *v as f32;
        }
    }
    Ok(out)
}

fn vector<const N: usize>(v: &[f64], what: &str, field: &str) -> Result<[f32; N]> {
    if v.len() != N {
        return Err(CoreError::format(
            what,
            format!("field {field} must have {N} values, found {}", v.len()),
        ));
    }
    let mut out = [0f32; N];
    for (o, x) in out.iter_mut().zip(v) {
        *o = *x as f32;
    }
    Ok(out)
}

impl NbrdfSet {
    pub fn read(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| CoreError::io(path, e))?;
        Self::from_json(&text, &path.display().to_string())
    }

    pub fn from_json(text: &str, what: &str) -> Result<Self> {
        let file: File = serde_json::from_str(text).map_err(|e| {
            CoreError::format(
                what,
                format!(
                    "not an NBRDF file (line {}, column {}): {e}",
                    e.line(),
                    e.column()
                ),
            )
        })?;
        let mut materials = BTreeMap::new();
        for (name, raw) in file.materials {
            let w = format!("{what}: material {name}");
            materials.insert(
                name.clone(),
                NbrdfMaterial {
                    name,
                    w1: transpose::<IN, HIDDEN>(&raw.w1, &w, "W1")?,
                    b1: vector::<HIDDEN>(&raw.b1, &w, "b1")?,
                    w2: transpose::<HIDDEN, HIDDEN>(&raw.w2, &w, "W2")?,
                    b2: vector::<HIDDEN>(&raw.b2, &w, "b2")?,
                    w3: transpose::<HIDDEN, OUT>(&raw.w3, &w, "W3")?,
                    b3: vector::<OUT>(&raw.b3, &w, "b3")?,
                },
            );
        }
        if materials.is_empty() {
            return Err(CoreError::format(what, "the file lists no materials"));
        }
        Ok(NbrdfSet { materials })
    }

    /// The materials' names, in order.
    pub fn names(&self) -> Vec<&str> {
        self.materials.keys().map(String::as_str).collect()
    }

    pub fn get(&self, name: &str) -> Result<&NbrdfMaterial> {
        self.materials.get(name).ok_or_else(|| {
            CoreError::Invalid(format!(
                "unknown material {name:?}; the NBRDF file has: {}",
                self.materials
                    .keys()
                    .cloned()
                    .collect::<Vec<_>>()
                    .join(", ")
            ))
        })
    }
}

impl NbrdfMaterial {
    fn forward(&self, x: [f32; IN]) -> [f32; OUT] {
        let mut h1 = [0f32; HIDDEN];
        for (o, h) in h1.iter_mut().enumerate() {
            let s: f32 = self.w1[o].iter().zip(&x).map(|(w, v)| w * v).sum();
            *h = (s + self.b1[o]).max(0.0);
        }
        let mut h2 = [0f32; HIDDEN];
        for (o, h) in h2.iter_mut().enumerate() {
            let s: f32 = self.w2[o].iter().zip(&h1).map(|(w, v)| w * v).sum();
            *h = (s + self.b2[o]).max(0.0);
        }
        let mut y = [0f32; OUT];
        for (o, v) in y.iter_mut().enumerate() {
            let s: f32 = self.w3[o].iter().zip(&h2).map(|(w, v)| w * v).sum();
            *v = (s + self.b3[o]).exp() - 1.0;
        }
        y
    }
}

impl IsotropicBrdf for NbrdfMaterial {
    fn eval_angles(&self, theta_h: f64, theta_d: f64, phi_d: f64) -> [f64; 3] {
        let (sh, ch) = theta_h.sin_cos();
        let (sd, cd) = theta_d.sin_cos();
        let (sp, cp) = phi_d.sin_cos();
        let x = [sh, 0.0, ch, sd * cp, sd * sp, cd].map(|v| v as f32);
        // exp(·) − 1 can dip just below zero; a BRDF cannot.
        self.forward(x).map(|v| (v as f64).max(0.0))
    }
}
