//! The isotropic BRDF interface that every source implements (MERL tables, NBRDF fits,
//! bivariate reductions, estimates), and Rusinkiewicz's change of variables.
//!
//! Frame: the surface's local frame has the normal along +Z. Both `wi` (toward the light) and
//! `wo` (toward the camera) point away from the surface. Angles are in radians. Values are
//! BRDF values in 1/sr, linear RGB.

/// A 3-vector in f64, used for directions.
pub type Vec3 = [f64; 3];

/// An azimuth φd with its sine and cosine, worked out once for every row of a table that
/// reads it ([`IsotropicBrdf::eval_row`]).
#[derive(Clone, Copy, Debug)]
pub struct Azimuth {
    pub angle: f64,
    pub sin: f64,
    pub cos: f64,
}

impl Azimuth {
    pub fn new(angle: f64) -> Azimuth {
        let (sin, cos) = angle.sin_cos();
        Azimuth { angle, sin, cos }
    }
}

/// An isotropic, reciprocal BRDF.
pub trait IsotropicBrdf: Sync {
    /// RGB value at Rusinkiewicz angles (θh, θd, φd). Cells a measurement did not cover
    /// return zero, as light there contributes nothing measurable.
    fn eval_angles(&self, theta_h: f64, theta_d: f64, phi_d: f64) -> [f64; 3];

    /// The values at (θh, θd) and each of `phi_d`, into `out` (one per azimuth), for
    /// tabulating a row at a time ([`crate::merl::MerlBrdf::tabulate`]): what
    /// [`IsotropicBrdf::eval_angles`] gives there, to the bit. Cells below the horizon are
    /// left to the caller, which marks them not measured.
    fn eval_row(&self, theta_h: f64, theta_d: f64, phi_d: &[Azimuth], out: &mut [[f64; 3]]) {
        for (phi, v) in phi_d.iter().zip(out) {
            if above_horizon(theta_h, theta_d, phi.angle) {
                *v = self.eval_angles(theta_h, theta_d, phi.angle);
            }
        }
    }

    /// Whether the source holds a value at these angles. Analytic and fitted sources cover
    /// every cell with both directions above the horizon; measured tables may have holes.
    fn measured(&self, theta_h: f64, theta_d: f64, phi_d: f64) -> bool {
        above_horizon(theta_h, theta_d, phi_d)
    }

    /// RGB value for a pair of local directions (normal = +Z). Zero below either horizon.
    fn eval_dirs(&self, wi: Vec3, wo: Vec3) -> [f64; 3] {
        if wi[2] <= 0.0 || wo[2] <= 0.0 {
            return [0.0; 3];
        }
        let (th, td, pd) = to_rusinkiewicz(wi, wo);
        self.eval_angles(th, td, pd)
    }
}

pub fn dot(a: Vec3, b: Vec3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

pub fn cross(a: Vec3, b: Vec3) -> Vec3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

pub fn normalize(a: Vec3) -> Vec3 {
    let n = dot(a, a).sqrt();
    if n == 0.0 {
        return a;
    }
    [a[0] / n, a[1] / n, a[2] / n]
}

pub fn add(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

pub fn sub(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

pub fn scale(a: Vec3, s: f64) -> Vec3 {
    [a[0] * s, a[1] * s, a[2] * s]
}

/// Angle between two unit vectors, accurate near 0 and π (unlike `acos` of the dot product).
pub(crate) fn angle_between(a: Vec3, b: Vec3) -> f64 {
    cross(a, b)
        .iter()
        .map(|c| c * c)
        .sum::<f64>()
        .sqrt()
        .atan2(dot(a, b))
}

/// Rotate `v` about +Z by `angle`.
pub(crate) fn rot_z(v: Vec3, angle: f64) -> Vec3 {
    let (s, c) = angle.sin_cos();
    [c * v[0] - s * v[1], s * v[0] + c * v[1], v[2]]
}

/// Rotate `v` about +Y by `angle` (right-handed, as a map's yaw turns it).
pub(crate) fn rot_y(v: Vec3, angle: f64) -> Vec3 {
    let (s, c) = angle.sin_cos();
    [c * v[0] + s * v[2], v[1], -s * v[0] + c * v[2]]
}

/// (θh, θd, φd) for local unit directions `wi`, `wo` (Rusinkiewicz 1998): the half vector's
/// polar angle, then `wi` expressed in the frame where the half vector is the pole.
pub(crate) fn to_rusinkiewicz(wi: Vec3, wo: Vec3) -> (f64, f64, f64) {
    let h = normalize(add(wi, wo));
    let theta_h = angle_between(h, [0.0, 0.0, 1.0]);
    let phi_h = h[1].atan2(h[0]);
    let d = rot_y(rot_z(wi, -phi_h), -theta_h);
    let theta_d = angle_between(d, [0.0, 0.0, 1.0]);
    let phi_d = d[1].atan2(d[0]);
    (theta_h, theta_d, phi_d)
}

/// What an isotropic microfacet BRDF is a function of, for a pair of directions above the
/// horizon: cos θh, cos θd, and each direction's cosine to the normal.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cosines {
    pub h: f64,
    pub d: f64,
    pub i: f64,
    pub o: f64,
}

impl Cosines {
    /// From local directions (normal = +Z), through the halfway vector: a renderer asks for
    /// directions, and going through Rusinkiewicz's angles (two arctangents, an arccosine and
    /// a sine and cosine back) cost a GGX lobe three times the lobe itself. `None` below
    /// either horizon.
    pub fn of_dirs(wi: Vec3, wo: Vec3) -> Option<Cosines> {
        if wi[2] <= 0.0 || wo[2] <= 0.0 {
            return None;
        }
        let h = normalize(add(wi, wo));
        Some(Cosines {
            h: h[2],
            d: dot(wi, h),
            i: wi[2],
            o: wo[2],
        })
    }

    /// From Rusinkiewicz's angles; `None` below either horizon.
    pub fn of_angles(theta_h: f64, theta_d: f64, phi_d: f64) -> Option<Cosines> {
        let (wi, wo) = from_rusinkiewicz(theta_h, theta_d, phi_d);
        (wi[2] > 0.0 && wo[2] > 0.0).then(|| Cosines {
            h: theta_h.cos(),
            d: theta_d.cos(),
            i: wi[2],
            o: wo[2],
        })
    }
}

/// The inverse of `to_rusinkiewicz` with φh = 0: returns (wi, wo).
pub fn from_rusinkiewicz(theta_h: f64, theta_d: f64, phi_d: f64) -> (Vec3, Vec3) {
    let h = [theta_h.sin(), 0.0, theta_h.cos()];
    let d = [
        theta_d.sin() * phi_d.cos(),
        theta_d.sin() * phi_d.sin(),
        theta_d.cos(),
    ];
    let wi = rot_y(d, theta_h);
    let wo = sub(scale(h, 2.0 * dot(wi, h)), wi);
    (wi, wo)
}

/// Whether the light and view directions of (θh, θd, φd) are both above the horizon: the
/// cells a gonioreflectometer can measure.
pub(crate) fn above_horizon(theta_h: f64, theta_d: f64, phi_d: f64) -> bool {
    let (wi, wo) = from_rusinkiewicz(theta_h, theta_d, phi_d);
    wi[2] > 0.0 && wo[2] > 0.0
}

/// `count` directions spread evenly over the sphere (a Fibonacci lattice about +Y): each stands
/// for an equal solid angle, 4π/`count`, and no two lie on one line of latitude.
pub fn fibonacci_sphere(count: usize) -> Vec<Vec3> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..count)
        .map(|i| {
            let y = 1.0 - 2.0 * (i as f64 + 0.5) / count as f64;
            let r = (1.0 - y * y).sqrt();
            let phi = golden * i as f64;
            [r * phi.cos(), y, r * phi.sin()]
        })
        .collect()
}

/// `count` directions spread evenly over the half sphere z ≥ 0 (a Fibonacci lattice about +Z),
/// each for a solid angle of 2π/`count`.
pub fn half_sphere(count: usize) -> Vec<Vec3> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..count)
        .map(|i| {
            let z = 1.0 - (i as f64 + 0.5) / count as f64;
            let r = (1.0 - z * z).sqrt();
            let phi = golden * i as f64;
            [r * phi.cos(), r * phi.sin(), z]
        })
        .collect()
}

/// An orthonormal tangent frame (t, b, n) for a unit normal, so that local = (t·v, b·v, n·v).
/// Isotropy makes the choice of tangent irrelevant; this one is continuous except at n = -Y.
pub fn tangent_frame(n: Vec3) -> (Vec3, Vec3) {
    let helper = if n[1].abs() < 0.9 {
        [0.0, 1.0, 0.0]
    } else {
        [1.0, 0.0, 0.0]
    };
    let t = normalize(cross(helper, n));
    let b = cross(n, t);
    (t, b)
}

/// Steps of [`directional_albedo`]'s quadrature over the half vector: θh on MERL's square-root
/// spacing (fine near the specular peak, where sharp lobes live), φh uniform. A Lambertian BRDF
/// and a GGX lobe of α 0.02 both integrate to within 0.5% (checked in the tests).
const ALBEDO_THETA_H: usize = 512;
const ALBEDO_PHI_H: usize = 128;

/// The directional albedo ∫ f(ωi, ωo) cos θi dωi for a view at `theta_o` from the normal, per
/// channel: the fraction of light from that direction that the surface reflects. A physical
/// surface keeps it at or below 1.
///
/// The integral runs over the half vector h (ωi is ωo mirrored about h), with
/// dωi = 4 (ωo·h) dωh, so that a sharp specular peak is resolved however small it is.
pub fn directional_albedo(brdf: &dyn IsotropicBrdf, theta_o: f64) -> [f64; 3] {
    let half_pi = std::f64::consts::FRAC_PI_2;
    let wo = [theta_o.sin(), 0.0, theta_o.cos()];
    let mut sum = [0.0; 3];
    let dphi = std::f64::consts::TAU / ALBEDO_PHI_H as f64;
    for i in 0..ALBEDO_THETA_H {
        // θh = s² π/2 with s uniform: dθh = 2 s π/2 ds.
        let s = (i as f64 + 0.5) / ALBEDO_THETA_H as f64;
        let theta_h = s * s * half_pi;
        let dtheta = 2.0 * s * half_pi / ALBEDO_THETA_H as f64;
        let (sin_h, cos_h) = theta_h.sin_cos();
        for j in 0..ALBEDO_PHI_H {
            let phi = (j as f64 + 0.5) * dphi;
            let h = [sin_h * phi.cos(), sin_h * phi.sin(), cos_h];
            let oh = dot(wo, h);
            if oh <= 0.0 {
                continue;
            }
            let wi = sub(scale(h, 2.0 * oh), wo);
            if wi[2] <= 0.0 {
                continue;
            }
            let f = brdf.eval_dirs(wi, wo);
            let w = wi[2] * 4.0 * oh * sin_h * dtheta * dphi;
            for c in 0..3 {
                sum[c] += f[c] * w;
            }
        }
    }
    sum
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The cosines from directions (what a renderer's BRDF evaluation takes) are the ones
    /// from the directions' Rusinkiewicz angles (what a table's tabulation takes), over
    /// directions from grazing to the normal, so that both give a microfacet BRDF the same
    /// value.
    #[test]
    fn the_cosines_from_directions_are_the_cosines_from_their_angles() {
        let dir = |theta: f64, phi: f64| {
            [
                theta.sin() * phi.cos(),
                theta.sin() * phi.sin(),
                theta.cos(),
            ]
        };
        let mut compared = 0;
        for i in 0..9 {
            for j in 0..9 {
                for k in 0..8 {
                    let wi = dir(0.01 + 0.17 * i as f64, 0.3 * k as f64);
                    let wo = dir(0.02 + 0.17 * j as f64, 2.0 - 0.45 * k as f64);
                    let (th, td, pd) = to_rusinkiewicz(wi, wo);
                    let (a, b) = (Cosines::of_dirs(wi, wo), Cosines::of_angles(th, td, pd));
                    let (a, b) = (a.expect("above"), b.expect("above"));
                    for (x, y) in [(a.h, b.h), (a.d, b.d), (a.i, b.i), (a.o, b.o)] {
                        assert!((x - y).abs() < 1e-12, "{a:?} against {b:?}");
                    }
                    compared += 1;
                }
            }
        }
        assert_eq!(compared, 648);
        assert_eq!(Cosines::of_dirs([0.0, 0.6, -0.8], [0.0, 0.0, 1.0]), None);
    }

    struct Lambert(f64);
    impl IsotropicBrdf for Lambert {
        fn eval_angles(&self, _: f64, _: f64, _: f64) -> [f64; 3] {
            [self.0 / std::f64::consts::PI; 3]
        }
    }

    #[test]
    fn lambertian_albedo_is_its_reflectance() {
        // Tolerance: the half-vector quadrature's error at 512 × 128 steps (measured below
        // 0.1% at these angles).
        for theta in [0.0, 0.7, 1.3] {
            let a = directional_albedo(&Lambert(0.8), theta);
            assert!(a.iter().all(|v| (v - 0.8).abs() < 0.004), "{theta}: {a:?}");
        }
    }

    #[test]
    fn rusinkiewicz_round_trip() {
        // Tolerance: f64 trigonometry on unit vectors, a few ulps per operation.
        for &(th, td, pd) in &[(0.3, 0.5, 1.0), (0.01, 1.2, -2.0), (1.0, 0.2, 0.4)] {
            let (wi, wo) = from_rusinkiewicz(th, td, pd);
            let (a, b, c) = to_rusinkiewicz(wi, wo);
            assert!((a - th).abs() < 1e-9 && (b - td).abs() < 1e-9 && (c - pd).abs() < 1e-9);
        }
    }
}
