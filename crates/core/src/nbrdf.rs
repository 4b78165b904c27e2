//! Neural BRDF fits (Sztrajman et al. 2021) of the MERL materials, as stored in
//! `merl_nbrdf.json`: a 6→21→21→3 MLP per material.
//!
//! Input x = (h, d): the half vector (sin θh, 0, cos θh) and the difference vector
//! (sin θd cos φd, sin θd sin φd, cos θd). Output rgb = exp(mlp(x)) − 1, in 1/sr with MERL's
//! channel scales already applied. Weight matrices are stored `[in][out]` (Keras kernels).

use std::collections::BTreeMap;
use std::path::Path;

use serde::Deserialize;

use super::brdf::{Azimuth, IsotropicBrdf};
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

    fn eval_row(&self, theta_h: f64, theta_d: f64, phi_d: &[Azimuth], out: &mut [[f64; 3]]) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2, checked just above.
            return unsafe { self.row_avx2(theta_h, theta_d, phi_d, out) };
        }
        self.row(theta_h, theta_d, phi_d, out)
    }
}

/// Cells of a row the network evaluates side by side: one AVX register of f32.
const LANES: usize = 8;

impl NbrdfMaterial {
    /// [`IsotropicBrdf::eval_row`] compiled for AVX2: the lanes run eight wide. Without FMA
    /// each lane rounds as [`NbrdfMaterial::forward`] does, so the row is the same to the
    /// bit (a test checks every cell of a table).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn row_avx2(&self, theta_h: f64, theta_d: f64, phi_d: &[Azimuth], out: &mut [[f64; 3]]) {
        self.row(theta_h, theta_d, phi_d, out)
    }

    /// A row of cells, [`LANES`] at a time: the same inputs as [`IsotropicBrdf::eval_angles`]
    /// (θh's and θd's sines computed once, φd's given), and the network run on each lane.
    #[inline(always)]
    fn row(&self, theta_h: f64, theta_d: f64, phi_d: &[Azimuth], out: &mut [[f64; 3]]) {
        let (sh, ch) = theta_h.sin_cos();
        let (sd, cd) = theta_d.sin_cos();
        let n = phi_d.len().min(out.len());
        for start in (0..n).step_by(LANES) {
            let mut x = [[0f32; LANES]; IN];
            for l in 0..LANES {
                // The last block runs past the row: its spare lanes repeat the last cell.
                let phi = phi_d[(start + l).min(n - 1)];
                let cell = [sh, 0.0, ch, sd * phi.cos, sd * phi.sin, cd];
                for (xi, v) in x.iter_mut().zip(cell) {
                    xi[l] = v as f32;
                }
            }
            let y = self.forward_lanes(&x);
            for (l, v) in out[start..n].iter_mut().take(LANES).enumerate() {
                *v = y.map(|y| (y[l] as f64).max(0.0));
            }
        }
    }

    /// [`NbrdfMaterial::forward`] on [`LANES`] inputs at once, with each lane's sums in the
    /// same order (from −0.0, as `Iterator::sum` of f32 starts), so each lane's result is
    /// `forward`'s to the bit.
    #[inline(always)]
    fn forward_lanes(&self, x: &[[f32; LANES]; IN]) -> [[f32; LANES]; OUT] {
        let h1 = layer(&self.w1, &self.b1, x);
        let h2 = layer(&self.w2, &self.b2, &h1);
        let mut y = [[0f32; LANES]; OUT];
        for (o, y) in y.iter_mut().enumerate() {
            let s = dot_lanes(&self.w3[o], &h2);
            for (y, s) in y.iter_mut().zip(s) {
                *y = (s + self.b3[o]).exp() - 1.0;
            }
        }
        y
    }
}

/// A hidden layer on [`LANES`] inputs: max(W·x + b, 0) per lane.
#[inline(always)]
fn layer<const I: usize>(
    w: &[[f32; I]; HIDDEN],
    b: &[f32; HIDDEN],
    x: &[[f32; LANES]; I],
) -> [[f32; LANES]; HIDDEN] {
    let mut h = [[0f32; LANES]; HIDDEN];
    for (o, h) in h.iter_mut().enumerate() {
        let s = dot_lanes(&w[o], x);
        for (h, s) in h.iter_mut().zip(s) {
            *h = (s + b[o]).max(0.0);
        }
    }
    h
}

/// Σᵢ wᵢ·xᵢ per lane, summed in i's order from −0.0.
#[inline(always)]
fn dot_lanes<const I: usize>(w: &[f32; I], x: &[[f32; LANES]; I]) -> [f32; LANES] {
    let mut s = [-0.0f32; LANES];
    for (w, x) in w.iter().zip(x) {
        for (s, x) in s.iter_mut().zip(x) {
            *s += w * x;
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::merl::{
        phi_d_center, theta_d_center, theta_h_center, MerlBrdf, CELLS, PHI_D_BINS, THETA_D_BINS,
    };

    /// A network with weights spread over ±1 (a fixed pseudo-random sequence), so that some
    /// units are cut at zero and some outputs fall below zero before the clamp.
    fn network() -> NbrdfMaterial {
        let mut state = 0x2545_f491_u32;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            state as f64 / u32::MAX as f64 * 2.0 - 1.0
        };
        let mut matrix = |rows: usize, cols: usize| -> Vec<Vec<f64>> {
            (0..rows)
                .map(|_| (0..cols).map(|_| next()).collect())
                .collect()
        };
        let (w1, w2, w3) = (
            matrix(IN, HIDDEN),
            matrix(HIDDEN, HIDDEN),
            matrix(HIDDEN, OUT),
        );
        let (b1, b2, b3) = (matrix(1, HIDDEN), matrix(1, HIDDEN), matrix(1, OUT));
        let json = serde_json::json!({"materials": {"test": {
            "W1": w1, "b1": b1[0], "W2": w2, "b2": b2[0], "W3": w3, "b3": b3[0],
        }}});
        let set = NbrdfSet::from_json(&json.to_string(), "test network").unwrap();
        set.get("test").unwrap().clone()
    }

    #[test]
    fn a_table_tabulated_by_rows_is_every_cell_evaluated_alone() {
        let m = network();
        let azimuths: Vec<Azimuth> = (0..PHI_D_BINS)
            .map(|k| Azimuth::new(phi_d_center(k)))
            .collect();
        let table = MerlBrdf::tabulate(&m);
        let mut cells = 0;
        for ih in 0..crate::merl::THETA_H_BINS {
            for jd in 0..THETA_D_BINS {
                let (th, td) = (theta_h_center(ih), theta_d_center(jd));
                // The portable lanes too, whatever the CPU picks for `tabulate`.
                let mut row = [[0.0; 3]; PHI_D_BINS];
                m.row(th, td, &azimuths, &mut row);
                for (kp, lanes) in row.iter().enumerate() {
                    let pd = phi_d_center(kp);
                    if !crate::brdf::above_horizon(th, td, pd) {
                        continue;
                    }
                    let alone = m.eval_angles(th, td, pd);
                    let tabulated = [0, 1, 2].map(|c| table.cell(c, ih, jd, kp));
                    assert_eq!(tabulated.map(f64::to_bits), alone.map(f64::to_bits));
                    assert_eq!(lanes.map(f64::to_bits), alone.map(f64::to_bits));
                    cells += 1;
                }
            }
        }
        assert!(cells > CELLS / 2, "{cells} cells above the horizon");
    }
}
