//! Rays against a triangle mesh: a bounding-volume hierarchy (binary, each box cut where the
//! surface area heuristic puts it, a few triangles per leaf) with closest-hit and any-hit
//! queries. Möller–Trumbore for the triangles, the slab test for the boxes.
//!
//! Not here: what the hits mean (per-pixel geometry in [`super::geometry`]).

use super::brdf::{add, cross, dot, sub, Vec3};
use super::mesh::Mesh;

/// Triangles per leaf at most: a few triangle tests cost less than another level of boxes.
/// The visibility bench took 0.95 of the time with 8 as with 4, side by side.
const LEAF_SIZE: usize = 8;

/// Bins of the triangles' centres per axis: a cut is tried between each two, 15 planes.
const BINS: usize = 16;

/// Depth below which a box is cut at the median instead: the heuristic may peel a few
/// triangles off at a time from an odd mesh, and the tree is built by recursion.
const DEEPEST_HEURISTIC: usize = 48;

/// A ray's hit: its distance, the triangle, and the barycentric coordinates (u, v) of the
/// hit on it (the weights of its second and third corners).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    pub t: f64,
    pub triangle: usize,
    pub u: f64,
    pub v: f64,
}

/// A mesh and its hierarchy, kept together: the surface that lights itself
/// ([`crate::bounce`]).
pub struct Surface {
    pub(crate) mesh: Mesh,
    bvh: Bvh,
    /// The length of the mesh's bounding box's diagonal.
    pub(crate) diagonal: f64,
}

impl Surface {
    pub fn new(mesh: Mesh, bvh: Bvh) -> Surface {
        let (lo, hi) = mesh.bounds();
        let d = sub(hi, lo);
        Surface {
            diagonal: dot(d, d).sqrt(),
            mesh,
            bvh,
        }
    }

    pub fn bvh(&self) -> &Bvh {
        &self.bvh
    }
}

#[derive(Clone, Copy, Debug)]
struct Node {
    lo: Vec3,
    hi: Vec3,
    /// A leaf's first entry in `order`, or an inner node's first child (the second follows).
    first: u32,
    /// Triangles in a leaf; 0 for an inner node.
    count: u32,
}

/// A node's box, first entry and count, as [`Bvh::layout`] gives them.
pub(super) type NodeBox = (Vec3, Vec3, u32, u32);

/// A mesh's triangles, arranged for ray queries.
pub struct Bvh {
    nodes: Vec<Node>,
    /// Triangle indices, leaf by leaf.
    order: Vec<u32>,
    /// Per triangle: a corner and the two edges from it.
    tris: Vec<[Vec3; 3]>,
}

impl Bvh {
    pub fn build(mesh: &Mesh) -> Bvh {
        let tris: Vec<[Vec3; 3]> = (0..mesh.triangles.len())
            .map(|t| {
                let [a, b, c] = mesh.corners(t);
                [a, sub(b, a), sub(c, a)]
            })
            .collect();
        let centres: Vec<Vec3> = (0..tris.len())
            .map(|t| {
                let [a, b, c] = mesh.corners(t);
                [0, 1, 2].map(|i| (a[i] + b[i] + c[i]) / 3.0)
            })
            .collect();
        let mut bvh = Bvh {
            nodes: Vec::with_capacity(2 * tris.len() / LEAF_SIZE + 1),
            order: (0..tris.len() as u32).collect(),
            tris,
        };
        bvh.nodes.push(Node {
            lo: [0.0; 3],
            hi: [0.0; 3],
            first: 0,
            count: 0,
        });
        bvh.split(0, (0, bvh.order.len()), 0, mesh, &centres);
        bvh
    }

    /// Fills node `at` with entries `start..end` of `order`, splitting it while it holds more
    /// than a leaf's worth.
    fn split(
        &mut self,
        at: usize,
        (start, end): (usize, usize),
        depth: usize,
        mesh: &Mesh,
        centres: &[Vec3],
    ) {
        let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        let (mut clo, mut chi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        for &t in &self.order[start..end] {
            for p in mesh.corners(t as usize) {
                for i in 0..3 {
                    lo[i] = lo[i].min(p[i]);
                    hi[i] = hi[i].max(p[i]);
                }
            }
            let c = centres[t as usize];
            for i in 0..3 {
                clo[i] = clo[i].min(c[i]);
                chi[i] = chi[i].max(c[i]);
            }
        }
        self.nodes[at].lo = lo;
        self.nodes[at].hi = hi;
        let n = end - start;
        let axis = (0..3)
            .max_by(|&a, &b| (chi[a] - clo[a]).total_cmp(&(chi[b] - clo[b])))
            .unwrap_or(0);
        if n <= LEAF_SIZE || chi[axis] - clo[axis] <= 0.0 {
            self.nodes[at].first = start as u32;
            self.nodes[at].count = n as u32;
            return;
        }
        let mid = if depth < DEEPEST_HEURISTIC {
            self.partition(start, end, mesh, centres, clo, chi)
        } else {
            self.order[start..end].select_nth_unstable_by(n / 2, |&a, &b| {
                centres[a as usize][axis].total_cmp(&centres[b as usize][axis])
            });
            start + n / 2
        };
        let left = self.nodes.len();
        let empty = Node {
            lo: [0.0; 3],
            hi: [0.0; 3],
            first: 0,
            count: 0,
        };
        self.nodes.push(empty);
        self.nodes.push(empty);
        self.nodes[at].first = left as u32;
        self.nodes[at].count = 0;
        self.split(left, (start, mid), depth + 1, mesh, centres);
        self.split(left + 1, (mid, end), depth + 1, mesh, centres);
    }

    /// Orders entries `start..end` of `order` into two runs and returns where the second
    /// starts: the cut, on some axis, among the planes between [`BINS`] bins of the triangles' centres,
    /// that leaves the least surface area of the two boxes times their triangles (a ray
    /// meets a box about as often as its area). A box that follows the surface closely
    /// is one the rays that leave the surface pass by.
    fn partition(
        &mut self,
        start: usize,
        end: usize,
        mesh: &Mesh,
        centres: &[Vec3],
        clo: Vec3,
        chi: Vec3,
    ) -> usize {
        let bin = |c: Vec3, axis: usize| {
            let f = (c[axis] - clo[axis]) / (chi[axis] - clo[axis]);
            ((f * BINS as f64) as usize).min(BINS - 1)
        };
        let mut best: Option<(f64, usize, usize)> = None;
        for axis in 0..3 {
            if chi[axis] - clo[axis] <= 0.0 {
                continue;
            }
            let mut boxes = [([f64::INFINITY; 3], [f64::NEG_INFINITY; 3], 0usize); BINS];
            for &t in &self.order[start..end] {
                let b = &mut boxes[bin(centres[t as usize], axis)];
                for p in mesh.corners(t as usize) {
                    for i in 0..3 {
                        b.0[i] = b.0[i].min(p[i]);
                        b.1[i] = b.1[i].max(p[i]);
                    }
                }
                b.2 += 1;
            }
            // Sweeps from the right, then from the left, adding bins to a box.
            let grow = |acc: &mut (Vec3, Vec3, usize), b: &(Vec3, Vec3, usize)| {
                for i in 0..3 {
                    acc.0[i] = acc.0[i].min(b.0[i]);
                    acc.1[i] = acc.1[i].max(b.1[i]);
                }
                acc.2 += b.2;
            };
            let mut right = [0.0; BINS];
            let mut acc = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3], 0);
            for k in (1..BINS).rev() {
                grow(&mut acc, &boxes[k]);
                right[k] = area(acc.0, acc.1) * acc.2 as f64;
            }
            let mut acc = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3], 0);
            for k in 1..BINS {
                grow(&mut acc, &boxes[k - 1]);
                let n_right = end - start - acc.2;
                if acc.2 == 0 || n_right == 0 {
                    continue;
                }
                let cost = area(acc.0, acc.1) * acc.2 as f64 + right[k];
                if best.is_none_or(|(c, _, _)| cost < c) {
                    best = Some((cost, axis, k));
                }
            }
        }
        let Some((_, axis, k)) = best else {
            // Every centre in one bin: halves, as they come.
            return start + (end - start) / 2;
        };
        let mut mid = start;
        for i in start..end {
            if bin(centres[self.order[i] as usize], axis) < k {
                self.order.swap(i, mid);
                mid += 1;
            }
        }
        mid
    }

    /// The tree's boxes (low corner, high corner, first, count, as in [`Node`]) and each
    /// triangle's corners in the order the leaves index: the layout
    /// [`super::visibility`] walks with packets of rays.
    pub(super) fn layout(&self) -> (Vec<NodeBox>, Vec<[Vec3; 3]>) {
        let nodes = self
            .nodes
            .iter()
            .map(|n| (n.lo, n.hi, n.first, n.count))
            .collect();
        let tris = self
            .order
            .iter()
            .map(|&t| {
                let [a, e1, e2] = self.tris[t as usize];
                [a, add(a, e1), add(a, e2)]
            })
            .collect();
        (nodes, tris)
    }

    /// The nearest hit within `(t_min, t_max)` of the ray from `origin` along `dir`.
    pub fn closest(&self, origin: Vec3, dir: Vec3, t_min: f64, t_max: f64) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        let mut far = t_max;
        self.walk(origin, dir, t_min, &mut far, &mut |t, hit| {
            best = Some(Hit { triangle: t, ..hit });
            false
        });
        best
    }

    /// Whether anything lies on the ray within `(t_min, t_max)`: the first hit ends the search.
    #[cfg(test)]
    pub(crate) fn occluded(&self, origin: Vec3, dir: Vec3, t_min: f64, t_max: f64) -> bool {
        let mut far = t_max;
        let mut hit = false;
        self.walk(origin, dir, t_min, &mut far, &mut |_, _| {
            hit = true;
            true
        });
        hit
    }

    /// Visits the triangles the ray may hit, nearest box first; `found` gets each hit nearer
    /// than `far` (which shrinks to it) and says whether to stop.
    fn walk(
        &self,
        origin: Vec3,
        dir: Vec3,
        t_min: f64,
        far: &mut f64,
        found: &mut dyn FnMut(usize, Hit) -> bool,
    ) {
        let inv = dir.map(|d| 1.0 / d);
        // Boxes to visit, each with where the ray enters it: a box is tested once, when its
        // parent is, and passed over when popped if a hit found since lies before it. The
        // tree is built by recursion to depth [`DEEPEST_HEURISTIC`] and then halves at the
        // median, so its depth stays far below the stack's size.
        let mut stack = [(0u32, 0f64); 128];
        let mut len = 0;
        if enters(&self.nodes[0], origin, inv, t_min, *far).is_none() {
            return;
        }
        stack[len] = (0, 0.0);
        len += 1;
        while len > 0 {
            len -= 1;
            let (i, enter) = stack[len];
            if enter > *far {
                continue;
            }
            let node = &self.nodes[i as usize];
            if node.count == 0 {
                let (a, b) = (node.first, node.first + 1);
                let open = |c: u32| enters(&self.nodes[c as usize], origin, inv, t_min, *far);
                // The nearer child is searched first, so that `far` shrinks early.
                let mut children = [(a, open(a)), (b, open(b))];
                if let [(_, Some(da)), (_, Some(db))] = children {
                    if db < da {
                        children.swap(0, 1);
                    }
                }
                for (c, enter) in children.into_iter().rev() {
                    if let Some(enter) = enter {
                        stack[len] = (c, enter);
                        len += 1;
                    }
                }
                continue;
            }
            let leaf = &self.order[node.first as usize..(node.first + node.count) as usize];
            for &t in leaf {
                if let Some(hit) = triangle(&self.tris[t as usize], origin, dir, t_min, *far) {
                    *far = hit.t;
                    if found(t as usize, hit) {
                        return;
                    }
                }
            }
        }
    }
}

/// Half the surface area of the box `lo`..`hi`.
fn area(lo: Vec3, hi: Vec3) -> f64 {
    let d = [0, 1, 2].map(|i| (hi[i] - lo[i]).max(0.0));
    d[0] * d[1] + d[1] * d[2] + d[2] * d[0]
}

/// Where within `(t_min, t_max)` the ray enters the box, if it passes through it.
fn enters(n: &Node, o: Vec3, inv: Vec3, t_min: f64, t_max: f64) -> Option<f64> {
    let (mut near, mut far) = (t_min, t_max);
    for i in 0..3 {
        let (a, b) = ((n.lo[i] - o[i]) * inv[i], (n.hi[i] - o[i]) * inv[i]);
        let (a, b) = if a <= b { (a, b) } else { (b, a) };
        // NaN (a ray along a face of the box) keeps the bounds as they are.
        near = if a > near { a } else { near };
        far = if b < far { b } else { far };
        if near > far {
            return None;
        }
    }
    Some(near)
}

/// Möller–Trumbore: the hit of the ray on the triangle (corner, two edges), either side.
fn triangle(tri: &[Vec3; 3], o: Vec3, d: Vec3, t_min: f64, t_max: f64) -> Option<Hit> {
    let [a, e1, e2] = *tri;
    let p = cross(d, e2);
    let det = dot(e1, p);
    if det.abs() < 1e-300 {
        return None;
    }
    let inv = 1.0 / det;
    let s = sub(o, a);
    let u = dot(s, p) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = cross(s, e1);
    let v = dot(d, q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    let t = dot(e2, q) * inv;
    (t > t_min && t < t_max).then_some(Hit {
        t,
        triangle: 0,
        u,
        v,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::uv_sphere;

    #[test]
    fn rays_hit_a_sphere_mesh_where_the_sphere_is() {
        let s = uv_sphere([0.0; 3], 1.0, 32, 64);
        let bvh = Bvh::build(&s);
        // Straight at the centre from +Z: the hit is near distance 4 (radius 1, from 5).
        let hit = bvh
            .closest([0.0, 0.0, 5.0], [0.0, 0.0, -1.0], 0.0, f64::INFINITY)
            .unwrap();
        assert!((hit.t - 4.0).abs() < 2e-3, "{hit:?}");
        // Every closest hit equals the nearest of all triangles, tested one by one.
        let mut rng = 1u64;
        let mut next = || {
            rng = rng
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (rng >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        for _ in 0..200 {
            let o = [next() * 3.0, next() * 3.0, 3.0];
            let d = crate::brdf::normalize([next() * 0.5, next() * 0.5, -1.0]);
            let brute = (0..s.triangles.len())
                .filter_map(|t| {
                    let [a, b, c] = s.corners(t);
                    triangle(&[a, sub(b, a), sub(c, a)], o, d, 0.0, f64::INFINITY)
                        .map(|h| Hit { triangle: t, ..h })
                })
                .min_by(|a, b| a.t.total_cmp(&b.t));
            let got = bvh.closest(o, d, 0.0, f64::INFINITY);
            assert_eq!(
                got.map(|h| h.triangle),
                brute.map(|h| h.triangle),
                "{o:?} {d:?}"
            );
            assert_eq!(bvh.occluded(o, d, 0.0, f64::INFINITY), brute.is_some());
        }
    }
}
