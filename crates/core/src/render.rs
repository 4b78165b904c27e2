//! The rendering equation as a dot product (docs/method.md), and forward rendering.
//!
//! For pixel x with normal n and view v, and lights ωⱼ with radiance Lⱼ and solid angle Δωⱼ:
//!     Lo(x) = Σⱼ f(θh, θd) · Lⱼ · max(0, n·ωⱼ) · Δωⱼ          (per colour channel)
//! With f = offset + Σₖ cₖ bₖ each pixel and channel is one row of A, and y = A·c.
//!
//! Speed: the inner loop visits every (pixel, light) pair, so it avoids `acos`. It computes
//! u = |a − b|² = 4 sin²(θ/2), which stays accurate in f32 for tiny angles (where cos θ rounds
//! to 1), and maps u to its bin through a table with an exact edge check ([`BinLut`]).
//!
//! Every renderer here visits a pixel's lights in one order, skipping the lights below the
//! pixel's horizon and, on a mesh, those its own object hides ([`super::visibility`]): one at
//! a time in `each_light`, or in blocks whose arithmetic runs in SIMD lanes in the rendering
//! matrix's pixel loop (`ColumnTable::pixel`), to the same sums. The analytic shapes are
//! taken as convex.

use std::collections::HashMap;
use std::sync::{Arc, Mutex, OnceLock};

use rayon::prelude::*;

use super::bivariate::{
    theta_d_lower_edge, Bivariate, ThetaHBinning, GRID_CELLS, N_THETA_D, N_THETA_H,
};
use super::brdf::{IsotropicBrdf, Vec3};
use super::envmap::LightSet;
use super::error::Result;
use super::geometry::{GeomPixel, PixelGeometry};
use super::merl::{self, MerlBrdf};
use super::raster::Raster;
use super::sharp::{fast_atan2, to_cap_edge, Cap};
use super::stop::Stop;
use super::visibility::{is_seen, Seen};

/// Pixels per rayon task: large enough to amortise scheduling, small enough to balance 2 cores.
const PIXELS_PER_TASK: usize = 256;
/// Most model columns a rendering matrix carries (K up to 10, plus the mean and an offset):
/// the pixel selection holds them in fixed-size arrays.
pub const MAX_COLUMNS: usize = 12;
/// Most columns one pass over the (pixel, light) pairs renders. Finding a pair's cell costs
/// about as much as gathering a dozen columns there, so the models with many columns (the
/// roughness search, the measured materials) render them in few, wide passes.
pub const PASS_COLUMNS: usize = 24;

/// Maps u = 4 sin²(θ/2) to the bin of θ, exactly, for monotone bin edges.
///
/// The table is indexed by u's bit pattern: for a positive f32 the bits grow with the value,
/// and their top bits are its logarithm in steps of 1/2^(23 − shift) of an octave. That
/// spacing suits both grids: √-spaced θh edges crowd together near 0 in θ (so in u) and so
/// do the θd edges, relative to their size. Each cell holds at most one edge, so one compare
/// finishes the lookup, with no square root in the pair loop.
#[derive(Clone)]
pub struct BinLut {
    base_bits: u32,
    shift: u32,
    start_bin: Vec<u16>,
    next_edge_u: Vec<f32>,
}

fn u_of_theta(theta: f64) -> f64 {
    let s = (theta / 2.0).sin();
    4.0 * s * s
}

impl BinLut {
    /// `lower_edges[b]` is the smallest θ of bin b (increasing, `lower_edges[0] = 0`).
    pub fn new(lower_edges: &[f64]) -> BinLut {
        let edges_u: Vec<f32> = lower_edges.iter().map(|e| u_of_theta(*e) as f32).collect();
        // Everything below half the first non-zero edge shares cell 0 (bin 0).
        let base_bits = (edges_u[1] * 0.5).to_bits();
        let top_bits = 4.0f32.to_bits();
        let mut shift = 18;
        loop {
            let cells = ((top_bits - base_bits) >> shift) as usize + 1;
            let mut start_bin = Vec::with_capacity(cells);
            let mut next_edge_u = Vec::with_capacity(cells);
            let mut ok = true;
            for q in 0..cells as u32 {
                let lo = if q == 0 {
                    0.0
                } else {
                    f32::from_bits(base_bits + (q << shift))
                };
                let hi = f32::from_bits(base_bits + ((q + 1) << shift));
                let b = edges_u.iter().rposition(|e| *e <= lo).unwrap_or(0);
                ok &= edges_u.iter().filter(|e| **e > lo && **e < hi).count() <= 1;
                start_bin.push(b as u16);
                next_edge_u.push(edges_u.get(b + 1).copied().unwrap_or(f32::INFINITY));
            }
            if ok {
                return BinLut {
                    base_bits,
                    shift,
                    start_bin,
                    next_edge_u,
                };
            }
            shift -= 1;
        }
    }

    pub fn theta_h(binning: ThetaHBinning) -> BinLut {
        let edges: Vec<f64> = (0..N_THETA_H).map(|i| binning.lower_edge(i)).collect();
        BinLut::new(&edges)
    }

    pub fn theta_d() -> BinLut {
        let edges: Vec<f64> = (0..N_THETA_D).map(theta_d_lower_edge).collect();
        BinLut::new(&edges)
    }

    #[inline(always)]
    pub fn bin(&self, u: f32) -> usize {
        self.bin_in(self.cell(u), u)
    }

    /// The table cell of u: arithmetic alone, which the pixel loop runs in SIMD lanes.
    #[inline(always)]
    fn cell(&self, u: f32) -> u32 {
        // u ≥ +0 (a squared distance), so its bits order like its value.
        let q = u.to_bits().saturating_sub(self.base_bits) >> self.shift;
        q.min(self.start_bin.len() as u32 - 1)
    }

    /// The bin of u, in its cell `q`.
    #[inline(always)]
    fn bin_in(&self, q: u32, u: f32) -> usize {
        let q = q as usize;
        let b = self.start_bin[q] as usize + (u >= self.next_edge_u[q]) as usize;
        b.min(N_THETA_H - 1)
    }
}

/// Footprint samples per θh bin for [`theta_h_smoothing`]: rings × spokes over the disc.
const FOOTPRINT_RINGS: usize = 8;
const FOOTPRINT_SPOKES: usize = 24;

/// [`theta_h_smoothing`], worked out once per binning and footprint: the footprints are
/// octaves of one radius, so a process meets few, and every rendering matrix asked for them
/// again (170,000 `acos` per build of a 4,096-light map).
fn smoothing_for(binning: ThetaHBinning, rho: f64) -> Arc<Vec<Vec<(usize, f64)>>> {
    type Memo = Mutex<HashMap<(ThetaHBinning, u64), Arc<Vec<Vec<(usize, f64)>>>>>;
    static MEMO: OnceLock<Memo> = OnceLock::new();
    let key = (binning, rho.to_bits());
    let memo = MEMO.get_or_init(Memo::default);
    // A thread that panicked holding the lock left the map whole: each entry is inserted at once.
    let lock = || {
        memo.lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    };
    if let Some(found) = lock().get(&key) {
        return found.clone();
    }
    // Worked out unlocked: two threads may both compute it, and both get the same weights.
    let weights = Arc::new(theta_h_smoothing(binning, rho));
    lock().entry(key).or_insert(weights).clone()
}

/// Averages over a disc of half vectors of angular radius `rho` around each θh bin centre:
/// `out[i]` lists (bin, weight) with weights summing to 1. With `rho` below the bin's own
/// width this is the identity; near the specular peak it spreads a light over the narrow
/// √-spaced bins its footprint covers.
pub(crate) fn theta_h_smoothing(binning: ThetaHBinning, rho: f64) -> Vec<Vec<(usize, f64)>> {
    (0..N_THETA_H)
        .map(|i| {
            let theta = binning.center(i);
            let mut weights = vec![0.0; N_THETA_H];
            let n = (FOOTPRINT_RINGS * FOOTPRINT_SPOKES) as f64;
            for ring in 0..FOOTPRINT_RINGS {
                // Equal-area rings: radius ∝ √((k + ½)/rings).
                let r = rho * ((ring as f64 + 0.5) / FOOTPRINT_RINGS as f64).sqrt();
                for spoke in 0..FOOTPRINT_SPOKES {
                    let a =
                        2.0 * std::f64::consts::PI * (spoke as f64 + 0.5) / FOOTPRINT_SPOKES as f64;
                    // Spherical law of cosines: polar angle of a point at distance r, bearing a.
                    let cos_t = theta.cos() * r.cos() + theta.sin() * r.sin() * a.cos();
                    let t = cos_t.clamp(-1.0, 1.0).acos();
                    weights[binning.bin(t)] += 1.0 / n;
                }
            }
            weights
                .into_iter()
                .enumerate()
                .filter(|(_, w)| *w > 0.0)
                .collect()
        })
        .collect()
}

/// Applies [`theta_h_smoothing`] to one channel-planar bivariate vector.
/// f′ of a bivariate vector: bins below `cap_bins` take bin `cap_bins`' value, per θd.
fn cut_flat(values: &[f64], cap_bins: usize) -> Vec<f64> {
    let mut out = values.to_vec();
    for c in 0..3 {
        let plane = &mut out[c * GRID_CELLS..(c + 1) * GRID_CELLS];
        for ih in 0..cap_bins.min(N_THETA_H) {
            for jd in 0..N_THETA_D {
                plane[ih * N_THETA_D + jd] = values[c * GRID_CELLS + cap_bins * N_THETA_D + jd];
            }
        }
    }
    out
}

/// What the cap adds to the columns that take it ([`crate::sharp`]): each one's
/// [`Cap::ring_sums`], laid out `[(ring·N_THETA_D + θd bin)·3 + channel]·k + i` for the i-th
/// of its k capped columns.
struct CapColumns {
    capped: Vec<usize>,
    sums: Vec<f32>,
}

impl CapColumns {
    fn new(cap: &Cap, columns: &[&[f64]], capped: Vec<usize>) -> CapColumns {
        let k = capped.len();
        let mut sums = vec![0f32; cap.rings() * N_THETA_D * 3 * k];
        for (i, j) in capped.iter().enumerate() {
            for (cell, value) in cap.ring_sums(columns[*j]).into_iter().enumerate() {
                sums[cell * k + i] = value;
            }
        }
        CapColumns { capped, sums }
    }

    /// Adds Σ over the cap's samples of (f − f′)·L·cos·Δω to one pixel's `out[c·m + j]`.
    fn add(&self, cap: &Cap, px: &GeomPixel, m: usize, luts: &Luts, out: &mut [f32]) {
        let k = self.capped.len();
        cap.each_spoke(px, |s| {
            let bd = luts.d.bin(dist2(s.dir, s.h));
            let at = (s.ring * N_THETA_D + bd) * 3 * k;
            for c in 0..3 {
                let sums = &self.sums[at + c * k..at + (c + 1) * k];
                for (&j, sum) in self.capped.iter().zip(sums) {
                    out[c * m + j] += sum * s.weight[c];
                }
            }
        });
    }
}

/// The lights ordered by height (their y), to find the one nearest a direction without visiting
/// all: a light nearer than the best so far lies within the best's chord of it, so within
/// that chord of it in y. Asked once per pixel of a mesh in every build with a cap, a scan of
/// every light cost pixels × lights; the same answer comes from a narrow band of heights
/// (the gold part's estimate, 2.5 s → 2.2 s, results identical to the last digit).
struct Mirrors<'a> {
    lights: &'a [PackedLight],
    /// Indices into `lights`, by ascending y.
    by_height: Vec<usize>,
}

impl<'a> Mirrors<'a> {
    fn new(lights: &'a [PackedLight]) -> Mirrors<'a> {
        let mut by_height: Vec<usize> = (0..lights.len()).collect();
        by_height.sort_by(|a, b| lights[*a].dir[1].total_cmp(&lights[*b].dir[1]));
        Mirrors { lights, by_height }
    }

    /// The light whose direction is nearest unit `r`.
    fn nearest(&self, r: [f32; 3]) -> Option<&PackedLight> {
        let y = |i: usize| self.lights[self.by_height[i]].dir[1];
        let start = self
            .by_height
            .partition_point(|j| self.lights[*j].dir[1] < r[1]);
        let mut best: Option<(f32, usize)> = None;
        // |d − r|² = 2 − 2 d·r: the chord of the best so far, squared.
        let reach = |best: Option<(f32, usize)>| best.map_or(f32::INFINITY, |(d, _)| 2.0 - 2.0 * d);
        let visit = |i: usize, best: &mut Option<(f32, usize)>| -> bool {
            let dy = y(i) - r[1];
            if dy * dy > reach(*best) {
                return false;
            }
            let j = self.by_height[i];
            let d = dot3(self.lights[j].dir, r);
            if best.is_none_or(|(b, _)| d > b) {
                *best = Some((d, j));
            }
            true
        };
        for i in start..self.by_height.len() {
            if !visit(i, &mut best) {
                break;
            }
        }
        for i in (0..start).rev() {
            if !visit(i, &mut best) {
                break;
            }
        }
        best.map(|(_, j)| &self.lights[j])
    }

    /// Whether a pixel sees its mirror direction: on a mesh, the cap's light comes only from
    /// where the pixel's own object does not hide the sky, told by the light nearest that
    /// direction.
    fn seen_by(&self, px: &GeomPixel, seen: Option<&[u64]>) -> bool {
        let Some(row) = seen else { return true };
        let (n, v) = (px.normal, px.view);
        let nv = dot3(n, v);
        let r = [
            2.0 * nv * n[0] - v[0],
            2.0 * nv * n[1] - v[1],
            2.0 * nv * n[2] - v[2],
        ];
        self.nearest(r).is_none_or(|l| is_seen(row, l.index))
    }
}

/// Each θh row of each channel, smoothed along θh: a row's weights applied to whole θd rows
/// of the table, in the weights' order, so every cell's sum rounds as a sum over its own
/// column would (from −0.0, as `Iterator::sum` starts) while the compiler vectorises over
/// the contiguous θd cells.
fn smooth_bivariate(values: &[f64], smoothing: &[Vec<(usize, f64)>]) -> Vec<f64> {
    let mut out = vec![-0.0; values.len()];
    for (plane, table) in out
        .chunks_exact_mut(GRID_CELLS)
        .zip(values.chunks_exact(GRID_CELLS))
    {
        for (row, weights) in plane.chunks_exact_mut(N_THETA_D).zip(smoothing) {
            for &(k, w) in weights {
                let from = &table[k * N_THETA_D..(k + 1) * N_THETA_D];
                for (o, v) in row.iter_mut().zip(from) {
                    *o += w * v;
                }
            }
        }
    }
    out
}

/// Footprints the renderers tell apart: a light's half-vector footprint is rounded to the
/// nearest of these, one octave apart, and the table it reads is smoothed for that footprint.
/// An octave is fine enough: the smoothing only matters where the footprint is wider than a
/// θh bin, and there a factor of √2 changes a render by less than the light compression does.
#[derive(Clone, Debug)]
pub struct Footprints {
    /// Half-vector footprint radius (radians) of each level, ascending.
    pub radii: Vec<f64>,
    /// The level of each light of the set, in the set's order.
    level: Vec<u32>,
}

/// Footprints below this (0.01°) are all treated alike: the narrowest θh bin is wider.
const SMALLEST_FOOTPRINT: f64 = 1.75e-4;

impl Footprints {
    /// A light of spread R moves the half vector over a disc of radius R/2. A set without
    /// spreads is taken as uniform discs of its solid angles.
    pub fn of(lights: &LightSet) -> Footprints {
        let octave = |i: usize| {
            let spread = lights.spread.get(i).map_or_else(
                || (lights.solid_angle[i] as f64 / std::f64::consts::PI).sqrt(),
                |s| *s as f64,
            );
            let rho = (spread / 2.0).max(SMALLEST_FOOTPRINT);
            (rho / SMALLEST_FOOTPRINT).log2().round() as i32
        };
        let mut octaves: Vec<i32> = (0..lights.len()).map(octave).collect();
        let level_of: Vec<i32> = octaves.clone();
        octaves.sort_unstable();
        octaves.dedup();
        let level = level_of
            .iter()
            .map(|o| octaves.binary_search(o).unwrap_or(0) as u32)
            .collect();
        Footprints {
            radii: octaves
                .iter()
                .map(|o| SMALLEST_FOOTPRINT * 2f64.powi(*o))
                .collect(),
            level,
        }
    }
}

/// A light premultiplied for the inner loop: direction, L·Δω per channel, and where its
/// footprint's table starts.
#[derive(Clone, Copy)]
struct PackedLight {
    dir: [f32; 3],
    power: [f32; 3],
    base: usize,
    /// The light's place in its set, for the visibility rows.
    index: u32,
}

/// Lights with power, each pointing at its footprint's table (`stride` values per level),
/// grouped by footprint so that consecutive lights read the same table.
fn pack(lights: &LightSet, footprints: &Footprints, stride: usize) -> Vec<PackedLight> {
    let mut packed: Vec<PackedLight> = lights
        .directions
        .iter()
        .zip(&lights.radiance)
        .zip(&lights.solid_angle)
        .zip(&footprints.level)
        .enumerate()
        .filter(|(_, (((_, l), w), _))| l.iter().any(|c| *c > 0.0) && **w > 0.0)
        .map(|(i, (((d, l), w), level))| PackedLight {
            dir: *d,
            power: l.map(|c| c * w),
            base: *level as usize * stride,
            index: i as u32,
        })
        .collect();
    // By footprint, then by direction (azimuth within bands of elevation), so that the lights
    // one pixel visits in turn read nearby cells of its table.
    // Keyed once per light: the key's `asin` and `atan2` per comparison were 2% of a capture.
    packed.sort_by_cached_key(|l| {
        let band = ((l.dir[1].clamp(-1.0, 1.0).asin() + 1.6) * 10.0) as u32;
        let azimuth = l.dir[2].atan2(l.dir[0]);
        let az = ((azimuth + 4.0) * 1000.0) as u32;
        (
            l.base,
            band,
            if band.is_multiple_of(2) {
                az
            } else {
                u32::MAX - az
            },
        )
    });
    packed
}

#[inline(always)]
fn dot3(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[inline(always)]
fn dist2(a: [f32; 3], b: [f32; 3]) -> f32 {
    let d = [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    dot3(d, d)
}

/// One (pixel, light) pair, worked out alone: the definition the pixel loop's blocks of
/// lanes ([`Lit::block`]) are tested against.
#[cfg(test)]
struct Pair {
    /// n·ω, positive.
    cos: f32,
    bh: usize,
    bd: usize,
}

/// The bin tables of θh and θd.
struct Luts {
    h: BinLut,
    d: BinLut,
}

impl Luts {
    fn new(binning: ThetaHBinning) -> Luts {
        Luts {
            h: BinLut::theta_h(binning),
            d: BinLut::theta_d(),
        }
    }
}

/// A light as the pixel loop meets it: a [`PackedLight`], or one with its half vector
/// worked out beforehand for a view every pixel shares ([`ViewLight`]).
trait Lit: Sized {
    fn packed(&self) -> &PackedLight;
    /// n·ω of this light at a pixel (normal n, view v); `None` when the light is below the
    /// pixel's horizon or opposite the view.
    fn cos(&self, n: [f32; 3], v: [f32; 3]) -> Option<f32>;
    /// The whole pair, bins included, worked out alone: the definition the blocks of lanes
    /// are tested against.
    #[cfg(test)]
    fn pair(&self, n: [f32; 3], v: [f32; 3], luts: &Luts) -> Option<Pair>;
    /// The lights as columns, for [`Lit::block`].
    fn lanes(lights: &[Self]) -> LightLanes;
    /// A pair's arithmetic for the lights `start..start + BLOCK` of `lanes`, short of the
    /// bins: written over columns, so that the compiler runs it eight lights at a time.
    fn block(
        lanes: &LightLanes,
        start: usize,
        n: [f32; 3],
        v: [f32; 3],
        luts: &Luts,
        out: &mut BlockPairs,
    );
    /// The θd bin of this light, lane `i` of `pairs`.
    fn bd(&self, pairs: &BlockPairs, i: usize, luts: &Luts) -> usize;
}

/// Lights per [`Lit::block`].
const BLOCK: usize = 64;

/// A light set as columns, one number per light, padded with unlit lights (a zero direction)
/// to whole blocks.
struct LightLanes {
    dir: [Vec<f32>; 3],
    /// The half vectors of a view every pixel shares ([`ViewLight`]); empty otherwise.
    h: [Vec<f32>; 3],
}

impl LightLanes {
    fn columns(len: usize, value: impl Fn(usize) -> [f32; 3]) -> [Vec<f32>; 3] {
        let padded = len.div_ceil(BLOCK) * BLOCK;
        std::array::from_fn(|k| {
            (0..padded)
                .map(|i| if i < len { value(i)[k] } else { 0.0 })
                .collect()
        })
    }

    /// Columns `start..start + BLOCK` of `c`, as an array: a constant length the compiler
    /// can vectorise over without bounds checks.
    #[inline(always)]
    fn at(c: &[Vec<f32>; 3], start: usize) -> [&[f32; BLOCK]; 3] {
        std::array::from_fn(|k| {
            c[k][start..start + BLOCK]
                .try_into()
                .expect("lanes padded to whole blocks")
        })
    }
}

/// One pixel's pairs with a block of lights, as [`Lit::block`] leaves them.
struct BlockPairs {
    /// Whether the light is above the pixel's horizon and not opposite its view.
    lit: [bool; BLOCK],
    /// n·ω.
    cos: [f32; BLOCK],
    /// |n − h|² and |ω − h|², which [`BinLut::bin`] takes (`ud` unused with a shared view),
    /// and their cells in the bin tables ([`BinLut::cell`]).
    uh: [f32; BLOCK],
    ud: [f32; BLOCK],
    qh: [u32; BLOCK],
    qd: [u32; BLOCK],
}

impl Default for BlockPairs {
    fn default() -> Self {
        BlockPairs {
            lit: [false; BLOCK],
            cos: [0.0; BLOCK],
            uh: [0.0; BLOCK],
            ud: [0.0; BLOCK],
            qh: [0; BLOCK],
            qd: [0; BLOCK],
        }
    }
}

impl Lit for PackedLight {
    #[inline(always)]
    fn packed(&self) -> &PackedLight {
        self
    }

    #[inline(always)]
    fn cos(&self, n: [f32; 3], v: [f32; 3]) -> Option<f32> {
        let cos = dot3(n, self.dir);
        if cos <= 0.0 {
            return None;
        }
        half_vector(self.dir, v)?;
        Some(cos)
    }

    #[cfg(test)]
    fn pair(&self, n: [f32; 3], v: [f32; 3], luts: &Luts) -> Option<Pair> {
        let cos = self.cos(n, v)?;
        let h = half_vector(self.dir, v)?;
        Some(Pair {
            cos,
            bh: luts.h.bin(dist2(n, h)),
            bd: luts.d.bin(dist2(self.dir, h)),
        })
    }

    fn lanes(lights: &[Self]) -> LightLanes {
        LightLanes {
            dir: LightLanes::columns(lights.len(), |i| lights[i].dir),
            h: [Vec::new(), Vec::new(), Vec::new()],
        }
    }

    #[inline(always)]
    fn block(
        lanes: &LightLanes,
        start: usize,
        n: [f32; 3],
        v: [f32; 3],
        luts: &Luts,
        out: &mut BlockPairs,
    ) {
        let [x, y, z] = LightLanes::at(&lanes.dir, start);
        for i in 0..BLOCK {
            let dir = [x[i], y[i], z[i]];
            let cos = dot3(n, dir);
            // `half_vector`'s test is folded into `lit` instead of an early return.
            let (h, len2) = half_vector_unchecked(dir, v);
            let (uh, ud) = (dist2(n, h), dist2(dir, h));
            // `pair`'s test (`cos <= 0.0` refuses), so that even a NaN is treated alike.
            out.lit[i] = ((cos > 0.0) | cos.is_nan()) & (len2 >= 1e-12);
            out.cos[i] = cos;
            out.uh[i] = uh;
            out.ud[i] = ud;
            out.qh[i] = luts.h.cell(uh);
            out.qd[i] = luts.d.cell(ud);
        }
    }

    #[inline(always)]
    fn bd(&self, pairs: &BlockPairs, i: usize, luts: &Luts) -> usize {
        luts.d.bin_in(pairs.qd[i], pairs.ud[i])
    }
}

impl Lit for ViewLight {
    #[inline(always)]
    fn packed(&self) -> &PackedLight {
        &self.light
    }

    #[inline(always)]
    fn cos(&self, n: [f32; 3], _: [f32; 3]) -> Option<f32> {
        let cos = dot3(n, self.light.dir);
        if cos <= 0.0 {
            return None;
        }
        Some(cos)
    }

    #[cfg(test)]
    fn pair(&self, n: [f32; 3], v: [f32; 3], luts: &Luts) -> Option<Pair> {
        let cos = self.cos(n, v)?;
        Some(Pair {
            cos,
            bh: luts.h.bin(dist2(n, self.h)),
            bd: self.bd as usize,
        })
    }

    fn lanes(lights: &[Self]) -> LightLanes {
        LightLanes {
            dir: LightLanes::columns(lights.len(), |i| lights[i].light.dir),
            h: LightLanes::columns(lights.len(), |i| lights[i].h),
        }
    }

    #[inline(always)]
    fn block(
        lanes: &LightLanes,
        start: usize,
        n: [f32; 3],
        _: [f32; 3],
        luts: &Luts,
        out: &mut BlockPairs,
    ) {
        let [x, y, z] = LightLanes::at(&lanes.dir, start);
        let [hx, hy, hz] = LightLanes::at(&lanes.h, start);
        for i in 0..BLOCK {
            let cos = dot3(n, [x[i], y[i], z[i]]);
            let uh = dist2(n, [hx[i], hy[i], hz[i]]);
            out.lit[i] = (cos > 0.0) | cos.is_nan();
            out.cos[i] = cos;
            out.uh[i] = uh;
            out.qh[i] = luts.h.cell(uh);
        }
    }

    #[inline(always)]
    fn bd(&self, _: &BlockPairs, _: usize, _: &Luts) -> usize {
        self.bd as usize
    }
}

#[inline(always)]
fn half_vector(l: [f32; 3], v: [f32; 3]) -> Option<[f32; 3]> {
    let (h, len2) = half_vector_unchecked(l, v);
    (len2 >= 1e-12).then_some(h)
}

/// The half vector of `l` and `v`, with |l + v|²: not finite where l and v are opposite,
/// which [`half_vector`] refuses and the SIMD lanes mask out ([`LightGeometry`]).
#[inline(always)]
fn half_vector_unchecked(l: [f32; 3], v: [f32; 3]) -> ([f32; 3], f32) {
    let hs = [l[0] + v[0], l[1] + v[1], l[2] + v[2]];
    let len2 = dot3(hs, hs);
    let inv = 1.0 / len2.sqrt();
    ([hs[0] * inv, hs[1] * inv, hs[2] * inv], len2)
}

/// The loop every renderer runs over one pixel's lights: `f` gets each light that is above
/// the pixel's horizon and, where `seen` is given (a bit per light of the set), not hidden by
/// the pixel's own object, with n·ω.
#[inline(always)]
fn each_light<L: Lit>(
    px: &GeomPixel,
    lights: &[L],
    seen: Option<&[u64]>,
    mut f: impl FnMut(&PackedLight, f32),
) {
    let (n, v) = (px.normal, px.view);
    for l in lights {
        let light = l.packed();
        if seen.is_some_and(|row| !is_seen(row, light.index)) {
            continue;
        }
        if let Some(cos) = l.cos(n, v) {
            f(light, cos);
        }
    }
}

/// Calls `$obj.$f::<M>(args)` with the column count `m` as a constant: a constant count lets
/// the compiler unroll and vectorise the accumulation.
macro_rules! by_columns {
    ($m:expr, $obj:ident . $f:ident ( $($arg:expr),* )) => {
        by_columns!(@ $m, $obj, $f, ($($arg),*), 1 2 3 4 5 6 7 8 9 10 11 12 13 14 15 16 17 18 19 20 21 22 23 24)
    };
    (@ $m:expr, $obj:ident, $f:ident, $args:tt, $($n:literal)*) => {
        match $m {
            $($n => by_columns!(@call $obj, $f, $n, $args),)*
            _ => unreachable!("column count checked in ColumnTable::new"),
        }
    };
    (@call $obj:ident, $f:ident, $n:literal, ($($arg:expr),*)) => {
        $obj.$f::<$n, _>($($arg),*)
    };
}

/// Bivariate vectors laid out for the gather, one table per footprint level:
/// `data[level·stride + (cell·3 + channel)·m + column]`.
struct ColumnTable {
    m: usize,
    data: Vec<f32>,
    luts: Luts,
}

impl ColumnTable {
    /// The lights' tables hold f′ for the columns that take the cap: each cut flat in its
    /// first `cap_bins[j]` θh bins ([`crate::sharp`]; 0 for a column without it), then
    /// smoothed for each footprint.
    fn new(
        columns: &[&[f64]],
        binning: ThetaHBinning,
        footprints: &Footprints,
        cap_bins: &[usize],
    ) -> ColumnTable {
        let m = columns.len();
        assert!(m <= PASS_COLUMNS, "at most {PASS_COLUMNS} columns");
        let stride = Self::stride(m);
        let mut data = vec![0f32; stride * footprints.radii.len()];
        let flat: Vec<Vec<f64>> = columns
            .iter()
            .zip(cap_bins)
            .map(|(c, bins)| cut_flat(c, *bins))
            .collect();
        // Level by level in parallel: a build's table is otherwise its one serial step, and
        // the models build many (the roughness search, the export's fit).
        data.par_chunks_mut(stride)
            .zip(&footprints.radii)
            .for_each(|(table, rho)| {
                let smoothing = smoothing_for(binning, *rho);
                let smoothed: Vec<Vec<f64>> = flat
                    .iter()
                    .map(|c| smooth_bivariate(c, &smoothing))
                    .collect();
                for g in 0..GRID_CELLS {
                    for c in 0..3 {
                        for (j, col) in smoothed.iter().enumerate() {
                            table[(g * 3 + c) * m + j] = col[c * GRID_CELLS + g] as f32;
                        }
                    }
                }
            });
        ColumnTable {
            m,
            data,
            luts: Luts::new(binning),
        }
    }

    fn stride(m: usize) -> usize {
        GRID_CELLS * 3 * m
    }

    /// One pass over `pixels` under `lights` (whose footprints are `footprints`, with this
    /// table's radii): every column's sum per pixel and channel, row `3·p + c`, and the cap's
    /// part where it is given.
    fn pass(
        &self,
        pixels: &[GeomPixel],
        lights: &LightSet,
        footprints: &Footprints,
        cap: Option<&(Cap, CapColumns)>,
    ) -> Vec<f32> {
        let m = self.m;
        let packed = pack(lights, footprints, Self::stride(m));
        let mirrors = Mirrors::new(&packed);
        let mut raw = vec![0f32; pixels.len() * 3 * m];
        let shared = pixels
            .first()
            .filter(|first| pixels.iter().all(|p| p.view == first.view))
            .map(|first| self.shared_view(first.view, &packed));
        let lanes = match &shared {
            Some(lights) => ViewLight::lanes(lights),
            None => PackedLight::lanes(&packed),
        };
        let seen = Seen::new(pixels, lights);
        raw.par_chunks_mut(PIXELS_PER_TASK * 3 * m)
            .zip(pixels.par_chunks(PIXELS_PER_TASK))
            .for_each(|(out, px)| {
                for (o, p) in out.chunks_mut(3 * m).zip(px) {
                    let row = seen.row(p);
                    match &shared {
                        Some(lights) => self.pixel(p, lights, &lanes, row, o),
                        None => self.pixel(p, &packed, &lanes, row, o),
                    }
                    if let Some((cap, columns)) = cap.filter(|_| mirrors.seen_by(p, row)) {
                        columns.add(cap, p, m, &self.luts, o);
                    }
                }
            });
        raw
    }

    /// Σⱼ over lights of column values × L·Δω·cos, for one pixel: out[c·m + col].
    fn pixel<L: Lit>(
        &self,
        px: &GeomPixel,
        lights: &[L],
        lanes: &LightLanes,
        seen: Option<&[u64]>,
        out: &mut [f32],
    ) {
        by_columns!(self.m, self.pixel_on_cpu(px, lights, lanes, seen, out))
    }

    /// [`ColumnTable::pixel`] for `M` columns, in the widest build the CPU runs.
    #[inline(always)]
    fn pixel_on_cpu<const M: usize, L: Lit>(
        &self,
        px: &GeomPixel,
        lights: &[L],
        lanes: &LightLanes,
        seen: Option<&[u64]>,
        out: &mut [f32],
    ) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2, checked just above.
            return unsafe { self.pixel_avx2::<M, L>(px, lights, lanes, seen, out) };
        }
        self.pixel_m::<M, L>(px, lights, lanes, seen, out)
    }

    /// [`ColumnTable::pixel`] compiled for AVX2: the columns' accumulation runs eight lanes
    /// wide instead of SSE's four. Without FMA the sums round exactly as the SSE build's do,
    /// so both give the same matrix bit for bit. One function per column count: compiled as
    /// one function for all 24, it grew so large that the compiler stopped inlining the
    /// per-light step into some of them, which then ran out of line, in SSE, as a call per
    /// light (a fifth of the README's main command).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn pixel_avx2<const M: usize, L: Lit>(
        &self,
        px: &GeomPixel,
        lights: &[L],
        lanes: &LightLanes,
        seen: Option<&[u64]>,
        out: &mut [f32],
    ) {
        self.pixel_m::<M, L>(px, lights, lanes, seen, out)
    }

    #[inline(always)]
    fn accumulate<const M: usize>(&self, acc: &mut [[f32; M]; 3], start: usize, w: [f32; 3]) {
        // The slice's length is a constant, which lets the compiler drop the bounds checks
        // in the loop below; `start` comes from bins < 90, so it is always in range.
        let row = &self.data[start..start + 3 * M];
        for c in 0..3 {
            for j in 0..M {
                acc[c][j] += w[c] * row[c * M + j];
            }
        }
    }

    #[inline(always)]
    fn pixel_m<const M: usize, L: Lit>(
        &self,
        px: &GeomPixel,
        lights: &[L],
        lanes: &LightLanes,
        seen: Option<&[u64]>,
        out: &mut [f32],
    ) {
        let mut acc = [[0f32; M]; 3];
        // `each_light`'s loop, written out in two steps: the pairs' arithmetic for a block
        // of lights, in SIMD lanes, then the bins and table reads light by light, in the
        // same order, so the sums round as the one-light-at-a-time loop's did. (Passed to
        // `each_light` as a closure, the step below was compiled out of line.)
        let (n, v) = (px.normal, px.view);
        let mut pairs = BlockPairs::default();
        for (b, block) in lights.chunks(BLOCK).enumerate() {
            L::block(lanes, b * BLOCK, n, v, &self.luts, &mut pairs);
            for (i, l) in block.iter().enumerate() {
                let light = l.packed();
                if !pairs.lit[i] || seen.is_some_and(|row| !is_seen(row, light.index)) {
                    continue;
                }
                let cos = pairs.cos[i];
                let bh = self.luts.h.bin_in(pairs.qh[i], pairs.uh[i]);
                let bd = l.bd(&pairs, i, &self.luts);
                let w = [
                    light.power[0] * cos,
                    light.power[1] * cos,
                    light.power[2] * cos,
                ];
                let start = light.base + (bh * N_THETA_D + bd) * 3 * M;
                self.accumulate::<M>(&mut acc, start, w);
            }
        }
        for c in 0..3 {
            out[c * M..(c + 1) * M].copy_from_slice(&acc[c]);
        }
    }

    /// With one view for every pixel (an orthographic camera), the half vector and θd of a
    /// light are the same at every pixel: they are computed once per light, and the pair
    /// loop is left with n·ω and θh.
    fn shared_view(&self, view: [f32; 3], lights: &[PackedLight]) -> Vec<ViewLight> {
        lights
            .iter()
            .filter_map(|l| {
                let h = half_vector(l.dir, view)?;
                Some(ViewLight {
                    light: *l,
                    h,
                    bd: self.luts.d.bin(dist2(l.dir, h)) as u32,
                })
            })
            .collect()
    }
}

/// A light with its half vector and θd bin for a view shared by all pixels.
#[derive(Clone, Copy)]
struct ViewLight {
    light: PackedLight,
    h: [f32; 3],
    bd: u32,
}

/// A (pixels·3) × m matrix: row `3·p + c` is pixel p, channel c. Optionally with an offset
/// vector (the fixed mean term) that the estimate subtracts from the observations.
#[derive(Clone, Debug)]
pub struct RenderingMatrix {
    pub columns: usize,
    pub pixels: Vec<GeomPixel>,
    /// Row-major, `rows[(3·p + c)·columns + j]`.
    pub rows: Vec<f32>,
    pub offset: Option<Vec<f32>>,
}

impl RenderingMatrix {
    /// Appends another matrix's rows (another view of the object, built with the same model
    /// columns), so that one selection and one solve see every view.
    pub fn append(&mut self, other: RenderingMatrix) -> Result<(), String> {
        if other.columns != self.columns || other.offset.is_some() != self.offset.is_some() {
            return Err(format!(
                "views built with different models ({} and {} columns)",
                self.columns, other.columns
            ));
        }
        self.pixels.extend(other.pixels);
        self.rows.extend(other.rows);
        if let (Some(a), Some(b)) = (&mut self.offset, other.offset) {
            a.extend(b);
        }
        Ok(())
    }

    /// Builds A for the given pixels, model columns and optional offset vector.
    pub fn build(
        pixels: &[GeomPixel],
        lights: &LightSet,
        columns: &[&[f64]],
        offset: Option<&[f64]>,
        binning: ThetaHBinning,
    ) -> RenderingMatrix {
        Self::build_under(pixels, &[lights], columns, offset, binning)
            .pop()
            .expect("a matrix for the one light set")
    }

    /// [`RenderingMatrix::build`] under each of `maps` in turn, each matrix the one `build`
    /// makes. Maps whose lights have the same footprints and cap read one table of the
    /// columns, smoothed once: a map's turns are such maps (turning moves its lights, not
    /// their sizes), and the exports' fit renders the same columns under three turns of each
    /// map, where the tables cost as much as the passes over the pixels.
    pub fn build_under(
        pixels: &[GeomPixel],
        maps: &[&LightSet],
        columns: &[&[f64]],
        offset: Option<&[f64]>,
        binning: ThetaHBinning,
    ) -> Vec<RenderingMatrix> {
        let mut all: Vec<&[f64]> = columns.to_vec();
        if let Some(o) = offset {
            all.push(o);
        }
        // Each table with the footprints' radii and the cap's bins per column it was made for.
        let mut tables: Vec<(Vec<f64>, Vec<usize>, ColumnTable)> = Vec::new();
        let mut out = Vec::with_capacity(maps.len());
        for lights in maps {
            let footprints = Footprints::of(lights);
            // Each column takes the cap or not by its own shape, so that whether it reads the
            // map does not depend on which columns share its pass (a photo rendered alone and
            // the same BRDF among a fit's columns must agree). Which of the cap's rings are
            // read is judged on the pass's capped columns together (`Cap::pruned_for`): a
            // column beside a sharper one may read rings it would leave out alone, which hold
            // below 0.2% of its light.
            let cap = Cap::of(lights, binning);
            let capped: Vec<usize> = cap.as_ref().map_or_else(Vec::new, |cap| {
                (0..all.len())
                    .filter(|j| cap.needed_by(&[all[*j]]))
                    .collect()
            });
            let cap = cap.filter(|_| !capped.is_empty());
            let cap_bins: Vec<usize> = (0..all.len())
                .map(|j| match &cap {
                    Some(c) if capped.contains(&j) => c.bins,
                    _ => 0,
                })
                .collect();
            let found = tables
                .iter()
                .position(|(radii, bins, _)| *radii == footprints.radii && *bins == cap_bins);
            let t = found.unwrap_or_else(|| {
                let table = ColumnTable::new(&all, binning, &footprints, &cap_bins);
                tables.push((footprints.radii.clone(), cap_bins, table));
                tables.len() - 1
            });
            let cap = cap.map(|cap| {
                let cap = cap.pruned_for(&capped.iter().map(|j| all[*j]).collect::<Vec<_>>());
                let columns = CapColumns::new(&cap, &all, capped);
                (cap, columns)
            });
            let raw = tables[t].2.pass(pixels, lights, &footprints, cap.as_ref());
            out.push(Self::split_offset(
                pixels,
                raw,
                columns.len(),
                offset.is_some(),
            ));
        }
        out
    }

    /// The matrix of a pass's raw rows (`k` columns, then the offset's if `offset`).
    fn split_offset(
        pixels: &[GeomPixel],
        raw: Vec<f32>,
        k: usize,
        offset: bool,
    ) -> RenderingMatrix {
        let (rows, offset) = if offset {
            let m = k + 1;
            let mut rows = Vec::with_capacity(pixels.len() * 3 * k);
            let mut off = Vec::with_capacity(pixels.len() * 3);
            for r in raw.chunks(m) {
                rows.extend_from_slice(&r[..k]);
                off.push(r[k]);
            }
            (rows, Some(off))
        } else {
            (raw, None)
        };
        RenderingMatrix {
            columns: k,
            pixels: pixels.to_vec(),
            rows,
            offset,
        }
    }

    /// The rows of the given pixels (indices into `pixels`), in that order.
    pub(crate) fn subset(&self, keep: &[usize]) -> RenderingMatrix {
        let k = self.columns;
        RenderingMatrix {
            columns: k,
            pixels: keep.iter().map(|&p| self.pixels[p].clone()).collect(),
            rows: keep
                .iter()
                .flat_map(|&p| &self.rows[3 * p * k..3 * (p + 1) * k])
                .copied()
                .collect(),
            offset: self.offset.as_ref().map(|o| {
                keep.iter()
                    .flat_map(|&p| &o[3 * p..3 * (p + 1)])
                    .copied()
                    .collect()
            }),
        }
    }

    /// Replaces pixel `i`'s rows (and offsets) with pixel `j`'s of `other`, a matrix of the
    /// same model built for the same pixel under other lights.
    pub(crate) fn replace_pixel(&mut self, i: usize, other: &RenderingMatrix, j: usize) {
        let n = 3 * self.columns;
        self.rows[i * n..(i + 1) * n].copy_from_slice(&other.rows[j * n..(j + 1) * n]);
        if let (Some(mine), Some(theirs)) = (&mut self.offset, &other.offset) {
            mine[3 * i..3 * i + 3].copy_from_slice(&theirs[3 * j..3 * j + 3]);
        }
    }

    pub fn row(&self, r: usize) -> &[f32] {
        &self.rows[r * self.columns..(r + 1) * self.columns]
    }

    /// y = A·c (+ offset): the image this model predicts, per pixel and channel.
    pub fn predict(&self, coefficients: &[f64]) -> Vec<f64> {
        self.predict_per_channel([coefficients; 3])
    }

    /// [`RenderingMatrix::predict`] with one coefficient vector per channel.
    pub fn predict_per_channel(&self, per_channel: [&[f64]; 3]) -> Vec<f64> {
        (0..self.pixels.len() * 3)
            .map(|r| {
                let coefficients = per_channel[r % 3];
                let base = self.offset.as_ref().map_or(0.0, |o| o[r] as f64);
                base + self
                    .row(r)
                    .iter()
                    .zip(coefficients)
                    .map(|(a, c)| *a as f64 * c)
                    .sum::<f64>()
            })
            .collect()
    }
}

/// Renders a bivariate BRDF through the same kernel as the rendering matrix.
pub fn render_bivariate(geom: &PixelGeometry, lights: &LightSet, brdf: &Bivariate) -> Raster {
    render_bivariates(geom, lights, &[brdf]).remove(0)
}

/// [`render_bivariate`] of each BRDF, in one pass over the (pixel, light) pairs, whose
/// geometry is most of a pass's cost: each image is the one its BRDF renders alone (every
/// column takes its own sums, and the cap by its own shape), but for the cap's rings a
/// sharper neighbour has it read, which hold below 0.2% of its light. The BRDFs share a θh
/// binning.
pub fn render_bivariates(
    geom: &PixelGeometry,
    lights: &LightSet,
    brdfs: &[&Bivariate],
) -> Vec<Raster> {
    render_bivariates_under(geom, &[lights], brdfs)
        .pop()
        .unwrap_or_default()
}

/// [`render_bivariates`] under each of `maps`: per map, each BRDF's image. Maps whose lights
/// are alike in size (a map's turns) share the BRDFs' tables ([`RenderingMatrix::build_under`]).
pub fn render_bivariates_under(
    geom: &PixelGeometry,
    maps: &[&LightSet],
    brdfs: &[&Bivariate],
) -> Vec<Vec<Raster>> {
    let mut images: Vec<Vec<Raster>> = maps
        .iter()
        .map(|_| Vec::with_capacity(brdfs.len()))
        .collect();
    let Some(first) = brdfs.first() else {
        return images;
    };
    let binning = first.grid.theta_h_binning;
    assert!(
        brdfs.iter().all(|b| b.grid.theta_h_binning == binning),
        "BRDFs rendered in one pass share a θh binning"
    );
    // A pass holds at most PASS_COLUMNS columns: more BRDFs take more passes.
    for chunk in brdfs.chunks(PASS_COLUMNS) {
        let tables: Vec<&[f64]> = chunk.iter().map(|b| b.values.as_slice()).collect();
        let passes = RenderingMatrix::build_under(&geom.pixels, maps, &tables, None, binning);
        for (per_map, a) in images.iter_mut().zip(passes) {
            per_map.extend((0..tables.len()).map(|j| {
                let mut img = Raster::black(geom.width, geom.height);
                for (p, px) in geom.pixels.iter().enumerate() {
                    let rgb = std::array::from_fn(|c| a.row(3 * p + c)[j]);
                    img.set(px.x as usize, px.y as usize, rgb);
                }
                img
            }));
        }
    }
    images
}

/// A BRDF on a unit sphere seen orthographically (the camera of
/// [`Camera::eval_orthographic`](super::geometry::Camera::eval_orthographic)), with the scale
/// that makes two such pictures comparable.
pub struct SpherePicture {
    /// Linear radiance, black off the sphere.
    pub radiance: Raster,
    /// The brightest pixel (any channel) of a white Lambertian sphere (albedo 1) under the
    /// same lights. Shown on this scale, a picture's brightness says how much light the
    /// material returns, whatever the room's: a fixed exposure would show a dim room's
    /// estimate black, and an automatic one would make every material look equally bright.
    pub white_peak: f32,
}

impl SpherePicture {
    /// An anisotropic lobe the estimate chose ([`crate::anisotropic`]) on a `size` × `size`
    /// sphere under `lights`, in the world's frame, each light widening the lobe by its spread
    /// ([`crate::anisotropy::render_lobe`]).
    pub fn render_lobe(
        lobe: &super::anisotropic::AnisotropicLobe,
        lights: &LightSet,
        size: usize,
    ) -> super::error::Result<SpherePicture> {
        use super::geometry::{Camera, Shape};
        let sphere =
            PixelGeometry::rasterize(&Camera::eval_orthographic(size), &Shape::unit_sphere())?;
        let lit = super::anisotropy::render_lobe(&sphere.pixels, lights, lobe);
        // A white Lambertian sphere returns its irradiance over π.
        let white_peak = irradiance(&sphere, lights)
            .iter()
            .flatten()
            .fold(0.0f64, |a, &e| a.max(e / std::f64::consts::PI))
            .max(f64::from(f32::MIN_POSITIVE)) as f32;
        let mut radiance = Raster::black(sphere.width, sphere.height);
        for (px, rgb) in sphere.pixels.iter().zip(lit) {
            radiance.set(px.x as usize, px.y as usize, rgb.map(|x| x as f32));
        }
        Ok(SpherePicture {
            radiance,
            white_peak,
        })
    }

    /// `brdf` on a `size` × `size` sphere under `lights`, rendered with a white Lambertian
    /// column beside it in one pass of the rendering kernel.
    pub fn render(
        brdf: &Bivariate,
        lights: &LightSet,
        size: usize,
    ) -> super::error::Result<SpherePicture> {
        use super::geometry::{Camera, Shape};
        let sphere =
            PixelGeometry::rasterize(&Camera::eval_orthographic(size), &Shape::unit_sphere())?;
        let white = super::analytic::lambert_column(brdf.grid);
        let a = RenderingMatrix::build(
            &sphere.pixels,
            lights,
            &[&brdf.values, &white],
            None,
            brdf.grid.theta_h_binning,
        );
        // Column 0 is the BRDF, column 1 the white sphere; rows are (pixel, channel).
        let white_peak = (0..a.pixels.len() * 3)
            .map(|r| a.row(r)[1])
            .fold(0.0f32, f32::max)
            .max(f32::MIN_POSITIVE);
        let mut radiance = Raster::black(sphere.width, sphere.height);
        for (p, px) in sphere.pixels.iter().enumerate() {
            let rgb = std::array::from_fn(|c| a.row(3 * p + c)[0]);
            radiance.set(px.x as usize, px.y as usize, rgb);
        }
        Ok(SpherePicture {
            radiance,
            white_peak,
        })
    }

    /// sRGB with [`SpherePicture::white_peak`] at full scale; brighter is clipped.
    pub fn to_srgb8(&self) -> image::RgbImage {
        self.radiance.to_srgb8(1.0 / self.white_peak)
    }
}

/// Renders a full (θh, θd, φd) MERL table: the ground truth path, where φd matters.
/// φd is the azimuth of ωᵢ about h, measured from the plane of n and h (Rusinkiewicz).
pub fn render_merl(geom: &PixelGeometry, lights: &LightSet, brdf: &MerlBrdf) -> Raster {
    render_merl_until(geom, lights, brdf, &Stop::default()).expect("nobody can stop a fresh Stop")
}

/// [`render_merl`], ended early with [`crate::CoreError::Stopped`] once `stop` is requested: a
/// simulated camera's photo takes seconds, and a cancelled capture must not wait for it.
pub fn render_merl_until(
    geom: &PixelGeometry,
    lights: &LightSet,
    brdf: &MerlBrdf,
    stop: &Stop,
) -> Result<Raster> {
    // Interleaved f32 RGB: one cache line per lookup instead of three f64 planes; unmeasured
    // cells become 0 (they contribute nothing). One table per footprint level, each with the
    // θh footprint average of the rendering matrix applied per (θd, φd) column.
    let cells = merl::CELLS;
    let footprints = Footprints::of(lights);
    // Whether the cap and which of its rings are needed is judged on the φd = 90° slice,
    // which holds the peak.
    let slice: Vec<f64> = (0..3)
        .flat_map(|c| {
            (0..GRID_CELLS).map(move |g| {
                let (ih, jd) = (g / N_THETA_D, g % N_THETA_D);
                brdf.cell(c, ih, jd, merl::PHI_D_BINS / 2).max(0.0)
            })
        })
        .collect();
    let cap = Cap::of(lights, ThetaHBinning::Sqrt)
        .filter(|cap| cap.needed_by(&[&slice]))
        .map(|cap| cap.pruned_for(&[&slice]));
    let cap_bins = cap.as_ref().map_or(0, |c| c.bins);
    let mut table = vec![[0f32; 3]; cells * footprints.radii.len()];
    for (level, rho) in footprints.radii.iter().enumerate() {
        let smoothing = smoothing_for(ThetaHBinning::Sqrt, *rho);
        table[level * cells..(level + 1) * cells]
            .par_chunks_mut(merl::PHI_D_BINS * merl::THETA_D_BINS)
            .enumerate()
            .for_each(|(ih, slab)| {
                for (r, t) in slab.iter_mut().enumerate() {
                    let (kp, jd) = (r % merl::PHI_D_BINS, r / merl::PHI_D_BINS);
                    for (c, v) in t.iter_mut().enumerate() {
                        *v = smoothing[ih]
                            .iter()
                            .map(|(k, w)| w * brdf.cell(c, (*k).max(cap_bins), jd, kp).max(0.0))
                            .sum::<f64>() as f32;
                    }
                }
            });
    }
    let luts = Luts::new(ThetaHBinning::Sqrt);
    let packed = pack(lights, &footprints, cells);
    let mirrors = Mirrors::new(&packed);
    // Light by light over a tile of neighbouring pixels, not pixel by pixel over the lights:
    // neighbours read nearby cells of a light's table, which is tens of megabytes, so the
    // reads stay in the cache. Each pixel still sums its lights in the same order.
    let shade = |tile: &[GeomPixel], rows: &[Option<Box<[u64]>>], out: &mut [[f32; 3]]| {
        let mut acc = vec![[0f64; 3]; tile.len()];
        let lanes = TileLanes::of(tile);
        let mut geometry = LightGeometry::default();
        for l in &packed {
            geometry.compute(&lanes, l.dir);
            for (i, (row, acc)) in rows.iter().zip(acc.iter_mut()).enumerate() {
                if !geometry.lit[i] || row.as_deref().is_some_and(|row| !is_seen(row, l.index)) {
                    continue;
                }
                let (bh, bd) = (luts.h.bin(geometry.uh[i]), luts.d.bin(geometry.ud[i]));
                let kp = phi_bin(geometry.phi[i]);
                let f = table[l.base + merl::cell_index(bh, bd, kp)];
                let cos = geometry.cos[i];
                for c in 0..3 {
                    acc[c] += (f[c] * l.power[c] * cos) as f64;
                }
            }
        }
        for (((px, row), acc), out) in tile.iter().zip(rows).zip(&mut acc).zip(out) {
            if let Some(cap) = cap.as_ref().filter(|_| mirrors.seen_by(px, row.as_deref())) {
                cap.each_spoke(px, |s| {
                    let bd = luts.d.bin(dist2(s.dir, s.h));
                    let kp = phi_d_bin(px.normal, s.h, s.dir);
                    for band in s.bands {
                        for c in 0..3 {
                            let f = brdf.cell(c, band.bin, bd, kp).max(0.0)
                                - brdf.cell(c, cap.bins, bd, kp).max(0.0);
                            acc[c] += f * (s.weight[c] * band.share) as f64;
                        }
                    }
                });
            }
            *out = acc.map(|x| x as f32);
        }
    };
    shade_tiles_until(geom, lights, stop, shade)
}

/// The most pixels [`TileLanes`] holds: [`shade_tiles_until`]'s tile.
const TILE: usize = PIXELS_PER_TASK / 4;

/// A tile's normals and views as columns, one number per pixel, for [`LightGeometry`] to
/// read in SIMD lanes.
struct TileLanes {
    len: usize,
    n: [[f32; TILE]; 3],
    v: [[f32; TILE]; 3],
}

impl TileLanes {
    fn of(tile: &[GeomPixel]) -> TileLanes {
        assert!(tile.len() <= TILE, "a tile holds at most {TILE} pixels");
        let mut lanes = TileLanes {
            len: tile.len(),
            n: [[0.0; TILE]; 3],
            v: [[0.0; TILE]; 3],
        };
        for (i, px) in tile.iter().enumerate() {
            for k in 0..3 {
                lanes.n[k][i] = px.normal[k];
                lanes.v[k][i] = px.view[k];
            }
        }
        lanes
    }
}

/// One light's geometry at every pixel of a tile: what the MERL renderer's pair needs before
/// its table read. Worked out pixel by pixel in the pair loop it was two thirds of a simulated
/// photo's time; here it is arithmetic alone over columns, which the compiler runs eight
/// pixels at a time (AVX2), leaving the bins and table reads to the scalar loop. Each number
/// is computed by the same operations as [`Lit::pair`] and [`phi_d_bin`], so the photo is
/// the same to the bit.
struct LightGeometry {
    /// Whether the light is above the pixel's horizon and not opposite its view.
    lit: [bool; TILE],
    /// n·ω.
    cos: [f32; TILE],
    /// |n − h|² and |ω − h|², which [`BinLut::bin`] takes.
    uh: [f32; TILE],
    ud: [f32; TILE],
    /// φd modulo π.
    phi: [f32; TILE],
}

impl Default for LightGeometry {
    fn default() -> Self {
        LightGeometry {
            lit: [false; TILE],
            cos: [0.0; TILE],
            uh: [0.0; TILE],
            ud: [0.0; TILE],
            phi: [0.0; TILE],
        }
    }
}

impl LightGeometry {
    fn compute(&mut self, lanes: &TileLanes, dir: [f32; 3]) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2, checked just above.
            return unsafe { self.compute_avx2(lanes, dir) };
        }
        self.compute_lanes(lanes, dir)
    }

    /// [`LightGeometry::compute_lanes`] compiled for AVX2. Without FMA, every operation
    /// rounds as the portable build's does.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn compute_avx2(&mut self, lanes: &TileLanes, dir: [f32; 3]) {
        self.compute_lanes(lanes, dir)
    }

    #[inline(always)]
    fn compute_lanes(&mut self, lanes: &TileLanes, dir: [f32; 3]) {
        for i in 0..lanes.len {
            let n = [lanes.n[0][i], lanes.n[1][i], lanes.n[2][i]];
            let v = [lanes.v[0][i], lanes.v[1][i], lanes.v[2][i]];
            let cos = dot3(n, dir);
            // `half_vector`'s test is folded into `lit` instead of an early return.
            let (h, len2) = half_vector_unchecked(dir, v);
            self.lit[i] = (cos > 0.0) & (len2 >= 1e-12);
            self.cos[i] = cos;
            self.uh[i] = dist2(n, h);
            self.ud[i] = dist2(dir, h);
            self.phi[i] = phi_d(n, h, dir);
        }
    }
}

/// The MERL φd bin of φd modulo π, as `merl::phi_d_bin`, in f32.
#[inline(always)]
fn phi_bin(phi: f32) -> usize {
    ((phi * (merl::PHI_D_BINS as f32 / std::f32::consts::PI)) as usize).min(merl::PHI_D_BINS - 1)
}

/// The MERL φd bin of a light from `dir` at half vector `h` on normal `n` ([`phi_d`]).
#[inline(always)]
fn phi_d_bin(n: [f32; 3], h: [f32; 3], dir: [f32; 3]) -> usize {
    phi_bin(phi_d(n, h, dir))
}

/// The azimuth of ωᵢ (`dir`) about half vector `h` from the plane of n and h, over [0, π]
/// with reciprocity: MERL's φd, in f32.
#[inline(always)]
fn phi_d(n: [f32; 3], h: [f32; 3], dir: [f32; 3]) -> f32 {
    // e2 = n × h / |n × h|, e1 = e2 × h; at θh ≈ 0 any frame serves (isotropy).
    let mut e2 = [
        n[1] * h[2] - n[2] * h[1],
        n[2] * h[0] - n[0] * h[2],
        n[0] * h[1] - n[1] * h[0],
    ];
    if dot3(e2, e2) < 1e-14 {
        e2 = if n[1].abs() < 0.9 {
            [n[2], 0.0, -n[0]]
        } else {
            [0.0, n[2], -n[1]]
        };
    }
    let e1 = [
        e2[1] * h[2] - e2[2] * h[1],
        e2[2] * h[0] - e2[0] * h[2],
        e2[0] * h[1] - e2[1] * h[0],
    ];
    phi_mod_pi(dot3(dir, e2), dot3(dir, e1))
}

/// atan2(y, x) taken modulo π, in [0, π]: the φd of reciprocity. A polynomial arctangent
/// (error at most 1e-5 rad, against a φd bin of 1°) in place of `atan2`, one of the costliest
/// steps of the MERL renderer's inner loop: 8% of its time, measured.
#[inline(always)]
fn phi_mod_pi(y: f32, x: f32) -> f32 {
    // Adding π turns (x, y) into (−x, −y): the upper half plane holds every class.
    let a = fast_atan2(y, x);
    if a < 0.0 {
        a + std::f32::consts::PI
    } else {
        a
    }
}

/// Renders any isotropic BRDF by evaluating it per (pixel, light) pair: slow, general, and
/// independent of the binning shortcuts above.
pub fn render_full(geom: &PixelGeometry, lights: &LightSet, brdf: &dyn IsotropicBrdf) -> Raster {
    render_in_frames(geom, lights, super::brdf::tangent_frame, |wi, wo| {
        brdf.eval_dirs(wi, wo)
    })
}

/// An anisotropic lobe ([`crate::anisotropic`]) rendered as [`render_full`] renders an
/// isotropic BRDF, each pixel in the lobe's own frame there: its highlights keep their
/// stretch, which no bivariate table holds.
pub fn render_anisotropic(
    geom: &PixelGeometry,
    lights: &LightSet,
    lobe: &super::anisotropic::AnisotropicLobe,
) -> Raster {
    render_in_frames(
        geom,
        lights,
        |n| lobe.frame(n),
        |wi, wo| lobe.eval_local(wi, wo),
    )
}

/// [`render_full`]'s loop, with the BRDF `eval` given directions in the frame `frame` lays on
/// each pixel's normal (tangent, bitangent, normal as x, y, z): an anisotropic BRDF in its
/// own tangent frame.
pub fn render_in_frames(
    geom: &PixelGeometry,
    lights: &LightSet,
    frame: impl Fn(Vec3) -> (Vec3, Vec3) + Sync,
    eval: impl Fn(Vec3, Vec3) -> [f64; 3] + Sync,
) -> Raster {
    // Point lights: this renderer is the independent check, so it takes no footprint. It
    // still splits off the cap ([`crate::sharp`]): f′ reads f at the cap's edge, in the same
    // azimuth about the normal.
    let packed = pack(lights, &Footprints::of(lights), 0);
    let mirrors = Mirrors::new(&packed);
    let cap = Cap::of(lights, ThetaHBinning::Sqrt);
    let theta_c = cap.as_ref().map_or(0.0, |c| c.edge(ThetaHBinning::Sqrt));
    let flat = |wi: [f64; 3], wo: [f64; 3]| match to_cap_edge(wi, wo, theta_c) {
        Some((a, b)) => eval(a, b),
        None => eval(wi, wo),
    };
    let shade = |px: &GeomPixel, seen: Option<&[u64]>| -> [f32; 3] {
        let n = px.normal.map(|c| c as f64);
        let (t, b) = frame(n);
        let local = |d: [f32; 3]| {
            let d = d.map(|c| c as f64);
            [
                super::brdf::dot(d, t),
                super::brdf::dot(d, b),
                super::brdf::dot(d, n),
            ]
        };
        let wo = local(px.view);
        let mut acc = [0f64; 3];
        // The loop's pair is not used: this renderer evaluates the BRDF in f64 itself.
        each_light(px, &packed, seen, |l, _| {
            let wi = local(l.dir);
            if wi[2] <= 0.0 {
                return;
            }
            let f = flat(wi, wo);
            for c in 0..3 {
                acc[c] += f[c] * l.power[c] as f64 * wi[2];
            }
        });
        if let Some(cap) = cap.as_ref().filter(|_| mirrors.seen_by(px, seen)) {
            cap.each_sample(px, |s| {
                let wi = local(s.dir);
                let (f, f_flat) = (eval(wi, wo), flat(wi, wo));
                for c in 0..3 {
                    acc[c] += (f[c] - f_flat[c]) * s.weight[c] as f64;
                }
            });
        }
        acc.map(|x| x as f32)
    };
    shade_pixels(geom, lights, shade)
}

/// The irradiance Σ L·cos·Δω per channel at each pixel from the lights it sees, in the
/// pixels' order: what a white Lambertian surface returns, times π.
pub fn irradiance(geom: &PixelGeometry, lights: &LightSet) -> Vec<[f64; 3]> {
    let packed = pack(lights, &Footprints::of(lights), 0);
    let seen = Seen::new(&geom.pixels, lights);
    geom.pixels
        .par_iter()
        .with_min_len(PIXELS_PER_TASK / 4)
        .map(|px| {
            let row = seen.fresh(px);
            let mut e = [0f64; 3];
            each_light(px, &packed, row.as_deref(), |l, cos| {
                for c in 0..3 {
                    e[c] += (l.power[c] * cos) as f64;
                }
            });
            e
        })
        .collect()
}

/// The fraction of the light reaching each pixel's tangent plane that its own object lets
/// through: Σ L·cos·Δω over the lights it sees, over the same sum for every light above its
/// horizon (all channels). 1 on a convex shape; the preview and report show it.
pub fn visible_fraction(geom: &PixelGeometry, lights: &LightSet) -> Raster {
    let packed = pack(lights, &Footprints::of(lights), 0);
    shade_pixels(geom, lights, |px, seen| {
        let irradiance = |seen: Option<&[u64]>| {
            let mut sum = 0f64;
            each_light(px, &packed, seen, |l, cos| {
                sum += (l.power.iter().sum::<f32>() * cos) as f64;
            });
            sum
        };
        let all = irradiance(None);
        let f = if all > 0.0 {
            (irradiance(seen) / all) as f32
        } else {
            1.0
        };
        [f; 3]
    })
}

/// Each pixel's `shade`, given the lights its object lets it see, into an image. Each
/// pixel's visibility is used once here, so it is worked out and dropped, not kept: a
/// full-resolution render would otherwise hold a row per pixel.
fn shade_pixels(
    geom: &PixelGeometry,
    lights: &LightSet,
    shade: impl Fn(&GeomPixel, Option<&[u64]>) -> [f32; 3] + Sync + Send,
) -> Raster {
    shade_pixels_until(geom, lights, &Stop::default(), shade).expect("nobody can stop a fresh Stop")
}

/// [`shade_pixels`], whose pixels are skipped once `stop` is requested, and then
/// [`crate::CoreError::Stopped`].
fn shade_pixels_until(
    geom: &PixelGeometry,
    lights: &LightSet,
    stop: &Stop,
    shade: impl Fn(&GeomPixel, Option<&[u64]>) -> [f32; 3] + Sync + Send,
) -> Result<Raster> {
    shade_tiles_until(geom, lights, stop, |tile, rows, out| {
        for ((px, row), out) in tile.iter().zip(rows).zip(out) {
            *out = shade(px, row.as_deref());
        }
    })
}

/// Pixels shaded a tile at a time, each tile with its pixels' visibility rows (None off a
/// mesh), on every core; ended early once `stop` is requested.
fn shade_tiles_until(
    geom: &PixelGeometry,
    lights: &LightSet,
    stop: &Stop,
    shade: impl Fn(&[GeomPixel], &[Option<Box<[u64]>>], &mut [[f32; 3]]) + Sync + Send,
) -> Result<Raster> {
    let seen = Seen::new(&geom.pixels, lights);
    let mut values = vec![[0f32; 3]; geom.pixels.len()];
    values
        .par_chunks_mut(TILE)
        .zip(geom.pixels.par_chunks(TILE))
        .for_each(|(out, tile)| {
            if stop.requested() {
                return;
            }
            let rows: Vec<Option<Box<[u64]>>> = tile.iter().map(|px| seen.fresh(px)).collect();
            shade(tile, &rows, out);
        });
    stop.check()?;
    let mut img = Raster::black(geom.width, geom.height);
    for (px, v) in geom.pixels.iter().zip(values) {
        img.set(px.x as usize, px.y as usize, v);
    }
    Ok(img)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Camera, Shape};

    #[test]
    fn the_polynomial_phi_matches_atan2_modulo_pi() {
        let mut worst = 0f64;
        for i in 0..20_000 {
            let t = i as f64 / 20_000.0 * std::f64::consts::TAU;
            for r in [1e-3, 0.5, 1.0] {
                let (y, x) = ((t.sin() * r) as f32, (t.cos() * r) as f32);
                let exact = (y as f64).atan2(x as f64).rem_euclid(std::f64::consts::PI);
                let d = (phi_mod_pi(y, x) as f64 - exact).abs();
                // π and 0 are the same class.
                worst = worst.max(d.min((d - std::f64::consts::PI).abs()));
            }
        }
        assert!(worst < 1.5e-5, "worst {worst}");
        assert_eq!(phi_mod_pi(0.0, 0.0), 0.0);
    }

    /// Smoothing whole θd rows at once rounds every cell as its own sum over the weights
    /// does: tables are the same to the bit as before the rows ran side by side.
    #[test]
    fn a_table_smoothed_by_rows_is_each_cell_smoothed_alone() {
        let values: Vec<f64> = (0..3 * GRID_CELLS)
            .map(|i| ((i * 7919) % 1000) as f64 / 37.0 - 3.0)
            .collect();
        for binning in [ThetaHBinning::Sqrt, ThetaHBinning::Uniform] {
            for rho in [1e-4, 0.01, 0.2] {
                let smoothing = theta_h_smoothing(binning, rho);
                let rows = smooth_bivariate(&values, &smoothing);
                for c in 0..3 {
                    for (i, weights) in smoothing.iter().enumerate() {
                        for jd in 0..N_THETA_D {
                            let alone: f64 = weights
                                .iter()
                                .map(|(k, w)| w * values[c * GRID_CELLS + k * N_THETA_D + jd])
                                .sum();
                            let cell = c * GRID_CELLS + i * N_THETA_D + jd;
                            assert_eq!(rows[cell].to_bits(), alone.to_bits(), "cell {cell}");
                        }
                    }
                }
            }
        }
    }

    /// The AVX2 build of the pixel loops must give the portable build's matrix bit for bit
    /// (no fused multiply-add), so that results do not depend on the CPU.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn the_avx2_loops_match_the_portable_ones_bit_for_bit() {
        use crate::bivariate::VALUES;
        use crate::envmap::EnvMap;
        use crate::geometry::{Camera, PixelGeometry, Shape};
        if !std::arch::is_x86_feature_detected!("avx2") {
            eprintln!("no AVX2 on this CPU: nothing to compare");
            return;
        }
        let (w, h) = (32, 16);
        // Some texels black, so that the lights packed are not whole blocks of lanes.
        let pixels: Vec<[f32; 3]> = (0..w * h)
            .map(|i| {
                if i % 37 == 0 {
                    return [0.0; 3];
                }
                [
                    (i % 7) as f32 + 0.5,
                    (i % 5) as f32 + 0.25,
                    (i % 3) as f32 + 1.0,
                ]
            })
            .collect();
        let lights = EnvMap::from_pixels(w, h, pixels, "test map")
            .unwrap()
            .lights(0.3);
        let orthographic =
            PixelGeometry::rasterize(&Camera::eval_orthographic(24), &Shape::unit_sphere())
                .unwrap();
        // A pinhole camera: every pixel its own view, the general loop's case.
        let pinhole = pinhole_sphere(24, 18);
        for (m, geometry) in [1, 5, 12, PASS_COLUMNS]
            .into_iter()
            .flat_map(|m| [(m, &orthographic), (m, &pinhole)])
        {
            let columns: Vec<Vec<f64>> = (0..m)
                .map(|j| {
                    (0..VALUES)
                        .map(|i| ((i * (j + 3)) % 101) as f64 / 101.0)
                        .collect()
                })
                .collect();
            let refs: Vec<&[f64]> = columns.iter().map(|c| c.as_slice()).collect();
            let footprints = Footprints::of(&lights);
            let table = ColumnTable::new(&refs, ThetaHBinning::Sqrt, &footprints, &vec![0; m]);
            let packed = pack(&lights, &footprints, ColumnTable::stride(m));
            assert_ne!(packed.len() % BLOCK, 0, "a last block partly filled");
            let shared = table.shared_view(geometry.pixels[0].view, &packed);
            let (packed_lanes, shared_lanes) =
                (PackedLight::lanes(&packed), ViewLight::lanes(&shared));
            let (mut fast, mut portable) = (vec![0f32; 3 * m], vec![0f32; 3 * m]);
            for px in &geometry.pixels {
                table.pixel(px, &packed, &packed_lanes, None, &mut fast);
                by_columns!(
                    m,
                    table.pixel_m(px, &packed, &packed_lanes, None, &mut portable)
                );
                assert_eq!(fast, portable, "general loop, {m} columns");
                assert_eq!(
                    fast,
                    one_light_at_a_time(&table, px, &packed),
                    "general loop"
                );
                table.pixel(px, &shared, &shared_lanes, None, &mut fast);
                by_columns!(
                    m,
                    table.pixel_m(px, &shared, &shared_lanes, None, &mut portable)
                );
                assert_eq!(fast, portable, "shared-view loop, {m} columns");
                assert_eq!(
                    fast,
                    one_light_at_a_time(&table, px, &shared),
                    "shared view"
                );
            }
        }
    }

    /// A pixel's row summed light by light through [`Lit::pair`], in f32 as the pixel loop
    /// sums: what its blocks of lanes must give to the bit.
    fn one_light_at_a_time<L: Lit>(table: &ColumnTable, px: &GeomPixel, lights: &[L]) -> Vec<f32> {
        let m = table.m;
        let mut acc = vec![0f32; 3 * m];
        for l in lights {
            let light = l.packed();
            if let Some(Pair { cos, bh, bd }) = l.pair(px.normal, px.view, &table.luts) {
                let start = light.base + (bh * N_THETA_D + bd) * 3 * m;
                for c in 0..3 {
                    for j in 0..m {
                        acc[c * m + j] += light.power[c] * cos * table.data[start + c * m + j];
                    }
                }
            }
        }
        acc
    }

    /// The unit sphere through a `width` × `height` pinhole camera a little off its axis:
    /// every pixel with its own view, the renderers' general case.
    fn pinhole_sphere(width: usize, height: usize) -> PixelGeometry {
        let f = 1.25 * width as f64;
        let camera = Camera::Pinhole {
            width,
            height,
            fx: f,
            fy: f,
            cx: width as f64 / 2.0,
            cy: height as f64 / 2.0,
            pose: crate::geometry::Pose {
                position: [0.3, 0.4, 3.0],
                look_at: [0.0; 3],
                up: [0.0, 1.0, 0.0],
            },
        };
        PixelGeometry::rasterize(&camera, &Shape::unit_sphere()).unwrap()
    }

    /// The MERL renderer's light geometry over a tile's lanes is the pair loop's, number for
    /// number: in its AVX2 build, in the portable one, and against [`Lit::pair`] and
    /// [`phi_d_bin`] pixel by pixel (a perspective camera, so every pixel has its own view).
    #[test]
    fn a_tile_s_light_geometry_is_the_pair_loop_s_to_the_bit() {
        let geometry = pinhole_sphere(40, 30);
        let luts = Luts::new(ThetaHBinning::Sqrt);
        let dirs = (0..200).map(|k| {
            let (a, z) = (k as f32 * 2.399_963, 1.0 - 2.0 * (k as f32 + 0.5) / 200.0);
            let r = (1.0 - z * z).sqrt();
            [r * a.cos(), z, r * a.sin()]
        });
        let mut checked = 0;
        for dir in dirs {
            let light = PackedLight {
                dir,
                power: [1.0; 3],
                base: 0,
                index: 0,
            };
            for tile in geometry.pixels.chunks(TILE) {
                let lanes = TileLanes::of(tile);
                let mut geo = LightGeometry::default();
                geo.compute(&lanes, dir);
                let mut portable = LightGeometry::default();
                portable.compute_lanes(&lanes, dir);
                for (i, px) in tile.iter().enumerate() {
                    assert_eq!(geo.lit[i], portable.lit[i]);
                    match light.pair(px.normal, px.view, &luts) {
                        None => assert!(!geo.lit[i], "lit where the pair loop is not"),
                        Some(pair) => {
                            assert!(geo.lit[i], "unlit where the pair loop is lit");
                            assert_eq!(geo.cos[i].to_bits(), pair.cos.to_bits());
                            assert_eq!(luts.h.bin(geo.uh[i]), pair.bh);
                            assert_eq!(luts.d.bin(geo.ud[i]), pair.bd);
                            let h = half_vector(dir, px.view).unwrap();
                            assert_eq!(phi_bin(geo.phi[i]), phi_d_bin(px.normal, h, dir));
                            for (a, b) in [
                                (geo.uh[i], portable.uh[i]),
                                (geo.ud[i], portable.ud[i]),
                                (geo.phi[i], portable.phi[i]),
                            ] {
                                assert_eq!(a.to_bits(), b.to_bits());
                            }
                            checked += 1;
                        }
                    }
                }
            }
        }
        assert!(checked > 10_000, "only {checked} lit pairs compared");
    }

    /// A map with structure at every scale: smooth bands, and a small bright lamp.
    fn textured_map() -> crate::envmap::EnvMap {
        let (w, h) = (128, 64);
        let pixels = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f32, (i / w) as f32);
                let lamp = if (x - 40.0).abs() < 2.0 && (y - 20.0).abs() < 2.0 {
                    30.0
                } else {
                    0.0
                };
                let band = 1.0 + 0.8 * (x * 0.3).sin() * (y * 0.2).cos();
                [band + lamp, 0.6 * band + lamp, 0.3 + lamp]
            })
            .collect();
        crate::envmap::EnvMap::from_pixels(w, h, pixels, "test map").unwrap()
    }

    /// A chosen anisotropic lobe, rendered fast for the previews (each light widening the lobe
    /// by its spread, [`crate::anisotropy::render_lobe`]) and with point lights and the cap
    /// ([`render_anisotropic`], what `brdfd render` relights with): on a map with a small bright
    /// lamp the two agree, at the estimate's 4,096 lights and at the preview's 512.
    #[test]
    fn a_widened_lobe_renders_as_point_lights_do() {
        let map = textured_map();
        let geometry =
            PixelGeometry::rasterize(&Camera::eval_orthographic(48), &Shape::unit_sphere())
                .unwrap();
        let lobe = crate::anisotropic::AnisotropicLobe {
            diffuse: [0.1, 0.1, 0.1],
            specular: [0.8; 3],
            axis: crate::brdf::normalize([0.3, 0.9, 0.2]),
            alpha_t: 0.25,
            alpha_b: 0.07,
        };
        let exact = render_anisotropic(&geometry, &map.compressed(4096, 0.0), &lobe);
        // Measured: 0.0021 at 4,096 lights, 0.036 at 512.
        for (count, bound) in [(4096, 0.01), (512, 0.06)] {
            let lights = map.compressed(count, 0.0);
            let mut fast = Raster::black(geometry.width, geometry.height);
            let lit = crate::anisotropy::render_lobe(&geometry.pixels, &lights, &lobe);
            for (px, rgb) in geometry.pixels.iter().zip(lit) {
                fast.set(px.x as usize, px.y as usize, rgb.map(|x| x as f32));
            }
            let e = fast.relative_rmse(&exact);
            eprintln!("{count} lights: {e:.4}");
            assert!(e < bound, "{count} lights: {e}");
        }
    }

    fn sharp_mirror(alpha: f64) -> crate::analytic::Microfacet {
        crate::analytic::Microfacet::one_lobe([0.0; 3], [1.0; 3], [1.0; 3], alpha)
    }

    /// Under a uniform sky a mirror-like lobe returns its directional albedo, whatever the
    /// lights: the cap's samples carry the right solid angles.
    #[test]
    fn a_sharp_lobe_under_a_uniform_sky_returns_its_albedo() {
        use crate::bivariate::Grid;
        let sky =
            crate::envmap::EnvMap::from_pixels(64, 32, vec![[1.0; 3]; 64 * 32], "sky").unwrap();
        let geometry =
            PixelGeometry::rasterize(&Camera::eval_orthographic(16), &Shape::unit_sphere())
                .unwrap();
        for alpha in [0.005, 0.02] {
            let brdf = sharp_mirror(alpha);
            let albedo = crate::brdf::directional_albedo(&brdf, 0.0)[0];
            let table = Bivariate::reduce(&brdf, Grid::default());
            for count in [128, 1024] {
                let lights = sky.compressed(count, 0.0);
                assert!(Cap::of(&lights, ThetaHBinning::Sqrt).is_some());
                for (name, image) in [
                    ("full", render_full(&geometry, &lights, &brdf)),
                    ("bivariate", render_bivariate(&geometry, &lights, &table)),
                ] {
                    let centre = image.get(8, 8)[0] as f64;
                    assert!(
                        (centre / albedo - 1.0).abs() < 0.03,
                        "α {alpha}, {count} lights, {name}: {centre} against {albedo}"
                    );
                }
            }
        }
    }

    /// A mirror-like lobe renders alike under 256 lights and under 4,096 once the cap reads
    /// the map itself; with the lights alone (a set without its map) the two differ by the
    /// light grid, several times as much.
    #[test]
    fn a_sharp_lobe_shows_no_light_grid() {
        use crate::bivariate::Grid;
        let map = textured_map();
        let geometry =
            PixelGeometry::rasterize(&Camera::eval_orthographic(48), &Shape::unit_sphere())
                .unwrap();
        let table = Bivariate::reduce(&sharp_mirror(0.01), Grid::default());
        let render = |count: usize, with_map: bool| {
            let mut lights = map.compressed(count, 0.0);
            if !with_map {
                lights.map = None;
            }
            render_bivariate(&geometry, &lights, &table)
        };
        let with_cap = render(256, true).relative_rmse(&render(4096, true));
        let lights_alone = render(256, false).relative_rmse(&render(4096, false));
        eprintln!(
            "256 against 4,096 lights: {with_cap:.4} with the cap, {lights_alone:.4} without"
        );
        assert!(with_cap < 0.05, "{with_cap}");
        assert!(
            with_cap * 3.0 < lights_alone,
            "{with_cap} against {lights_alone}"
        );
    }

    /// BRDFs rendered in one pass are each the image it renders alone: to the bit for one
    /// that needs no cap, and within the cap's pruning (rings holding below 0.2% of a
    /// column's light) for those a sharper neighbour has read more of it (a mirror, a sharp
    /// lobe, a broad one, and a mixture of lobes).
    #[test]
    fn brdfs_rendered_together_are_each_rendered_alone() {
        use crate::analytic::{Lobe, Microfacet};
        use crate::bivariate::Grid;
        let map = textured_map();
        let geometry =
            PixelGeometry::rasterize(&Camera::eval_orthographic(32), &Shape::unit_sphere())
                .unwrap();
        let mut mixed = Microfacet::one_lobe([0.1, 0.2, 0.3], [0.5; 3], [1.0; 3], 0.004);
        mixed.lobes.push(Lobe {
            f0: [0.2; 3],
            f90: [1.0; 3],
            alpha: 0.08,
        });
        let models = [
            sharp_mirror(0.002),
            sharp_mirror(0.03),
            Microfacet::one_lobe([0.4; 3], [0.04; 3], [1.0; 3], 0.5),
            mixed,
        ];
        let tables: Vec<Bivariate> = models
            .iter()
            .map(|m| Bivariate::reduce(m, Grid::default()))
            .collect();
        for count in [256, 2048] {
            let lights = map.compressed(count, 0.0);
            let cap = Cap::of(&lights, ThetaHBinning::Sqrt).expect("a map's lights have a cap");
            let together =
                render_bivariates(&geometry, &lights, &tables.iter().collect::<Vec<_>>());
            for (i, (table, image)) in tables.iter().zip(&together).enumerate() {
                let alone = render_bivariate(&geometry, &lights, table);
                if !cap.needed_by(&[&table.values]) {
                    let bits = |r: &Raster| -> Vec<u32> {
                        r.pixels.iter().flatten().map(|v| v.to_bits()).collect()
                    };
                    assert_eq!(bits(image), bits(&alone), "{count} lights, BRDF {i}");
                } else {
                    let e = image.relative_rmse(&alone);
                    assert!(e < 0.002, "{count} lights, BRDF {i}: {e}");
                }
            }
        }
    }

    /// Under several maps at once, each matrix is the one its map's pass makes alone, to the
    /// bit, whether its table is its own or shared: a map at three turns (whose lights are
    /// alike in size, so they share one), beside another map and a hand-placed light set.
    #[test]
    fn matrices_under_several_maps_are_each_map_s_own() {
        use crate::analytic::Microfacet;
        use crate::bivariate::Grid;
        let textured = textured_map();
        let other = crate::envmap::EnvMap::from_pixels(
            64,
            32,
            (0..64 * 32)
                .map(|i| [1.0 + (i % 7) as f32, 0.5, 2.0 * ((i / 64) % 3) as f32])
                .collect(),
            "another map",
        )
        .unwrap();
        let sphere =
            PixelGeometry::rasterize(&Camera::eval_orthographic(24), &Shape::unit_sphere())
                .unwrap();
        let tables: Vec<Bivariate> = [
            sharp_mirror(0.01),
            Microfacet::one_lobe([0.3; 3], [0.04; 3], [1.0; 3], 0.3),
        ]
        .iter()
        .map(|m| Bivariate::reduce(m, Grid::default()))
        .collect();
        let columns: Vec<&[f64]> = tables.iter().map(|t| t.values.as_slice()).collect();
        let hand = LightSet {
            directions: vec![[0.0, 0.6, 0.8], [0.6, 0.0, 0.8]],
            radiance: vec![[2.0; 3], [0.5, 1.0, 1.5]],
            solid_angle: vec![0.05, 0.2],
            ..LightSet::default()
        };
        let maps = [
            textured.compressed(256, 0.0),
            textured.compressed(256, 1.3),
            other.compressed(128, 0.2),
            textured.compressed(256, 4.0),
            hand,
        ];
        let lit: Vec<&LightSet> = maps.iter().collect();
        let binning = ThetaHBinning::Sqrt;
        let offset = columns[1];
        let together = RenderingMatrix::build_under(
            &sphere.pixels,
            &lit,
            &columns[..1],
            Some(offset),
            binning,
        );
        for (i, (lights, a)) in maps.iter().zip(&together).enumerate() {
            let alone = RenderingMatrix::build(
                &sphere.pixels,
                lights,
                &columns[..1],
                Some(offset),
                binning,
            );
            let bits = |v: &[f32]| -> Vec<u32> { v.iter().map(|x| x.to_bits()).collect() };
            assert_eq!(bits(&a.rows), bits(&alone.rows), "map {i}");
            assert_eq!(
                bits(a.offset.as_ref().unwrap()),
                bits(alone.offset.as_ref().unwrap()),
                "map {i}"
            );
        }
        // The turns' lights are alike in size: what lets them share a table.
        assert_eq!(
            Footprints::of(&maps[0]).radii,
            Footprints::of(&maps[3]).radii
        );
    }

    /// The preview's scale: a white Lambertian sphere reaches full white, a grey one its
    /// albedo, and neither depends on how bright the room was.
    #[test]
    fn sphere_pictures_are_on_the_white_spheres_scale() {
        use crate::analytic::lambert_column;
        use crate::bivariate::Grid;
        use crate::envmap::EnvMap;
        let (w, h) = (16, 8);
        let room = |gain: f32| {
            let pixels = (0..w * h)
                .map(|i| [gain * (1.0 + (i % 5) as f32), gain, gain * 0.5])
                .collect();
            EnvMap::from_pixels(w, h, pixels, "test map")
                .unwrap()
                .lights(0.4)
        };
        let grid = Grid::default();
        let lambert = |albedo: f64| {
            let values = lambert_column(grid).iter().map(|v| v * albedo).collect();
            Bivariate::from_values(grid, values, vec![true; GRID_CELLS])
        };
        let peak = |albedo: f64, gain: f32| {
            let picture = SpherePicture::render(&lambert(albedo), &room(gain), 48).unwrap();
            let srgb = picture.to_srgb8();
            srgb.pixels().flat_map(|p| p.0).max().unwrap()
        };
        assert_eq!(peak(1.0, 1.0), 255);
        // Linear 0.5 is sRGB 188.
        assert_eq!(peak(0.5, 1.0), 188);
        assert_eq!(peak(0.5, 40.0), 188, "a brighter room, the same picture");
    }

    #[test]
    fn lut_matches_direct_binning() {
        let h = BinLut::theta_h(ThetaHBinning::Sqrt);
        let d = BinLut::theta_d();
        // Angles straddling every edge, plus a dense sweep.
        let mut angles: Vec<f64> = (0..90)
            .flat_map(|i| {
                let e = ThetaHBinning::Sqrt.lower_edge(i);
                [e * (1.0 - 1e-4), e * (1.0 + 1e-4) + 1e-9]
            })
            .collect();
        angles.extend((0..20000).map(|i| i as f64 / 20000.0 * std::f64::consts::FRAC_PI_2));
        let mut mismatches = 0;
        for th in angles {
            let u = u_of_theta(th) as f32;
            // f32 rounding of u can move an angle within ~1e-7 relative of an edge.
            let expect_h = merl::theta_h_bin(th);
            if h.bin(u) != expect_h {
                mismatches += 1;
            }
            assert!(h.bin(u).abs_diff(expect_h) <= 1);
            assert!(d.bin(u).abs_diff(merl::theta_d_bin(th)) <= 1);
        }
        assert!(mismatches <= 4, "{mismatches} mismatches");
    }
}
