//! Light the object throws on itself: two bounces.
//!
//! Where a mesh is concave, a point sees its own surface in some directions instead of the
//! room. Direct light counts those directions as dark ([`super::visibility`]); in a photo they
//! hold what that surface reflects of the room. A bounce adds it back: each hidden direction
//! is followed to the surface it meets, and that surface's radiance toward the point (the BRDF
//! applied to the light it sees itself) lights the point as a light in that direction would.
//!
//! A point gathers over [`GATHER`] directions spread over the sphere, one solid angle each.
//! The points met are gathered into cells ([`CELLS_ACROSS`] to the mesh's diagonal, split by
//! which way they face), and each cell's radiance is tabulated per BRDF and map over a
//! grid of outgoing directions ([`THETA_STEPS`] × [`PHI_STEPS`]), from the map merged to
//! [`SOURCE_GRID`] lights; a point reads it between the grid's nodes. Which direction meets
//! which cell ([`Paths`]) depends on the geometry alone: the estimate follows the paths once
//! and lights them again with each new BRDF.
//!
//! The cells a point's paths end in follow their own hidden directions the same way, to the
//! cells they meet: those are lit by the room alone, and light the first cells as their
//! lights do. So a point gathers light that left the room and met the part once or twice
//! before it. Walls of a metal that reflects most of its light pass much of it on again: in
//! gold's grooves a second bounce is about a third of the bounced light (docs/evaluation.md).
//! Light that meets the part three times or more is left out.

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

/// Directions a cell gathers the second bounce from: that light has met the part's surface
/// twice, and is smoother than what a point sees directly.
pub const CELL_GATHER: usize = 256;

/// The second bounce's lights of a cell, merged onto this grid of its hemisphere (steps of
/// 1 − cos θ, and of azimuth) before the cell's BRDF is applied to them: each of a cell's
/// hundred or so hidden directions was a light of its own, and lighting the cells took
/// four times as long as with the room's lights alone.
const MERGED_BOUNCE: (usize, usize) = (4, 8);

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
/// directions each does not see the room in, and the cell each meets; and the same for those
/// cells, which the second bounce lights.
pub struct Paths {
    /// Per pixel, in the pixels' order: its steps, a range of `steps`.
    ranges: Vec<std::ops::Range<u32>>,
    steps: Vec<Step>,
    cells: Vec<Cell>,
    /// The second bounce: per cell a pixel's path ends in (the first of `cells`, in order),
    /// its own hidden directions, a range of `cell_steps`. The cells only these end in are
    /// lit by the room alone.
    cell_ranges: Vec<std::ops::Range<u32>>,
    cell_steps: Vec<Step>,
    /// The cells' points, whose own lights are looked up in it.
    cell_occluder: Occluder,
}

#[derive(Clone, Copy)]
struct Step {
    /// The gather direction's index: in [`gather_lights`] for a pixel's step, in
    /// [`cell_gather_lights`] for a cell's.
    gather: u16,
    cell: u32,
}

#[derive(Clone, Copy)]
struct Cell {
    normal: Vec3,
}

/// The gather directions as a light set, one solid angle each: the visibility tables take
/// light sets, and find which of these a point sees the room in. [`GATHER`] of them for a
/// pixel's point, [`CELL_GATHER`] for a cell's.
fn gather_lights() -> &'static LightSet {
    static LIGHTS: OnceLock<LightSet> = OnceLock::new();
    LIGHTS.get_or_init(|| gather_set(GATHER))
}

fn cell_gather_lights() -> &'static LightSet {
    static LIGHTS: OnceLock<LightSet> = OnceLock::new();
    LIGHTS.get_or_init(|| gather_set(CELL_GATHER))
}

fn gather_set(count: usize) -> LightSet {
    let omega = 4.0 * std::f64::consts::PI / count as f64;
    let mut set = LightSet::default();
    for d in fibonacci_sphere(count) {
        set.directions.push(d.map(|c| c as f32));
        set.radiance.push([1.0; 3]);
        set.solid_angle.push(omega as f32);
        set.spread
            .push((omega / std::f64::consts::PI).sqrt() as f32);
    }
    set
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
                let point = &occluder.points()[s.id as usize];
                hidden(&surface, gather, point, table.row(&occluder, s.id))
            })
            .collect();
        stop.check()?;
        if met.iter().all(Vec::is_empty) {
            return Ok(None);
        }
        // Cells in the pixels' order, so that the same pixels make the same cells.
        let mut index = CellIndex::new(surface.diagonal / CELLS_ACROSS);
        let (ranges, steps) = index.steps(&met);
        // The second bounce: the first cells' own hidden directions. The cells these alone
        // meet are placed by their own points; the first cells keep where the pixels' paths
        // put them.
        let firsts = Occluder::new(surface.bvh(), index.cells_and_points().1);
        let cell_gather = cell_gather_lights();
        let table = firsts.table(cell_gather);
        let met: Vec<Vec<(u16, Met)>> = (0..firsts.points().len())
            .into_par_iter()
            .map(|c| {
                if stop.requested() {
                    return Vec::new();
                }
                hidden(
                    &surface,
                    cell_gather,
                    &firsts.points()[c],
                    table.row(&firsts, c as u32),
                )
            })
            .collect();
        stop.check()?;
        index.close();
        let (cell_ranges, cell_steps) = index.steps(&met);
        let (cells, points) = index.cells_and_points();
        Ok(Some(Paths {
            ranges,
            steps,
            cells,
            cell_ranges,
            cell_steps,
            cell_occluder: firsts.with_points(points),
        }))
    }

    /// Hidden directions followed, over all pixels (the cells' own are not counted).
    pub fn len(&self) -> usize {
        self.steps.len()
    }

    pub fn is_empty(&self) -> bool {
        self.steps.is_empty()
    }

    /// The cells the paths end in, the pixels' and the cells' own.
    pub fn cells(&self) -> usize {
        self.cells.len()
    }

    /// The bounced light each pixel reflects toward its viewer (linear RGB, in the pixels'
    /// order, which must be the order [`Paths::new`] was given): each cell lit by `lights`
    /// and by the cells it sees, through the BRDF `eval`, which takes directions (toward the
    /// light, toward the viewer) in the frame `frame` lays on a normal (tangent, bitangent,
    /// normal as x, y, z), and that light reflected again at the pixel.
    pub fn radiance(
        &self,
        pixels: &[GeomPixel],
        lights: &LightSet,
        frame: impl Fn(Vec3) -> (Vec3, Vec3) + Sync,
        eval: impl Fn(Vec3, Vec3) -> [f64; 3] + Sync,
    ) -> Vec<[f64; 3]> {
        self.radiance_of(pixels, lights, Bounces::Two, frame, eval)
    }

    fn radiance_of(
        &self,
        pixels: &[GeomPixel],
        lights: &LightSet,
        bounces: Bounces,
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
        // Each cell lit by the room's lights it sees, in its own frame.
        let once: Vec<Grid> = (0..self.cells.len())
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
        // The cells the pixels' paths end in, lit again by the room and by the cells they
        // see, each of which lights them as a light of one gather direction's solid angle.
        let grids = match bounces {
            Bounces::One => once,
            Bounces::Two => {
                let cell_gather = cell_gather_lights();
                let omega = 4.0 * std::f64::consts::PI / CELL_GATHER as f64;
                let again: Vec<Option<Grid>> = self
                    .cell_ranges
                    .par_iter()
                    .enumerate()
                    .map(|(c, range)| {
                        let steps = &self.cell_steps[range.start as usize..range.end as usize];
                        if steps.is_empty() {
                            return None;
                        }
                        let n = self.cells[c].normal;
                        let (t, b) = frame(n);
                        let local = |d: Vec3| [dot(d, t), dot(d, b), dot(d, n)];
                        let bounced = steps.iter().map(|step| {
                            let (d, l) = self.along(step, cell_gather, &once, &frame);
                            (local(d), l.map(|x| x * omega))
                        });
                        Some(Grid::lit(&merged(bounced), &eval))
                    })
                    .collect();
                // Light adds: the room's part is the first lighting's.
                let mut twice = once;
                for (grid, more) in twice.iter_mut().zip(again) {
                    if let Some(more) = more {
                        grid.add(&more);
                    }
                }
                twice
            }
        };
        tracing::debug!(
            "bounce grids: {} cells ({} with paths of their own, {} of them), {} sources, {:.2} s",
            self.cells.len(),
            self.cell_ranges.len(),
            self.cell_steps.len(),
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
                    let (_, l) = self.along(step, gather, &grids, &frame);
                    for c in 0..3 {
                        acc[c] += f[c] * l[c] * wi[2] * omega;
                    }
                }
                acc
            })
            .collect()
    }

    /// A step's direction in `gather` (world frame) and the radiance its cell sends back
    /// along it, read from that cell's grid.
    fn along(
        &self,
        step: &Step,
        gather: &LightSet,
        grids: &[Grid],
        frame: &impl Fn(Vec3) -> (Vec3, Vec3),
    ) -> (Vec3, [f64; 3]) {
        let d = gather.directions[step.gather as usize].map(f64::from);
        let cell = self.cells[step.cell as usize];
        let (ct, cb) = frame(cell.normal);
        let back = scale(d, -1.0);
        let out = [dot(back, ct), dot(back, cb), dot(back, cell.normal)];
        (d, grids[step.cell as usize].at(out))
    }
}

/// Lights above a cell's horizon (direction in its frame, power) merged onto the
/// [`MERGED_BOUNCE`] grid of its hemisphere: each node's power at its lights' power-weighted
/// mean direction.
fn merged(lights: impl Iterator<Item = (Vec3, [f64; 3])>) -> Vec<(Vec3, [f64; 3])> {
    let (rows, columns) = MERGED_BOUNCE;
    let mut nodes = vec![([0.0; 3], [0.0; 3]); rows * columns];
    for (d, p) in lights.filter(|(d, _)| d[2] > 0.0) {
        let i = (((1.0 - d[2]) * rows as f64) as usize).min(rows - 1);
        let phi = d[1].atan2(d[0]).rem_euclid(std::f64::consts::TAU);
        let j = ((phi / std::f64::consts::TAU * columns as f64) as usize).min(columns - 1);
        let node = &mut nodes[i * columns + j];
        node.0 = add(node.0, scale(d, p[0] + p[1] + p[2] + 1e-30));
        node.1 = add(node.1, p);
    }
    nodes
        .into_iter()
        .filter(|(_, p)| p.iter().any(|&x| x > 0.0))
        .map(|(d, p)| (normalize(d), p))
        .collect()
}

/// How many times light met the part before it reaches a pixel's own point: once, or up to
/// twice (what the renders and the estimate take).
#[derive(Clone, Copy)]
enum Bounces {
    #[cfg_attr(not(test), allow(dead_code))]
    One,
    Two,
}

/// The directions of `gather` above `point`'s horizon that `row` (its row of their table)
/// says do not reach the room, each with the surface it meets.
fn hidden(surface: &Surface, gather: &LightSet, point: &Point, row: &[u64]) -> Vec<(u16, Met)> {
    let origin = point.origin.map(f64::from);
    let normal = point.normal.map(f64::from);
    (0..gather.len())
        .filter_map(|g| {
            let d = gather.directions[g].map(f64::from);
            if dot(d, normal) <= 0.0 || is_seen(row, g as u32) {
                return None;
            }
            surface.meet(origin, d).map(|m| (g as u16, m))
        })
        .collect()
}

/// The cells the paths end in, as they are met: a cell is the points met in one cube of
/// `size` that face one way ([`facing`]), placed at their mean, lifted as far off the surface
/// as the farthest of them needed.
struct CellIndex {
    size: f64,
    index: std::collections::HashMap<([i64; 3], u8), u32>,
    /// Per cell: the sum of its points, of their normals, the largest lift, and how many.
    sums: Vec<(Vec3, Vec3, f64, u32)>,
    /// Cells below this are closed: points met in them later no longer move them.
    closed: usize,
}

impl CellIndex {
    fn new(size: f64) -> CellIndex {
        CellIndex {
            size,
            index: std::collections::HashMap::new(),
            sums: Vec::new(),
            closed: 0,
        }
    }

    /// Each list's points met, as steps into their cells, the steps of list i being the
    /// range i of the answer's ranges.
    fn steps(&mut self, met: &[Vec<(u16, Met)>]) -> (Vec<std::ops::Range<u32>>, Vec<Step>) {
        let mut ranges = Vec::with_capacity(met.len());
        let mut steps = Vec::new();
        for list in met {
            let start = steps.len() as u32;
            for (g, m) in list {
                let cell = self.cell_of(m);
                steps.push(Step { gather: *g, cell });
            }
            ranges.push(start..steps.len() as u32);
        }
        (ranges, steps)
    }

    fn cell_of(&mut self, m: &Met) -> u32 {
        let (at, normal) = (m.at.map(f64::from), m.normal.map(f64::from));
        let key = (at.map(|c| (c / self.size).floor() as i64), facing(normal));
        let sums = &mut self.sums;
        let cell = *self.index.entry(key).or_insert_with(|| {
            sums.push(([0.0; 3], [0.0; 3], 0.0, 0));
            sums.len() as u32 - 1
        });
        if (cell as usize) >= self.closed {
            let s = &mut self.sums[cell as usize];
            s.0 = add(s.0, at);
            s.1 = add(s.1, normal);
            s.2 = s.2.max(m.lift as f64);
            s.3 += 1;
        }
        cell
    }

    /// Leaves the cells so far where they are.
    fn close(&mut self) {
        self.closed = self.sums.len();
    }

    /// Each cell's normal, and its point: its mean, lifted off the surface along its mean
    /// normal.
    fn cells_and_points(&self) -> (Vec<Cell>, Vec<Point>) {
        self.sums
            .iter()
            .map(|&(at, n, lift, count)| {
                let normal = normalize(n);
                let centre = scale(at, 1.0 / count as f64);
                (
                    Cell { normal },
                    Point {
                        origin: add(centre, scale(normal, lift)).map(|c| c as f32),
                        normal: normal.map(|c| c as f32),
                    },
                )
            })
            .unzip()
    }
}

/// Adds to `img`, a render of `geom`'s pixels under `lights`, the light each pixel's own
/// surface throws on it ([`Paths::radiance`], with the BRDF `eval` in the frames `frame`
/// lays): a render of a concave part with two bounces. Nothing changes off a mesh or on a
/// convex one. Returns the hidden directions followed from the pixels.
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
        "bounce: {} hidden directions of {} pixels into {} cells, followed in {:.2} s, lit in {:.2} s",
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

    fn add(&mut self, other: &Grid) {
        for (a, b) in self.values.iter_mut().zip(&other.values) {
            for c in 0..3 {
                a[c] += b[c];
            }
        }
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
    use crate::geometry::Camera;
    use crate::mesh::Mesh;

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

    /// The test bowl seen from above, and a Lambertian BRDF of albedo `rho`.
    fn bowl(rho: [f64; 3]) -> (Mesh, PixelGeometry, impl Fn(Vec3, Vec3) -> [f64; 3] + Copy) {
        let mesh = crate::mesh::bowl(0.9, 24, 48);
        let geom = PixelGeometry::of_mesh(&Camera::eval_orthographic(64), &mesh).unwrap();
        let f = rho.map(|r| r / std::f64::consts::PI);
        let lambert = move |wi: Vec3, wo: Vec3| {
            if wi[2] <= 0.0 || wo[2] <= 0.0 {
                [0.0; 3]
            } else {
                f
            }
        };
        (mesh, geom, lambert)
    }

    /// The brute force's own hit: the nearest triangle of `mesh` along `d` from `origin`, as
    /// the point just above its face (where that point's own rays start) and the normal there
    /// turned toward where the ray came from.
    fn brute_meet(bvh: &Bvh, mesh: &Mesh, origin: Vec3, d: Vec3) -> Option<(Vec3, Vec3)> {
        let hit = bvh.closest(origin, d, 0.0, f64::INFINITY)?;
        let at = add(origin, scale(d, hit.t));
        let [a, b, c] = mesh.corners(hit.triangle);
        let mut face = normalize(crate::brdf::cross(
            crate::brdf::sub(b, a),
            crate::brdf::sub(c, a),
        ));
        if dot(face, d) > 0.0 {
            face = scale(face, -1.0);
        }
        let mut n = mesh.normal_at(hit.triangle, hit.u, hit.v);
        if dot(n, face) < 0.0 {
            n = scale(n, -1.0);
        }
        Some((add(at, scale(face, 1e-4)), n))
    }

    /// Inside a white Lambertian bowl under three lights: the first bounce each pixel gathers
    /// through the cells and grids, against a brute-force sum that follows 20,000 directions
    /// from the pixel and casts each light's ray from the point it meets.
    #[test]
    fn a_bowl_lights_itself_as_a_brute_force_sum_says() {
        let rho = [0.8, 0.6, 0.4];
        let (mesh, geom, lambert) = bowl(rho);
        let lights = three_lights();
        let paths = Paths::new(&geom.pixels, &Stop::default())
            .unwrap()
            .expect("a bowl hides some of its directions");
        let ours = paths.radiance_of(
            &geom.pixels,
            &lights,
            Bounces::One,
            crate::brdf::tangent_frame,
            lambert,
        );

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
                let Some((from, n_y)) = brute_meet(&bvh, &mesh, origin, *d) else {
                    continue;
                };
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

    /// Inside the bowl again, the light that met the wall twice: the two bounces less the
    /// first, against a brute force that follows 2,000 directions from the pixel and, from
    /// each point met, 500 more to the points that light it, whose lights' rays are cast.
    #[test]
    fn a_bowl_s_second_bounce_is_what_a_brute_force_sum_says() {
        let rho = [0.9, 0.7, 0.5];
        let f = rho.map(|r| r / std::f64::consts::PI);
        let (mesh, geom, lambert) = bowl(rho);
        let lights = three_lights();
        let paths = Paths::new(&geom.pixels, &Stop::default()).unwrap().unwrap();
        let lit = |bounces| {
            paths.radiance_of(
                &geom.pixels,
                &lights,
                bounces,
                crate::brdf::tangent_frame,
                lambert,
            )
        };
        let (once, twice) = (lit(Bounces::One), lit(Bounces::Two));

        let bvh = Bvh::build(&mesh);
        let meet = |origin: Vec3, d: Vec3| brute_meet(&bvh, &mesh, origin, d);
        // The room's light a point reflects, per unit of f.
        let direct = |from: Vec3, n: Vec3| -> [f64; 3] {
            let mut sum = [0.0; 3];
            for k in 0..lights.len() {
                let l = lights.directions[k].map(f64::from);
                let cos = dot(l, n);
                if cos <= 0.0 || bvh.closest(from, l, 0.0, f64::INFINITY).is_some() {
                    continue;
                }
                for c in 0..3 {
                    sum[c] += lights.radiance[k][c] as f64 * 1e-3 * cos;
                }
            }
            sum
        };
        let (outer, inner) = (fibonacci_sphere(2_000), fibonacci_sphere(500));
        let (w_outer, w_inner) = (
            4.0 * std::f64::consts::PI / outer.len() as f64,
            4.0 * std::f64::consts::PI / inner.len() as f64,
        );
        let occluder = geom.pixels[0].shadow.as_ref().unwrap().occluder.clone();
        let (mut worst, mut checked) = (0f64, 0);
        for (i, px) in geom.pixels.iter().enumerate().step_by(211) {
            let p = occluder.points()[px.shadow.as_ref().unwrap().id as usize];
            let (origin, normal) = (p.origin.map(f64::from), p.normal.map(f64::from));
            let mut sum = [0.0; 3];
            for d in outer.iter().filter(|d| dot(**d, normal) > 0.0) {
                let Some((y, n_y)) = meet(origin, *d) else {
                    continue;
                };
                for e in inner.iter().filter(|e| dot(**e, n_y) > 0.0) {
                    let Some((z, n_z)) = meet(y, *e) else {
                        continue;
                    };
                    let l = direct(z, n_z);
                    for c in 0..3 {
                        // f at z, then at y, then at the pixel.
                        sum[c] += f[c]
                            * l[c]
                            * f[c]
                            * dot(*e, n_y)
                            * w_inner
                            * f[c]
                            * dot(*d, normal)
                            * w_outer;
                    }
                }
            }
            if sum.iter().any(|&v| v < 1e-3) {
                continue;
            }
            for c in 0..3 {
                let second = twice[i][c] - once[i][c];
                worst = worst.max((second - sum[c]).abs() / sum[c]);
            }
            checked += 1;
        }
        assert!(checked >= 10, "{checked} pixels checked");
        // Measured 0.033 over 12 pixels.
        assert!(
            worst < 0.06,
            "the second bounce is off by {worst:.3} of the brute-force sum"
        );
    }

    #[test]
    fn a_convex_mesh_hides_nothing_from_itself() {
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
