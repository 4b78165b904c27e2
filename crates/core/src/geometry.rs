//! Per-pixel geometry: which pixels see the object, and each one's world normal and view
//! vector (toward the camera). Comes from a camera model plus a built-in shape, a triangle
//! mesh ([`super::mesh`], cast through its hierarchy, [`super::bvh`]), or a normal-map EXR.
//! Light the object itself blocks is not modelled here.
//!
//! Camera frame (OpenGL): the camera looks along its −Z, +Y is up in the image, +X right;
//! image rows run downward. A pose is given as position, look-at point and up vector in the
//! world frame (+Y up, docs/bench-setup.md, "Conventions").

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use rayon::prelude::*;

use super::brdf::{add, cross, dot, normalize, scale, sub, tangent_frame, Vec3};
use super::bvh::{Bvh, Hit, Surface};
use super::error::{CoreError, Result};
use super::mesh::{Mesh, Placement, Units};
use super::visibility::{Occluder, Point, Shadow};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Pose {
    pub position: Vec3,
    pub look_at: Vec3,
    #[serde(default = "up_y")]
    pub up: Vec3,
}

fn up_y() -> Vec3 {
    [0.0, 1.0, 0.0]
}

impl Pose {
    /// Camera axes in the world: (right, up, forward).
    pub fn axes(&self) -> Result<(Vec3, Vec3, Vec3)> {
        let fwd = normalize(sub(self.look_at, self.position));
        let right = cross(fwd, self.up);
        if dot(right, right) < 1e-12 || dot(fwd, fwd) < 0.5 {
            return Err(CoreError::Invalid(
                "camera pose: look_at equals position or is parallel to up".into(),
            ));
        }
        let right = normalize(right);
        Ok((right, cross(right, fwd), fwd))
    }
}

/// A camera model with its pose.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "kebab-case", deny_unknown_fields)]
pub enum Camera {
    /// Parallel projection; `extent` is the world width the image covers.
    Orthographic {
        width: usize,
        height: usize,
        extent: f64,
        #[serde(flatten)]
        pose: Pose,
    },
    /// Pinhole with intrinsics in pixels (focal lengths and principal point).
    Pinhole {
        width: usize,
        height: usize,
        fx: f64,
        fy: f64,
        cx: f64,
        cy: f64,
        #[serde(flatten)]
        pose: Pose,
    },
}

/// A ray from the camera: origin and unit direction (world).
struct Ray {
    origin: Vec3,
    dir: Vec3,
}

impl Camera {
    /// The evaluation camera of docs/evaluation.md: orthographic, looking down −Z at a unit
    /// sphere at the origin that fills the frame.
    pub fn eval_orthographic(size: usize) -> Camera {
        Camera::Orthographic {
            width: size,
            height: size,
            extent: 2.0,
            pose: Pose {
                position: [0.0, 0.0, 10.0],
                look_at: [0.0, 0.0, 0.0],
                up: up_y(),
            },
        }
    }

    /// The camera turned by `angle` radians (right-handed) about the world +Y axis through
    /// the origin: the turntable's axis. A turntable turning the object by θ under a fixed
    /// camera and light is, in the object's frame, the camera and the light turned by −θ, so
    /// a view at turntable angle θ is geometry from `turned_about_y(−θ)` and lights at yaw
    /// `yaw − θ`.
    pub fn turned_about_y(&self, angle: f64) -> Camera {
        let (s, c) = angle.sin_cos();
        let turn = |v: Vec3| [c * v[0] + s * v[2], v[1], -s * v[0] + c * v[2]];
        let mut cam = self.clone();
        let pose = match &mut cam {
            Camera::Orthographic { pose, .. } | Camera::Pinhole { pose, .. } => pose,
        };
        pose.position = turn(pose.position);
        pose.look_at = turn(pose.look_at);
        pose.up = turn(pose.up);
        cam
    }

    pub fn size(&self) -> (usize, usize) {
        match self {
            Camera::Orthographic { width, height, .. } | Camera::Pinhole { width, height, .. } => {
                (*width, *height)
            }
        }
    }

    /// A copy with a different resolution and the same field of view, so geometry can be
    /// computed for a photo of any size.
    pub fn resized(&self, width: usize, height: usize) -> Camera {
        let mut c = self.clone();
        match &mut c {
            Camera::Orthographic {
                width: w,
                height: h,
                ..
            } => {
                *w = width;
                *h = height;
            }
            Camera::Pinhole {
                width: w,
                height: h,
                fx,
                fy,
                cx,
                cy,
                ..
            } => {
                let s = width as f64 / *w as f64;
                let t = height as f64 / *h as f64;
                *fx *= s;
                *cx *= s;
                *fy *= t;
                *cy *= t;
                *w = width;
                *h = height;
            }
        }
        c
    }

    fn ray(&self, x: usize, y: usize, axes: &(Vec3, Vec3, Vec3)) -> Ray {
        self.ray_at(x as f64 + 0.5, y as f64 + 0.5, axes)
    }

    /// The ray through the image point (u, v), in pixels from the image's top-left corner
    /// (pixel (x, y) covers [x, x+1) × [y, y+1)): its origin and unit direction.
    pub fn ray_through(&self, u: f64, v: f64) -> Result<(Vec3, Vec3)> {
        let r = self.ray_at(u, v, &self.pose().axes()?);
        Ok((r.origin, r.dir))
    }

    fn ray_at(&self, u: f64, v: f64, axes: &(Vec3, Vec3, Vec3)) -> Ray {
        let (right, up, fwd) = *axes;
        match self {
            Camera::Orthographic {
                width,
                height,
                extent,
                pose,
            } => {
                let px = extent / *width as f64;
                let sx = (u - *width as f64 / 2.0) * px;
                let sy = (*height as f64 / 2.0 - v) * px;
                Ray {
                    origin: add(pose.position, add(scale(right, sx), scale(up, sy))),
                    dir: fwd,
                }
            }
            Camera::Pinhole {
                fx,
                fy,
                cx,
                cy,
                pose,
                ..
            } => {
                let a = (u - cx) / fx;
                let b = -(v - cy) / fy;
                Ray {
                    origin: pose.position,
                    dir: normalize(add(fwd, add(scale(right, a), scale(up, b)))),
                }
            }
        }
    }

    fn pose(&self) -> &Pose {
        match self {
            Camera::Orthographic { pose, .. } | Camera::Pinhole { pose, .. } => pose,
        }
    }
}

/// A built-in object shape, in world units.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "kebab-case", deny_unknown_fields)]
pub enum Shape {
    Sphere {
        center: Vec3,
        radius: f64,
    },
    /// A square of side `2·half_size` facing `normal`.
    Plane {
        center: Vec3,
        normal: Vec3,
        half_size: f64,
    },
    /// A corrugated sheet like the paper's sample: height a·sin(2πx/period) over a square of
    /// side `2·half_size` in its local XY plane, local +Z tilted `tilt_deg` from the world +Z
    /// toward +Y (a sample leaning back on the bench).
    Corrugated {
        center: Vec3,
        half_size: f64,
        amplitude: f64,
        period: f64,
        tilt_deg: f64,
    },
    /// A triangle mesh from a file (OBJ, STL or PLY; a path relative to the file that names
    /// it), in `units`, placed in the world: rotated about its own origin by `rotation_deg`
    /// (about X, then Y, then Z), then moved to `position` (metres).
    Mesh {
        file: PathBuf,
        #[serde(default)]
        units: Units,
        #[serde(default)]
        rotation_deg: Vec3,
        #[serde(default)]
        position: Vec3,
    },
}

impl Shape {
    /// The shape in a few words, for the operator: "a sphere", "the mesh part.stl".
    pub fn describe(&self) -> String {
        match self {
            Shape::Sphere { .. } => "a sphere".into(),
            Shape::Plane { .. } => "a plane".into(),
            Shape::Corrugated { .. } => "a corrugated sheet".into(),
            Shape::Mesh { file, .. } => format!(
                "the mesh {}",
                file.file_name().map_or(file.display().to_string(), |f| f
                    .to_string_lossy()
                    .into_owned())
            ),
        }
    }

    pub fn unit_sphere() -> Shape {
        Shape::Sphere {
            center: [0.0; 3],
            radius: 1.0,
        }
    }

    /// First hit of a ray: (distance, outward unit normal).
    fn intersect(&self, ray: &Ray) -> Option<(f64, Vec3)> {
        match self {
            Shape::Sphere { center, radius } => {
                let oc = sub(ray.origin, *center);
                let b = dot(oc, ray.dir);
                let c = dot(oc, oc) - radius * radius;
                let disc = b * b - c;
                if disc < 0.0 {
                    return None;
                }
                let t = -b - disc.sqrt();
                (t > 0.0).then(|| {
                    (
                        t,
                        normalize(sub(add(ray.origin, scale(ray.dir, t)), *center)),
                    )
                })
            }
            Shape::Plane {
                center,
                normal,
                half_size,
            } => {
                let n = normalize(*normal);
                let denom = dot(ray.dir, n);
                if denom.abs() < 1e-12 {
                    return None;
                }
                let t = dot(sub(*center, ray.origin), n) / denom;
                let p = sub(add(ray.origin, scale(ray.dir, t)), *center);
                let (tu, tv) = tangent_frame(n);
                (t > 0.0 && dot(p, tu).abs() <= *half_size && dot(p, tv).abs() <= *half_size)
                    .then_some((t, n))
            }
            Shape::Corrugated {
                center,
                half_size,
                amplitude,
                period,
                tilt_deg,
            } => corrugated_hit(
                ray,
                *center,
                *half_size,
                *amplitude,
                *period,
                tilt_deg.to_radians(),
            ),
            // Cast through its hierarchy, built once per image ([`PixelGeometry::of_mesh`]).
            Shape::Mesh { .. } => None,
        }
    }

    /// The mesh a `Shape::Mesh` names, read and placed in the world.
    pub fn mesh(&self) -> Result<Option<Mesh>> {
        match self {
            Shape::Mesh {
                file,
                units,
                rotation_deg,
                position,
            } => Ok(Some(Mesh::read(
                file,
                &Placement {
                    units: *units,
                    rotation_deg: *rotation_deg,
                    position: *position,
                },
            )?)),
            _ => Ok(None),
        }
    }
}

/// Local axes of the corrugated sheet in the world: x stays world X, z tilts toward +Y.
fn corrugated_axes(tilt: f64) -> (Vec3, Vec3, Vec3) {
    let (s, c) = tilt.sin_cos();
    ([1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c])
}

fn corrugated_hit(
    ray: &Ray,
    center: Vec3,
    half: f64,
    a: f64,
    period: f64,
    tilt: f64,
) -> Option<(f64, Vec3)> {
    let (ex, ey, ez) = corrugated_axes(tilt);
    let to_local = |v: Vec3| [dot(v, ex), dot(v, ey), dot(v, ez)];
    let o = to_local(sub(ray.origin, center));
    let d = to_local(ray.dir);
    let k = 2.0 * std::f64::consts::PI / period;
    let g = |t: f64| (o[2] + t * d[2]) - a * (k * (o[0] + t * d[0])).sin();
    // Bracket the slab |z| ≤ a, march in steps well below the period, then bisect.
    if d[2].abs() < 1e-12 {
        return None;
    }
    let (t0, t1) = {
        let ta = (a - o[2]) / d[2];
        let tb = (-a - o[2]) / d[2];
        (ta.min(tb).max(0.0), ta.max(tb))
    };
    if t1 <= t0 {
        return None;
    }
    let horizontal = (d[0] * d[0] + d[1] * d[1]).sqrt().max(1e-9);
    let step = (period / 64.0 / horizontal).min((t1 - t0) / 8.0).max(1e-9);
    let mut ta = t0;
    let mut ga = g(ta);
    while ta < t1 {
        let tb = (ta + step).min(t1);
        let gb = g(tb);
        if ga == 0.0 || ga.signum() != gb.signum() {
            let (mut lo, mut hi) = (ta, tb);
            for _ in 0..60 {
                let mid = 0.5 * (lo + hi);
                if g(mid).signum() == ga.signum() {
                    lo = mid
                } else {
                    hi = mid
                }
            }
            let t = 0.5 * (lo + hi);
            let x = o[0] + t * d[0];
            let y = o[1] + t * d[1];
            if x.abs() > half || y.abs() > half {
                return None;
            }
            let slope = a * k * (k * x).cos();
            let n_local = normalize([-slope, 0.0, 1.0]);
            let n = add(
                scale(ex, n_local[0]),
                add(scale(ey, n_local[1]), scale(ez, n_local[2])),
            );
            return Some((t, n));
        }
        ta = tb;
        ga = gb;
    }
    None
}

/// One object pixel: image position, world normal and unit view vector (toward the camera),
/// and, on a mesh, the object that may hide some of its lights.
#[derive(Clone, Debug, PartialEq)]
pub struct GeomPixel {
    pub x: u32,
    pub y: u32,
    pub normal: [f32; 3],
    pub view: [f32; 3],
    /// `None` for the analytic shapes and normal maps, which are taken as convex.
    pub shadow: Option<Shadow>,
}

impl GeomPixel {
    fn new(x: usize, y: usize, normal: Vec3, view: Vec3) -> GeomPixel {
        GeomPixel {
            x: x as u32,
            y: y as u32,
            normal: normal.map(|c| c as f32),
            view: view.map(|c| c as f32),
            shadow: None,
        }
    }
}

/// The object pixels of an image; pixels not listed are outside the mask.
#[derive(Clone, Debug)]
pub struct PixelGeometry {
    pub width: usize,
    pub height: usize,
    pub pixels: Vec<GeomPixel>,
}

impl PixelGeometry {
    /// The same pixels as if the object hid none of its own lights: what brdfd assumed before
    /// meshes cast shadows, kept to measure how much the occlusion matters.
    pub fn without_occlusion(&self) -> PixelGeometry {
        let mut g = self.clone();
        for px in &mut g.pixels {
            px.shadow = None;
        }
        g
    }
}

/// The surface a ray `hit` at `p`, on the side `toward` points to (toward where the ray came
/// from): its normal, and how far off the surface rays from it must start. The side seen
/// counts: a sheet has two, a file's winding may be inside out, and its normals may disagree
/// with its winding. Rays start above the faces around the point: an interpolated normal tilts
/// from its face, so the face's corners (and its neighbours', about as much) stand above the
/// normal's tangent plane; as high as that, twice over, so that a faceted convex surface does
/// not hide its own light, and never less than 10⁻⁵ of the mesh's `diagonal`.
pub(crate) fn seen_side(
    mesh: &Mesh,
    hit: &Hit,
    p: Vec3,
    toward: Vec3,
    diagonal: f64,
) -> (Vec3, f64) {
    let [a, b, c] = mesh.corners(hit.triangle);
    let mut face = normalize(cross(sub(b, a), sub(c, a)));
    if dot(face, toward) < 0.0 {
        face = scale(face, -1.0);
    }
    let mut n = mesh.normal_at(hit.triangle, hit.u, hit.v);
    if dot(n, face) < 0.0 {
        n = scale(n, -1.0);
    }
    let above = [a, b, c]
        .iter()
        .map(|q| dot(n, sub(*q, p)))
        .fold(0.0, f64::max);
    (n, 2.0 * above + 1e-5 * diagonal)
}

/// Pixels whose normal is within this many degrees of perpendicular to the view are dropped:
/// silhouette pixels mix object and background.
pub const GRAZING_LIMIT_DEG: f64 = 85.0;

/// A mesh pixel whose 4-neighbour's surface point is farther than this many footprints
/// (allowing for the slope) is across a depth discontinuity, and mixes two surfaces: it is
/// dropped. A smooth surface's neighbours are one footprint apart, up to the slope's change
/// between them; a groove's wall seen past its rim is many.
pub const DEPTH_JUMP: f64 = 3.0;

/// A mesh this many times wider than the camera's view, or this many times narrower, was most
/// likely read in the wrong units (a part in millimetres read as metres is 1000× too big).
const UNIT_MISTAKE: f64 = 100.0;

/// A warning for a mesh whose size is far from what the camera frames, with the size found.
pub fn scale_warning(camera: &Camera, mesh: &Mesh) -> Option<String> {
    let (lo, hi) = mesh.bounds();
    // The box's longest side: what a ruler across the part would say.
    let size = (0..3).map(|i| hi[i] - lo[i]).fold(0.0, f64::max);
    let pose = camera.pose();
    let view = match camera {
        Camera::Orthographic { extent, .. } => *extent,
        Camera::Pinhole { fx, width, .. } => {
            let to = sub(pose.look_at, pose.position);
            dot(to, to).sqrt() * *width as f64 / fx
        }
    };
    (size > view * UNIT_MISTAKE || size * UNIT_MISTAKE < view).then(|| {
        format!(
            "the mesh is {size:.4} m across and the camera's view {view:.4} m wide: are its units right (`units = \"mm\"` for a file in millimetres)?"
        )
    })
}

impl PixelGeometry {
    /// Leaves out the object's outline: pixels with a neighbour (of the eight, within the
    /// frame) that is not an object pixel. A RAW file's demosaic fills each pixel's missing
    /// colours from its neighbours, so on the outline it mixes in the background: on the
    /// simulated gold sphere at 96² that 1-pixel rim held 97% of a RAW merge's squared error.
    pub fn drop_outline(&mut self) {
        let (w, h) = (self.width, self.height);
        let mut object = vec![false; w * h];
        for p in &self.pixels {
            object[p.y as usize * w + p.x as usize] = true;
        }
        self.pixels.retain(|p| {
            let (x, y) = (p.x as i64, p.y as i64);
            (-1..=1).all(|dy| {
                (-1..=1).all(|dx| {
                    let (nx, ny) = (x + dx, y + dy);
                    let in_frame = (0..w as i64).contains(&nx) && (0..h as i64).contains(&ny);
                    !in_frame || object[ny as usize * w + nx as usize]
                })
            })
        });
    }

    /// Casts one ray per pixel centre.
    pub fn rasterize(camera: &Camera, shape: &Shape) -> Result<PixelGeometry> {
        if let Some(mesh) = shape.mesh()? {
            return PixelGeometry::of_mesh(camera, &mesh);
        }
        let axes = camera.pose().axes()?;
        let (width, height) = camera.size();
        let min_cos = GRAZING_LIMIT_DEG.to_radians().cos();
        let seen = |x: usize, y: usize| {
            let ray = camera.ray(x, y, &axes);
            let (_, n) = shape.intersect(&ray)?;
            let v = scale(ray.dir, -1.0);
            (dot(n, v) > min_cos).then(|| GeomPixel::new(x, y, n, v))
        };
        // A 16-megapixel photo's object is millions of pixels, a quarter of a gigabyte: one
        // thread growing a list of them spent most of its time copying and faulting pages in.
        // So each row is counted first, then all rows are written in parallel, each straight
        // into its own part of one list.
        let counts: Vec<usize> = (0..height)
            .into_par_iter()
            .map(|y| (0..width).filter(|x| seen(*x, y).is_some()).count())
            .collect();
        let total = counts.iter().sum();
        let mut pixels: Vec<GeomPixel> = Vec::with_capacity(total);
        let mut rows = Vec::with_capacity(height);
        let mut rest = &mut pixels.spare_capacity_mut()[..total];
        for (y, count) in counts.iter().enumerate() {
            let (row, after) = rest.split_at_mut(*count);
            rows.push((y, row));
            rest = after;
        }
        rows.into_par_iter().for_each(|(y, row)| {
            let mut slots = row.iter_mut();
            for px in (0..width).filter_map(|x| seen(x, y)) {
                slots
                    .next()
                    .expect("a row has as many pixels as when it was counted")
                    .write(px);
            }
            assert!(
                slots.next().is_none(),
                "a row has as many pixels as when it was counted"
            );
        });
        // SAFETY: the rows cover the first `total` slots, and each row's slots were all
        // written (the asserts above), so they hold initialised pixels.
        unsafe { pixels.set_len(total) };
        Ok(PixelGeometry {
            width,
            height,
            pixels,
        })
    }

    /// A mesh as the camera sees it: one ray per pixel centre through the mesh's hierarchy, the
    /// normal interpolated where the mesh has normals (flat otherwise) and turned toward the
    /// camera. A pixel is kept only where its footprint lies on one smooth piece of surface:
    /// not on the silhouette (a 4-neighbour misses the mesh), not across a depth
    /// discontinuity (a 4-neighbour's point is farther than [`DEPTH_JUMP`] footprints, allowing
    /// for the slope), not at a grazing angle.
    pub fn of_mesh(camera: &Camera, mesh: &Mesh) -> Result<PixelGeometry> {
        let axes = camera.pose().axes()?;
        let (width, height) = camera.size();
        if let Some(w) = scale_warning(camera, mesh) {
            tracing::warn!("{w}");
        }
        let bvh = Bvh::build(mesh);
        let min_cos = GRAZING_LIMIT_DEG.to_radians().cos();
        // Per pixel: the hit point, the normal, the view vector, the footprint's size, and how
        // far off the surface its shadow rays start.
        type Sample = (Vec3, Vec3, Vec3, f64, f64);
        let (lo, hi) = mesh.bounds();
        let diagonal = dot(sub(hi, lo), sub(hi, lo)).sqrt();
        let samples: Vec<Option<Sample>> = (0..width * height)
            .into_par_iter()
            .map(|i| {
                let ray = camera.ray(i % width, i / width, &axes);
                let hit = bvh.closest(ray.origin, ray.dir, 0.0, f64::INFINITY)?;
                let v = scale(ray.dir, -1.0);
                let footprint = match camera {
                    Camera::Orthographic { extent, width, .. } => extent / *width as f64,
                    Camera::Pinhole { fx, .. } => hit.t / fx,
                };
                let p = add(ray.origin, scale(ray.dir, hit.t));
                let (n, lift) = seen_side(mesh, &hit, p, v, diagonal);
                Some((p, n, v, footprint, lift))
            })
            .collect();
        if samples.iter().all(Option::is_none) {
            let (lo, hi) = mesh.bounds();
            return Err(CoreError::Invalid(format!(
                "the mesh is outside the camera's view: it spans {lo:.3?} to {hi:.3?} (metres), and no pixel's ray meets it; check its position and units, and the camera's pose"
            )));
        }
        let at = |x: i64, y: i64| -> Option<&Sample> {
            if !(0..width as i64).contains(&x) || !(0..height as i64).contains(&y) {
                return None;
            }
            samples[y as usize * width + x as usize].as_ref()
        };
        let mut pixels = Vec::new();
        let mut points = Vec::new();
        for y in 0..height as i64 {
            for x in 0..width as i64 {
                let Some(&(p, n, v, footprint, lift)) = at(x, y) else {
                    continue;
                };
                let cos = dot(n, v);
                if cos <= min_cos {
                    continue;
                }
                // Neighbouring points of one surface are about a footprint apart, more where
                // it slopes away from the camera.
                let spacing = footprint / cos;
                // Beyond the frame's edge nothing is known, as for the analytic shapes.
                let in_frame = |x: i64, y: i64| {
                    (0..width as i64).contains(&x) && (0..height as i64).contains(&y)
                };
                let smooth = [(1, 0), (-1, 0), (0, 1), (0, -1)].iter().all(|(dx, dy)| {
                    !in_frame(x + dx, y + dy)
                        || at(x + dx, y + dy).is_some_and(|q| {
                            let d = sub(q.0, p);
                            dot(d, d).sqrt() <= DEPTH_JUMP * spacing
                        })
                });
                if smooth {
                    pixels.push(GeomPixel::new(x as usize, y as usize, n, v));
                    points.push(Point {
                        origin: add(p, scale(n, lift)).map(|c| c as f32),
                        normal: n.map(|c| c as f32),
                    });
                }
            }
        }
        let surface = std::sync::Arc::new(Surface::new(mesh.clone(), bvh));
        let occluder = std::sync::Arc::new(Occluder::of_surface(surface, points));
        for (id, px) in pixels.iter_mut().enumerate() {
            px.shadow = Some(Shadow {
                occluder: occluder.clone(),
                id: id as u32,
            });
        }
        Ok(PixelGeometry {
            width,
            height,
            pixels,
        })
    }

    /// Reads world-frame normals from an EXR (RGB = x, y, z); pixels whose normal has length
    /// below ½ are outside the mask. View vectors come from `camera`, resized to the map.
    pub(crate) fn from_normal_map(path: &Path, camera: &Camera) -> Result<PixelGeometry> {
        let map = super::envmap::EnvMap::load_raw_exr(path)?;
        let camera = camera.resized(map.0, map.1);
        let axes = camera.pose().axes()?;
        let min_cos = GRAZING_LIMIT_DEG.to_radians().cos();
        let mut pixels = Vec::new();
        for (i, p) in map.2.iter().enumerate() {
            let n = p.map(|c| c as f64);
            if p.iter().any(|c| !c.is_finite()) {
                return Err(CoreError::NonFinite {
                    what: path.display().to_string(),
                    x: i % map.0,
                    y: i / map.0,
                    channel: 0,
                    value: p[0],
                });
            }
            if dot(n, n) < 0.25 {
                continue;
            }
            let (x, y) = (i % map.0, i / map.0);
            let v = scale(camera.ray(x, y, &axes).dir, -1.0);
            let n = normalize(n);
            if dot(n, v) > min_cos {
                pixels.push(GeomPixel::new(x, y, n, v));
            }
        }
        Ok(PixelGeometry {
            width: map.0,
            height: map.1,
            pixels,
        })
    }
}

/// The largest image side a geometry may ask for: beyond any camera's, and it bounds the
/// per-pixel buffers before they are allocated.
pub const MAX_IMAGE_SIDE: usize = 65_536;

/// Geometry as a rig or the command line describes it: a camera plus a shape or normal map.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneGeometry {
    pub camera: Camera,
    #[serde(default)]
    pub shape: Option<Shape>,
    #[serde(default)]
    pub normal_map: Option<PathBuf>,
}

impl SceneGeometry {
    /// Reads a TOML geometry file; errors name the file, line and field.
    pub fn read(path: &Path) -> Result<SceneGeometry> {
        let text = std::fs::read_to_string(path).map_err(|e| CoreError::io(path, e))?;
        let mut g: SceneGeometry =
            toml::from_str(&text).map_err(|e| CoreError::format(path.display(), e.to_string()))?;
        g.check()
            .map_err(|e| CoreError::format(path.display(), e))?;
        g.resolve_files(path.parent().unwrap_or(Path::new(".")));
        Ok(g)
    }

    /// Files named relative to the file that names them (a normal map, a mesh) are found
    /// beside it: `dir` is that file's folder.
    pub fn resolve_files(&mut self, dir: &Path) {
        if let Some(nm) = &self.normal_map {
            if nm.is_relative() {
                self.normal_map = Some(dir.join(nm));
            }
        }
        if let Some(Shape::Mesh { file, .. }) = &mut self.shape {
            if file.is_relative() && !super::mesh::is_builtin(file) {
                *file = dir.join(&*file);
            }
        }
    }

    /// Checks every number a file can get wrong, so that a typo is an error naming the field
    /// rather than a NaN image or an empty mask later: sizes, intrinsics, the pose, the
    /// shape's dimensions.
    pub fn check(&self) -> std::result::Result<(), String> {
        let finite = |field: &str, v: &[f64]| -> std::result::Result<(), String> {
            match v.iter().find(|x| !x.is_finite()) {
                Some(x) => Err(format!("{field} must be a finite number, not {x}")),
                None => Ok(()),
            }
        };
        let positive = |field: &str, v: f64| -> std::result::Result<(), String> {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(format!("{field} must be a positive number, not {v}"))
            }
        };
        let (width, height) = self.camera.size();
        for (field, n) in [("camera.width", width), ("camera.height", height)] {
            if !(1..=MAX_IMAGE_SIDE).contains(&n) {
                return Err(format!(
                    "{field} {n} is outside 1..={MAX_IMAGE_SIDE} pixels"
                ));
            }
        }
        let pose = match &self.camera {
            Camera::Orthographic { extent, pose, .. } => {
                positive("camera.extent", *extent)?;
                pose
            }
            Camera::Pinhole {
                fx,
                fy,
                cx,
                cy,
                pose,
                ..
            } => {
                positive("camera.fx", *fx)?;
                positive("camera.fy", *fy)?;
                finite("camera.cx, cy", &[*cx, *cy])?;
                pose
            }
        };
        finite("camera.position", &pose.position)?;
        finite("camera.look_at", &pose.look_at)?;
        finite("camera.up", &pose.up)?;
        pose.axes().map_err(|e| e.to_string())?;
        match &self.shape {
            Some(Shape::Sphere { center, radius }) => {
                finite("shape.center", center)?;
                positive("shape.radius", *radius)?;
            }
            Some(Shape::Plane {
                center,
                normal,
                half_size,
            }) => {
                finite("shape.center", center)?;
                finite("shape.normal", normal)?;
                if dot(*normal, *normal) == 0.0 {
                    return Err("shape.normal must not be zero".into());
                }
                positive("shape.half_size", *half_size)?;
            }
            Some(Shape::Corrugated {
                center,
                half_size,
                amplitude,
                period,
                tilt_deg,
            }) => {
                finite("shape.center", center)?;
                positive("shape.half_size", *half_size)?;
                finite("shape.amplitude, tilt_deg", &[*amplitude, *tilt_deg])?;
                positive("shape.period", *period)?;
            }
            Some(Shape::Mesh {
                rotation_deg,
                position,
                ..
            }) => {
                finite("shape.rotation_deg", rotation_deg)?;
                finite("shape.position", position)?;
            }
            None => {}
        }
        Ok(())
    }

    /// Per-pixel geometry at the given image size.
    pub fn pixels(&self, width: usize, height: usize) -> Result<PixelGeometry> {
        let camera = self.camera.resized(width, height);
        match (&self.shape, &self.normal_map) {
            (Some(shape), None) => PixelGeometry::rasterize(&camera, shape),
            (None, Some(path)) => {
                let g = PixelGeometry::from_normal_map(path, &camera)?;
                if (g.width, g.height) != (width, height) {
                    return Err(CoreError::Invalid(format!(
                        "normal map {} is {}×{} but the photo is {width}×{height}",
                        path.display(),
                        g.width,
                        g.height
                    )));
                }
                Ok(g)
            }
            _ => Err(CoreError::Invalid(
                "geometry needs exactly one of `shape` or `normal_map`".into(),
            )),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dropping_the_outline_keeps_pixels_whose_neighbours_are_all_on_the_object() {
        let camera = Camera::eval_orthographic(16);
        let mut g = PixelGeometry::rasterize(&camera, &Shape::unit_sphere()).unwrap();
        let before: std::collections::HashSet<_> = g.pixels.iter().map(|p| (p.x, p.y)).collect();
        g.drop_outline();
        assert!(!g.pixels.is_empty() && g.pixels.len() < before.len());
        for p in &g.pixels {
            for (dx, dy) in [
                (-1i64, -1i64),
                (0, -1),
                (1, -1),
                (-1, 0),
                (1, 0),
                (-1, 1),
                (0, 1),
                (1, 1),
            ] {
                let (nx, ny) = (p.x as i64 + dx, p.y as i64 + dy);
                if !(0..16).contains(&nx) || !(0..16).contains(&ny) {
                    continue; // the frame's edge is not the object's
                }
                let n = (nx as u32, ny as u32);
                assert!(before.contains(&n), "{:?} kept beside {n:?}", (p.x, p.y));
            }
        }
        // A plane filling the frame has no outline: the frame's edge is not one.
        let plane = Shape::Plane {
            center: [0.0, 0.0, 0.0],
            normal: [0.0, 0.0, 1.0],
            half_size: 10.0,
        };
        let mut g = PixelGeometry::rasterize(&camera, &plane).unwrap();
        let n = g.pixels.len();
        g.drop_outline();
        assert_eq!(g.pixels.len(), n);
    }

    #[test]
    fn sphere_normals_face_the_orthographic_camera() {
        let g = PixelGeometry::rasterize(&Camera::eval_orthographic(64), &Shape::unit_sphere())
            .unwrap();
        // π/4 of the frame is disc; the grazing cut removes a thin rim.
        let frac = g.pixels.len() as f64 / (64.0 * 64.0);
        assert!(frac > 0.70 && frac < std::f64::consts::FRAC_PI_4, "{frac}");
        let centre = g.pixels.iter().find(|p| p.x == 32 && p.y == 32).unwrap();
        assert!(centre.normal[2] > 0.99 && centre.view == [0.0, 0.0, 1.0]);
        // Image right is world +X, image up is world +Y.
        let right = g.pixels.iter().find(|p| p.x == 60 && p.y == 32).unwrap();
        assert!(right.normal[0] > 0.8);
        let top = g.pixels.iter().find(|p| p.x == 32 && p.y == 4).unwrap();
        assert!(top.normal[1] > 0.8);
    }

    #[test]
    fn rows_written_side_by_side_list_each_seen_pixel_once_in_reading_order() {
        // An off-centre sphere, so that rows hold different counts and some hold none.
        let camera = Camera::Orthographic {
            width: 97,
            height: 61,
            extent: 3.0,
            pose: Pose {
                position: [0.4, -0.3, 10.0],
                look_at: [0.4, -0.3, 0.0],
                up: [0.0, 1.0, 0.0],
            },
        };
        let shape = Shape::unit_sphere();
        let g = PixelGeometry::rasterize(&camera, &shape).unwrap();
        let axes = camera.pose().axes().unwrap();
        let min_cos = GRAZING_LIMIT_DEG.to_radians().cos();
        let mut expected = Vec::new();
        for y in 0..61 {
            for x in 0..97 {
                let ray = camera.ray(x, y, &axes);
                if let Some((_, n)) = shape.intersect(&ray) {
                    if dot(n, scale(ray.dir, -1.0)) > min_cos {
                        expected.push((x as u32, y as u32, n.map(|c| c as f32)));
                    }
                }
            }
        }
        let got: Vec<_> = g.pixels.iter().map(|p| (p.x, p.y, p.normal)).collect();
        assert!(!got.is_empty() && got.len() < 97 * 61);
        assert_eq!(got, expected);
    }

    #[test]
    fn geometry_files_with_impossible_numbers_are_refused() {
        // Issue 20, D14: each of these passed `config check` before.
        let good = SceneGeometry {
            camera: Camera::eval_orthographic(64),
            shape: Some(Shape::unit_sphere()),
            normal_map: None,
        };
        assert_eq!(good.check(), Ok(()));
        let pinhole = |fx: f64, width: usize| Camera::Pinhole {
            width,
            height: 64,
            fx,
            fy: 100.0,
            cx: 32.0,
            cy: 32.0,
            pose: Pose {
                position: [0.0, 0.0, 5.0],
                look_at: [0.0; 3],
                up: up_y(),
            },
        };
        let cases = [
            (pinhole(f64::NAN, 64), Shape::unit_sphere(), "camera.fx"),
            (pinhole(100.0, 0), Shape::unit_sphere(), "camera.width"),
            (
                pinhole(100.0, 64),
                Shape::Sphere {
                    center: [0.0; 3],
                    radius: -5.0,
                },
                "shape.radius",
            ),
            (
                Camera::Orthographic {
                    width: 64,
                    height: 64,
                    extent: 2.0,
                    pose: Pose {
                        position: [1.0; 3],
                        look_at: [1.0; 3],
                        up: up_y(),
                    },
                },
                Shape::unit_sphere(),
                "look_at equals position",
            ),
        ];
        for (camera, shape, says) in cases {
            let g = SceneGeometry {
                camera,
                shape: Some(shape),
                normal_map: None,
            };
            let e = g.check().unwrap_err();
            assert!(e.contains(says), "{e}");
        }
    }

    #[test]
    fn corrugated_sheet_has_varied_normals() {
        let shape = Shape::Corrugated {
            center: [0.0; 3],
            half_size: 1.0,
            amplitude: 0.15,
            period: 0.5,
            tilt_deg: 20.0,
        };
        let g = PixelGeometry::rasterize(&Camera::eval_orthographic(64), &shape).unwrap();
        assert!(g.pixels.len() > 2000);
        let min_x = g.pixels.iter().map(|p| p.normal[0]).fold(1.0f32, f32::min);
        let max_x = g.pixels.iter().map(|p| p.normal[0]).fold(-1.0f32, f32::max);
        // Slope a·2π/period ≈ 1.9, so normals swing about ±60° across each ridge.
        assert!(min_x < -0.7 && max_x > 0.7, "{min_x} {max_x}");
    }
}
