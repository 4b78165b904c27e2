//! Which lights a point of a mesh sees past the mesh itself: self-occlusion.
//!
//! A light at infinity counts for a surface point only if the ray from the point towards it
//! leaves the object. 50,000 pixels under 4,096 lights are 2·10⁸ rays, so they are not cast
//! one by one: the lights go in packets of `CLUSTER` neighbouring directions, and one walk
//! of the BVH per pixel and packet carries a bit per ray still open. A box is entered only if
//! it reaches above the pixel's tangent plane (nothing below it can be met by a ray that leaves
//! the surface; each box keeps the slab its triangles lie in, so that a wall's own boxes are
//! seen to lie in the wall's plane) and some open ray passes through it, tested ray by ray in one vector pass. Each
//! triangle on the way is tested against all the open rays at once: a ray from o meets
//! triangle abc exactly when its direction lies in the trihedral cone from o through a, b and
//! c, three signs of dot products. A walk ends when every ray of its packet is blocked.
//!
//! Answers are kept per light set (by a fingerprint of its directions) and per pixel: the
//! estimate builds many matrices over the same pixels and lights, and each asks again.

use std::collections::hash_map::DefaultHasher;
use std::hash::{Hash, Hasher};
use std::sync::{Arc, Mutex, OnceLock};

use super::brdf::{cross as cross64, dot as dot64, sub as sub64, Vec3};
use super::bvh::{Bvh, Surface};
use super::envmap::LightSet;
use super::geometry::GeomPixel;

/// Lights per packet: one bit each in a u64. On the surface-area tree with slabs, 64 ran the
/// bench's visibility in 0.91 of the time 32 took, side by side; on the median split's tree
/// without slabs, 16, 32 and 64 had taken about as long as one another.
const CLUSTER: usize = 64;

/// A surface point whose visibility is asked: where the rays start (just off the surface,
/// along the normal) and the normal.
#[derive(Clone, Copy, Debug)]
pub struct Point {
    pub origin: [f32; 3],
    pub normal: [f32; 3],
}

/// One box of the BVH and the layer its triangles lie in, in one cache line.
#[derive(Clone, Copy)]
#[repr(C, align(64))]
struct BoxNode {
    lo: [f32; 3],
    hi: [f32; 3],
    /// A leaf's first triangle, or an inner node's first child (the second follows).
    first: u32,
    /// A leaf's triangle count, or [`INNER`] with the axis from an inner node's first
    /// child's centre to its second's (bits 0–1, and bit 2 if the second is the lower):
    /// the walk takes the child the rays meet first without reading either.
    meta: u32,
    /// The layer the box's triangles lie in: a unit vector near their normal, and the least
    /// and greatest `across · v` over their corners v (all 0 where the box has no layer). A
    /// tilted wall's box stands far above the wall's own tangent plane, and a ray grazing
    /// along the wall passes through box after box of it; the layer is as thin as the wall,
    /// so that [`BoxNode::above`] passes over them.
    across: [f32; 3],
    layer: [f32; 2],
}

/// The instruction sets the packet tests are written for.
const PORTABLE: u8 = 0;
const AVX2: u8 = 1;
const AVX512: u8 = 2;

/// Proof that this CPU runs the instruction set `S`: made only where that was checked, it
/// lets the safe functions that take one use `S`'s intrinsics.
#[derive(Clone, Copy)]
struct Isa<const S: u8>(());

impl Isa<PORTABLE> {
    fn portable() -> Isa<PORTABLE> {
        Isa(())
    }
}

impl<const S: u8> Isa<S> {
    /// # Safety
    /// The CPU must have the instruction set `S`.
    #[cfg(target_arch = "x86_64")]
    unsafe fn assumed() -> Isa<S> {
        Isa(())
    }
}

/// The flag of an inner node in [`BoxNode::meta`].
const INNER: u32 = 1 << 31;

/// A mesh as the object that may hide its own points' lights, and those points.
pub struct Occluder {
    nodes: Vec<BoxNode>,
    tris: Vec<[[f32; 3]; 3]>,
    points: Vec<Point>,
    /// The middle of the mesh's box: the boxes and triangles are kept about it, so that f32
    /// rounds them by the part's size, not by where it stands.
    centre: [f64; 3],
    /// What the test of a box against a tangent plane may be off by in f32, with room to
    /// spare: a box is passed over only when it lies this far below the plane.
    slack: f32,
    tables: Mutex<Vec<(u64, Arc<Table>)>>,
    /// The mesh itself, for the light it throws on itself ([`crate::bounce`]); `None` for an
    /// occluder of points off the pixels (a bounce's own cells).
    surface: Option<Arc<Surface>>,
}

/// A pixel's place in its object's [`Occluder`]: the pixel is `points[id]` there.
#[derive(Clone)]
pub struct Shadow {
    pub occluder: Arc<Occluder>,
    pub id: u32,
}

impl PartialEq for Shadow {
    fn eq(&self, other: &Shadow) -> bool {
        Arc::ptr_eq(&self.occluder, &other.occluder) && self.id == other.id
    }
}

impl std::fmt::Debug for Shadow {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Shadow(point {})", self.id)
    }
}

/// Neighbouring light directions, [`CLUSTER`] at a time.
struct Clusters {
    packets: Vec<Packet>,
}

/// Up to [`CLUSTER`] light directions, laid out across (one array per axis) so that one
/// box or triangle is tested against all of them in a few vector instructions; unused
/// places hold a copy of the last direction and are never active.
#[derive(Clone)]
struct Packet {
    len: usize,
    dir: [[f32; CLUSTER]; 3],
    inv: [[f32; CLUSTER]; 3],
    /// Each direction's index in the light set.
    index: [u32; CLUSTER],
    /// Whether the directions' mean points up each axis.
    heading: [bool; 3],
}

/// The visibility of one light set, per point, worked out as points are asked for.
pub struct Table {
    clusters: Clusters,
    words: usize,
    rows: Vec<OnceLock<Box<[u64]>>>,
}

impl Occluder {
    /// The occluder of `bvh`'s mesh for `points`.
    pub fn new(bvh: &Bvh, points: Vec<Point>) -> Occluder {
        let (nodes, tris) = bvh.layout();
        let centre = nodes.first().map_or([0.0; 3], |&(lo, hi, _, _)| {
            [0, 1, 2].map(|i| (lo[i] + hi[i]) / 2.0)
        });
        let f = |v: Vec3| [0, 1, 2].map(|i| (v[i] - centre[i]) as f32);
        let middle = |i: usize| {
            let (lo, hi, _, _) = nodes[i];
            [0, 1, 2].map(|k| (lo[k] + hi[k]) / 2.0)
        };
        let nodes: Vec<BoxNode> = nodes
            .iter()
            .map(|&(lo, hi, first, count)| {
                let meta = if count == 0 {
                    let (a, b) = (middle(first as usize), middle(first as usize + 1));
                    (0..3)
                        .max_by(|&i, &j| (b[i] - a[i]).abs().total_cmp(&(b[j] - a[j]).abs()))
                        .map_or(INNER, |i| {
                            INNER | i as u32 | if b[i] < a[i] { 4 } else { 0 }
                        })
                } else {
                    count
                };
                BoxNode {
                    lo: f(lo),
                    hi: f(hi),
                    first,
                    meta,
                    across: [0.0; 3],
                    layer: [0.0; 2],
                }
            })
            .collect();
        // Half the box's greatest width, about its middle.
        let reach = nodes.first().map_or(0.0, |root| {
            (0..3)
                .map(|i| root.hi[i].max(-root.lo[i]))
                .fold(0f32, f32::max)
        });
        let mut occluder = Occluder {
            nodes,
            tris: tris.into_iter().map(|t| t.map(f)).collect(),
            points,
            centre,
            // The bound on a box's height above a plane takes some 50 roundings of 2⁻²⁴ of
            // `reach` at worst; this is 130 of them. It stays below the rays' lift off the
            // surface (at least 10⁻⁵ of the mesh's diagonal, which is 2 `reach` or more), so
            // a wall's own boxes are still passed over.
            slack: 8e-6 * reach,
            tables: Mutex::new(Vec::new()),
            surface: None,
        };
        let held = occluder.held();
        for (at, range) in held.into_iter().enumerate() {
            let layer = layer_of(&occluder.tris[range]);
            let node = &mut occluder.nodes[at];
            (node.across, node.layer) = layer;
        }
        occluder
    }

    /// The triangles under each box: a range, as the tree orders them.
    fn held(&self) -> Vec<std::ops::Range<usize>> {
        let mut held = vec![0..0; self.nodes.len()];
        // A box's children come after it.
        for at in (0..self.nodes.len()).rev() {
            let node = self.nodes[at];
            held[at] = if node.meta & INNER != 0 {
                let (a, b) = (&held[node.first as usize], &held[node.first as usize + 1]);
                debug_assert_eq!(a.end, b.start);
                a.start..b.end
            } else {
                node.first as usize..(node.first + node.meta) as usize
            };
        }
        held
    }

    /// `o` in the frame the boxes and triangles are kept in.
    fn local(&self, o: [f32; 3]) -> [f32; 3] {
        [0, 1, 2].map(|i| (o[i] as f64 - self.centre[i]) as f32)
    }

    /// The same mesh's occluder for other `points`: its boxes and their layers as they are
    /// (laying them out again costs a pass over the whole tree), and no tables yet.
    pub fn with_points(&self, points: Vec<Point>) -> Occluder {
        Occluder {
            nodes: self.nodes.clone(),
            tris: self.tris.clone(),
            points,
            centre: self.centre,
            slack: self.slack,
            tables: Mutex::new(Vec::new()),
            surface: self.surface.clone(),
        }
    }

    /// The occluder of `surface`'s mesh for `points`, which keeps the surface for the light
    /// it throws on itself.
    pub fn of_surface(surface: Arc<Surface>, points: Vec<Point>) -> Occluder {
        let mut occluder = Occluder::new(surface.bvh(), points);
        occluder.surface = Some(surface);
        occluder
    }

    pub fn surface(&self) -> Option<&Arc<Surface>> {
        self.surface.as_ref()
    }

    pub fn points(&self) -> &[Point] {
        &self.points
    }

    /// The table of `lights`, made (empty) on first use.
    pub fn table(&self, lights: &LightSet) -> Arc<Table> {
        let key = fingerprint(lights);
        let mut tables = self.tables.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((_, t)) = tables.iter().find(|(k, _)| *k == key) {
            return t.clone();
        }
        let table = Arc::new(Table {
            clusters: Clusters::of(lights),
            words: lights.len().div_ceil(64),
            rows: (0..self.points.len()).map(|_| OnceLock::new()).collect(),
        });
        tables.push((key, table.clone()));
        table
    }

    /// Bit i of the answer is set when light i of the table's set is above point `id`'s
    /// horizon (or on it) and its ray leaves the object.
    fn seen(&self, id: usize, clusters: &Clusters, words: usize) -> Box<[u64]> {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f") {
                // SAFETY: the CPU has AVX-512F, checked just above.
                return unsafe { self.seen_avx512(id, clusters, words) };
            }
            if std::arch::is_x86_feature_detected!("avx2") {
                // SAFETY: the CPU has AVX2, checked just above.
                return unsafe { self.seen_avx2(id, clusters, words) };
            }
        }
        self.seen_with(Isa::portable(), id, clusters, words)
    }

    /// [`Occluder::seen`] with the packet tests in AVX2 ([`avx2`]): a packet's 64 rays in
    /// eight 8-lane steps, each ending in one move-mask. They add and multiply in the portable
    /// tests' order, without fused multiply-adds, so every build gives the same answer.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn seen_avx2(&self, id: usize, clusters: &Clusters, words: usize) -> Box<[u64]> {
        self.seen_with(Isa::<AVX2>::assumed(), id, clusters, words)
    }

    /// [`Occluder::seen`] with the packet tests in AVX-512 ([`avx512`]): four 16-lane steps.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    unsafe fn seen_avx512(&self, id: usize, clusters: &Clusters, words: usize) -> Box<[u64]> {
        self.seen_with(Isa::<AVX512>::assumed(), id, clusters, words)
    }

    #[inline(always)]
    fn seen_with<const SIMD: u8>(
        &self,
        isa: Isa<SIMD>,
        id: usize,
        clusters: &Clusters,
        words: usize,
    ) -> Box<[u64]> {
        let Point { origin, normal } = self.points[id];
        let origin = self.local(origin);
        let mut out = vec![0u64; words].into_boxed_slice();
        let frontier = self.frontier(origin, normal);
        let mut stack = Vec::with_capacity(frontier.len() + 64);
        for packet in &clusters.packets {
            let up = packet.facing(isa, normal);
            if up == 0 {
                continue;
            }
            stack.clear();
            stack.extend(frontier.iter().map(|&at| (at, up)));
            let mut open = up & !self.blocked(isa, origin, normal, packet, up, &mut stack);
            while open != 0 {
                let i = packet.index[open.trailing_zeros() as usize] as usize;
                out[i >> 6] |= 1 << (i & 63);
                open &= open - 1;
            }
        }
        out
    }

    /// Where every walk from `o` starts: the boxes above the tangent plane that do not hold
    /// `o`, and the leaves that do, nearest last. Each walk would otherwise first go down the
    /// same boxes about `o`, which every ray passes through.
    fn frontier(&self, o: [f32; 3], n: [f32; 3]) -> Vec<u32> {
        let mut frontier = Vec::new();
        let mut stack = vec![0u32];
        while let Some(at) = stack.pop() {
            let node = &self.nodes[at as usize];
            if !node.above(o, n, dot(n, o), self.slack) {
                continue;
            }
            let holds_o = (0..3).all(|i| node.lo[i] <= o[i] && o[i] <= node.hi[i]);
            if holds_o && node.meta & INNER != 0 {
                stack.extend([node.first, node.first + 1]);
            } else {
                frontier.push(at);
            }
        }
        frontier
    }

    /// Which of the `active` rays of `packet` from `o` meet a triangle, walking from the
    /// boxes on `stack` (each with the rays that may meet it). Each box on the way is tested
    /// against every ray still open, so that the walk follows the rays.
    #[inline(always)]
    fn blocked<const SIMD: u8>(
        &self,
        isa: Isa<SIMD>,
        o: [f32; 3],
        n: [f32; 3],
        packet: &Packet,
        active: u64,
        stack: &mut Vec<(u32, u64)>,
    ) -> u64 {
        let mut open = active;
        let level = dot(n, o);
        while let Some((at, mask)) = stack.pop() {
            let node = &self.nodes[at as usize];
            let mask = mask & open;
            if mask == 0 || !node.above(o, n, level, self.slack) {
                continue;
            }
            let mask = packet.through(isa, node, o, mask);
            if mask == 0 {
                continue;
            }
            if node.meta & INNER != 0 {
                // The child the rays meet first goes on top, to be walked first: its hits
                // end the walk sooner.
                let (a, b) = (node.first, node.first + 1);
                let ahead = packet.heading[(node.meta & 3) as usize] ^ (node.meta & 4 != 0);
                let (later, sooner) = if ahead { (b, a) } else { (a, b) };
                // Fetched while the sooner child's walk begins: a box is a cache line, and
                // the tree does not fit in L2.
                #[cfg(target_arch = "x86_64")]
                for child in [a, b] {
                    let p: *const BoxNode = &self.nodes[child as usize];
                    // SAFETY: a prefetch only hints the cache; `p` points into `nodes`.
                    unsafe {
                        std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(
                            p.cast(),
                        )
                    };
                }
                stack.extend([(later, mask), (sooner, mask)]);
                continue;
            }
            let leaf = &self.tris[node.first as usize..(node.first + node.meta) as usize];
            for tri in leaf {
                let hits = packet.hits(isa, tri, o, n, mask & open);
                open &= !hits;
                if open == 0 {
                    return active;
                }
            }
        }
        active & !open
    }
}

impl BoxNode {
    /// Whether the box's triangles may reach above the tangent plane at `o`, where `n · o`
    /// is `level`: a ray that leaves the surface meets nothing below it. Two bounds on
    /// their height above the plane: the box's corner furthest along `n` (exact in f32, as
    /// the triangle test's own), and the furthest point of the box and the layer together,
    /// where `n` is split into its part across the layer (which the layer bounds) and the
    /// rest (which the box bounds).
    #[inline(always)]
    fn above(&self, o: [f32; 3], n: [f32; 3], level: f32, slack: f32) -> bool {
        let mut height = 0.0;
        for i in 0..3 {
            let far = if n[i] > 0.0 { self.hi[i] } else { self.lo[i] };
            height += n[i] * (far - o[i]);
        }
        if height <= 0.0 {
            return false;
        }
        let along = dot(n, self.across);
        let rest = sub(n, [0, 1, 2].map(|i| along * self.across[i]));
        let side = if along >= 0.0 {
            self.layer[1]
        } else {
            self.layer[0]
        };
        let mut bound = along * side - level;
        for i in 0..3 {
            let far = if rest[i] > 0.0 {
                self.hi[i]
            } else {
                self.lo[i]
            };
            bound += rest[i] * far;
        }
        // Not a number passes: the box is walked.
        bound >= -slack || bound.is_nan()
    }
}

/// The layer triangles lie in: the triangles' normals weighted by area (turned to agree
/// with the largest's, for a file's winding may differ from face to face), and the least
/// and greatest height of their corners along it, rounded outwards. None (all 0) where the
/// normals cancel.
fn layer_of(tris: &[[[f32; 3]; 3]]) -> ([f32; 3], [f32; 2]) {
    let wide = |v: [f32; 3]| v.map(|c| c as f64);
    let normals: Vec<Vec3> = tris
        .iter()
        .map(|t| {
            let (a, b, c) = (wide(t[0]), wide(t[1]), wide(t[2]));
            cross64(sub64(b, a), sub64(c, a))
        })
        .collect();
    let largest = normals
        .iter()
        .copied()
        .max_by(|a, b| dot64(*a, *a).total_cmp(&dot64(*b, *b)))
        .unwrap_or([0.0; 3]);
    let mut sum = [0f64; 3];
    for n in &normals {
        let s = if dot64(*n, largest) < 0.0 { -1.0 } else { 1.0 };
        sum = [0, 1, 2].map(|i| sum[i] + s * n[i]);
    }
    let length = dot64(sum, sum).sqrt();
    if !(length > 0.0 && length.is_finite()) {
        return ([0.0; 3], [0.0; 2]);
    }
    // Measured along the rounded vector, the one the walk uses.
    let across = sum.map(|c| (c / length) as f32);
    let (mut lower, mut upper) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in tris.iter().flatten() {
        let d = dot64(wide(across), wide(*v));
        lower = lower.min(d);
        upper = upper.max(d);
    }
    (
        across,
        [(lower as f32).next_down(), (upper as f32).next_up()],
    )
}

impl Packet {
    /// The bits of the places `f` holds for, among the packet's directions.
    #[inline(always)]
    fn mask(&self, f: impl Fn(usize) -> bool) -> u64 {
        let mut m = 0u64;
        for j in 0..CLUSTER {
            m |= (f(j) as u64) << j;
        }
        m & (u64::MAX >> (64 - self.len))
    }

    /// The rays of `mask` from `o` that pass through the box (the slab test, ray by ray).
    #[inline(always)]
    fn through<const SIMD: u8>(&self, _: Isa<SIMD>, node: &BoxNode, o: [f32; 3], mask: u64) -> u64 {
        let lo = sub(node.lo, o);
        let hi = sub(node.hi, o);
        #[cfg(target_arch = "x86_64")]
        match SIMD {
            // SAFETY: an `Isa<SIMD>` exists only where the CPU has SIMD.
            AVX2 => return unsafe { avx2::through(self, lo, hi, mask) },
            AVX512 => return unsafe { avx512::through(self, lo, hi, mask) },
            _ => {}
        }
        let mut near = [0f32; CLUSTER];
        let mut far = [f32::INFINITY; CLUSTER];
        for i in 0..3 {
            for j in 0..CLUSTER {
                let (a, b) = (lo[i] * self.inv[i][j], hi[i] * self.inv[i][j]);
                near[j] = near[j].max(a.min(b));
                far[j] = far[j].min(a.max(b));
            }
        }
        self.mask(|j| near[j] <= far[j]) & mask
    }

    /// The rays on the side of the plane through the origin that `n` points to (on the
    /// plane counts: its light has no cosine to give).
    #[inline(always)]
    fn facing<const SIMD: u8>(&self, _: Isa<SIMD>, n: [f32; 3]) -> u64 {
        let all = u64::MAX >> (64 - self.len);
        #[cfg(target_arch = "x86_64")]
        match SIMD {
            // SAFETY: an `Isa<SIMD>` exists only where the CPU has SIMD.
            AVX2 => return unsafe { avx2::inside(self, [n; 3], all) },
            AVX512 => return unsafe { avx512::inside(self, [n; 3], all) },
            _ => {}
        }
        let d = &self.dir;
        self.mask(|j| n[0] * d[0][j] + n[1] * d[1][j] + n[2] * d[2][j] >= 0.0) & all
    }

    /// The rays of `mask` from `o` that pass through the triangle: those whose direction
    /// lies in the trihedral cone from `o` through its corners.
    #[inline(always)]
    fn hits<const SIMD: u8>(
        &self,
        _: Isa<SIMD>,
        tri: &[[f32; 3]; 3],
        o: [f32; 3],
        n: [f32; 3],
        mask: u64,
    ) -> u64 {
        let (a, b, c) = (sub(tri[0], o), sub(tri[1], o), sub(tri[2], o));
        // Wholly below the tangent plane: no ray that leaves the surface gets there.
        if dot(n, a) <= 0.0 && dot(n, b) <= 0.0 && dot(n, c) <= 0.0 {
            return 0;
        }
        let (mut bc, mut ca, mut ab) = (cross(b, c), cross(c, a), cross(a, b));
        let det = dot(a, bc);
        if det == 0.0 {
            // `o` is in the triangle's plane: rays graze it edge on.
            return 0;
        }
        if det < 0.0 {
            (bc, ca, ab) = (neg(bc), neg(ca), neg(ab));
        }
        #[cfg(target_arch = "x86_64")]
        match SIMD {
            // SAFETY: an `Isa<SIMD>` exists only where the CPU has SIMD.
            AVX2 => return unsafe { avx2::inside(self, [bc, ca, ab], mask) },
            AVX512 => return unsafe { avx512::inside(self, [bc, ca, ab], mask) },
            _ => {}
        }
        let d = &self.dir;
        let side = |e: [f32; 3], j: usize| e[0] * d[0][j] + e[1] * d[1][j] + e[2] * d[2][j];
        // On an edge counts as through, so that no ray slips between two triangles.
        self.mask(|j| side(bc, j) >= 0.0 && side(ca, j) >= 0.0 && side(ab, j) >= 0.0) & mask
    }
}

impl Clusters {
    /// The lights in order along a Z-curve over the octahedral map of directions, cut into
    /// runs of [`CLUSTER`]: each run is a small patch of the sphere.
    fn of(lights: &LightSet) -> Clusters {
        // A direction that is not a number is seen by no point: the vector builds' box tests
        // and the portable one's would treat it differently.
        let mut order: Vec<(u64, u32)> = lights
            .directions
            .iter()
            .enumerate()
            .filter(|(_, d)| d.iter().all(|c| c.is_finite()))
            .map(|(i, d)| (morton(octahedral(*d)), i as u32))
            .collect();
        order.sort_unstable();
        let packets = order
            .chunks(CLUSTER)
            .map(|run| {
                let mut p = Packet {
                    len: run.len(),
                    dir: [[0.0; CLUSTER]; 3],
                    inv: [[0.0; CLUSTER]; 3],
                    index: [run[0].1; CLUSTER],
                    heading: [false; 3],
                };
                let mut mean = [0f32; 3];
                for j in 0..CLUSTER {
                    let (_, i) = run[j.min(run.len() - 1)];
                    let d = lights.directions[i as usize];
                    p.index[j] = i;
                    mean = [0, 1, 2].map(|k| mean[k] + d[k]);
                    for k in 0..3 {
                        p.dir[k][j] = d[k];
                        // Finite, so that a box face through the origin gives 0, never
                        // 0 × ∞: the slab test then needs no case for NaN.
                        p.inv[k][j] = (1.0 / d[k]).clamp(-1e30, 1e30);
                    }
                }
                p.heading = mean.map(|c| c > 0.0);
                p
            })
            .collect();
        Clusters { packets }
    }
}

impl Table {
    /// The lights point `id` of `occluder` sees, one bit per light of the set.
    pub fn row(&self, occluder: &Occluder, id: u32) -> &[u64] {
        self.rows[id as usize]
            .get_or_init(|| occluder.seen(id as usize, &self.clusters, self.words))
    }
}

/// The visibility of each pixel's lights, for one light set: the tables of the pixels'
/// occluders (usually one), looked up once per build.
pub struct Seen {
    tables: Vec<(Arc<Occluder>, Arc<Table>)>,
}

impl Seen {
    pub fn new(pixels: &[GeomPixel], lights: &LightSet) -> Seen {
        let mut tables: Vec<(Arc<Occluder>, Arc<Table>)> = Vec::new();
        for s in pixels.iter().filter_map(|p| p.shadow.as_ref()) {
            if !tables.iter().any(|(o, _)| Arc::ptr_eq(o, &s.occluder)) {
                tables.push((s.occluder.clone(), s.occluder.table(lights)));
            }
        }
        Seen { tables }
    }

    /// The pixel's visible lights (a bit per light), or `None` when nothing hides its lights;
    /// kept for the next build that asks.
    pub fn row(&self, px: &GeomPixel) -> Option<&[u64]> {
        let s = px.shadow.as_ref()?;
        let (o, t) = self.table_of(s)?;
        Some(t.row(o, s.id))
    }

    /// As [`Seen::row`], worked out afresh (or taken from a kept one) and not kept: for a
    /// renderer that asks once per pixel.
    pub fn fresh(&self, px: &GeomPixel) -> Option<Box<[u64]>> {
        let s = px.shadow.as_ref()?;
        let (o, t) = self.table_of(s)?;
        Some(match t.rows[s.id as usize].get() {
            Some(kept) => kept.clone(),
            None => o.seen(s.id as usize, &t.clusters, t.words),
        })
    }

    fn table_of(&self, s: &Shadow) -> Option<(&Arc<Occluder>, &Arc<Table>)> {
        self.tables
            .iter()
            .find(|(o, _)| Arc::ptr_eq(o, &s.occluder))
            .map(|(o, t)| (o, t))
    }
}

/// Whether bit `i` of a visibility row is set.
#[inline(always)]
pub(crate) fn is_seen(row: &[u64], i: u32) -> bool {
    row[(i >> 6) as usize] >> (i & 63) & 1 == 1
}

fn fingerprint(lights: &LightSet) -> u64 {
    let mut h = DefaultHasher::new();
    lights.len().hash(&mut h);
    for d in &lights.directions {
        d.map(f32::to_bits).hash(&mut h);
    }
    h.finish()
}

/// The octahedral map of a unit direction onto [0, 1)²: equal areas of the sphere land on
/// nearly equal areas of the square, and neighbours stay neighbours.
fn octahedral(d: [f32; 3]) -> (u32, u32) {
    let l1 = d[0].abs() + d[1].abs() + d[2].abs();
    let (mut x, mut y) = (d[0] / l1, d[1] / l1);
    if d[2] < 0.0 {
        (x, y) = ((1.0 - y.abs()) * x.signum(), (1.0 - x.abs()) * y.signum());
    }
    let q = |v: f32| (((v + 1.0) / 2.0).clamp(0.0, 1.0) * 65_535.0) as u32;
    (q(x), q(y))
}

fn morton((x, y): (u32, u32)) -> u64 {
    let spread = |v: u32| {
        let mut v = v as u64 & 0xffff;
        v = (v | (v << 8)) & 0x00ff_00ff;
        v = (v | (v << 4)) & 0x0f0f_0f0f;
        v = (v | (v << 2)) & 0x3333_3333;
        (v | (v << 1)) & 0x5555_5555
    };
    spread(x) | (spread(y) << 1)
}

#[inline(always)]
fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[inline(always)]
fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

#[inline(always)]
fn neg(a: [f32; 3]) -> [f32; 3] {
    [-a[0], -a[1], -a[2]]
}

#[inline(always)]
fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// The packet tests in AVX2 intrinsics, eight rays to a vector.
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::{Packet, CLUSTER};
    use std::arch::x86_64::*;

    /// [`Packet::through`]: the rays that pass through the box `lo`..`hi` (relative to the
    /// rays' origin).
    #[inline]
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn through(p: &Packet, lo: [f32; 3], hi: [f32; 3], mask: u64) -> u64 {
        let mut m = 0u64;
        for g in 0..CLUSTER / 8 {
            if (mask >> (8 * g)) & 0xff == 0 {
                continue;
            }
            let mut near = _mm256_setzero_ps();
            let mut far = _mm256_set1_ps(f32::INFINITY);
            for i in 0..3 {
                let inv = _mm256_loadu_ps(p.inv[i][8 * g..].as_ptr());
                let a = _mm256_mul_ps(_mm256_set1_ps(lo[i]), inv);
                let b = _mm256_mul_ps(_mm256_set1_ps(hi[i]), inv);
                near = _mm256_max_ps(near, _mm256_min_ps(a, b));
                far = _mm256_min_ps(far, _mm256_max_ps(a, b));
            }
            let ok = _mm256_cmp_ps::<_CMP_LE_OQ>(near, far);
            m |= (_mm256_movemask_ps(ok) as u32 as u64) << (8 * g);
        }
        m & mask
    }

    /// [`Packet::hits`]' last step: the rays on the inner side of all three planes
    /// `e` (through the origin).
    #[inline]
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn inside(p: &Packet, e: [[f32; 3]; 3], mask: u64) -> u64 {
        let mut m = 0u64;
        let zero = _mm256_setzero_ps();
        for g in 0..CLUSTER / 8 {
            if (mask >> (8 * g)) & 0xff == 0 {
                continue;
            }
            let d = [0, 1, 2].map(|k| _mm256_loadu_ps(p.dir[k][8 * g..].as_ptr()));
            let mut all = _mm256_castsi256_ps(_mm256_set1_epi32(-1));
            for plane in e {
                // (x·dx + y·dy) + z·dz, as the portable test sums.
                let s = _mm256_add_ps(
                    _mm256_add_ps(
                        _mm256_mul_ps(_mm256_set1_ps(plane[0]), d[0]),
                        _mm256_mul_ps(_mm256_set1_ps(plane[1]), d[1]),
                    ),
                    _mm256_mul_ps(_mm256_set1_ps(plane[2]), d[2]),
                );
                all = _mm256_and_ps(all, _mm256_cmp_ps::<_CMP_GE_OQ>(s, zero));
            }
            m |= (_mm256_movemask_ps(all) as u32 as u64) << (8 * g);
        }
        m & mask
    }
}

/// The packet tests in AVX-512 intrinsics, sixteen rays to a vector, as [`avx2`]'s.
#[cfg(target_arch = "x86_64")]
mod avx512 {
    use super::{Packet, CLUSTER};
    use std::arch::x86_64::*;

    #[inline]
    #[target_feature(enable = "avx512f")]
    pub(super) unsafe fn through(p: &Packet, lo: [f32; 3], hi: [f32; 3], mask: u64) -> u64 {
        let mut m = 0u64;
        for g in 0..CLUSTER / 16 {
            let lanes = ((mask >> (16 * g)) & 0xffff) as u16;
            if lanes == 0 {
                continue;
            }
            let mut near = _mm512_setzero_ps();
            let mut far = _mm512_set1_ps(f32::INFINITY);
            for i in 0..3 {
                let inv = _mm512_loadu_ps(p.inv[i][16 * g..].as_ptr());
                let a = _mm512_mul_ps(_mm512_set1_ps(lo[i]), inv);
                let b = _mm512_mul_ps(_mm512_set1_ps(hi[i]), inv);
                near = _mm512_max_ps(near, _mm512_min_ps(a, b));
                far = _mm512_min_ps(far, _mm512_max_ps(a, b));
            }
            let ok = _mm512_mask_cmp_ps_mask::<_CMP_LE_OQ>(lanes, near, far);
            m |= (ok as u64) << (16 * g);
        }
        m
    }

    #[inline]
    #[target_feature(enable = "avx512f")]
    pub(super) unsafe fn inside(p: &Packet, e: [[f32; 3]; 3], mask: u64) -> u64 {
        let mut m = 0u64;
        let zero = _mm512_setzero_ps();
        for g in 0..CLUSTER / 16 {
            let mut lanes = ((mask >> (16 * g)) & 0xffff) as u16;
            if lanes == 0 {
                continue;
            }
            let d = [0, 1, 2].map(|k| _mm512_loadu_ps(p.dir[k][16 * g..].as_ptr()));
            for plane in e {
                let s = _mm512_add_ps(
                    _mm512_add_ps(
                        _mm512_mul_ps(_mm512_set1_ps(plane[0]), d[0]),
                        _mm512_mul_ps(_mm512_set1_ps(plane[1]), d[1]),
                    ),
                    _mm512_mul_ps(_mm512_set1_ps(plane[2]), d[2]),
                );
                lanes = _mm512_mask_cmp_ps_mask::<_CMP_GE_OQ>(lanes, s, zero);
            }
            m |= (lanes as u64) << (16 * g);
        }
        m
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::normalize;
    use crate::mesh::{bowl, grooved_plate};

    fn lights(n: usize) -> LightSet {
        // A Fibonacci sphere: even, and no two directions on one grid line.
        let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        let directions: Vec<[f32; 3]> = (0..n)
            .map(|i| {
                let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
                let r = (1.0 - z * z).sqrt();
                let a = golden * i as f64;
                [r * a.cos(), r * a.sin(), z].map(|c| c as f32)
            })
            .collect();
        LightSet {
            radiance: vec![[1.0; 3]; n],
            solid_angle: vec![(4.0 * std::f64::consts::PI / n as f64) as f32; n],
            spread: Vec::new(),
            directions,
            map: None,
        }
    }

    /// Numbers in [0, 1) from `seed`, the same on every machine.
    fn uniform(mut seed: u64) -> impl FnMut() -> f64 {
        move || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    /// Triangle `t`'s face normal, turned up.
    fn up_normal(mesh: &crate::mesh::Mesh, t: usize) -> Vec3 {
        let [a, b, c] = mesh.corners(t);
        let n = normalize(crate::brdf::cross(
            crate::brdf::sub(b, a),
            crate::brdf::sub(c, a),
        ));
        if n[2] < 0.0 {
            n.map(|c| -c)
        } else {
            n
        }
    }

    /// Every build of the packet tests gives the same answer: the portable one, and AVX2 and
    /// AVX-512 where this CPU has them (the walk dispatches to the widest).
    #[test]
    fn the_vector_builds_agree_with_the_portable_one() {
        let mesh = grooved_plate(1.0, 1.0, 3, 0.25, 24, 12);
        let bvh = Bvh::build(&mesh);
        let points: Vec<Point> = (0..200)
            .map(|i| {
                let x = (i as f32 / 200.0 - 0.5) * 0.9;
                let band = ((x + 0.5) * 3.0).fract();
                let slope = if (0.25..0.5).contains(&band) {
                    1.0
                } else {
                    -1.0
                };
                let n = normalize([slope, 0.0, 1.0]).map(|c| c as f32);
                Point {
                    origin: [x, 0.1 * (i % 7) as f32 - 0.3, 0.01],
                    normal: if (0.25..0.75).contains(&band) {
                        n
                    } else {
                        [0.0, 0.0, 1.0]
                    },
                }
            })
            .collect();
        let occluder = Occluder::new(&bvh, points);
        let set = lights(1000);
        let clusters = Clusters::of(&set);
        let words = set.len().div_ceil(64);
        let (mut seen, mut up) = (0, 0);
        for id in 0..occluder.points.len() {
            let portable = occluder.seen_with(Isa::portable(), id, &clusters, words);
            seen += portable.iter().map(|w| w.count_ones()).sum::<u32>();
            let n = occluder.points[id].normal;
            up += set.directions.iter().filter(|d| dot(n, **d) > 0.0).count() as u32;
            #[cfg(target_arch = "x86_64")]
            {
                if std::arch::is_x86_feature_detected!("avx2") {
                    let avx2 = unsafe { occluder.seen_avx2(id, &clusters, words) };
                    assert_eq!(avx2, portable, "AVX2, point {id}");
                }
                if std::arch::is_x86_feature_detected!("avx512f") {
                    let avx512 = unsafe { occluder.seen_avx512(id, &clusters, words) };
                    assert_eq!(avx512, portable, "AVX-512, point {id}");
                }
            }
        }
        assert!(
            seen * 10 < up * 9,
            "the points see {seen} of {up}: too little is hidden"
        );
    }

    /// A box is passed over only when its triangles lie below the tangent plane, and on a
    /// tilted wall the slabs pass over the wall's own boxes, which stand above the plane.
    #[test]
    fn a_box_is_passed_over_only_below_the_tangent_plane() {
        let mesh = grooved_plate(0.1, 0.1, 4, 0.01, 64, 32);
        let occluder = Occluder::new(&Bvh::build(&mesh), Vec::new());
        let held = occluder.held();
        let mut uniform = uniform(11);
        let mut next = || uniform() as f32;
        let (mut planes, mut passed_over) = (0, 0);
        for _ in 0..300 {
            let o = occluder.local([
                next() * 0.1 - 0.05,
                next() * 0.1 - 0.05,
                next() * 0.012 - 0.011,
            ]);
            let n = normalize([0, 1, 2].map(|_| next() as f64 * 2.0 - 1.0)).map(|c| c as f32);
            let level = dot(n, o);
            for (at, node) in occluder.nodes.iter().enumerate() {
                let height = occluder.tris[held[at].clone()]
                    .iter()
                    .flatten()
                    .map(|v| {
                        (0..3)
                            .map(|i| n[i] as f64 * (v[i] - o[i]) as f64)
                            .sum::<f64>()
                    })
                    .fold(f64::NEG_INFINITY, f64::max);
                let above = node.above(o, n, level, occluder.slack);
                assert!(above || height < 0.0, "box {at} stands {height} above");
                planes += 1;
                passed_over += !above as usize;
            }
        }
        assert!(
            passed_over * 10 > planes,
            "{passed_over} of {planes} passed over"
        );
        // A point on a groove's wall, just off it along the wall's normal.
        let t = (0..mesh.triangles.len())
            .find(|&t| {
                let [a, b, c] = mesh.corners(t);
                a[2] < -0.001 && b[2] < -0.001 && c[2] < -0.001 && a[0] != b[0]
            })
            .expect("a triangle on a wall");
        let [a, b, c] = mesh.corners(t);
        let n = up_normal(&mesh, t);
        let o =
            occluder.local([0, 1, 2].map(|i| ((a[i] + b[i] + c[i]) / 3.0 + 1e-6 * n[i]) as f32));
        let n = n.map(|c| c as f32);
        let own = occluder
            .nodes
            .iter()
            .enumerate()
            .filter(|(at, node)| {
                node.meta & INNER == 0
                    && occluder.tris[held[*at].clone()].iter().flatten().all(|v| {
                        let d: f64 = (0..3).map(|i| n[i] as f64 * (v[i] - o[i]) as f64).sum();
                        d.abs() < 2e-6
                    })
            })
            .map(|(_, node)| node)
            .collect::<Vec<_>>();
        assert!(own.len() > 4, "{} leaves on the wall", own.len());
        let boxes_above = own
            .iter()
            .filter(|node| {
                let height: f32 = (0..3)
                    .map(|i| n[i] * if n[i] > 0.0 { node.hi[i] } else { node.lo[i] } - n[i] * o[i])
                    .sum();
                height > 0.0
            })
            .count();
        let layers_above = own
            .iter()
            .filter(|node| node.above(o, n, dot(n, o), occluder.slack));
        assert_eq!(
            boxes_above,
            own.len(),
            "the wall's boxes stand above its plane"
        );
        assert_eq!(layers_above.count(), 0, "the wall's layers do not");
    }

    /// The layers change which boxes the walk enters, never an answer: on the grooved plate
    /// where it stands, and moved 3 m off, the walk with them gives bit for bit what the walk
    /// with the boxes alone gives.
    #[test]
    fn the_layers_change_no_answer() {
        let set = lights(1000);
        let clusters = Clusters::of(&set);
        let words = set.len().div_ceil(64);
        for shift in [0.0, 3.0] {
            let mut mesh = grooved_plate(1.0, 1.0, 3, 0.25, 24, 12);
            for p in &mut mesh.positions {
                p[0] += shift;
            }
            let bvh = Bvh::build(&mesh);
            let points: Vec<Point> = (0..300)
                .map(|i| {
                    // On the walls and the tops, just off them.
                    let t = (i * 7919) % mesh.triangles.len();
                    let [a, b, c] = mesh.corners(t);
                    let n = up_normal(&mesh, t);
                    let p = [0, 1, 2].map(|k| (a[k] + b[k] + c[k]) / 3.0 + 1e-5 * n[k]);
                    Point {
                        origin: p.map(|c| c as f32),
                        normal: n.map(|c| c as f32),
                    }
                })
                .collect();
            let with = Occluder::new(&bvh, points.clone());
            let mut without = Occluder::new(&bvh, points);
            for node in &mut without.nodes {
                (node.across, node.layer) = ([0.0; 3], [0.0; 2]);
            }
            let (mut entered, mut hidden) = (0, 0);
            for id in 0..with.points.len() {
                let a = with.seen(id, &clusters, words);
                let b = without.seen(id, &clusters, words);
                assert_eq!(a, b, "point {id}, plate moved {shift} m");
                let n = with.points[id].normal;
                let up = set.directions.iter().filter(|d| dot(n, **d) >= 0.0).count();
                hidden += up - a.iter().map(|w| w.count_ones() as usize).sum::<usize>();
                let o = with.local(with.points[id].origin);
                let level = dot(n, o);
                entered += with
                    .nodes
                    .iter()
                    .zip(&without.nodes)
                    .filter(|(l, b)| {
                        l.above(o, n, level, with.slack) != b.above(o, n, level, with.slack)
                    })
                    .count();
            }
            assert!(hidden > 1000, "the case hides too little: {hidden}");
            assert!(
                entered > 1000,
                "the layers pass over only {entered} more boxes"
            );
        }
    }

    /// The packet walk gives, light for light, what a ray cast one by one gives.
    #[test]
    fn the_packet_walk_agrees_with_rays_cast_one_by_one() {
        let cases = [grooved_plate(1.0, 1.0, 3, 0.25, 24, 12), bowl(0.5, 12, 24)];
        let set = lights(2000);
        for mesh in cases {
            let bvh = Bvh::build(&mesh);
            let mut next = uniform(7);
            // Points on random triangles, with their faces' normals turned up.
            let points: Vec<(Vec3, Vec3)> = (0..60)
                .map(|_| {
                    let t = (next() * mesh.triangles.len() as f64) as usize;
                    let [a, b, c] = mesh.corners(t);
                    let (mut u, mut v) = (next(), next());
                    if u + v > 1.0 {
                        (u, v) = (1.0 - u, 1.0 - v);
                    }
                    let p = [0, 1, 2].map(|i| a[i] + u * (b[i] - a[i]) + v * (c[i] - a[i]));
                    (p, up_normal(&mesh, t))
                })
                .collect();
            let lift = 1e-6;
            let occluder = Occluder::new(
                &bvh,
                points
                    .iter()
                    .map(|(p, n)| Point {
                        origin: [0, 1, 2].map(|i| (p[i] + lift * n[i]) as f32),
                        normal: n.map(|c| c as f32),
                    })
                    .collect(),
            );
            let table = occluder.table(&set);
            let (mut disagree, mut hidden, mut asked) = (0, 0, 0);
            for (id, (p, n)) in points.iter().enumerate() {
                let row = table.row(&occluder, id as u32);
                let o = [0, 1, 2].map(|i| p[i] + lift * n[i]);
                for (i, d) in set.directions.iter().enumerate() {
                    let d = d.map(|c| c as f64);
                    let up = crate::brdf::dot(d, *n) > 0.0;
                    let expect = up && !bvh.occluded(o, d, 1e-9, f64::INFINITY);
                    asked += up as usize;
                    hidden += (up && !expect) as usize;
                    disagree += (is_seen(row, i as u32) != expect) as usize;
                }
            }
            eprintln!("{disagree} of {asked} rays above the horizon disagree; {hidden} hidden");
            // Rays along a triangle's edge may fall either way in f32 and f64.
            assert!(
                disagree * 10_000 <= asked,
                "{disagree} of {asked} rays disagree"
            );
            assert!(
                hidden * 20 > asked,
                "the case hides too little: {hidden} of {asked}"
            );
        }
    }
}
