//! The object camera's pose (and focal length) from a photo of a printed board: the board's
//! corners found in the photo ([`board`]), a homography from the board's plane to the image
//! (normalised DLT) taken apart with the intrinsics for a first pose, then Levenberg–Marquardt
//! on the reprojection error over the pose and, where the view pins it down, the focal length.
//! The RMS reprojection error is reported as OpenCV's `calibrateCamera` reports it.
//!
//! Conventions: pixel coordinates are continuous, pixel (x, y) covering [x, x+1) × [y, y+1)
//! (so its centre is at x + 0.5), as [`Camera`]'s rays are cast. The camera frame is
//! OpenCV's: x right, y down, z forward.

pub mod board;
pub mod error;
pub mod silhouette;

use error::fail;
pub use error::PoseError;

use nalgebra::{DMatrix, Matrix3, Rotation3, Vector3};

use brdfd_core::brdf::Vec3;
use brdfd_core::geometry::{Camera, Pose};

/// A pinhole camera's intrinsics, in pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Intrinsics {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
}

impl Intrinsics {
    fn matrix(&self) -> Matrix3<f64> {
        Matrix3::new(self.fx, 0.0, self.cx, 0.0, self.fy, self.cy, 0.0, 0.0, 1.0)
    }

    fn scaled_focal(&self, s: f64) -> Intrinsics {
        Intrinsics {
            fx: self.fx * s,
            fy: self.fy * s,
            ..*self
        }
    }
}

/// World to camera: a camera-frame point is `rotation · world + translation`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Extrinsics {
    pub rotation: Rotation3<f64>,
    pub translation: Vector3<f64>,
}

impl Extrinsics {
    /// The camera's centre in the world.
    pub fn centre(&self) -> Vector3<f64> {
        -(self.rotation.inverse() * self.translation)
    }

    /// Where a world point lands in the image, or `None` behind the camera.
    pub fn project(&self, k: &Intrinsics, p: Vec3) -> Option<[f64; 2]> {
        let c = self.rotation * Vector3::from(p) + self.translation;
        (c.z > 1e-12).then(|| [k.cx + k.fx * c.x / c.z, k.cy + k.fy * c.y / c.z])
    }

    /// The pose as a rig file writes it: position, a point looked at (`distance` ahead), and
    /// the image's up.
    pub fn to_pose(&self, distance: f64) -> Pose {
        let inv = self.rotation.inverse();
        let centre = self.centre();
        let forward = inv * Vector3::z();
        let up = inv * -Vector3::y();
        let look_at = centre + forward * distance;
        let round = |v: Vector3<f64>| [v.x, v.y, v.z].map(|c| (c * 1e6).round() / 1e6);
        Pose {
            position: round(centre),
            look_at: round(look_at),
            up: [up.x, up.y, up.z].map(|c| (c * 1e6).round() / 1e6),
        }
    }

    /// A rig file's pose as world-to-camera (`None` for a pose the camera refuses).
    pub fn of_pose(pose: &Pose) -> Option<Extrinsics> {
        let (right, up, forward) = pose.axes().ok()?;
        let rows = Matrix3::from_rows(&[
            Vector3::from(right).transpose(),
            (-Vector3::from(up)).transpose(),
            Vector3::from(forward).transpose(),
        ]);
        let rotation = Rotation3::from_matrix_unchecked(rows);
        let translation = -(rotation * Vector3::from(pose.position));
        Some(Extrinsics {
            rotation,
            translation,
        })
    }
}

/// A pinhole rig camera's intrinsics and pose, or `None` for an orthographic one.
pub fn pinhole(camera: &Camera) -> Option<(Intrinsics, Extrinsics)> {
    match camera {
        Camera::Pinhole {
            fx,
            fy,
            cx,
            cy,
            pose,
            ..
        } => Some((
            Intrinsics {
                fx: *fx,
                fy: *fy,
                cx: *cx,
                cy: *cy,
            },
            Extrinsics::of_pose(pose)?,
        )),
        Camera::Orthographic { .. } => None,
    }
}

/// One board corner: where it is on the bench (world, metres) and where the photo shows it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Correspondence {
    pub world: Vec3,
    pub pixel: [f64; 2],
}

/// Whether the focal length is solved for, or held.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Focal {
    /// Held at the intrinsics given.
    Fixed,
    /// Refined from the view when it pins the focal length down (a board seen at a slant);
    /// held, with a reason, when it does not.
    Refine,
}

/// A solved pose.
#[derive(Debug, Clone)]
pub struct PoseFit {
    pub intrinsics: Intrinsics,
    pub extrinsics: Extrinsics,
    /// RMS reprojection error over the corners, pixels (√(Σ‖residual‖² / n)).
    pub rms_px: f64,
    /// The largest corner's reprojection error, pixels.
    pub worst_px: f64,
    pub corners: usize,
    /// The focal length's relative standard error when it was refined; why it was held
    /// otherwise.
    pub focal: Result<f64, String>,
}

/// Fewest corners a pose is solved from: the homography needs 4, and a pose from so few
/// cannot be checked by its residuals.
pub const MIN_CORNERS: usize = 8;

/// The focal length is kept from the view only when its relative standard error is below
/// this (a board seen square-on cannot tell focal length from distance).
const FOCAL_SIGMA_MAX: f64 = 0.005;

/// The pose of a camera of intrinsics `k` that sees the planar board `points` (all on one
/// plane in the world), and its focal length if `focal` asks and the view allows.
pub fn solve(points: &[Correspondence], k: Intrinsics, focal: Focal) -> Result<PoseFit, String> {
    solve_views(&[points.to_vec()], k, focal)
}

/// One camera's pose from several views of the board, each on its own plane in the world (the
/// board turned on the turntable between them): the first pose from the view with the most
/// corners, refined over all of them. Views at different slants pin the focal length down
/// where one seen square-on cannot.
pub fn solve_views(
    views: &[Vec<Correspondence>],
    k: Intrinsics,
    focal: Focal,
) -> Result<PoseFit, String> {
    let points: Vec<Correspondence> = views.iter().flatten().copied().collect();
    let points = &points[..];
    let largest = views
        .iter()
        .max_by_key(|v| v.len())
        .map_or(&[][..], |v| &v[..]);
    if largest.len() < MIN_CORNERS {
        return Err(format!(
            "{} board corners found, {MIN_CORNERS} needed at least",
            largest.len()
        ));
    }
    let plane = Plane::through(largest)?;
    let local: Vec<[f64; 2]> = largest.iter().map(|p| plane.local(p.world)).collect();
    let pixels: Vec<[f64; 2]> = largest.iter().map(|p| p.pixel).collect();
    let h = homography(&local, &pixels)?;
    let start = plane.to_world(from_homography(&h, &k)?);
    let fixed = refine(points, k, start, false);
    let (fit, focal_result) = match focal {
        Focal::Fixed => (fixed, Err("held, as asked".to_string())),
        Focal::Refine => {
            let free = refine(points, k, fixed.extrinsics, true);
            match free.focal_sigma {
                Some(s) if s < FOCAL_SIGMA_MAX => (free, Ok(s)),
                s => (
                    fixed,
                    Err(format!(
                        "held: the view pins it down to {} only (the board needs to be seen at more of a slant, or turned between views)",
                        s.map_or("nothing".to_string(), |s| format!("{:.1}%", s * 100.0))
                    )),
                ),
            }
        }
    };
    let errors: Vec<f64> = points
        .iter()
        .map(|p| match fit.extrinsics.project(&fit.intrinsics, p.world) {
            Some(q) => (q[0] - p.pixel[0]).hypot(q[1] - p.pixel[1]),
            None => f64::INFINITY,
        })
        .collect();
    let n = errors.len() as f64;
    Ok(PoseFit {
        intrinsics: fit.intrinsics,
        extrinsics: fit.extrinsics,
        rms_px: (errors.iter().map(|e| e * e).sum::<f64>() / n).sqrt(),
        worst_px: errors.iter().copied().fold(0.0, f64::max),
        corners: points.len(),
        focal: focal_result,
    })
}

/// The board's plane in the world, with axes in it.
struct Plane {
    origin: Vector3<f64>,
    /// Columns: two in-plane axes and the normal.
    axes: Matrix3<f64>,
}

impl Plane {
    fn through(points: &[Correspondence]) -> Result<Plane, String> {
        let n = points.len() as f64;
        let origin = points
            .iter()
            .fold(Vector3::zeros(), |a, p| a + Vector3::from(p.world))
            / n;
        let mut scatter = Matrix3::zeros();
        for p in points {
            let d = Vector3::from(p.world) - origin;
            scatter += d * d.transpose();
        }
        let eig = scatter.symmetric_eigen();
        let mut order = [0, 1, 2];
        order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
        let [most, second, flat] = order.map(|i| eig.eigenvalues[i]);
        if second <= 1e-9 * most || flat > 1e-9 * second {
            return Err("the board's corners are all on a line (only one row of the board in view?), or not on one plane".into());
        }
        let u = eig.eigenvectors.column(order[0]).into_owned();
        let v = eig.eigenvectors.column(order[1]).into_owned();
        Ok(Plane {
            origin,
            axes: Matrix3::from_columns(&[u, v, u.cross(&v)]),
        })
    }

    fn local(&self, p: Vec3) -> [f64; 2] {
        let d = self.axes.transpose() * (Vector3::from(p) - self.origin);
        [d.x, d.y]
    }

    /// A plane-to-camera pose as world to camera.
    fn to_world(&self, plane: Extrinsics) -> Extrinsics {
        let r = plane.rotation.matrix() * self.axes.transpose();
        let rotation = Rotation3::from_matrix_unchecked(r);
        Extrinsics {
            rotation,
            translation: plane.translation - rotation * self.origin,
        }
    }
}

/// The homography taking plane points to pixels: the normalised DLT (Hartley and Zisserman,
/// algorithm 4.2), each side moved to its centroid and scaled to a mean distance of √2.
fn homography(from: &[[f64; 2]], to: &[[f64; 2]]) -> Result<Matrix3<f64>, String> {
    let (ta, tb) = (normaliser(from), normaliser(to));
    let mut a = DMatrix::zeros(2 * from.len(), 9);
    for (i, (p, q)) in from.iter().zip(to).enumerate() {
        let p = ta * Vector3::new(p[0], p[1], 1.0);
        let q = tb * Vector3::new(q[0], q[1], 1.0);
        let (x, y, u, v) = (p.x / p.z, p.y / p.z, q.x / q.z, q.y / q.z);
        let rows = [
            [-x, -y, -1.0, 0.0, 0.0, 0.0, u * x, u * y, u],
            [0.0, 0.0, 0.0, -x, -y, -1.0, v * x, v * y, v],
        ];
        for (r, row) in rows.iter().enumerate() {
            for (c, value) in row.iter().enumerate() {
                a[(2 * i + r, c)] = *value;
            }
        }
    }
    // The null vector of A is the eigenvector of AᵀA with the least eigenvalue.
    let eig = (a.transpose() * &a).symmetric_eigen();
    let least = eig.eigenvalues.imin();
    let h = eig.eigenvectors.column(least);
    let hn = Matrix3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], h[8]);
    let tb_inv = tb
        .try_inverse()
        .ok_or("the corners found are all at one pixel")?;
    let hm = tb_inv * hn * ta;
    if !hm.iter().all(|x| x.is_finite()) || hm[(2, 2)].abs() < 1e-300 && hm.norm() < 1e-300 {
        return Err("no homography fits the corners found".into());
    }
    Ok(hm)
}

fn normaliser(points: &[[f64; 2]]) -> Matrix3<f64> {
    let n = points.len() as f64;
    let (mx, my) = points
        .iter()
        .fold((0.0, 0.0), |(x, y), p| (x + p[0] / n, y + p[1] / n));
    let mean_distance = points
        .iter()
        .map(|p| (p[0] - mx).hypot(p[1] - my))
        .sum::<f64>()
        / n;
    let s = if mean_distance > 0.0 {
        std::f64::consts::SQRT_2 / mean_distance
    } else {
        1.0
    };
    Matrix3::new(s, 0.0, -s * mx, 0.0, s, -s * my, 0.0, 0.0, 1.0)
}

/// The plane-to-camera pose a homography stands for, given the intrinsics (Zhang 2000, §2):
/// K⁻¹H = λ[r₁ r₂ t], the rotation made orthonormal, the plane in front of the camera.
fn from_homography(h: &Matrix3<f64>, k: &Intrinsics) -> Result<Extrinsics, String> {
    let m = k
        .matrix()
        .try_inverse()
        .ok_or("the intrinsics are singular")?
        * h;
    let (h1, h2, h3) = (m.column(0), m.column(1), m.column(2));
    let mut lambda = 2.0 / (h1.norm() + h2.norm());
    if (lambda * h3).z < 0.0 {
        lambda = -lambda;
    }
    let (r1, r2) = (h1 * lambda, h2 * lambda);
    let r = Matrix3::from_columns(&[r1, r2, r1.cross(&r2)]);
    let svd = r.svd(true, true);
    let (u, v_t) = (svd.u.ok_or("SVD failed")?, svd.v_t.ok_or("SVD failed")?);
    let mut rotation = u * v_t;
    if rotation.determinant() < 0.0 {
        rotation = -rotation;
    }
    Ok(Extrinsics {
        rotation: Rotation3::from_matrix_unchecked(rotation),
        translation: h3 * lambda,
    })
}

struct Refined {
    intrinsics: Intrinsics,
    extrinsics: Extrinsics,
    /// The focal length's relative standard error, when it was a parameter.
    focal_sigma: Option<f64>,
}

/// Levenberg–Marquardt on the reprojection error. Parameters: a small rotation applied on
/// the left of the current one, the translation, and (with `with_focal`) the log of a scale
/// on both focal lengths. The Jacobian is by central differences: 7 parameters and a few
/// hundred residuals make that cheap, and it cannot disagree with the projection.
fn refine(
    points: &[Correspondence],
    k: Intrinsics,
    start: Extrinsics,
    with_focal: bool,
) -> Refined {
    let np = if with_focal { 7 } else { 6 };
    let residuals = |e: &Extrinsics, k: &Intrinsics| -> Vec<f64> {
        let mut r = Vec::with_capacity(2 * points.len());
        for p in points {
            let c = e.rotation * Vector3::from(p.world) + e.translation;
            // A corner behind the camera gets a large residual rather than a wrong sign.
            let z = c.z.max(1e-9);
            r.push(k.cx + k.fx * c.x / z - p.pixel[0]);
            r.push(k.cy + k.fy * c.y / z - p.pixel[1]);
        }
        r
    };
    let apply = |e: &Extrinsics, k: &Intrinsics, d: &[f64]| -> (Extrinsics, Intrinsics) {
        let turn = Rotation3::new(Vector3::new(d[0], d[1], d[2]));
        let moved = Extrinsics {
            rotation: turn * e.rotation,
            translation: e.translation + Vector3::new(d[3], d[4], d[5]),
        };
        let k2 = if with_focal {
            k.scaled_focal(d[6].exp())
        } else {
            *k
        };
        (moved, k2)
    };
    let cost = |r: &[f64]| r.iter().map(|x| x * x).sum::<f64>();
    let (mut e, mut kk) = (start, k);
    let mut r = residuals(&e, &kk);
    let mut lambda = 1e-3;
    let mut jtj = DMatrix::<f64>::zeros(np, np);
    for _ in 0..100 {
        // Steps scaled to the parameter: radians, metres at the board's distance, log focal.
        let distance = e.translation.norm().max(1e-6);
        let steps = [
            1e-7,
            1e-7,
            1e-7,
            1e-7 * distance,
            1e-7 * distance,
            1e-7 * distance,
            1e-7,
        ];
        let mut j = DMatrix::<f64>::zeros(r.len(), np);
        for c in 0..np {
            let mut d = vec![0.0; 7];
            d[c] = steps[c];
            let (ep, kp) = apply(&e, &kk, &d);
            d[c] = -steps[c];
            let (em, km) = apply(&e, &kk, &d);
            let (rp, rm) = (residuals(&ep, &kp), residuals(&em, &km));
            for i in 0..r.len() {
                j[(i, c)] = (rp[i] - rm[i]) / (2.0 * steps[c]);
            }
        }
        jtj = j.transpose() * &j;
        let g = j.transpose() * nalgebra::DVector::from_column_slice(&r);
        let before = cost(&r);
        let mut improved = false;
        for _ in 0..20 {
            let mut a = jtj.clone();
            for i in 0..np {
                a[(i, i)] += lambda * jtj[(i, i)].max(1e-12);
            }
            let Some(step) = a.lu().solve(&(-&g)) else {
                lambda *= 10.0;
                continue;
            };
            let mut d = [0.0; 7];
            d[..np].copy_from_slice(step.as_slice());
            let (e2, k2) = apply(&e, &kk, &d);
            let r2 = residuals(&e2, &k2);
            if cost(&r2) < before {
                (e, kk, r) = (e2, k2, r2);
                lambda = (lambda / 10.0).max(1e-12);
                improved = true;
                break;
            }
            lambda *= 10.0;
        }
        if !improved || (before - cost(&r)) <= 1e-12 * before.max(1e-30) {
            break;
        }
    }
    let focal_sigma = with_focal.then(|| {
        // σ² of the parameters: the residual variance times (JᵀJ)⁻¹.
        let dof = (r.len() as f64 - np as f64).max(1.0);
        let variance = cost(&r) / dof;
        jtj.clone()
            .try_inverse()
            .map_or(f64::INFINITY, |inv| (inv[(6, 6)] * variance).sqrt())
    });
    Refined {
        intrinsics: kk,
        extrinsics: e,
        focal_sigma,
    }
}

/// The board's corners found in one photo, where they are in the world with the board turned
/// `turn_deg` on the turntable.
#[derive(Debug, Clone)]
pub struct Found {
    pub name: String,
    pub size: (u32, u32),
    pub turn_deg: f64,
    pub corners: Vec<Correspondence>,
}

/// Finds the board in `photo` (8-bit grey, from the rig's object camera), the board turned
/// `turn_deg` (right-handed about the turntable's axis, the world's +Y through the origin)
/// from where its board file places it.
pub fn find(
    board: &board::Board,
    photo: &image::GrayImage,
    name: &str,
    turn_deg: f64,
) -> error::Result<Found> {
    let (s, c) = turn_deg.to_radians().sin_cos();
    let corners = board
        .detect(photo)
        .map_err(|e| PoseError::InPhoto {
            photo: name.to_string(),
            source: Box::new(e),
        })?
        .into_iter()
        .map(|p| {
            let [x, y, z] = p.world;
            Correspondence {
                world: [c * x + s * z, y, -s * x + c * z],
                ..p
            }
        })
        .collect();
    Ok(Found {
        name: name.to_string(),
        size: (photo.width(), photo.height()),
        turn_deg,
        corners,
    })
}

/// A photo from the rig's object camera has the camera's shape (at any size).
pub fn check_photo_size(
    rig_camera: &Camera,
    (pw, ph): (u32, u32),
    name: &str,
) -> error::Result<()> {
    let (w, h) = rig_camera.size();
    let (sx, sy) = (pw as f64 / w as f64, ph as f64 / h as f64);
    if (sx - sy).abs() > 0.01 * sx {
        fail!(
            Photos,
            "{name} is {pw}×{ph}, and the rig's camera is {w}×{h}: a photo of another shape is from another camera, cropped, or turned (portrait)"
        );
    }
    Ok(())
}

/// A rig camera with the pose (and focal length) photos of the board gave it.
#[derive(Debug, Clone)]
pub struct Calibrated {
    /// The rig's camera, at its own size, with the pose and focal length found.
    pub camera: Camera,
    /// The fit, in the photos' pixels.
    pub fit: PoseFit,
    pub photo_size: (u32, u32),
    /// The focal length the solve started from (pixels of the photo), and where it came from.
    pub start_fx: f64,
    pub start_from: String,
    /// The views solved from.
    pub views: Vec<Found>,
}

/// The lens's focal length as a photo's file gives it, for the solve to start from.
#[derive(Debug, Clone, PartialEq)]
pub struct LensFocal {
    /// Millimetres, as the file says.
    pub mm: f64,
    /// Pixels of the photo, and how they were found; `None` where the file does not say how
    /// large the sensor is.
    pub px: Option<(f64, String)>,
}

/// The camera's pose from the board's corners in one or more views (one camera that did not
/// move; the board turned between them), starting from the lens's focal length (the photos'
/// EXIF) or else the rig's, and refining it if `focal` asks and the views allow. `look_at`
/// is written where the camera's axis passes the board's centre.
pub fn calibrate(
    rig_camera: &Camera,
    views: Vec<Found>,
    board_centre: Vec3,
    lens: Option<LensFocal>,
    focal: Focal,
) -> error::Result<Calibrated> {
    let Some(first) = views.first() else {
        fail!(Photos, "no photo of the board to solve from");
    };
    let (pw, ph) = first.size;
    let (w, h) = rig_camera.size();
    for v in &views {
        if v.size != (pw, ph) {
            fail!(
                Photos,
                "{} is {}×{}, and {} {pw}×{ph}: the views are of one camera",
                v.name,
                v.size.0,
                v.size.1,
                first.name
            );
        }
    }
    check_photo_size(rig_camera, first.size, &first.name)?;
    let at_photo = rig_camera.resized(pw as usize, ph as usize);
    let Some((mut k, _)) = pinhole(&at_photo) else {
        fail!(
            Camera,
            "the rig's camera is orthographic: a pose from a board needs a pinhole camera (type = \"pinhole\", with fx, fy, cx, cy)"
        );
    };
    let mut start_from = "the rig's fx".to_string();
    // With the focal length held, the rig's is kept; refined, it starts from the lens's.
    if let (Focal::Refine, Some(lens)) = (focal, lens) {
        if let Some((fx, how)) = lens.px {
            k = Intrinsics {
                fx,
                fy: fx * k.fy / k.fx,
                ..k
            };
            start_from = format!("EXIF: {} mm, {how}", lens.mm);
        } else {
            start_from = format!(
                "the rig's fx: the EXIF gives {} mm but not the sensor's size (--sensor-width-mm gives it)",
                lens.mm
            );
        }
    }
    let start_fx = k.fx;
    let groups: Vec<Vec<Correspondence>> = views.iter().map(|v| v.corners.clone()).collect();
    let fit = solve_views(&groups, k, focal).map_err(|e| PoseError::NoPose(e.to_string()))?;
    let centre = Vector3::from(board_centre);
    let distance = (fit.extrinsics.rotation * centre + fit.extrinsics.translation).z;
    let pose = fit.extrinsics.to_pose(distance.max(1e-3));
    let camera = match at_photo {
        Camera::Pinhole {
            width,
            height,
            cx,
            cy,
            ..
        } => Camera::Pinhole {
            width,
            height,
            fx: fit.intrinsics.fx,
            fy: fit.intrinsics.fy,
            cx,
            cy,
            pose,
        },
        Camera::Orthographic { .. } => unreachable!("a pinhole camera, checked above"),
    }
    .resized(w, h);
    Ok(Calibrated {
        camera,
        fit,
        photo_size: (pw, ph),
        start_fx,
        start_from,
        views,
    })
}

/// The angle between two rotations, degrees.
pub fn angle_between_deg(a: &Rotation3<f64>, b: &Rotation3<f64>) -> f64 {
    (a.inverse() * b).angle().to_degrees()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A photo without the board fails as that, named, with the cause kept: a caller can
    /// tell "retake the photo" from "fix the board file" without reading prose.
    #[test]
    fn a_photo_without_the_board_is_told_apart_from_a_bad_board() {
        let blank = image::GrayImage::from_pixel(64, 48, image::Luma([128]));
        let e = find(&board::Board::default(), &blank, "blank.jpg", 0.0).unwrap_err();
        let PoseError::InPhoto { photo, source } = &e else {
            panic!("{e:?}");
        };
        assert_eq!(photo, "blank.jpg");
        assert!(
            matches!(**source, PoseError::BoardNotFound(_)),
            "{source:?}"
        );
        assert_eq!(e.to_string(), "blank.jpg");
        let cause = std::error::Error::source(&e).map(|s| s.to_string());
        assert!(
            cause
                .as_deref()
                .is_some_and(|c| c.starts_with("no 9 × 6 ChArUco board")),
            "{cause:?}"
        );
        let bad = board::Board {
            rows: 2,
            ..board::Board::default()
        };
        assert!(matches!(bad.check(), Err(PoseError::Board(_))));
    }

    fn camera() -> (Intrinsics, Extrinsics) {
        let k = Intrinsics {
            fx: 1900.0,
            fy: 1900.0,
            cx: 800.0,
            cy: 533.5,
        };
        let pose = Pose {
            position: [0.18, 0.12, 0.45],
            look_at: [0.01, -0.01, 0.0],
            up: [0.05, 1.0, 0.0],
        };
        (k, Extrinsics::of_pose(&pose).unwrap())
    }

    fn board(k: &Intrinsics, e: &Extrinsics, noise: f64) -> Vec<Correspondence> {
        let mut seed = 7u64;
        let mut rand = move || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let mut v = Vec::new();
        for i in 0..8 {
            for j in 0..5 {
                let world = [i as f64 * 0.03 - 0.105, j as f64 * 0.03 - 0.06, 0.0];
                let q = e.project(k, world).unwrap();
                v.push(Correspondence {
                    world,
                    pixel: [q[0] + noise * rand(), q[1] + noise * rand()],
                });
            }
        }
        v
    }

    #[test]
    fn a_pose_round_trips_through_the_rig_files_form() {
        let (k, e) = camera();
        let back = Extrinsics::of_pose(&e.to_pose(0.5)).unwrap();
        assert!(angle_between_deg(&e.rotation, &back.rotation) < 1e-4);
        assert!((e.centre() - back.centre()).norm() < 1e-6);
        // A rig camera of these intrinsics and pose casts, through the pixel a point projects
        // to, the ray through that point: the conventions (pixel centres at + 0.5, image rows
        // down) are the rasteriser's.
        let camera = Camera::Pinhole {
            width: 1600,
            height: 1067,
            fx: k.fx,
            fy: k.fy,
            cx: k.cx,
            cy: k.cy,
            pose: e.to_pose(0.5),
        };
        let p = [0.02, -0.03, 0.01];
        let q = e.project(&k, p).unwrap();
        let (o, d) = camera.ray_through(q[0], q[1]).unwrap();
        let to_p = Vector3::from(p) - Vector3::from(o);
        let off_ray = (to_p - Vector3::from(d) * to_p.dot(&Vector3::from(d))).norm();
        assert!(off_ray < 1e-6, "{off_ray}");
    }

    #[test]
    fn exact_corners_give_the_pose_and_the_focal_length() {
        let (k, e) = camera();
        let pts = board(&k, &e, 0.0);
        // Start 3% off in focal length: the slanted view recovers it.
        let fit = solve(&pts, k.scaled_focal(1.03), Focal::Refine).unwrap();
        assert!(fit.rms_px < 1e-6, "rms {}", fit.rms_px);
        assert!(angle_between_deg(&fit.extrinsics.rotation, &e.rotation) < 1e-6);
        assert!((fit.extrinsics.centre() - e.centre()).norm() < 1e-8);
        assert!(
            (fit.intrinsics.fx - k.fx).abs() < 1e-5,
            "{}",
            fit.intrinsics.fx
        );
    }

    #[test]
    fn noisy_corners_give_a_pose_within_the_noise() {
        let (k, e) = camera();
        // Uniform noise of ±0.25 px: 0.14 px RMS per axis.
        let fit = solve(&board(&k, &e, 0.5), k, Focal::Fixed).unwrap();
        assert!(fit.rms_px > 0.1 && fit.rms_px < 0.25, "rms {}", fit.rms_px);
        assert!(angle_between_deg(&fit.extrinsics.rotation, &e.rotation) < 0.05);
        assert!((fit.extrinsics.centre() - e.centre()).norm() < 5e-4);
    }

    #[test]
    fn a_square_on_view_holds_the_focal_length() {
        let k = Intrinsics {
            fx: 1900.0,
            fy: 1900.0,
            cx: 800.0,
            cy: 533.5,
        };
        let e = Extrinsics::of_pose(&Pose {
            position: [0.0, 0.0, 0.5],
            look_at: [0.0, 0.0, 0.0],
            up: [0.0, 1.0, 0.0],
        })
        .unwrap();
        let fit = solve(&board(&k, &e, 0.5), k, Focal::Refine).unwrap();
        let why = fit.focal.unwrap_err();
        assert!(why.contains("slant"), "{why}");
        assert_eq!(fit.intrinsics.fx, k.fx);
    }

    #[test]
    fn too_few_or_collinear_corners_are_refused() {
        let (k, e) = camera();
        let pts = board(&k, &e, 0.0);
        assert!(solve(&pts[..5], k, Focal::Fixed)
            .unwrap_err()
            .contains("8 needed"));
        let line: Vec<_> = pts
            .iter()
            .filter(|p| p.world[1] == pts[0].world[1])
            .copied()
            .collect();
        let mut line = line;
        line.extend(line.clone());
        assert!(solve(&line, k, Focal::Fixed).unwrap_err().contains("line"));
    }
}
