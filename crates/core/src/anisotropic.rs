//! Lambert with one anisotropic GGX/Smith lobe: what the estimate relights with when the photo
//! asks for anisotropy ([`crate::anisotropy`] compares it with an isotropic lobe, and fits it).
//!
//! Its tangent frame is laid on the surface from one axis: at a point of normal n, the lobe's
//! tangent is t = a − (a·n)n normalised and its bitangent n × t. A part brushed along one
//! direction has such a frame; so does a print whose layer lines run around the axis it was
//! printed on (the lobe then smooth along b). Unlike every other model of brdfd, its value
//! depends on the half vector's azimuth about the normal: it is rendered with each pixel's
//! frame ([`crate::render::render_anisotropic`]), and no bivariate or MERL-layout table holds
//! it.

use serde::{Deserialize, Serialize};

use super::brdf::{
    cross, dot, from_rusinkiewicz, normalize, rot_z, scale, sub, tangent_frame, Vec3,
};

/// Lambert plus one anisotropic GGX lobe, per channel:
/// f = diffuse/π + specular · D(h) · G₂(wi, wo) / (4 cos θi cos θo), without Fresnel (the
/// weights hold it, as the comparison fits them).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AnisotropicLobe {
    /// Lambert's albedo per channel.
    pub diffuse: [f64; 3],
    /// The lobe's weight per channel.
    pub specular: [f64; 3],
    /// The axis (world frame, unit) laid on the surface as the lobe's tangent t.
    pub axis: [f64; 3],
    /// The roughness along t (αt).
    pub alpha_t: f64,
    /// The roughness along b = n × t (αb).
    pub alpha_b: f64,
}

impl AnisotropicLobe {
    /// The lobe's tangent and bitangent at a point of (unit) normal `n`. Where the axis is the
    /// normal itself, the frame has no preferred azimuth and any tangent serves.
    pub fn frame(&self, n: Vec3) -> (Vec3, Vec3) {
        frame_at(self.axis, n)
    }

    /// The BRDF's value for directions in the lobe's frame (t, b, n as x, y, z); zero below
    /// either horizon.
    pub fn eval_local(&self, wi: Vec3, wo: Vec3) -> [f64; 3] {
        if wi[2] <= 0.0 || wo[2] <= 0.0 {
            return [0.0; 3];
        }
        let h = normalize([wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2]]);
        let lobe = ggx_d(h, self.alpha_t, self.alpha_b)
            * smith_g2(wi, wo, self.alpha_t, self.alpha_b)
            / (4.0 * wi[2] * wo[2]);
        std::array::from_fn(|c| self.diffuse[c] / std::f64::consts::PI + self.specular[c] * lobe)
    }

    /// The roughness of the smooth direction and of the rough one.
    pub fn smooth_and_rough(&self) -> (f64, f64) {
        (
            self.alpha_t.min(self.alpha_b),
            self.alpha_t.max(self.alpha_b),
        )
    }

    /// Whether the values can be rendered: finite, non-negative weights, roughnesses in
    /// (0, 1] and a unit axis. Says which field is wrong.
    pub fn check(&self) -> Result<(), String> {
        let weights = self.diffuse.iter().chain(&self.specular);
        if !weights.clone().all(|w| w.is_finite() && *w >= 0.0) {
            return Err(format!(
                "weights must be finite and non-negative: diffuse {:?}, specular {:?}",
                self.diffuse, self.specular
            ));
        }
        for (name, a) in [("alpha_t", self.alpha_t), ("alpha_b", self.alpha_b)] {
            if !(a > 0.0 && a <= 1.0) {
                return Err(format!("{name} {a} is not in (0, 1]"));
            }
        }
        let len = dot(self.axis, self.axis).sqrt();
        if !len.is_finite() || (len - 1.0).abs() >= 1e-3 {
            return Err(format!("axis {:?} is not a unit vector", self.axis));
        }
        Ok(())
    }
}

/// `brdf-anisotropic.binary`'s first bytes (docs/formats.md).
pub const TABLE_MAGIC: &[u8; 8] = b"BRDFDAN1";
/// Its cells along θh (square-root spaced, as MERL's), φh, θd and φd.
pub const TABLE_DIMS: [usize; 4] = [32, 32, 32, 32];

/// A lobe tabulated over (θh, φh, θd, φd) in its own tangent frame: the anisotropic
/// counterpart of the MERL table, which cannot hold an azimuth of the half vector.
#[derive(Clone, Debug, PartialEq)]
pub struct AnisotropicTable {
    /// Cells along θh, φh, θd, φd.
    pub dims: [usize; 4],
    /// RGB per cell, θh slowest and φd fastest; −1 where a direction is below the horizon.
    pub values: Vec<[f32; 3]>,
}

impl AnisotropicTable {
    /// The angles at a cell's centre: θh = ((i + ½)/n)²·π/2, φh = (j + ½)/n·π (the lobe is
    /// the same turned half a turn about the normal), θd = (k + ½)/n·π/2, φd = (l + ½)/n·π
    /// (reciprocity: swapping the directions adds π to φd).
    pub fn angles(dims: [usize; 4], [i, j, k, l]: [usize; 4]) -> [f64; 4] {
        use std::f64::consts::{FRAC_PI_2, PI};
        let centre = |i: usize, n: usize| (i as f64 + 0.5) / n as f64;
        [
            centre(i, dims[0]).powi(2) * FRAC_PI_2,
            centre(j, dims[1]) * PI,
            centre(k, dims[2]) * FRAC_PI_2,
            centre(l, dims[3]) * PI,
        ]
    }

    /// The file's bytes: the magic, the four dimensions (u32, little-endian), then each
    /// cell's R, G, B (f32, little-endian).
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(24 + 12 * self.values.len());
        out.extend_from_slice(TABLE_MAGIC);
        for d in self.dims {
            out.extend_from_slice(&(d as u32).to_le_bytes());
        }
        for v in self.values.iter().flatten() {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out
    }

    /// Reads [`AnisotropicTable::to_bytes`]'s layout back; says what is wrong otherwise.
    pub fn from_bytes(bytes: &[u8]) -> Result<AnisotropicTable, String> {
        if bytes.len() < 24 || &bytes[..8] != TABLE_MAGIC {
            return Err("not a brdfd anisotropic table (no BRDFDAN1 header)".into());
        }
        let dims: [usize; 4] = std::array::from_fn(|i| {
            u32::from_le_bytes(bytes[8 + 4 * i..12 + 4 * i].try_into().unwrap()) as usize
        });
        let cells = dims
            .iter()
            .try_fold(1usize, |a, &d| a.checked_mul(d))
            .filter(|&c| c > 0)
            .ok_or_else(|| format!("dimensions {dims:?} hold no cells or too many"))?;
        let body = &bytes[24..];
        if Some(body.len()) != cells.checked_mul(12) {
            return Err(format!(
                "dimensions {dims:?} need {cells} cells of 12 bytes, and the file holds {} bytes after its header",
                body.len()
            ));
        }
        let values = body
            .chunks_exact(12)
            .map(|c| {
                std::array::from_fn(|k| f32::from_le_bytes(c[4 * k..4 * k + 4].try_into().unwrap()))
            })
            .collect();
        Ok(AnisotropicTable { dims, values })
    }
}

impl AnisotropicLobe {
    /// The lobe on [`TABLE_DIMS`]'s cells, φh measured from its tangent t.
    pub fn tabulate(&self) -> AnisotropicTable {
        use rayon::prelude::*;
        let dims = TABLE_DIMS;
        let cells = dims.iter().product::<usize>();
        let values = (0..cells)
            .into_par_iter()
            .map(|index| {
                let l = index % dims[3];
                let k = (index / dims[3]) % dims[2];
                let j = (index / (dims[3] * dims[2])) % dims[1];
                let i = index / (dims[3] * dims[2] * dims[1]);
                let [theta_h, phi_h, theta_d, phi_d] = AnisotropicTable::angles(dims, [i, j, k, l]);
                let (wi, wo) = from_rusinkiewicz(theta_h, theta_d, phi_d);
                let (wi, wo) = (rot_z(wi, phi_h), rot_z(wo, phi_h));
                if wi[2] <= 0.0 || wo[2] <= 0.0 {
                    return [-1.0; 3];
                }
                self.eval_local(wi, wo).map(|x| x as f32)
            })
            .collect();
        AnisotropicTable { dims, values }
    }
}

/// The tangent t = a − (a·n)n (normalised) and bitangent n × t laid on a surface of normal
/// `n` from the axis `a`; any frame about n where the axis is the normal.
pub fn frame_at(axis: Vec3, n: Vec3) -> (Vec3, Vec3) {
    let t = sub(axis, scale(n, dot(axis, n)));
    let len = dot(t, t).sqrt();
    let t = if len > 1e-6 {
        scale(t, 1.0 / len)
    } else {
        tangent_frame(n).0
    };
    (t, cross(n, t))
}

/// The anisotropic GGX distribution of a unit half vector in the lobe's frame.
fn ggx_d(h: Vec3, at: f64, ab: f64) -> f64 {
    let k = h[0] * h[0] / (at * at) + h[1] * h[1] / (ab * ab) + h[2] * h[2];
    1.0 / (std::f64::consts::PI * at * ab * k * k)
}

/// Smith's height-correlated masking and shadowing, 1 / (1 + Λ(wi) + Λ(wo)).
fn smith_g2(wi: Vec3, wo: Vec3, at: f64, ab: f64) -> f64 {
    let lambda = |w: Vec3| {
        ((1.0 + (at * at * w[0] * w[0] + ab * ab * w[1] * w[1]) / (w[2] * w[2])).sqrt() - 1.0) / 2.0
    };
    1.0 / (1.0 + lambda(wi) + lambda(wo))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lobe(at: f64, ab: f64) -> AnisotropicLobe {
        AnisotropicLobe {
            diffuse: [0.0; 3],
            specular: [1.0; 3],
            axis: [1.0, 0.0, 0.0],
            alpha_t: at,
            alpha_b: ab,
        }
    }

    /// ∫ D(h) cos θh dω = 1: the distribution is a density of the projected microfacet area.
    #[test]
    fn the_distribution_projects_to_unit_area() {
        for (at, ab) in [(0.1, 0.1), (0.06, 0.24), (0.3, 0.8)] {
            let (nt, np) = (2000, 400);
            let mut sum = 0.0;
            for i in 0..nt {
                // θ on a grid fine near the pole, where a sharp lobe lies.
                let u = (i as f64 + 0.5) / nt as f64;
                let theta = u * u * std::f64::consts::FRAC_PI_2;
                let dtheta = 2.0 * u * std::f64::consts::FRAC_PI_2 / nt as f64;
                for j in 0..np {
                    let phi = (j as f64 + 0.5) / np as f64 * std::f64::consts::TAU;
                    let h = [
                        theta.sin() * phi.cos(),
                        theta.sin() * phi.sin(),
                        theta.cos(),
                    ];
                    sum += ggx_d(h, at, ab)
                        * theta.cos()
                        * theta.sin()
                        * dtheta
                        * std::f64::consts::TAU
                        / np as f64;
                }
            }
            assert!((sum - 1.0).abs() < 0.01, "α {at}/{ab}: {sum}");
        }
    }

    #[test]
    fn a_lobe_is_as_wide_along_its_rough_direction_as_its_roughness_says() {
        let l = lobe(0.05, 0.2);
        let up = [0.0, 0.0, 1.0];
        // Tilt the light by the same angle along t and along b: the lobe falls faster along t
        // (about 3.5 times, by D alone).
        let tilt = |x: f64, y: f64| normalize([x, y, 1.0]);
        let along_t = l.eval_local(tilt(0.1, 0.0), up)[0];
        let along_b = l.eval_local(tilt(0.0, 0.1), up)[0];
        assert!(along_b > 3.0 * along_t, "{along_t} {along_b}");
        // Swapping the roughnesses swaps the directions.
        let swapped = lobe(0.2, 0.05);
        let a = swapped.eval_local(tilt(0.1, 0.0), up)[0];
        assert!((a - along_b).abs() < 1e-9 * a, "{a} {along_b}");
    }

    #[test]
    fn the_brdf_is_zero_below_either_horizon() {
        let mut l = lobe(0.07, 0.3);
        l.diffuse = [0.2, 0.3, 0.4];
        let up = normalize([-0.5, 0.4, 0.6]);
        assert!(l.eval_local([0.0, 0.6, 0.8], up)[0] > 0.0);
        assert_eq!(l.eval_local([0.0, 0.6, -0.8], up), [0.0; 3]);
        assert_eq!(l.eval_local(up, [0.0, 0.6, -0.8]), [0.0; 3]);
    }

    #[test]
    fn the_frame_lays_the_axis_on_the_surface() {
        let n = normalize([0.0, 0.6, 0.8]);
        let (t, b) = frame_at([1.0, 1.0, 0.0].map(|x: f64| x / 2f64.sqrt()), n);
        assert!(dot(t, n).abs() < 1e-12 && dot(b, n).abs() < 1e-12);
        assert!(dot(t, [1.0, 0.0, 0.0]) > 0.0, "{t:?}");
        // The axis along the normal: still a frame.
        let (t, b) = frame_at(n, n);
        assert!((dot(t, t) - 1.0).abs() < 1e-12 && dot(t, b).abs() < 1e-12);
    }

    #[test]
    fn the_table_holds_the_lobe_at_its_cells_and_reads_back() {
        let mut l = lobe(0.24, 0.06);
        l.diffuse = [0.02, 0.03, 0.04];
        let table = l.tabulate();
        assert_eq!(table.values.len(), TABLE_DIMS.iter().product::<usize>());
        let back = AnisotropicTable::from_bytes(&table.to_bytes()).unwrap();
        assert_eq!(back, table);
        // Cells checked against the lobe, evaluated from the cell's directions built here
        // from the half vector and the difference vector.
        let dims = TABLE_DIMS;
        let (mut above, mut below) = (0, 0);
        for index in (0..table.values.len()).step_by(997) {
            let cell = [
                index / (dims[1] * dims[2] * dims[3]),
                (index / (dims[2] * dims[3])) % dims[1],
                (index / dims[3]) % dims[2],
                index % dims[3],
            ];
            let [th, ph, td, pd] = AnisotropicTable::angles(dims, cell);
            let h = [th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos()];
            // d in the half vector's frame, turned into the world's: wi = rotate d by θh
            // about the axis n × h's direction (y turned by φh), then by φh about z.
            let d = [td.sin() * pd.cos(), td.sin() * pd.sin(), td.cos()];
            let tilted = [
                d[0] * th.cos() + d[2] * th.sin(),
                d[1],
                -d[0] * th.sin() + d[2] * th.cos(),
            ];
            let wi = rot_z(tilted, ph);
            let wo = sub(scale(h, 2.0 * dot(wi, h)), wi);
            let v = table.values[index];
            if wi[2] <= 0.0 || wo[2] <= 0.0 {
                assert_eq!(v, [-1.0; 3]);
                below += 1;
                continue;
            }
            above += 1;
            let f = l.eval_local(wi, wo);
            for c in 0..3 {
                assert!(
                    ((v[c] as f64) - f[c]).abs() <= 1e-5 * f[c].max(1.0),
                    "{cell:?}: {v:?} {f:?}"
                );
            }
        }
        assert!(above > 500 && below > 50, "{above} {below}");
        assert!(AnisotropicTable::from_bytes(b"BRDFDAN1").is_err());
        let mut short = table.to_bytes();
        short.pop();
        assert!(AnisotropicTable::from_bytes(&short)
            .unwrap_err()
            .contains("after its header"));
    }

    #[test]
    fn bad_values_are_named() {
        let mut l = lobe(0.1, 0.2);
        assert!(l.check().is_ok());
        l.alpha_b = 0.0;
        assert!(l.check().unwrap_err().contains("alpha_b"));
        l.alpha_b = 0.2;
        l.specular[1] = f64::NAN;
        assert!(l.check().unwrap_err().contains("weights"));
        l.specular[1] = 1.0;
        l.axis = [2.0, 0.0, 0.0];
        assert!(l.check().unwrap_err().contains("axis"));
    }
}
