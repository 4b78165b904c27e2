//! Several materials on one part: a painted logo, a label, a plated insert, a two-colour print.
//!
//! One BRDF fitted to every pixel of such a part is a compromise that is none of its
//! materials. The whole part's estimate is where this starts: it renders the shading (light,
//! shape, shadows and a BRDF), so what the photo departs from it by, neighbourhood by
//! neighbourhood (`Cells`), is the appearance the shading leaves (issue 43, item 3). Where
//! the part holds materials of different colours, that departure falls into two groups: the
//! one material redder than the compromise, the other bluer. The pixels are split between
//! them (`two_means`), each group is estimated on its own, and each pixel goes again to the
//! material whose estimate renders it closer, [`ROUNDS`] times. On a mesh, every view's pixels
//! of one triangle vote for its material (`Labels`): the views of a turntable agree, and the
//! materials' edges follow the mesh's.
//!
//! The split is kept only when it is asked for and pays: the photo's colour departs from the
//! whole estimate's by [`DEPARTS_FROM`] (RMS of ln colour shares over the neighbourhoods),
//! each material holds [`MIN_SHARE`] of the pixels, and the materials together re-render the
//! photo at most [`BETTER_BY`] of the whole estimate's misfit.
//!
//! Not here: materials of one colour that differ in gloss alone, and more than two materials
//! (docs/method.md, "Two materials"). Each material's bounce, on a concave mesh, is lit through
//! its own BRDF wherever the bounced light comes from.

use std::collections::HashMap;

use super::basis::Basis;
use super::error::{CoreError, Result};
use super::estimate::{
    estimate_views_shared, Estimate, EstimateOptions, Outcome, Rerendered, Shared, View,
};
use super::geometry::{GeomPixel, PixelGeometry};
use super::render::render_bivariates;

/// How far (RMS over the neighbourhoods of the ln colour shares, red and blue, against the
/// whole estimate's) the photo's colour must depart from place to place before it is split.
/// The single-material domes of brdfd's Mitsuba set measure 0.025–0.037, its grooved gold
/// 0.18 (walls that light each other in gold's colour), a sphere of MERL's gold paint 0.11,
/// the two-tone dome 0.86 (docs/evaluation.md). The several-materials flag
/// judges its own figure, over larger blocks of the first view, by the same threshold.
pub const DEPARTS_FROM: f64 = 0.25;

/// The least share of the part's pixels a material must hold: a smaller group is a
/// highlight or an edge the compromise missed, not a material.
pub const MIN_SHARE: f64 = 0.05;

/// How much closer the materials together must re-render the photo than the whole estimate
/// (the ratio of their misfits, relative RMS) for the split to be kept.
pub const BETTER_BY: f64 = 0.75;

/// Times the pixels go again to the material that renders them closer, each followed by the
/// materials' estimates made again.
pub const ROUNDS: usize = 1;

/// Marks a triangle no view saw in [`Split::triangles`].
pub const UNSEEN: u8 = u8::MAX;

/// A pixel of a view and its material (an index into [`Split::parts`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Labelled {
    pub x: u32,
    pub y: u32,
    pub material: u8,
}

/// The whole part's estimate and, when the part holds two materials, their split.
pub struct Materials {
    pub whole: Estimate,
    pub split: Option<Split>,
    /// How far the photo's colour departs from the whole estimate's from place to place
    /// (RMS of ln colour shares; see [`DEPARTS_FROM`]); `None` with too few pixels, and when
    /// the split is off ([`EstimateOptions::materials`] or `checks`).
    pub departure: Option<f64>,
}

/// Two materials on one part, each estimated on its own pixels.
pub struct Split {
    /// Each material's estimate, in the order of [`Split::labels`].
    pub parts: Vec<Estimate>,
    /// Per view, each pixel of its geometry and its material.
    pub labels: Vec<Vec<Labelled>>,
    /// On a mesh, each triangle's material ([`UNSEEN`] where no view saw it).
    pub triangles: Option<Vec<u8>>,
    /// The materials' re-render of the photo, together: ‖A·c − y‖ / ‖y‖ over every
    /// candidate, each by its own material, each material's candidates weighted by its pixels
    /// per candidate.
    pub fit_error: f64,
    /// Pixels in each material, over every view.
    pub pixels: Vec<usize>,
}

/// The estimate of a part that may carry two materials: the whole part's, then, when the
/// photo's colour asks for it and the split pays ([`Materials`]), each material's.
pub fn estimate_materials(
    basis: &Basis,
    views: &[View],
    options: &EstimateOptions,
    shared: &Shared,
) -> Result<Materials> {
    let whole = estimate_views_shared(basis, views, options, shared)?;
    if !(options.materials && options.checks) {
        return Ok(Materials {
            whole,
            split: None,
            departure: None,
        });
    }
    let cells = Cells::new(views, &whole.rerender);
    let sums = cells.neighbourhoods(&whole.rerender, |i| {
        whole.rerender[i].predicted.map(f64::from)
    });
    let departs: Vec<Option<[f64; 2]>> = sums.iter().map(|(o, p)| colour_departure(o, p)).collect();
    let departure = spread_of(&departs);
    tracing::debug!("materials: the colour departs by {departure:?} (split from {DEPARTS_FROM})");
    if !departure.is_some_and(|d| d >= DEPARTS_FROM) {
        return Ok(Materials {
            whole,
            split: None,
            departure,
        });
    }
    let labels = Labels::of(views);
    let mut chosen = two_means(&departs);
    let mut best: Option<Split> = None;
    for round in 0..=ROUNDS {
        options.stop.check()?;
        let per_view = labels.spread(views, &whole.rerender, &chosen, &cells);
        // A material's estimate that fails leaves the whole part's, which stands on its own.
        let parts = match estimate_parts(basis, views, &per_view, options, shared) {
            Ok(Some(parts)) => parts,
            Ok(None) => break,
            Err(CoreError::Stopped) => return Err(CoreError::Stopped),
            Err(e) => {
                tracing::warn!("the part's two materials could not be estimated apart: {e}");
                break;
            }
        };
        let pixels: Vec<usize> = (0..2)
            .map(|k| per_view.iter().flatten().filter(|l| **l == k).count())
            .collect();
        let fit_error = together(&parts, &pixels);
        tracing::debug!(
            "materials, round {round}: fit {fit_error:.4} against the whole part's {:.4}",
            whole.fit_error
        );
        let split = Split {
            pixels,
            triangles: labels.triangles(views, &per_view),
            labels: labelled(views, &per_view),
            parts,
            fit_error,
        };
        if round < ROUNDS {
            chosen = closer(views, &whole.rerender, &split, &cells);
        }
        // A round that fits worse than the one before it is not kept.
        if best
            .as_ref()
            .is_none_or(|b| b.fit_error.is_nan() || split.fit_error < b.fit_error)
        {
            best = Some(split);
        }
    }
    // Each material's figures are written, and read back, as numbers.
    let split = best.filter(|s| {
        s.fit_error <= BETTER_BY * whole.fit_error
            && s.parts.iter().all(|p| p.fit_error.is_finite())
    });
    Ok(Materials {
        whole,
        split,
        departure,
    })
}

/// Each view's pixels with their labels.
fn labelled(views: &[View], labels: &[Vec<u8>]) -> Vec<Vec<Labelled>> {
    views
        .iter()
        .zip(labels)
        .map(|(v, l)| {
            v.geometry
                .pixels
                .iter()
                .zip(l)
                .map(|(p, m)| Labelled {
                    x: p.x,
                    y: p.y,
                    material: *m,
                })
                .collect()
        })
        .collect()
}

/// Each material's estimate from its own pixels; `None` when either holds too few. A view
/// with none of a material's pixels the photo measured is left out of its estimate, and the
/// estimate's view numbers are put back to the part's, so that its re-render's view 0 is the
/// part's first view (its report compares it with that view's photo).
fn estimate_parts(
    basis: &Basis,
    views: &[View],
    labels: &[Vec<u8>],
    options: &EstimateOptions,
    shared: &Shared,
) -> Result<Option<Vec<Estimate>>> {
    let total: usize = labels.iter().map(Vec::len).sum();
    let geometries: Vec<Vec<PixelGeometry>> = (0..2u8)
        .map(|k| {
            views
                .iter()
                .zip(labels)
                .map(|(v, l)| PixelGeometry {
                    width: v.geometry.width,
                    height: v.geometry.height,
                    pixels: v
                        .geometry
                        .pixels
                        .iter()
                        .zip(l)
                        .filter(|(_, m)| **m == k)
                        .map(|(p, _)| p.clone())
                        .collect(),
                })
                .collect()
        })
        .collect();
    let small = |g: &Vec<PixelGeometry>| {
        let count: usize = g.iter().map(|g| g.pixels.len()).sum();
        (count as f64) < MIN_SHARE * total as f64
    };
    if geometries.iter().any(small) {
        return Ok(None);
    }
    let mut parts = Vec::with_capacity(2);
    for own in &geometries {
        let (kept, sub): (Vec<usize>, Vec<View>) = views
            .iter()
            .zip(own)
            .enumerate()
            .filter(|(_, (v, g))| g.pixels.iter().any(|p| measured(v, p, options.white)))
            .map(|(i, (v, g))| (i, View { geometry: g, ..*v }))
            .unzip();
        let mut estimate = estimate_views_shared(basis, &sub, options, shared)?;
        for r in &mut estimate.rerender {
            r.view = kept[r.view];
        }
        if let Outcome::Basis(b) = &mut estimate.outcome {
            for v in &mut b.chosen_views {
                *v = kept[*v];
            }
        }
        parts.push(estimate);
    }
    Ok(Some(parts))
}

/// Whether the photo measured pixel `p` of view `v`: every channel finite, not negative, and
/// below the white level if there is one (what makes a pixel a candidate).
fn measured(v: &View, p: &GeomPixel, white: Option<f32>) -> bool {
    v.photo
        .get(p.x as usize, p.y as usize)
        .iter()
        .all(|c| c.is_finite() && *c >= 0.0 && white.is_none_or(|w| *c < w))
}

/// The materials' misfit together: relative RMS over their candidates, each material's
/// weighted by its pixels per candidate, so that a material spread to fewer candidates than
/// it has pixels counts for all of them.
fn together(parts: &[Estimate], pixels: &[usize]) -> f64 {
    let (mut miss, mut all) = (0.0, 0.0);
    for (part, n) in parts.iter().zip(pixels) {
        let weight = *n as f64 / part.rerender.len().max(1) as f64;
        for r in &part.rerender {
            for c in 0..3 {
                miss += weight * f64::from(r.predicted[c] - r.observed[c]).powi(2);
                all += weight * f64::from(r.observed[c]).powi(2);
            }
        }
    }
    (miss / all).sqrt()
}

/// For each re-rendered pixel, which material's estimate renders its neighbourhood closer
/// (in ln radiance, over the three channels).
fn closer(
    views: &[View],
    rerender: &[Rerendered],
    split: &Split,
    cells: &Cells,
) -> Vec<Option<u8>> {
    let brdfs: Vec<_> = split.parts.iter().map(|p| &p.brdf).collect();
    // Each view's candidates, rendered through each material's BRDF.
    let mut rendered: Vec<Vec<[f64; 3]>> = vec![vec![[0.0; 3]; rerender.len()]; brdfs.len()];
    for (v, view) in views.iter().enumerate() {
        let mine: Vec<usize> = (0..rerender.len())
            .filter(|i| rerender[*i].view == v)
            .collect();
        let by_place: HashMap<(u32, u32), &GeomPixel> = view
            .geometry
            .pixels
            .iter()
            .map(|p| ((p.x, p.y), p))
            .collect();
        let geom = PixelGeometry {
            width: view.geometry.width,
            height: view.geometry.height,
            pixels: mine
                .iter()
                .filter_map(|i| by_place.get(&(rerender[*i].x, rerender[*i].y)))
                .map(|p| (*p).clone())
                .collect(),
        };
        let images = render_bivariates(&geom, view.lights, &brdfs);
        for (k, image) in images.iter().enumerate() {
            for i in &mine {
                let r = &rerender[*i];
                rendered[k][*i] = image.get(r.x as usize, r.y as usize).map(f64::from);
            }
        }
    }
    let per_material: Vec<Vec<([f64; 3], [f64; 3])>> = rendered
        .iter()
        .map(|r| cells.neighbourhoods(rerender, |i| r[i]))
        .collect();
    (0..rerender.len())
        .map(|i| {
            let misses: Vec<Option<f64>> = per_material
                .iter()
                .map(|sums| log_miss(&sums[i].0, &sums[i].1))
                .collect();
            match (misses[0], misses[1]) {
                (Some(a), Some(b)) => Some(u8::from(b < a)),
                _ => None,
            }
        })
        .collect()
}

/// How far a rendered neighbourhood is from the photo's: the sum of squared ln ratios over
/// the channels; `None` where a channel is black in either.
fn log_miss(observed: &[f64; 3], predicted: &[f64; 3]) -> Option<f64> {
    (observed.iter().chain(predicted).all(|v| *v > 0.0)).then(|| {
        (0..3)
            .map(|c| (observed[c] / predicted[c]).ln().powi(2))
            .sum()
    })
}

/// A view's cell: the view, and the cell's column and row.
type Cell = (usize, u32, u32);

/// The re-rendered pixels of each view gathered into square cells about as wide as the
/// candidates are apart: a pixel where every object pixel is a candidate, wider where the
/// candidates were spread over a larger photo. A candidate's neighbourhood is its cell and the
/// 8 around it, about 9 candidates whatever the photo's resolution: one pixel's colour is
/// noisy where it is dark, nine agree on a material.
struct Cells {
    /// Each view's cell side, in pixels.
    side: Vec<u32>,
}

impl Cells {
    fn new(views: &[View], rerender: &[Rerendered]) -> Cells {
        let mut candidates = vec![0usize; views.len()];
        for r in rerender {
            candidates[r.view] += 1;
        }
        Cells {
            side: views
                .iter()
                .zip(&candidates)
                .map(|(v, n)| {
                    let per = v.geometry.pixels.len() as f64 / (*n).max(1) as f64;
                    per.sqrt().round().max(1.0) as u32
                })
                .collect(),
        }
    }

    fn of(&self, view: usize, x: u32, y: u32) -> Cell {
        let s = self.side[view];
        (view, x / s, y / s)
    }

    /// The 3 × 3 cells about `cell` (fewer at the image's top and left edges).
    fn around((view, cx, cy): Cell) -> impl Iterator<Item = Cell> {
        (-1i64..=1).flat_map(move |dy| {
            (-1i64..=1).filter_map(move |dx| {
                let (x, y) = (i64::from(cx) + dx, i64::from(cy) + dy);
                (x >= 0 && y >= 0).then_some((view, x as u32, y as u32))
            })
        })
    }

    /// Each re-rendered pixel's neighbourhood: the sums of what the photo measured and of
    /// `predicted` there.
    fn neighbourhoods(
        &self,
        rerender: &[Rerendered],
        predicted: impl Fn(usize) -> [f64; 3],
    ) -> Vec<([f64; 3], [f64; 3])> {
        let mut sums: HashMap<Cell, ([f64; 3], [f64; 3])> = HashMap::new();
        for (i, r) in rerender.iter().enumerate() {
            let s = sums.entry(self.of(r.view, r.x, r.y)).or_default();
            let q = predicted(i);
            for c in 0..3 {
                s.0[c] += f64::from(r.observed[c]);
                s.1[c] += q[c];
            }
        }
        rerender
            .iter()
            .map(|r| {
                let (mut o, mut p) = ([0.0; 3], [0.0; 3]);
                for cell in Cells::around(self.of(r.view, r.x, r.y)) {
                    if let Some(s) = sums.get(&cell) {
                        for c in 0..3 {
                            o[c] += s.0[c];
                            p[c] += s.1[c];
                        }
                    }
                }
                (o, p)
            })
            .collect()
    }

    /// Each cell's label: the one most of its labelled pixels carry.
    fn labels(&self, rerender: &[Rerendered], chosen: &[Option<u8>]) -> HashMap<Cell, u8> {
        let mut votes: HashMap<Cell, [u32; 2]> = HashMap::new();
        for (r, l) in rerender.iter().zip(chosen) {
            if let Some(l) = l {
                votes.entry(self.of(r.view, r.x, r.y)).or_default()[*l as usize] += 1;
            }
        }
        votes
            .into_iter()
            .map(|(cell, v)| (cell, u8::from(v[1] > v[0])))
            .collect()
    }

    /// The label nearest pixel (x, y) of `view` carries: its cell's, else the commoner in the
    /// ring of cells about it, out to [`REACH`] cells.
    fn label_near(&self, labels: &HashMap<Cell, u8>, view: usize, x: u32, y: u32) -> Option<u8> {
        let (_, cx, cy) = self.of(view, x, y);
        for reach in 0..=REACH {
            let mut votes = [0u32; 2];
            for dy in -reach..=reach {
                for dx in -reach..=reach {
                    if dx.abs().max(dy.abs()) != reach {
                        continue;
                    }
                    let (x, y) = (i64::from(cx) + dx, i64::from(cy) + dy);
                    if x < 0 || y < 0 {
                        continue;
                    }
                    if let Some(l) = labels.get(&(view, x as u32, y as u32)) {
                        votes[*l as usize] += 1;
                    }
                }
            }
            if votes[0] + votes[1] > 0 {
                return Some(u8::from(votes[1] > votes[0]));
            }
        }
        None
    }
}

/// Cells a pixel's label is looked for across, at most, beyond its own.
const REACH: i64 = 4;

/// The photo's share of red and of blue in a neighbourhood's light against the estimate's
/// (ln): shares of the sum, not ratios to green, as a saturated red or blue material has next
/// to no green. `None` where a channel is black.
pub fn colour_departure(observed: &[f64; 3], predicted: &[f64; 3]) -> Option<[f64; 2]> {
    if !observed.iter().chain(predicted).all(|v| *v > 0.0) {
        return None;
    }
    let (so, sp): (f64, f64) = (observed.iter().sum(), predicted.iter().sum());
    let share = |c: usize| (observed[c] / so).ln() - (predicted[c] / sp).ln();
    Some([share(0), share(2)])
}

/// Pixels below which the departure's spread is not measured.
const MIN_PIXELS: usize = 200;

/// The RMS distance of the departures from their mean: a cast over the whole photo (the
/// map's white balance) moves the mean, not the spread.
fn spread_of(departs: &[Option<[f64; 2]>]) -> Option<f64> {
    let d: Vec<[f64; 2]> = departs.iter().flatten().copied().collect();
    if d.len() < MIN_PIXELS {
        return None;
    }
    let n = d.len() as f64;
    let mean = [0, 1].map(|k| d.iter().map(|p| p[k]).sum::<f64>() / n);
    Some(
        (d.iter()
            .map(|p| (p[0] - mean[0]).powi(2) + (p[1] - mean[1]).powi(2))
            .sum::<f64>()
            / n)
            .sqrt(),
    )
}

/// Two groups of the departures (k-means, k = 2), started from either side of their mean
/// along the direction they spread most in: each pixel's group, `None` where it has no
/// departure.
fn two_means(departs: &[Option<[f64; 2]>]) -> Vec<Option<u8>> {
    let d: Vec<[f64; 2]> = departs.iter().flatten().copied().collect();
    let n = d.len().max(1) as f64;
    let mean = [0, 1].map(|k| d.iter().map(|p| p[k]).sum::<f64>() / n);
    // The covariance's leading eigenvector, and the spread along it.
    let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
    for p in &d {
        let (x, y) = (p[0] - mean[0], p[1] - mean[1]);
        sxx += x * x / n;
        sxy += x * y / n;
        syy += y * y / n;
    }
    let lead = 0.5 * (sxx + syy + ((sxx - syy).powi(2) + 4.0 * sxy * sxy).sqrt());
    let axis = if sxy.abs() > 1e-12 {
        [lead - syy, sxy]
    } else if sxx >= syy {
        [1.0, 0.0]
    } else {
        [0.0, 1.0]
    };
    let len = (axis[0] * axis[0] + axis[1] * axis[1]).sqrt();
    let s = lead.sqrt() / len.max(1e-300);
    let mut centres = [
        [mean[0] - s * axis[0], mean[1] - s * axis[1]],
        [mean[0] + s * axis[0], mean[1] + s * axis[1]],
    ];
    let nearest = |p: &[f64; 2], c: &[[f64; 2]; 2]| {
        let d2 = |q: &[f64; 2]| (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2);
        u8::from(d2(&c[1]) < d2(&c[0]))
    };
    for _ in 0..30 {
        let mut sums = [[0.0; 3]; 2];
        for p in &d {
            let k = nearest(p, &centres) as usize;
            sums[k][0] += p[0];
            sums[k][1] += p[1];
            sums[k][2] += 1.0;
        }
        let next = [0, 1].map(|k| {
            if sums[k][2] > 0.0 {
                [sums[k][0] / sums[k][2], sums[k][1] / sums[k][2]]
            } else {
                centres[k]
            }
        });
        if next == centres {
            break;
        }
        centres = next;
    }
    departs
        .iter()
        .map(|p| p.as_ref().map(|p| nearest(p, &centres)))
        .collect()
}

/// How labels of re-rendered pixels spread to every pixel of every view: on a mesh, through
/// the triangles (each triangle takes its pixels' majority, over every view); elsewhere,
/// through the image (each pixel takes the majority of the labelled pixels near it).
struct Labels {
    /// Per view, each geometry pixel's triangle, when every view is of one mesh.
    triangles: Option<Vec<Vec<Option<u32>>>>,
    /// The mesh's triangle count.
    count: usize,
}

impl Labels {
    fn of(views: &[View]) -> Labels {
        let per_view: Option<Vec<(usize, Vec<Option<u32>>)>> =
            views.iter().map(|v| triangles_of(v.geometry)).collect();
        match per_view {
            Some(t) if t.windows(2).all(|w| w[0].0 == w[1].0) && !t.is_empty() => Labels {
                count: t[0].0,
                triangles: Some(t.into_iter().map(|(_, t)| t).collect()),
            },
            _ => Labels {
                triangles: None,
                count: 0,
            },
        }
    }

    /// Every pixel's label, per view, from the labels of the re-rendered pixels: on a mesh,
    /// its triangle's (the majority of the triangle's candidates over every view or, where
    /// none fell on it, of its pixels' cells); off a mesh, or off every triangle, its cell's
    /// or the nearest cell's ([`Cells::label_near`]); else the commoner label.
    fn spread(
        &self,
        views: &[View],
        rerender: &[Rerendered],
        chosen: &[Option<u8>],
        cells: &Cells,
    ) -> Vec<Vec<u8>> {
        let near = cells.labels(rerender, chosen);
        let overall = u8::from(
            2 * chosen.iter().filter(|l| **l == Some(1)).count()
                > chosen.iter().filter(|l| l.is_some()).count(),
        );
        let by_triangle: Option<Vec<Option<u8>>> = self.triangles.as_ref().map(|triangles| {
            let mut at: Vec<HashMap<(u32, u32), u8>> = vec![HashMap::new(); views.len()];
            for (r, l) in rerender.iter().zip(chosen) {
                if let Some(l) = l {
                    at[r.view].insert((r.x, r.y), *l);
                }
            }
            let mut votes = vec![[0u32; 2]; self.count];
            for ((v, view), tris) in views.iter().enumerate().zip(triangles) {
                for (p, t) in view.geometry.pixels.iter().zip(tris) {
                    if let (Some(t), Some(l)) = (t, at[v].get(&(p.x, p.y))) {
                        votes[*t as usize][*l as usize] += 1;
                    }
                }
            }
            let mut by: Vec<Option<u8>> = votes
                .iter()
                .map(|v| (v[0] + v[1] > 0).then(|| u8::from(v[1] > v[0])))
                .collect();
            // A triangle no candidate fell on takes the majority of its pixels' cells, over
            // every view: all its pixels then carry one label, as the record paints it.
            let mut near_votes = vec![[0u32; 2]; self.count];
            for ((v, view), tris) in views.iter().enumerate().zip(triangles) {
                for (p, t) in view.geometry.pixels.iter().zip(tris) {
                    let Some(t) = t else { continue };
                    if by[*t as usize].is_none() {
                        if let Some(l) = cells.label_near(&near, v, p.x, p.y) {
                            near_votes[*t as usize][l as usize] += 1;
                        }
                    }
                }
            }
            for (b, v) in by.iter_mut().zip(&near_votes) {
                if b.is_none() && v[0] + v[1] > 0 {
                    *b = Some(u8::from(v[1] > v[0]));
                }
            }
            by
        });
        views
            .iter()
            .enumerate()
            .map(|(v, view)| {
                view.geometry
                    .pixels
                    .iter()
                    .enumerate()
                    .map(|(i, p)| {
                        let voted = match (&by_triangle, &self.triangles) {
                            (Some(by), Some(tris)) => tris[v][i].and_then(|t| by[t as usize]),
                            _ => None,
                        };
                        voted
                            .or_else(|| cells.label_near(&near, v, p.x, p.y))
                            .unwrap_or(overall)
                    })
                    .collect()
            })
            .collect()
    }

    /// Each triangle's label, from every view's pixels (already spread); `None` off a mesh.
    fn triangles(&self, views: &[View], labels: &[Vec<u8>]) -> Option<Vec<u8>> {
        let triangles = self.triangles.as_ref()?;
        let mut out = vec![UNSEEN; self.count];
        for ((_, tris), l) in views.iter().zip(triangles).zip(labels) {
            for (t, l) in tris.iter().zip(l) {
                if let Some(t) = t {
                    out[*t as usize] = *l;
                }
            }
        }
        Some(out)
    }
}

/// Each pixel's triangle, and the mesh's triangle count, when the geometry is of a mesh:
/// found by a ray back from the point its shadow rays start at, along its normal, to the
/// surface just below.
pub fn triangles_of(geometry: &PixelGeometry) -> Option<(usize, Vec<Option<u32>>)> {
    let shadow = geometry.pixels.first()?.shadow.as_ref()?;
    let surface = shadow.occluder.surface()?.clone();
    let reach = surface.diagonal * 1e-2;
    let triangles = geometry
        .pixels
        .iter()
        .map(|p| {
            let s = p.shadow.as_ref()?;
            let point = s.occluder.points().get(s.id as usize)?;
            let origin = point.origin.map(f64::from);
            let down = point.normal.map(|c| -f64::from(c));
            surface
                .bvh()
                .closest(origin, down, 0.0, reach)
                .map(|h| h.triangle as u32)
        })
        .collect();
    Some((surface.mesh.triangles.len(), triangles))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn two_means_parts_two_groups_of_departures_and_leaves_the_unmeasured_out() {
        let mut d: Vec<Option<[f64; 2]>> = Vec::new();
        for i in 0..300 {
            let wobble = 0.02 * ((i % 7) as f64 - 3.0);
            d.push(Some([0.4 + wobble, -0.3 - wobble]));
            d.push(Some([-0.5 - wobble, 0.35 + wobble]));
        }
        d.push(None);
        let l = two_means(&d);
        assert_eq!(l.last(), Some(&None));
        let first = l[0].unwrap();
        for (i, x) in l[..600].iter().enumerate() {
            assert_eq!(*x, Some(if i % 2 == 0 { first } else { 1 - first }));
        }
    }

    #[test]
    fn a_cast_over_the_whole_photo_does_not_spread_the_departures() {
        let cast: Vec<Option<[f64; 2]>> = (0..500).map(|_| Some([0.3, -0.2])).collect();
        assert!(spread_of(&cast).unwrap() < 1e-12);
        // Two equal groups 2d apart spread by d.
        let two: Vec<Option<[f64; 2]>> = (0..500)
            .map(|i| Some(if i % 2 == 0 { [0.3, 0.0] } else { [-0.3, 0.0] }))
            .collect();
        assert!((spread_of(&two).unwrap() - 0.3).abs() < 1e-12);
        // Too few pixels to say.
        assert!(spread_of(&cast[..MIN_PIXELS - 1]).is_none());
    }

    #[test]
    fn the_departure_is_of_colour_shares_not_of_brightness() {
        let o = [2.0, 1.0, 0.5];
        assert_eq!(colour_departure(&o, &o.map(|v| 3.0 * v)), Some([0.0, 0.0]));
        let d = colour_departure(&[1.0, 1.0, 2.0], &[1.0, 1.0, 1.0]).unwrap();
        assert!(d[0] < 0.0 && d[1] > 0.0);
        assert_eq!(colour_departure(&[1.0, 0.0, 1.0], &[1.0, 1.0, 1.0]), None);
    }

    #[test]
    fn a_pixel_takes_its_cells_label_or_the_nearest_labelled_cells() {
        let cells = Cells { side: vec![3, 3] };
        let mut labels = HashMap::new();
        labels.insert((0, 3, 0), 1u8);
        labels.insert((0, 4, 0), 1u8);
        labels.insert((0, 3, 1), 0u8);
        // Its own cell's (pixels 9–11 across are cell 3).
        assert_eq!(cells.label_near(&labels, 0, 10, 4), Some(0));
        // The ring about it: cells 3 and 4 of row 0 against cell 3 of row 1.
        assert_eq!(cells.label_near(&labels, 0, 14, 3), Some(1));
        // Beyond the reach, none.
        assert_eq!(cells.label_near(&labels, 0, 3 * 20, 0), None);
        // Another view's cells are not this one's.
        assert_eq!(cells.label_near(&labels, 1, 10, 4), None);
    }
}
