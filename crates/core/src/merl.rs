//! The MERL BRDF database's `.binary` format (Matusik et al. 2003): reading, writing, and
//! tabulating any isotropic BRDF into it.
//!
//! Layout: three little-endian i32 (90, 90, 180), then 3 × 1,458,000 f64 stored channel-planar
//! (all R, then G, then B), cell index `φd + 180·θd + 180·90·θh`. Stored values are divided by
//! the channel scale factors below; negative values mark cells that were not measured.
//! This module does not interpolate: a lookup returns its cell, as MERL's reference code does.

use std::path::Path;

use super::brdf::{above_horizon, Azimuth, IsotropicBrdf};
use super::error::{CoreError, Result};

pub const THETA_H_BINS: usize = 90;
pub const THETA_D_BINS: usize = 90;
pub const PHI_D_BINS: usize = 180;
pub const CELLS: usize = THETA_H_BINS * THETA_D_BINS * PHI_D_BINS;
const HEADER_BYTES: usize = 12;
/// The exact size of a valid file: the header plus three channel planes of f64.
pub const FILE_BYTES: usize = HEADER_BYTES + 3 * CELLS * 8;
/// MERL's per-channel scale factors: stored value × scale = BRDF in 1/sr.
pub const CHANNEL_SCALE: [f64; 3] = [1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0];
const HALF_PI: f64 = std::f64::consts::FRAC_PI_2;

/// θh bin: square-root spacing, so the specular peak near θh = 0 gets most of the bins.
pub(crate) fn theta_h_bin(theta_h: f64) -> usize {
    if theta_h <= 0.0 {
        return 0;
    }
    (((theta_h / HALF_PI).sqrt() * THETA_H_BINS as f64) as usize).min(THETA_H_BINS - 1)
}

pub(crate) fn theta_d_bin(theta_d: f64) -> usize {
    ((theta_d.max(0.0) / HALF_PI * THETA_D_BINS as f64) as usize).min(THETA_D_BINS - 1)
}

/// φd bin over [0, π): reciprocity maps φd and φd + π to the same value.
pub(crate) fn phi_d_bin(phi_d: f64) -> usize {
    let mut p = phi_d.rem_euclid(2.0 * std::f64::consts::PI);
    if p >= std::f64::consts::PI {
        p -= std::f64::consts::PI;
    }
    ((p / std::f64::consts::PI * PHI_D_BINS as f64) as usize).min(PHI_D_BINS - 1)
}

/// Centre angles of a cell, inverse of the bin functions.
pub(crate) fn theta_h_center(i: usize) -> f64 {
    let s = (i as f64 + 0.5) / THETA_H_BINS as f64;
    s * s * HALF_PI
}

pub fn theta_d_center(j: usize) -> f64 {
    (j as f64 + 0.5) / THETA_D_BINS as f64 * HALF_PI
}

pub(crate) fn phi_d_center(k: usize) -> f64 {
    (k as f64 + 0.5) / PHI_D_BINS as f64 * std::f64::consts::PI
}

/// Each φd cell centre, with its sine and cosine.
fn phi_d_centres() -> &'static [Azimuth; PHI_D_BINS] {
    static CENTRES: std::sync::OnceLock<[Azimuth; PHI_D_BINS]> = std::sync::OnceLock::new();
    CENTRES.get_or_init(|| std::array::from_fn(|k| Azimuth::new(phi_d_center(k))))
}

pub(crate) fn cell_index(ih: usize, jd: usize, kp: usize) -> usize {
    kp + PHI_D_BINS * (jd + THETA_D_BINS * ih)
}

/// A full (θh, θd, φd) table in 1/sr. Negative entries are cells without a measurement.
#[derive(Clone)]
pub struct MerlBrdf {
    /// Channel-planar: `values[c * CELLS + cell_index(..)]`, already multiplied by the scale.
    values: Vec<f64>,
}

impl MerlBrdf {
    /// Reads a `.binary` file. Errors name the file and what is wrong with it.
    pub fn read(path: &Path) -> Result<Self> {
        let bytes = std::fs::read(path).map_err(|e| CoreError::io(path, e))?;
        Self::from_bytes(&bytes, &path.display().to_string())
    }

    pub fn from_bytes(bytes: &[u8], what: &str) -> Result<Self> {
        if bytes.len() < HEADER_BYTES {
            return Err(CoreError::format(
                what,
                format!(
                    "truncated MERL file: {} bytes, the header alone is {HEADER_BYTES}",
                    bytes.len()
                ),
            ));
        }
        let dims: Vec<i32> = bytes[..HEADER_BYTES]
            .chunks_exact(4)
            .map(|c| i32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        if dims != [90, 90, 180] {
            return Err(CoreError::format(
                what,
                format!(
                    "MERL header says {}×{}×{}, expected 90×90×180 (is this a MERL .binary file?)",
                    dims[0], dims[1], dims[2]
                ),
            ));
        }
        if bytes.len() != FILE_BYTES {
            let kind = if bytes.len() < FILE_BYTES {
                "truncated"
            } else {
                "oversized"
            };
            return Err(CoreError::format(
                what,
                format!(
                    "{kind} MERL file: {} bytes, a 90×90×180 table is exactly {FILE_BYTES} bytes",
                    bytes.len()
                ),
            ));
        }
        let mut values = Vec::with_capacity(3 * CELLS);
        for (i, chunk) in bytes[HEADER_BYTES..].chunks_exact(8).enumerate() {
            let raw = f64::from_le_bytes(chunk.try_into().expect("chunks_exact(8)"));
            if !raw.is_finite() {
                return Err(CoreError::format(
                    what,
                    format!("non-finite value at byte offset {}", HEADER_BYTES + 8 * i),
                ));
            }
            values.push(raw * CHANNEL_SCALE[i / CELLS]);
        }
        Ok(MerlBrdf { values })
    }

    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(FILE_BYTES);
        for d in [90i32, 90, 180] {
            out.extend_from_slice(&d.to_le_bytes());
        }
        for (i, v) in self.values.iter().enumerate() {
            out.extend_from_slice(&(v / CHANNEL_SCALE[i / CELLS]).to_le_bytes());
        }
        out
    }

    pub fn write(&self, path: &Path) -> Result<()> {
        std::fs::write(path, self.to_bytes()).map_err(|e| CoreError::io(path, e))
    }

    /// Tabulates `source` at every cell centre. Cells whose light or view direction lies below
    /// the horizon are marked not measured (-1 in stored units), as in MERL's own files.
    pub fn tabulate(source: &dyn IsotropicBrdf) -> Self {
        use rayon::prelude::*;
        let not_measured = CHANNEL_SCALE.map(|s| -s);
        let mut values = vec![0.0; 3 * CELLS];
        let (r, rest) = values.split_at_mut(CELLS);
        let (g, b) = rest.split_at_mut(CELLS);
        // A row of the table (θh, θd) at a time: cells of a row are contiguous in each
        // channel's plane, and a source evaluates a row faster than its cells one by one.
        r.par_chunks_mut(PHI_D_BINS)
            .zip(g.par_chunks_mut(PHI_D_BINS))
            .zip(b.par_chunks_mut(PHI_D_BINS))
            .enumerate()
            .for_each(|(row, ((r, g), b))| {
                let (ih, jd) = (row / THETA_D_BINS, row % THETA_D_BINS);
                let (th, td) = (theta_h_center(ih), theta_d_center(jd));
                let mut rgb = [[0.0; 3]; PHI_D_BINS];
                source.eval_row(th, td, phi_d_centres(), &mut rgb);
                for (kp, v) in rgb.iter().enumerate() {
                    let v = if above_horizon(th, td, phi_d_center(kp)) {
                        v
                    } else {
                        &not_measured
                    };
                    (r[kp], g[kp], b[kp]) = (v[0], v[1], v[2]);
                }
            });
        MerlBrdf { values }
    }

    /// The whole table, channel-planar (see the field): what identifies a material.
    pub fn values(&self) -> &[f64] {
        &self.values
    }

    /// The raw cell value (negative: not measured).
    pub fn cell(&self, channel: usize, ih: usize, jd: usize, kp: usize) -> f64 {
        self.values[channel * CELLS + cell_index(ih, jd, kp)]
    }

    /// Builds a table from a function of the cell's indices, for expanding reduced BRDFs.
    pub fn from_cells(f: impl Fn(usize, usize, usize) -> [f64; 3]) -> Self {
        let mut values = vec![0.0; 3 * CELLS];
        for ih in 0..THETA_H_BINS {
            for jd in 0..THETA_D_BINS {
                for kp in 0..PHI_D_BINS {
                    let rgb = f(ih, jd, kp);
                    let idx = cell_index(ih, jd, kp);
                    for c in 0..3 {
                        values[c * CELLS + idx] = rgb[c];
                    }
                }
            }
        }
        MerlBrdf { values }
    }
}

impl IsotropicBrdf for MerlBrdf {
    fn eval_angles(&self, theta_h: f64, theta_d: f64, phi_d: f64) -> [f64; 3] {
        let idx = cell_index(theta_h_bin(theta_h), theta_d_bin(theta_d), phi_d_bin(phi_d));
        let mut out = [0.0; 3];
        for (c, o) in out.iter_mut().enumerate() {
            *o = self.values[c * CELLS + idx].max(0.0);
        }
        out
    }

    fn measured(&self, theta_h: f64, theta_d: f64, phi_d: f64) -> bool {
        let idx = cell_index(theta_h_bin(theta_h), theta_d_bin(theta_d), phi_d_bin(phi_d));
        self.values[idx] >= 0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bins_invert_centres() {
        for i in 0..90 {
            assert_eq!(theta_h_bin(theta_h_center(i)), i);
            assert_eq!(theta_d_bin(theta_d_center(i)), i);
        }
        for k in 0..180 {
            assert_eq!(phi_d_bin(phi_d_center(k)), k);
            assert_eq!(phi_d_bin(phi_d_center(k) + std::f64::consts::PI), k);
            assert_eq!(phi_d_bin(phi_d_center(k) - std::f64::consts::PI), k);
        }
    }

    #[test]
    fn rejects_wrong_header_and_truncation() {
        let mut bytes = vec![0u8; 12];
        bytes[0..4].copy_from_slice(&90i32.to_le_bytes());
        bytes[4..8].copy_from_slice(&90i32.to_le_bytes());
        bytes[8..12].copy_from_slice(&90i32.to_le_bytes());
        let e = MerlBrdf::from_bytes(&bytes, "x.binary")
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("x.binary") && e.contains("90×90×90"), "{e}");
        bytes[8..12].copy_from_slice(&180i32.to_le_bytes());
        bytes.extend_from_slice(&[0u8; 80]);
        let e = MerlBrdf::from_bytes(&bytes, "x.binary")
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("truncated") && e.contains("92 bytes"), "{e}");
        let e = MerlBrdf::from_bytes(&[1, 2], "y.binary")
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("y.binary") && e.contains("truncated"), "{e}");
    }
}
