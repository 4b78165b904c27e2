//! Light the object throws on itself: one bounce.
//!
//! Where a mesh is concave, a point sees its own surface in some directions instead of the
//! room. Direct light counts those directions as dark ([`super::visibility`]); in a photo they
//! hold what that surface reflects of the room. One bounce adds it back: each hidden direction
//! is followed to the surface it meets, and that surface's radiance toward the point (the BRDF
//! applied to the room's light it sees itself) lights the point as a light in that direction
//! would.
//!
//! A point gathers over [`GATHER`] directions spread over the sphere, one solid angle each.
//! The points met are gathered into cells ([`CELLS_ACROSS`] to the mesh's diagonal, split by
//! which way they face), and each cell's radiance is tabulated once per BRDF and map over a
//! grid of outgoing directions ([`THETA_STEPS`] × [`PHI_STEPS`]), from the map merged to
//! [`SOURCE_GRID`] lights; a point reads it between the grid's nodes. Which direction meets
//! which cell ([`Paths`]) depends on the geometry alone: the estimate follows the paths once
//! and lights them again with each new BRDF.
//!
//! Not here: light that bounces twice or more. Walls of a metal that reflects most of its
//! light pass some of it on again, which one bounce leaves out (docs/evaluation.md).

use std::sync::{Arc, OnceLock};

use rayon::prelude::*;

use super::brdf::{add, dot, fibonacci_sphere, normalize, scale, Vec3};
use super::bvh::Surface;
use super::envmap::LightSet;
use super::geometry::{seen_side, GeomPixel, PixelGeometry};
use super::raster::Raster;
use super::stop::Stop;
use super::visibility::{is_seen, Occluder, Point};
use super::Result;

/// Directions a point gathers its bounced light from, over the whole sphere (half of them
/// above its tangent plane). A GGX lobe of α 0.2 spans about 10 of them.
pub const GATHER: usize = 512;

/// Cells across the mesh's bounding diagonal: the bounced light is read as constant over a
/// cell's width.
pub const CELLS_ACROSS: f64 = 96.0;

/// The grid of a cell's outgoing directions: steps of 1 − cos θ, and of azimuth.
pub const THETA_STEPS: usize = 8;
pub const PHI_STEPS: usize = 16;

/// The map merged onto this grid (azimuth by polar angle) lights the cells: their light is
/// read once more through a BRDF and spread over a pixel's lobe, so a coarse map serves.
pub const SOURCE_GRID: (usize, usize) = (16, 8);

/// Where each pixel's hidden directions lead: for the pixels of one mesh, the gather
/// directions each does not see the room in, and the cell each meets.
pub struct Paths {
    /// Per pixel, in the pixels' order: its steps, a range of `steps`.
    ranges: Vec<std::ops::Range<u32>>,
    steps: Vec<Step>,
    cells: Vec<Cell>,
    /// The cells' points, whose own lights are looked up in it.
    cell_occluder: Occluder,
}

#[derive(Clone, Copy)]
struct Step {
    /// The gather direction's index in [`gather_lights`].
    gather: u16,
    cell: u32,
}

#[derive(Clone, Copy)]
struct Cell {
    normal: Vec3,
}

/// The gather directions as a light set, one solid angle each: the visibility tables take
/// light sets, and find which of these a point sees the room in.
fn gather_lights() -> &'static LightSet {
    static LIGHTS: OnceLock<LightSet> = OnceLock::new();
    LIGHTS.get_or_init(|| {
        let omega = 4.0 * std::f64::consts::PI / GATHER as f64;
        let mut set = LightSet::default();
        for d in fibonacci_sphere(GATHER) {
            set.directions.push(d.map(|c| c as f32));
            set.radiance.push([1.0; 3]);
            set.solid_angle.push(omega as f32);
            set.spread
                .push((omega / std::f64::consts::PI).sqrt() as f32);
        }
        set
    })
}

/// A hidden direction's end: the point met, the normal there turned toward where the ray
/// came from, and how far off the surface the point's own rays must start.
struct Met {
    at: [f32; 3],
    normal: [f32; 3],
    lift: f32,
}

impl Paths {
    /// The paths of `pixels`, which must lie on one mesh's [`Surface`] (the first pixel's:
    /// pixels of another, or off a mesh, have none). `None` when no pixel is on a mesh, or
    /// none hides any direction from itself: a convex part.
    /// Ended early, with [`crate::CoreError::Stopped`], once `stop` is requested: a part of
    /// many triangles takes seconds.
    pub fn new(pixels: &[GeomPixel], stop: &Stop) -> Result<Option<Paths>> {
        let Some(occluder) = pixels.iter().find_map(|p| p.shadow.as_ref()) else {
            return Ok(None);
        };
        let occluder = occluder.occluder.clone();
        let Some(surface) = occluder.surface().cloned() else {
            return Ok(None);
        };
        let gather = gather_lights();
        let table = occluder.table(gather);
        let met: Vec<Vec<(u16, Met)>> = pixels
            .par_iter()
            .map(|px| {
                let Some(s) = px
                    .shadow
                    .as_ref()
                    .filter(|s| Arc::ptr_eq(&s.occluder, &occluder))
                else {
                    return Vec::new();
                };
                if stop.requested() {
                    return Vec::new();
                }
                let point = occluder.points()[s.id as usize];
                let row = table.row(&occluder, s.id);
                let origin = point.origin.map(f64::from);
                let normal = point.normal.map(f64::from);
                (0..GATHER)
                    .filter_map(|g| {
                        let d = gather.directions[g].map(f64::from);
                        if dot(d, normal) <= 0.0 || is_seen(row, g as u32) {
                            return None;
                        }
                        surface.meet(origin, d).map(|m| (g as u16, m))
                    })
                    .collect()
            })
            .collect();
        stop.check()?;
        if met.iter().all(Vec::is_empty) {
            return Ok(None);
        }
        // Cells in the pixels' order, so that the same pixels make the same cells.
        let size = surface.diagonal / CELLS_ACROSS;
        let mut index = std::collections::HashMap::new();
        let mut sums: Vec<(Vec3, Vec3, f64, u32)> = Vec::new();
        let mut ranges = Vec::with_capacity(pixels.len());
        let mut steps = Vec::new();
        for list in &met {
            let start = steps.len() as u32;
            for (g, m) in list {
                let (at, normal) = (m.at.map(f64::from), m.normal.map(f64::from));
                let key = (at.map(|c| (c / size).floor() as i64), facing(normal));
                let cell = *index.entry(key).or_insert_with(|| {
                    sums.push(([0.0; 3], [0.0; 3], 0.0, 0));
                    sums.len() as u32 - 1
                });
                let s = &mut sums[cell as usize];
                s.0 = add(s.0, at);
                s.1 = add(s.1, normal);
                s.2 = s.2.max(m.lift as f64);
                s.3 += 1;
                steps.push(Step { gather: *g, cell });
            }
            ranges.push(start..steps.len() as u32);
        }
        let mut cells = Vec::with_capacity(sums.len());
        let mut points = Vec::with_capacity(sums.len());
        for (at, n, lift, count) in sums {
            let normal = normalize(n);
            let centre = scale(at, 1.0 / count as f64);
            cells.push(Cell { normal });
            points.push(Point {
                origin: add(centre, scale(normal, lift)).map(|c| c as f32),
                normal: normal.map(|c| c as f32),
            });
        }
        Ok(Some(Paths {
            ranges,
            steps,
            cells,
            cell_occluder: Occluder::new(surface.bvh(), points),
        }))
    }

    /// Hidden directions followed, over all pixels.
    pub fn len(&self) -> usize {
        self.steps.len()
    }

    pub fn is_empty(&self) -> bool {
        self.steps.is_empty()
    }

    /// The cells the paths end in.
    pub fn cells(&self) -> usize {
        self.cells.len()
    }

    /// The bounced light each pixel reflects toward its viewer (linear RGB, in the pixels'
    /// order, which must be the order [`Paths::new`] was given): each cell lit by `lights`
    /// through the BRDF `eval`, which takes directions (toward the light, toward the viewer)
    /// in the frame `frame` lays on a normal (tangent, bitangent, normal as x, y, z), and that
    /// light reflected again at the pixel.
    pub fn radiance(
        &self,
        pixels: &[GeomPixel],
        lights: &LightSet,
        frame: impl Fn(Vec3) -> (Vec3, Vec3) + Sync,
        eval: impl Fn(Vec3, Vec3) -> [f64; 3] + Sync,
    ) -> Vec<[f64; 3]> {
        assert_eq!(pixels.len(), self.ranges.len(), "the paths' own pixels");
        let t0 = std::time::Instant::now();
        let sources = super::anisotropy::merged_onto(lights, SOURCE_GRID.0, SOURCE_GRID.1);
        let table = self.cell_occluder.table(&sources);
        let power: Vec<(Vec3, [f64; 3])> = (0..sources.len())
            .map(|k| {
                let omega = sources.solid_angle[k] as f64;
                (
                    sources.directions[k].map(f64::from),
                    sources.radiance[k].map(|r| r as f64 * omega),
                )
            })
            .collect();
        let grids: Vec<Grid> = (0..self.cells.len())
            .into_par_iter()
            .map(|c| {
                let n = self.cells[c].normal;
                let (t, b) = frame(n);
                let local = |d: Vec3| [dot(d, t), dot(d, b), dot(d, n)];
                let row = table.row(&self.cell_occluder, c as u32);
                let lit: Vec<(Vec3, [f64; 3])> = power
                    .iter()
                    .enumerate()
                    .filter(|&(k, (d, _))| dot(*d, n) > 0.0 && is_seen(row, k as u32))
                    .map(|(_, &(d, p))| (local(d), p))
                    .collect();
                Grid::lit(&lit, &eval)
            })
            .collect();
        tracing::debug!(
            "bounce grids: {} cells, {} sources, {:.2} s",
            self.cells.len(),
            sources.len(),
            t0.elapsed().as_secs_f64()
        );
        let gather = gather_lights();
        let omega = 4.0 * std::f64::consts::PI / GATHER as f64;
        pixels
            .par_iter()
            .zip(&self.ranges)
            .map(|(px, range)| {
                if range.is_empty() {
                    return [0.0; 3];
                }
                let n = px.normal.map(f64::from);
                let (t, b) = frame(n);
                let local = |d: Vec3| [dot(d, t), dot(d, b), dot(d, n)];
                let wo = local(px.view.map(f64::from));
                let mut acc = [0.0; 3];
                for step in &self.steps[range.start as usize..range.end as usize] {
                    let d = gather.directions[step.gather as usize].map(f64::from);
                    let wi = local(d);
                    let f = eval(wi, wo);
                    if f == [0.0; 3] {
                        continue;
                    }
                    let cell = self.cells[step.cell as usize];
                    let (ct, cb) = frame(cell.normal);
                    let back = scale(d, -1.0);
                    let out = [dot(back, ct), dot(back, cb), dot(back, cell.normal)];
                    let l = grids[step.cell as usize].at(out);
                    for c in 0..3 {
                        acc[c] += f[c] * l[c] * wi[2] * omega;
                    }
                }
                acc
            })
            .collect()
    }
}

/// Adds to `img`, a render of `geom`'s pixels under `lights`, the light each pixel's own
/// surface throws on it ([`Paths::radiance`], with the BRDF `eval` in the frames `frame`
/// lays): a render of a concave part with one bounce. Nothing changes off a mesh or on a
/// convex one. Returns the hidden directions followed.
pub fn add_to(
    img: &mut Raster,
    geom: &PixelGeometry,
    lights: &LightSet,
    frame: impl Fn(Vec3) -> (Vec3, Vec3) + Sync,
    eval: impl Fn(Vec3, Vec3) -> [f64; 3] + Sync,
) -> usize {
    add_to_until(img, geom, lights, &Stop::default(), frame, eval)
        .expect("nobody can stop a fresh Stop")
}

/// [`add_to`], ended early with [`crate::CoreError::Stopped`] once `stop` is requested.
pub fn add_to_until(
    img: &mut Raster,
    geom: &PixelGeometry,
    lights: &LightSet,
    stop: &Stop,
    frame: impl Fn(Vec3) -> (Vec3, Vec3) + Sync,
    eval: impl Fn(Vec3, Vec3) -> [f64; 3] + Sync,
) -> Result<usize> {
    let t = std::time::Instant::now();
    let Some(paths) = Paths::new(&geom.pixels, stop)? else {
        return Ok(0);
    };
    let followed = t.elapsed();
    let bounced = paths.radiance(&geom.pixels, lights, frame, eval);
    tracing::debug!(
        "one bounce: {} hidden directions of {} pixels into {} cells, followed in {:.2} s, lit in {:.2} s",
        paths.len(),
        geom.pixels.len(),
        paths.cells(),
        followed.as_secs_f64(),
        (t.elapsed() - followed).as_secs_f64()
    );
    for (px, l) in geom.pixels.iter().zip(bounced) {
        let v = &mut img.pixels[px.y as usize * img.width + px.x as usize];
        for c in 0..3 {
            v[c] += l[c] as f32;
        }
    }
    Ok(paths.len())
}

impl Surface {
    /// The point the ray from `origin` along `d` meets first, if any, as a pixel's own point
    /// is taken ([`seen_side`]).
    fn meet(&self, origin: Vec3, d: Vec3) -> Option<Met> {
        let hit = self.bvh().closest(origin, d, 0.0, f64::INFINITY)?;
        let at = add(origin, scale(d, hit.t));
        let (normal, lift) = seen_side(&self.mesh, &hit, at, scale(d, -1.0), self.diagonal);
        Some(Met {
            at: at.map(|c| c as f32),
            normal: normal.map(|c| c as f32),
            lift: lift as f32,
        })
    }
}

/// Which of 32 bins a normal falls in (its octahedral x and y on a 4 × 4 grid, and the sign of
/// its z): the two sides of a thin wall, or two faces meeting at an edge, are not one cell.
fn facing(n: Vec3) -> u8 {
    let l1 = n[0].abs() + n[1].abs() + n[2].abs();
    let (u, v) = (n[0] / l1, n[1] / l1);
    let bin = |x: f64| (((x + 1.0) / 2.0 * 4.0) as i64).clamp(0, 3) as u8;
    bin(u) * 8 + bin(v) * 2 + (n[2] < 0.0) as u8
}

/// A cell's outgoing radiance on a grid of directions in its frame: rows of equal 1 − cos θ
/// (node i at (i + ½)/[`THETA_STEPS`]), columns of azimuth.
struct Grid {
    values: Vec<[f64; 3]>,
}

impl Grid {
    /// The radiance each node's direction gets from `lit` (direction in the cell's frame and
    /// power, per light) through `eval`.
    fn lit(lit: &[(Vec3, [f64; 3])], eval: &impl Fn(Vec3, Vec3) -> [f64; 3]) -> Grid {
        let mut values = vec![[0.0; 3]; THETA_STEPS * PHI_STEPS];
        if lit.is_empty() {
            return Grid { values };
        }
        for i in 0..THETA_STEPS {
            let cos = 1.0 - (i as f64 + 0.5) / THETA_STEPS as f64;
            let sin = (1.0 - cos * cos).sqrt();
            for j in 0..PHI_STEPS {
                let phi = (j as f64 + 0.5) / PHI_STEPS as f64 * std::f64::consts::TAU;
                let wo = [sin * phi.cos(), sin * phi.sin(), cos];
                let v = &mut values[i * PHI_STEPS + j];
                for (wi, p) in lit {
                    let f = eval(*wi, wo);
                    for c in 0..3 {
                        v[c] += f[c] * p[c] * wi[2];
                    }
                }
            }
        }
        Grid { values }
    }

    /// The radiance toward `wo` (in the cell's frame), bilinear between the nodes; 0 below
    /// the cell's horizon.
    fn at(&self, wo: Vec3) -> [f64; 3] {
        if wo[2] <= 0.0 {
            return [0.0; 3];
        }
        let fi = ((1.0 - wo[2]) * THETA_STEPS as f64 - 0.5).clamp(0.0, (THETA_STEPS - 1) as f64);
        let phi = wo[1].atan2(wo[0]).rem_euclid(std::f64::consts::TAU);
        let fj = phi / std::f64::consts::TAU * PHI_STEPS as f64 - 0.5;
        let (i0, ti) = (fi.floor() as usize, fi - fi.floor());
        let i1 = (i0 + 1).min(THETA_STEPS - 1);
        let j0f = fj.floor();
        let tj = fj - j0f;
        let j0 = (j0f as i64).rem_euclid(PHI_STEPS as i64) as usize;
        let j1 = (j0 + 1) % PHI_STEPS;
        let v = |i: usize, j: usize| self.values[i * PHI_STEPS + j];
        let (a, b, c, d) = (v(i0, j0), v(i0, j1), v(i1, j0), v(i1, j1));
        std::array::from_fn(|k| {
            (a[k] * (1.0 - tj) + b[k] * tj) * (1.0 - ti) + (c[k] * (1.0 - tj) + d[k] * tj) * ti
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bvh::Bvh;

    /// A Lambertian cell under uniform light of radiance 1 over its open half: π·ρ/π = ρ in
    /// every direction, read back at any direction between the nodes.
    #[test]
    fn a_white_cell_under_a_white_half_sphere_sends_its_albedo_everywhere() {
        let n = 400;
        let omega = 2.0 * std::f64::consts::PI / n as f64;
        let lit: Vec<(Vec3, [f64; 3])> = crate::brdf::half_sphere(n)
            .into_iter()
            .map(|d| (d, [omega; 3]))
            .collect();
        let rho = [0.8, 0.5, 0.2];
        let grid = Grid::lit(&lit, &|_, _| rho.map(|r| r / std::f64::consts::PI));
        for wo in [[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [-0.3, -0.9, 0.3162]] {
            let l = grid.at(normalize(wo));
            for c in 0..3 {
                assert!((l[c] - rho[c]).abs() < 1e-3, "{wo:?}: {l:?}");
            }
        }
        assert_eq!(grid.at([0.0, 1.0, -0.1]), [0.0; 3]);
    }

    /// Three lights of power 1 (radiance × solid angle), placed by hand.
    fn three_lights() -> LightSet {
        let mut set = LightSet::default();
        for (d, rgb) in [
            (normalize([0.0, 0.3, 1.0]), [1.0, 1.0, 1.0]),
            (normalize([0.7, 0.0, 0.7]), [0.5, 1.0, 2.0]),
            (normalize([-0.5, -0.5, 0.7]), [2.0, 0.5, 0.5]),
        ] {
            set.directions.push(d.map(|c| c as f32));
            set.radiance.push(rgb.map(|c| c as f32 * 1e3));
            set.solid_angle.push(1e-3);
            set.spread.push(0.0);
        }
        set
    }

    /// Inside a white Lambertian bowl under three lights: the bounce each pixel gathers
    /// through the cells and grids, against a brute-force sum that follows 20,000 directions
    /// from the pixel and casts each light's ray from the point it meets.
    #[test]
    fn a_bowl_lights_itself_as_a_brute_force_sum_says() {
        use crate::geometry::{Camera, PixelGeometry};
        let mesh = crate::mesh::bowl(0.9, 24, 48);
        let geom = PixelGeometry::of_mesh(&Camera::eval_orthographic(64), &mesh).unwrap();
        let lights = three_lights();
        let rho = [0.8, 0.6, 0.4];
        let lambert = |wi: Vec3, wo: Vec3| {
            if wi[2] <= 0.0 || wo[2] <= 0.0 {
                [0.0; 3]
            } else {
                rho.map(|r| r / std::f64::consts::PI)
            }
        };
        let paths = Paths::new(&geom.pixels, &Stop::default())
            .unwrap()
            .expect("a bowl hides some of its directions");
        let ours = paths.radiance(&geom.pixels, &lights, crate::brdf::tangent_frame, lambert);

        // The brute force's own hits: the nearest triangle, its normal turned to the ray's
        // side, each light's ray cast from just above the face.
        let bvh = Bvh::build(&mesh);
        let n = 20_000;
        let omega = 4.0 * std::f64::consts::PI / n as f64;
        let dirs = fibonacci_sphere(n);
        let occluder = geom.pixels[0].shadow.as_ref().unwrap().occluder.clone();
        let (mut worst, mut checked) = (0f64, 0);
        for (i, px) in geom.pixels.iter().enumerate().step_by(97) {
            let p = occluder.points()[px.shadow.as_ref().unwrap().id as usize];
            let (origin, normal) = (p.origin.map(f64::from), p.normal.map(f64::from));
            let mut sum = [0.0; 3];
            for d in dirs.iter().filter(|d| dot(**d, normal) > 0.0) {
                let Some(hit) = bvh.closest(origin, *d, 0.0, f64::INFINITY) else {
                    continue;
                };
                let at = add(origin, scale(*d, hit.t));
                let [a, b, c] = mesh.corners(hit.triangle);
                let mut face = normalize(crate::brdf::cross(
                    crate::brdf::sub(b, a),
                    crate::brdf::sub(c, a),
                ));
                if dot(face, *d) > 0.0 {
                    face = scale(face, -1.0);
                }
                let mut n_y = mesh.normal_at(hit.triangle, hit.u, hit.v);
                if dot(n_y, face) < 0.0 {
                    n_y = scale(n_y, -1.0);
                }
                let from = add(at, scale(face, 1e-4));
                for k in 0..lights.len() {
                    let l = lights.directions[k].map(f64::from);
                    let cos_y = dot(l, n_y);
                    if cos_y <= 0.0 || bvh.closest(from, l, 0.0, f64::INFINITY).is_some() {
                        continue;
                    }
                    let power = lights.radiance[k].map(|r| r as f64 * 1e-3);
                    for c in 0..3 {
                        // ρ/π at the met point, then ρ/π at the pixel.
                        let f = rho[c] / std::f64::consts::PI;
                        sum[c] += f * power[c] * cos_y * f * dot(*d, normal) * omega;
                    }
                }
            }
            if sum.iter().any(|&v| v < 1e-3) {
                continue;
            }
            for c in 0..3 {
                worst = worst.max((ours[i][c] - sum[c]).abs() / sum[c]);
            }
            checked += 1;
        }
        assert!(checked > 10, "{checked} pixels checked");
        assert!(
            worst < 0.1,
            "the bounce is off by {worst:.3} of the brute-force sum"
        );
    }

    #[test]
    fn a_convex_mesh_hides_nothing_from_itself() {
        use crate::geometry::{Camera, PixelGeometry};
        let mesh = crate::mesh::uv_sphere([0.0; 3], 0.9, 24, 48);
        let geom = PixelGeometry::of_mesh(&Camera::eval_orthographic(48), &mesh).unwrap();
        assert!(Paths::new(&geom.pixels, &Stop::default())
            .unwrap()
            .is_none());
    }

    /// A BRDF that varies with the outgoing direction, under one light at the normal: the grid
    /// reads it back at any direction, in the cell's own frame (a flipped azimuth or a row
    /// read upside down would give 1 − x for 1 + x).
    #[test]
    fn a_cell_sends_what_its_brdf_gives_toward_each_direction() {
        let lit = [([0.0, 0.0, 1.0], [1.0; 3])];
        let grid = Grid::lit(&lit, &|_, wo: Vec3| [1.0 + wo[0], 1.0 + wo[1], wo[2]]);
        for wo in [
            [0.3, 0.1, 0.9],
            [-0.5, 0.4, 0.6],
            [0.1, -0.8, 0.5],
            [-0.6, -0.6, 0.4],
        ] {
            let wo = normalize(wo);
            let l = grid.at(wo);
            let want = [1.0 + wo[0], 1.0 + wo[1], wo[2]];
            for c in 0..3 {
                assert!(
                    (l[c] - want[c]).abs() < 0.03,
                    "{wo:?}: {l:?} against {want:?}"
                );
            }
        }
    }

    #[test]
    fn the_gather_directions_cover_the_sphere_evenly() {
        let set = gather_lights();
        assert_eq!(set.len(), GATHER);
        let total: f64 = set.solid_angle.iter().map(|&w| w as f64).sum();
        assert!((total - 4.0 * std::f64::consts::PI).abs() < 1e-3);
        // Any direction has a gather direction within the spacing of the lattice.
        let near = |d: Vec3| {
            set.directions
                .iter()
                .map(|g| dot(g.map(f64::from), d))
                .fold(-1.0, f64::max)
        };
        for d in [
            [0.0, 1.0, 0.0],
            [1.0, 0.0, 0.0],
            normalize([1.0, -2.0, 0.5]),
        ] {
            assert!(near(d) > (0.1f64).cos(), "{d:?}");
        }
    }
}
