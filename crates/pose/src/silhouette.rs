//! The object's own pose on the bench, refined from its silhouette: the mesh's outline,
//! rasterised through the calibrated camera, aligned with the object's outline in photos
//! (the object against the empty bench, at each turntable view).
//!
//! The photo's mask is soft: a pixel on the outline covers the object by the share its
//! difference from the empty bench is of the object's contrast nearby. A lens's blur keeps
//! that share's sum, so the soft mask's outline is where the object's is, not a blur's width
//! outside it (a threshold on the difference would put it there, and move the object toward
//! the camera to fill it). The mesh's mask is soft the same way: 4 × 4 samples a pixel.
//!
//! The offset searched is what an object set down on a turntable gets wrong: where it stands
//! (a translation) and which way it faces (a turn about the vertical through its middle). A
//! pattern search maximises the masks' intersection over union, summed over the views; a
//! single view pins the distance from the camera only through the outline's size, the
//! turntable's slanted views pin it as well as the rest.

use nalgebra::Vector3;

use super::{pinhole, Extrinsics, Intrinsics};
use crate::error::{fail, Result};
use brdfd_core::brdf::Vec3;
use brdfd_core::geometry::{Camera, Shape};
use brdfd_core::mesh::{rotation, Mesh};

/// Samples per pixel each way in the mesh's mask.
const SUPERSAMPLE: usize = 4;
/// Pixels within this of the outline of what differs from the bench are given a share;
/// others are in or out. That outline stands outside the object's by about the blur's width
/// (it is where the difference rises above the noise), so the band reaches well inside.
const BAND: usize = 4;
/// The largest side, in pixels, the object's region is searched at; a larger photo is
/// averaged down to it (a 16 MP photo's outline is no better a guide than its 400-px one
/// once the blur of its lens is counted, and it costs 100× the time).
const MAX_REGION_SIDE: usize = 400;
/// Fewest pixels the object must cover in a photo to be told from noise.
const MIN_OBJECT_PIXELS: usize = 50;
/// The search goes no further than this from where the rig places the object: farther, the
/// placement is wrong, not a few millimetres off.
const MAX_SHIFT_M: f64 = 0.03;
const MAX_TURN_DEG: f64 = 20.0;

/// How much of each pixel the object covers, 0 to 1.
#[derive(Debug, Clone, PartialEq)]
pub struct Mask {
    pub width: usize,
    pub height: usize,
    pub cover: Vec<f32>,
}

impl Mask {
    /// The object's mask from a photo of it and one of the empty bench from the same place,
    /// at the same exposure (8-bit grey). The difference's noise is measured from the photo
    /// (most of a frame is bench); the object is the largest piece that differs by more, its
    /// holes filled (the outline is what is aligned).
    pub fn from_photos(
        empty: &image::GrayImage,
        object: &image::GrayImage,
        name: &str,
    ) -> Result<Mask> {
        if empty.dimensions() != object.dimensions() {
            fail!(
                Photos,
                "{name}: the object's photo is {}×{} and the empty bench's {}×{}: they must be of one camera at one size",
                object.width(),
                object.height(),
                empty.width(),
                empty.height()
            );
        }
        let (w, h) = (object.width() as usize, object.height() as usize);
        // The difference is taken in linear light, in 255ths of white: a blurred edge mixes
        // the object's radiance with the bench's, and only there is a pixel's share of the
        // object its share of the contrast (in sRGB a bright object's edge would look wider).
        let linear = |v: u8| brdfd_core::raster::srgb_to_linear(v as f32 / 255.0) * 255.0;
        let diff: Vec<f32> = object
            .pixels()
            .zip(empty.pixels())
            .map(|(a, b)| (linear(a.0[0]) - linear(b.0[0])).abs())
            .collect();
        // The median of |a − b| over bench pixels is 0.674 σ of the difference's noise. A
        // clean JPEG's may be 0; the floor is then a code and a half at the bench's level
        // (its codes are 2 of 255 apart in linear light on white card), and 2 at least.
        let sigma = median(diff.clone()) / 0.6745;
        let level = median(empty.pixels().map(|p| p.0[0] as f32).collect()) as u8;
        let code = linear(level.saturating_add(1)) - linear(level);
        let floor = (1.5 * code).max(2.0);
        let threshold = (5.0 * sigma).max(floor);
        let seen: Vec<bool> = diff.iter().map(|d| *d > threshold).collect();
        let object_px = largest_piece(&seen, w, h);
        let count = object_px.iter().filter(|p| **p).count();
        if count < MIN_OBJECT_PIXELS {
            fail!(
                Silhouette,
                "{name}: no object found: the photo differs from the empty bench's by more than {threshold:.1} of 255 in linear light (5 σ of its noise, at least {floor:.1}) in {count} connected pixels; is the object in view, and was the empty photo taken without it?"
            );
        }
        let inside = fill_holes(&object_px, w, h);
        let near = distance_to_edge(&inside, w, h, BAND + 1);
        let interior: Vec<bool> = (0..w * h)
            .map(|i| inside[i] && near[i] > BAND as u8)
            .collect();
        let all_interior: Vec<f32> = (0..w * h)
            .filter(|&i| interior[i])
            .map(|i| diff[i])
            .collect();
        let overall = if all_interior.is_empty() {
            median(
                diff.iter()
                    .zip(&inside)
                    .filter(|(_, s)| **s)
                    .map(|(d, _)| *d)
                    .collect(),
            )
        } else {
            median(all_interior)
        };
        let mut cover = vec![0.0f32; w * h];
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                if near[i] as usize > BAND {
                    cover[i] = if inside[i] { 1.0 } else { 0.0 };
                    continue;
                }
                let contrast = local_contrast(&diff, &interior, w, h, x, y).unwrap_or(overall);
                cover[i] = if contrast > threshold {
                    (diff[i] / contrast).min(1.0)
                } else {
                    inside[i] as u8 as f32
                };
            }
        }
        Ok(Mask {
            width: w,
            height: h,
            cover,
        })
    }

    /// Pixels that cover anything: (x0, y0, x1, y1), ends excluded.
    fn bounds(&self) -> Option<(usize, usize, usize, usize)> {
        let mut b: Option<(usize, usize, usize, usize)> = None;
        for (i, c) in self.cover.iter().enumerate() {
            if *c > 0.0 {
                let (x, y) = (i % self.width, i / self.width);
                b = Some(match b {
                    None => (x, y, x + 1, y + 1),
                    Some((x0, y0, x1, y1)) => (x0.min(x), y0.min(y), x1.max(x + 1), y1.max(y + 1)),
                });
            }
        }
        b
    }

    /// The mask averaged over `f` × `f` blocks (the edge's partial blocks dropped).
    fn shrunk(&self, f: usize) -> Mask {
        let (w, h) = (self.width / f, self.height / f);
        let cover = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                let mut s = 0.0;
                for dy in 0..f {
                    for dx in 0..f {
                        s += self.cover[(y * f + dy) * self.width + x * f + dx];
                    }
                }
                s / (f * f) as f32
            })
            .collect();
        Mask {
            width: w,
            height: h,
            cover,
        }
    }
}

/// The middle value (0 for none).
fn median(mut v: Vec<f32>) -> f32 {
    if v.is_empty() {
        return 0.0;
    }
    let mid = v.len() / 2;
    *v.select_nth_unstable_by(mid, f32::total_cmp).1
}

/// The object's contrast near an outline pixel: the median difference of the interior pixels
/// within 6 (else 10) pixels.
fn local_contrast(
    diff: &[f32],
    interior: &[bool],
    w: usize,
    h: usize,
    x: usize,
    y: usize,
) -> Option<f32> {
    for r in [6usize, 10] {
        let mut v = Vec::new();
        for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
            for xx in x.saturating_sub(r)..(x + r + 1).min(w) {
                if interior[yy * w + xx] {
                    v.push(diff[yy * w + xx]);
                }
            }
        }
        if !v.is_empty() {
            return Some(median(v));
        }
    }
    None
}

/// The largest 8-connected piece of `set`.
fn largest_piece(set: &[bool], w: usize, h: usize) -> Vec<bool> {
    let mut label = vec![0u32; w * h];
    let mut best = (0u32, 0usize);
    let mut next = 0u32;
    let mut stack = Vec::new();
    for start in 0..w * h {
        if !set[start] || label[start] != 0 {
            continue;
        }
        next += 1;
        label[start] = next;
        stack.push(start);
        let mut size = 0;
        while let Some(i) = stack.pop() {
            size += 1;
            for j in neighbours(i % w, i / w, w, h) {
                if set[j] && label[j] == 0 {
                    label[j] = next;
                    stack.push(j);
                }
            }
        }
        if size > best.1 {
            best = (next, size);
        }
    }
    label.iter().map(|l| *l != 0 && *l == best.0).collect()
}

const NEIGHBOURS_8: [(i64, i64); 8] = [
    (-1, -1),
    (0, -1),
    (1, -1),
    (-1, 0),
    (1, 0),
    (-1, 1),
    (0, 1),
    (1, 1),
];

/// The indices of pixel (x, y)'s 8 neighbours inside a `w` × `h` frame.
fn neighbours(x: usize, y: usize, w: usize, h: usize) -> impl Iterator<Item = usize> {
    NEIGHBOURS_8.iter().filter_map(move |(dx, dy)| {
        let (nx, ny) = (x as i64 + dx, y as i64 + dy);
        ((0..w as i64).contains(&nx) && (0..h as i64).contains(&ny))
            .then(|| ny as usize * w + nx as usize)
    })
}

/// `set` with its holes filled: what the frame's edge cannot reach through `!set`
/// (4-connected) is inside.
fn fill_holes(set: &[bool], w: usize, h: usize) -> Vec<bool> {
    let mut outside = vec![false; w * h];
    let mut stack: Vec<usize> = (0..w * h)
        .filter(|&i| {
            let (x, y) = (i % w, i / w);
            !set[i] && (x == 0 || y == 0 || x == w - 1 || y == h - 1)
        })
        .collect();
    for &i in &stack {
        outside[i] = true;
    }
    while let Some(i) = stack.pop() {
        let (x, y) = (i % w, i / w);
        let mut visit = |j: usize| {
            if !set[j] && !outside[j] {
                outside[j] = true;
                stack.push(j);
            }
        };
        if x > 0 {
            visit(i - 1);
        }
        if x + 1 < w {
            visit(i + 1);
        }
        if y > 0 {
            visit(i - w);
        }
        if y + 1 < h {
            visit(i + w);
        }
    }
    outside.iter().map(|o| !o).collect()
}

/// Each pixel's chessboard distance to the nearest pixel on the other side of `set`'s
/// outline, up to `cap`.
fn distance_to_edge(set: &[bool], w: usize, h: usize, cap: usize) -> Vec<u8> {
    let mut d = vec![cap as u8; w * h];
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            let differs = neighbours(x, y, w, h).any(|j| set[j] != set[i]);
            if differs {
                d[i] = 1;
            }
        }
    }
    // Grown a ring at a time: few rings are needed.
    for ring in 2..=cap as u8 {
        let before = d.clone();
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                if before[i] < ring {
                    continue;
                }
                let touches = neighbours(x, y, w, h).any(|j| before[j] == ring - 1);
                if touches {
                    d[i] = ring;
                }
            }
        }
    }
    d
}

/// One view of the object: the camera (as calibrated) and the turntable's angle, and the
/// object's mask in its photo.
pub struct View {
    pub camera: Camera,
    pub turn_deg: f64,
    pub mask: Mask,
}

/// A correction to where the rig places the object: turned by `turn_deg` about the vertical
/// through `pivot` (the placed mesh's middle), then moved by `shift` (metres, world).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Offset {
    pub shift: Vec3,
    pub turn_deg: f64,
    pub pivot: Vec3,
}

impl Offset {
    fn apply(&self, p: Vec3) -> Vec3 {
        let (s, c) = self.turn_deg.to_radians().sin_cos();
        let q = [
            p[0] - self.pivot[0],
            p[1] - self.pivot[1],
            p[2] - self.pivot[2],
        ];
        let turned = [c * q[0] + s * q[2], q[1], -s * q[0] + c * q[2]];
        [0, 1, 2].map(|i| turned[i] + self.pivot[i] + self.shift[i])
    }

    /// The mesh shape placed with the correction: its rotation and position rewritten so
    /// that it stands where the offset puts it. Other shapes are returned as they are.
    pub fn placed(&self, shape: &Shape) -> Shape {
        let Shape::Mesh {
            file,
            units,
            rotation_deg,
            position,
        } = shape
        else {
            return shape.clone();
        };
        let r = rotation(*rotation_deg);
        let (s, c) = self.turn_deg.to_radians().sin_cos();
        let turn = [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]];
        let mut m = [[0.0; 3]; 3];
        for (i, row) in m.iter_mut().enumerate() {
            for (j, v) in row.iter_mut().enumerate() {
                *v = (0..3).map(|k| turn[i][k] * r[k][j]).sum();
            }
        }
        let round = |v: f64, digits: i32| {
            let f = 10f64.powi(digits);
            let r = (v * f).round() / f;
            if r == 0.0 {
                0.0
            } else {
                r
            }
        };
        Shape::Mesh {
            file: file.clone(),
            units: *units,
            rotation_deg: euler_deg(&m).map(|a| round(a, 4)),
            position: self.apply(*position).map(|p| round(p, 7)),
        }
    }
}

/// Rotations about X, then Y, then Z (degrees) for R = Rz·Ry·Rx, as [`rotation`] makes them.
pub fn euler_deg(r: &[[f64; 3]; 3]) -> Vec3 {
    let sy = (-r[2][0]).clamp(-1.0, 1.0);
    let y = sy.asin();
    let (x, z) = if sy.abs() < 1.0 - 1e-12 {
        (r[2][1].atan2(r[2][2]), r[1][0].atan2(r[0][0]))
    } else {
        // Y at ±90°: only X ∓ Z is fixed; Z is taken as 0.
        ((sy * r[0][1]).atan2(r[1][1]), 0.0)
    };
    [x, y, z].map(f64::to_degrees)
}

/// What the search found.
#[derive(Debug, Clone)]
pub struct Refined {
    pub offset: Offset,
    /// The masks' intersection over union, each view, where the rig placed the object and
    /// where the offset puts it.
    pub iou_before: Vec<f64>,
    pub iou_after: Vec<f64>,
    /// Masks compared.
    pub evaluations: usize,
}

/// A view made ready for the search: the camera turned for the view, the mask cut to the
/// object's region (and averaged down if large).
struct Prepared {
    k: Intrinsics,
    e: Extrinsics,
    /// The region searched in the (averaged) mask: x0, y0, width, height.
    region: (usize, usize, usize, usize),
    mask: Vec<f32>,
}

impl Prepared {
    fn new(view: &View) -> Result<Prepared> {
        let Some((k, e)) = pinhole(&view.camera.turned_about_y(-view.turn_deg.to_radians())) else {
            fail!(
                Camera,
                "the object's silhouette is aligned through a pinhole camera"
            );
        };
        let (cw, ch) = view.camera.size();
        if (cw, ch) != (view.mask.width, view.mask.height) {
            fail!(
                Photos,
                "the object's photo is {}×{}, and the camera {cw}×{ch}",
                view.mask.width,
                view.mask.height
            );
        }
        let Some((x0, y0, x1, y1)) = view.mask.bounds() else {
            fail!(Silhouette, "the object's mask is empty");
        };
        let side = (x1 - x0).max(y1 - y0);
        // Room around the object for the search to move it.
        let f = side.div_ceil(MAX_REGION_SIDE / 2).max(1);
        let mask = if f > 1 {
            view.mask.shrunk(f)
        } else {
            view.mask.clone()
        };
        let k = Intrinsics {
            fx: k.fx / f as f64,
            fy: k.fy / f as f64,
            cx: k.cx / f as f64,
            cy: k.cy / f as f64,
        };
        let margin = (side / f / 2).max(8);
        let rx0 = (x0 / f).saturating_sub(margin);
        let ry0 = (y0 / f).saturating_sub(margin);
        let rx1 = (x1.div_ceil(f) + margin).min(mask.width);
        let ry1 = (y1.div_ceil(f) + margin).min(mask.height);
        let (rw, rh) = (rx1 - rx0, ry1 - ry0);
        let cut = (0..rw * rh)
            .map(|i| mask.cover[(ry0 + i / rw) * mask.width + rx0 + i % rw])
            .collect();
        Ok(Prepared {
            k,
            e,
            region: (rx0, ry0, rw, rh),
            mask: cut,
        })
    }

    /// The mesh's soft mask in the region, its vertices placed by `offset`; `None` where a
    /// vertex is behind the camera.
    fn cover(&self, mesh: &Mesh, offset: &Offset, samples: &mut Vec<u8>) -> Option<Vec<f32>> {
        let (x0, y0, w, h) = self.region;
        let s = SUPERSAMPLE;
        let (sw, sh) = (w * s, h * s);
        samples.clear();
        samples.resize(sw * sh, 0);
        let projected: Option<Vec<[f64; 2]>> = mesh
            .positions
            .iter()
            .map(|p| {
                self.e.project(&self.k, offset.apply(*p)).map(|[u, v]| {
                    // Sample coordinates: sample (i, j) is centred at (i + ½, j + ½).
                    [(u - x0 as f64) * s as f64, (v - y0 as f64) * s as f64]
                })
            })
            .collect();
        let projected = projected?;
        for t in &mesh.triangles {
            let [a, b, c] = t.map(|i| projected[i as usize]);
            fill_triangle(a, b, c, sw, sh, samples);
        }
        Some(
            (0..w * h)
                .map(|i| {
                    let (x, y) = (i % w, i / w);
                    let mut n = 0u32;
                    for j in 0..s {
                        let row = &samples[(y * s + j) * sw + x * s..][..s];
                        n += row.iter().map(|v| *v as u32).sum::<u32>();
                    }
                    n as f32 / (s * s) as f32
                })
                .collect(),
        )
    }
}

/// The mesh's soft mask over the whole frame of `camera` at turntable view `turn_deg`,
/// placed by `offset`: the masks the tests align.
#[cfg(test)]
fn outline(mesh: &Mesh, camera: &Camera, turn_deg: f64, offset: &Offset) -> Option<Mask> {
    let (w, h) = camera.size();
    let (k, e) = pinhole(&camera.turned_about_y(-turn_deg.to_radians()))?;
    let p = Prepared {
        k,
        e,
        region: (0, 0, w, h),
        mask: vec![],
    };
    Some(Mask {
        width: w,
        height: h,
        cover: p.cover(mesh, offset, &mut Vec::new())?,
    })
}

/// Marks the samples whose centres the triangle covers (either winding; edges included).
fn fill_triangle(a: [f64; 2], b: [f64; 2], c: [f64; 2], w: usize, h: usize, out: &mut [u8]) {
    let area = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
    if area == 0.0 || !area.is_finite() {
        return;
    }
    let lo = |v: f64| (v - 0.5).ceil().max(0.0) as usize;
    let hi = |v: f64, n: usize| ((v - 0.5).floor() + 1.0).clamp(0.0, n as f64) as usize;
    let (x0, x1) = (
        lo(a[0].min(b[0]).min(c[0])),
        hi(a[0].max(b[0]).max(c[0]), w),
    );
    let (y0, y1) = (
        lo(a[1].min(b[1]).min(c[1])),
        hi(a[1].max(b[1]).max(c[1]), h),
    );
    let sign = area.signum();
    let edge = |p: [f64; 2], q: [f64; 2], x: f64, y: f64| {
        sign * ((q[0] - p[0]) * (y - p[1]) - (q[1] - p[1]) * (x - p[0]))
    };
    for y in y0..y1 {
        let py = y as f64 + 0.5;
        for x in x0..x1 {
            let px = x as f64 + 0.5;
            if edge(a, b, px, py) >= 0.0 && edge(b, c, px, py) >= 0.0 && edge(c, a, px, py) >= 0.0 {
                out[y * w + x] = 1;
            }
        }
    }
}

/// The search's moves, in steps: ± along each of the 4 axes, or ± along two at once.
fn moves(pairs: bool) -> Vec<[f64; 4]> {
    let mut all = Vec::new();
    for i in 0..4 {
        for a in [1.0, -1.0] {
            if !pairs {
                let mut m = [0.0; 4];
                m[i] = a;
                all.push(m);
                continue;
            }
            for j in i + 1..4 {
                for b in [1.0, -1.0] {
                    let mut m = [0.0; 4];
                    (m[i], m[j]) = (a, b);
                    all.push(m);
                }
            }
        }
    }
    all
}

/// Intersection over union of two soft masks.
fn iou(a: &[f32], b: &[f32]) -> (f64, f64) {
    let (mut inter, mut union) = (0.0f64, 0.0f64);
    for (x, y) in a.iter().zip(b) {
        inter += x.min(*y) as f64;
        union += x.max(*y) as f64;
    }
    (inter, union)
}

/// Searches the offset from where the rig places `mesh` (as placed) that best aligns its
/// outline with the views' masks.
pub fn refine(mesh: &Mesh, views: &[View]) -> Result<Refined> {
    if views.is_empty() {
        fail!(
            Photos,
            "no photo of the object to align its silhouette with"
        );
    }
    let prepared = views
        .iter()
        .map(Prepared::new)
        .collect::<Result<Vec<_>>>()?;
    let (lo, hi) = mesh.bounds();
    let pivot = [0, 1, 2].map(|i| (lo[i] + hi[i]) / 2.0);
    let mut samples = Vec::new();
    let mut evaluations = 0;
    // Per view, and summed: the sum weighs each view by its object's size.
    let mut score = |q: &[f64; 4]| -> Option<(f64, Vec<f64>)> {
        evaluations += 1;
        let offset = Offset {
            shift: [q[0], q[1], q[2]],
            turn_deg: q[3],
            pivot,
        };
        let (mut inter, mut union) = (0.0, 0.0);
        let mut each = Vec::new();
        for p in &prepared {
            let cover = p.cover(mesh, &offset, &mut samples)?;
            let (i, u) = iou(&cover, &p.mask);
            inter += i;
            union += u;
            each.push(if u > 0.0 { i / u } else { 0.0 });
        }
        Some((if union > 0.0 { inter / union } else { 0.0 }, each))
    };
    let mut q = [0.0f64; 4];
    let Some((mut best, before)) = score(&q) else {
        fail!(
            Silhouette,
            "the mesh, where the rig places it, reaches behind the camera"
        );
    };
    if best <= 0.0 {
        fail!(Silhouette, "the mesh's outline, where the rig places it, does not overlap the object in the photo: check the shape's position and the object's place on the bench");
    }
    // Steps in metres and degrees, halved until a tenth of a pixel's worth is reached.
    let mut step = [4e-3, 4e-3, 4e-3, 2.0];
    let smallest = [1e-5, 1e-5, 1e-5, 0.005];
    let limit = [MAX_SHIFT_M, MAX_SHIFT_M, MAX_SHIFT_M, MAX_TURN_DEG];
    while step[3] >= smallest[3] {
        let mut moved = false;
        // Along each axis first, then along each pair of them together: a turn and a shift
        // across the view move the outline alike, and a ridge between them stops moves along
        // one axis at a time short of the best.
        for pairs in [false, true] {
            if moved {
                break;
            }
            for m in moves(pairs) {
                let mut t = q;
                for i in 0..4 {
                    t[i] += m[i] * step[i];
                }
                if (0..4).any(|i| t[i].abs() > limit[i]) {
                    continue;
                }
                if let Some((s, _)) = score(&t) {
                    if s > best {
                        (best, q, moved) = (s, t, true);
                    }
                }
            }
        }
        if !moved {
            if step == smallest {
                // A round at the smallest steps has found nothing better.
                break;
            }
            for (s, m) in step.iter_mut().zip(&smallest) {
                *s = (*s / 2.0).max(*m);
            }
        }
    }
    let (_, after) = score(&q).expect("the best offset was scored");
    let near_limit = (0..4).any(|i| q[i].abs() > 0.9 * limit[i]);
    if near_limit {
        fail!(
            Silhouette,
            "the object's silhouette is best matched {:.1} mm and {:.1}° from where the rig places it, at the edge of the search: place the object as the rig's [geometry.shape] says (or correct its position and rotation_deg), then refine again",
            Vector3::new(q[0], q[1], q[2]).norm() * 1000.0,
            q[3]
        );
    }
    Ok(Refined {
        offset: Offset {
            shift: [q[0], q[1], q[2]],
            turn_deg: q[3],
            pivot,
        },
        iou_before: before,
        iou_after: after,
        evaluations,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use brdfd_core::geometry::Pose;

    fn camera() -> Camera {
        Camera::Pinhole {
            width: 640,
            height: 424,
            fx: 2400.0,
            fy: 2400.0,
            cx: 320.0,
            cy: 212.0,
            pose: Pose {
                position: [0.0, 0.25, 1.2],
                look_at: [0.0, 0.0, 0.0],
                up: [0.0, 1.0, 0.0],
            },
        }
    }

    fn block() -> (Shape, Mesh) {
        let shape = Shape::Mesh {
            file: "builtin:grooved-block.obj".into(),
            units: brdfd_core::mesh::Units::Mm,
            rotation_deg: [-25.0, 0.0, 0.0],
            position: [0.0; 3],
        };
        let mesh = shape.mesh().unwrap().unwrap();
        (shape, mesh)
    }

    #[test]
    fn euler_angles_make_the_rotation_back() {
        for deg in [
            [-25.0, 0.0, 0.0],
            [10.0, 35.0, -70.0],
            [170.0, -60.0, 120.0],
        ] {
            let r = rotation(deg);
            let back = rotation(euler_deg(&r));
            for i in 0..3 {
                for j in 0..3 {
                    assert!((r[i][j] - back[i][j]).abs() < 1e-12, "{deg:?}");
                }
            }
        }
    }

    #[test]
    fn the_placement_written_puts_the_mesh_where_the_offset_does() {
        let (shape, mesh) = block();
        let offset = Offset {
            shift: [0.003, -0.001, 0.002],
            turn_deg: 3.0,
            pivot: [0.001, 0.002, -0.004],
        };
        let moved = offset.placed(&shape).mesh().unwrap().unwrap();
        for (a, b) in mesh.positions.iter().zip(&moved.positions) {
            let want = offset.apply(*a);
            for c in 0..3 {
                assert!((want[c] - b[c]).abs() < 1e-6, "{want:?} against {b:?}");
            }
        }
    }

    #[test]
    fn the_search_finds_an_offset_from_masks_of_three_views() {
        let (_, mesh) = block();
        let cam = camera();
        let (lo, hi) = mesh.bounds();
        let pivot = [0, 1, 2].map(|i| (lo[i] + hi[i]) / 2.0);
        let truth = Offset {
            // Off the search's grid of steps (4 mm and 2° halved).
            shift: [0.00273, 0.00041, -0.00338],
            turn_deg: 1.73,
            pivot,
        };
        let views: Vec<View> = [0.0, 30.0, -30.0]
            .iter()
            .map(|&t| View {
                camera: cam.clone(),
                turn_deg: t,
                mask: outline(&mesh, &cam, t, &truth).unwrap(),
            })
            .collect();
        let found = refine(&mesh, &views).unwrap();
        let o = found.offset;
        let miss = (0..3)
            .map(|i| (o.shift[i] - truth.shift[i]).powi(2))
            .sum::<f64>()
            .sqrt();
        assert!(miss < 1e-4, "{o:?}");
        assert!((o.turn_deg - truth.turn_deg).abs() < 0.05, "{o:?}");
        assert!(found.iou_after.iter().all(|v| *v > 0.995), "{found:?}");
        assert!(found.iou_before.iter().all(|v| *v < 0.95), "{found:?}");
    }

    #[test]
    fn a_blurred_outline_gives_a_mask_of_the_objects_own_area() {
        // A disc of radius 40 px, 40% of white over a bench of 5% (linear light), blurred by
        // σ ≈ 0.8 px and written as 8-bit sRGB, as a camera's JPEG is.
        let (w, h) = (160u32, 120u32);
        let truth = |x: f64, y: f64| ((x - 80.3).powi(2) + (y - 61.7).powi(2)).sqrt() < 40.0;
        let sharp: Vec<f64> = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f64, (i / w) as f64);
                let mut n = 0;
                for j in 0..8 {
                    for k in 0..8 {
                        n += truth(x + (j as f64 + 0.5) / 8.0, y + (k as f64 + 0.5) / 8.0) as u32;
                    }
                }
                n as f64 / 64.0
            })
            .collect();
        let kernel = [0.054, 0.244, 0.403, 0.244, 0.054];
        let blur = |v: &[f64], dx: i64, dy: i64| -> Vec<f64> {
            (0..(w * h) as i64)
                .map(|i| {
                    let (x, y) = (i % w as i64, i / w as i64);
                    (0..5)
                        .map(|k| {
                            let (sx, sy) = (
                                (x + dx * (k - 2)).clamp(0, w as i64 - 1),
                                (y + dy * (k - 2)).clamp(0, h as i64 - 1),
                            );
                            kernel[k as usize] * v[(sy * w as i64 + sx) as usize]
                        })
                        .sum()
                })
                .collect()
        };
        let soft = blur(&blur(&sharp, 1, 0), 0, 1);
        let srgb = |v: f64| {
            image::Luma([(brdfd_core::raster::linear_to_srgb(v as f32) * 255.0).round() as u8])
        };
        let empty = image::GrayImage::from_pixel(w, h, srgb(0.05));
        let object =
            image::GrayImage::from_fn(w, h, |x, y| srgb(0.05 + 0.35 * soft[(y * w + x) as usize]));
        let mask = Mask::from_photos(&empty, &object, "disc").unwrap();
        let area: f64 = mask.cover.iter().map(|c| *c as f64).sum();
        let want = std::f64::consts::PI * 1600.0;
        assert!((area / want - 1.0).abs() < 0.005, "{area} against {want}");
        let centre = [0usize, 1].map(|axis| {
            let moment: f64 = (0..(w * h) as usize)
                .map(|i| {
                    let at = if axis == 0 {
                        i % w as usize
                    } else {
                        i / w as usize
                    };
                    (at as f64 + 0.5) * mask.cover[i] as f64
                })
                .sum();
            moment / area
        });
        assert!(
            (centre[0] - 80.3).abs() < 0.02 && (centre[1] - 61.7).abs() < 0.02,
            "{centre:?}"
        );
        // The blur itself spreads a σ·√(2/π)-wide strip along the outline: 3% of this disc.
        let exact: Vec<f32> = sharp.iter().map(|v| *v as f32).collect();
        let (i, u) = iou(&mask.cover, &exact);
        assert!(i / u > 0.96, "IoU {}", i / u);
        // The empty bench again: no object.
        let e = Mask::from_photos(&empty, &empty, "empty.png").unwrap_err();
        assert!(format!("{e}").contains("empty.png: no object found"), "{e}");
    }
}
