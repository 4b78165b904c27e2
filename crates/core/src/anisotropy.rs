//! Does the photo ask for an anisotropic lobe? Every model of the estimate is isotropic: its
//! highlights are as wide along the surface's every direction. Brushed or machined metal and
//! FDM prints with layer lines have a grain: their highlights stretch across it. An isotropic
//! fit of such a surface is a compromise, too sharp across the grain and too blurred along
//! it, and its misfit alone does not say why.
//!
//! The evidence here is a comparison of two fits on the same pixels and lights: Lambert plus
//! one isotropic GGX/Smith lobe, against Lambert plus one anisotropic lobe whose tangent frame
//! follows a grain direction g laid on the surface (at each point, t = g − (g·n)n, normalised:
//! what a part brushed or printed along one direction has). The anisotropic fit searches g
//! over every direction, and the roughnesses along (αt) and across (αb) the grain. The
//! weights of both are solved exactly for each shape tried (non-negative least squares, per
//! channel). When the anisotropic lobe re-renders the photo much closer than the best
//! isotropic one, the photo asks for anisotropy: the report flags it with the grain found.
//!
//! The fits render the pixels directly: each pixel's lights through the full anisotropic
//! GGX, not a bivariate table, which cannot hold an azimuth. To keep a search of a few hundred
//! shapes cheap, a lobe is followed only as far from the mirror direction as it reaches, with
//! the estimate's own lights while it is sharp, and with the map merged to [`LIGHTS`] lights
//! once it is rough. A merged light's spread of directions widens the lobe by its second
//! moment (α² + m₂/4, the half vector moving half as far as the light), so that a lobe is not
//! read as sharper than the lights can show. A first pass, cheap, asks whether anisotropy
//! may help; only then a second measures the lobe with the estimate's lights for every
//! roughness that can show a grain (0.06–0.13 s, then 0.7 s, on 2 cores).
//!
//! What the photo's noise adds to both misfits is not told apart: a noisy photo (a path
//! tracer's at 32 samples a pixel) hides a grain that a merged bracket shows.

use rayon::prelude::*;
use serde::Serialize;

use super::anisotropic::{frame_at, AnisotropicLobe};
use super::brdf::{add, angle_between, cross, dot, half_sphere, normalize, scale, tangent_frame};
use super::envmap::LightSet;
use super::geometry::GeomPixel;
use super::stop::Stop;
use super::visibility::{is_seen, Seen};

/// Lights the map is merged to for rough lobes (a 32 × 16 grid of directions).
pub const LIGHTS: usize = GRID_U * GRID_V;
const GRID_U: usize = 32;
const GRID_V: usize = 16;
/// Lobes sharper than this (their roughest α) are rendered with the estimate's own lights,
/// as far from the mirror direction as [`REACH`] takes them; rougher ones with the merged
/// lights. The first pass keeps the estimate's lights for sharp lobes only, which the merged
/// lights cannot show (a chrome's highlights would read as stretched by the merged cells);
/// the second for every lobe whose sharp axis can show a grain.
const DETECT_FINE_BELOW: f64 = 0.12;
const MEASURE_FINE_BELOW: f64 = 0.3;
const REACH: f64 = 4.0;
/// The first pass's anisotropic misfit, over the isotropic one, below which the second pass
/// measures the lobe (looser than the report's flag, `brdfd_report::flags`, at 0.75, so that
/// a case near it is measured).
const MAY_ASK: f64 = 0.85;
/// Pixels needed, at least, for a comparison.
const MIN_PIXELS: usize = 100;
/// Pixels compared, spread over the candidates.
pub const PIXELS: usize = 1_000;
/// Directions of the grain tried first: a Fibonacci half sphere, about 23° apart.
const COARSE_DIRECTIONS: usize = 24;
/// The same for the second pass, which measures the lobe: about 16° apart.
const MEASURE_DIRECTIONS: usize = 48;
/// The ratio αb/αt of the coarse search's lobes; the refinement moves it freely.
const COARSE_RATIO: f64 = 2.5;
/// Roughnesses of the isotropic search: log-spaced from a near mirror to a nearly diffuse
/// lobe.
const ISO_ALPHAS: usize = 18;
const ALPHA_MIN: f64 = 0.01;
const ALPHA_MAX: f64 = 0.8;
/// Rounds of the refinements: each halves the steps.
const REFINE_ROUNDS: usize = 6;
/// Moves of the anisotropic lobe's search, at most, besides its halvings.
const MAX_MOVES: usize = 12;

/// The two fits compared, and the anisotropic lobe's shape.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Anisotropy {
    /// ‖prediction − photo‖ / ‖photo‖ of Lambert plus the best isotropic GGX lobe.
    pub isotropic_misfit: f64,
    /// The isotropic lobe's roughness.
    pub isotropic_alpha: f64,
    /// The same with the best anisotropic lobe.
    pub anisotropic_misfit: f64,
    /// The direction searched (world frame, unit): at each point, the lobe's tangent is this
    /// axis laid on the surface, t = a − (a·n)n normalised, and its bitangent n × t.
    pub axis: [f64; 3],
    /// Whether the lobe is smooth along the axis laid on the surface (a grain that runs along
    /// it, as a part brushed along one direction has); otherwise smooth across it (a grain
    /// that runs around it, as a print's layer lines run around the axis it was printed on).
    pub smooth_along_axis: bool,
    /// The grain's direction (world frame, unit) where the pixels face on average: the axis,
    /// or the direction across it there.
    pub grain: [f64; 3],
    /// Roughness along the grain (αt), smooth; αt ≤ αb.
    pub alpha_along: f64,
    /// Roughness across the grain (αb).
    pub alpha_across: f64,
    /// Pixels compared.
    pub pixels: usize,
    /// The anisotropic fit itself, with its weights: what the estimate relights with when it
    /// is [`Anisotropy::chosen`] (its weights then solved on every candidate).
    pub lobe: AnisotropicLobe,
    /// Whether the estimate relights with [`Anisotropy::lobe`] rather than its model: the
    /// photo asks for anisotropy ([`Anisotropy::asks`]) and the lobe, its weights solved again
    /// on every candidate ([`refit`]), re-renders it closer than the model does. Set by the
    /// estimate, which knows its model's fit; the lobe's weights are then the refitted ones.
    pub chosen: bool,
}

impl Anisotropy {
    /// How much closer the anisotropic lobe re-renders the photo: its misfit over the
    /// isotropic one's (1 when it is no better).
    pub fn misfit_ratio(&self) -> f64 {
        if self.isotropic_misfit > 0.0 {
            self.anisotropic_misfit / self.isotropic_misfit
        } else {
            1.0
        }
    }

    /// αb/αt: 1 for an isotropic highlight.
    pub fn stretch(&self) -> f64 {
        self.alpha_across / self.alpha_along
    }

    /// Whether the photo asks for anisotropy: the anisotropic lobe re-renders it much closer
    /// than any isotropic one ([`ASKS_BELOW`]), and is much rougher across its grain than
    /// along it ([`MIN_STRETCH`]).
    pub fn asks(&self) -> bool {
        self.misfit_ratio() <= ASKS_BELOW && self.stretch() >= MIN_STRETCH
    }
}

/// The anisotropic lobe's misfit, over the best isotropic one's, at or below which the photo
/// asks for anisotropy. On brdfd's Mitsuba set: brushed aluminium (α 0.06 along the grain,
/// 0.24 across) 0.28; the in-model domes 0.88–0.98; the parts outside the model for other
/// reasons 0.92–1.00; the simulated presets 0.88–0.98.
pub const ASKS_BELOW: f64 = 0.75;
/// And the lobe must be this much rougher across the grain than along it: a lobe as wide
/// both ways that fits better is not a grain.
pub const MIN_STRETCH: f64 = 1.5;

/// One view's pixels for the comparison: their geometry, what the photo measured, and the
/// lights (in the same frame).
pub struct ViewSamples<'a> {
    pub pixels: &'a [GeomPixel],
    pub observed: &'a [[f64; 3]],
    pub lights: &'a LightSet,
}

/// A pixel's lights, with what of their geometry no lobe shape changes: each light's
/// direction and its half vector with the view, the half vector's cosine to the normal,
/// 1/cos² of the light's, its power (radiance × solid angle) and the widening of a lobe by
/// its spread of directions (m₂/4: R²/8 for a disc of radius R). Laid out field by field, sharpest first, and padded to
/// whole lanes with lights of no power, so that the loop over them runs [`LANES`] wide.
struct Lights {
    /// Lights, without the padding.
    len: usize,
    /// `data[field · padded + light]`.
    data: Vec<f32>,
}

/// One light as a pixel sees it, before [`Lights::new`] lays them out.
struct Pair {
    dir: [f32; 3],
    half: [f32; 3],
    cos_h: f32,
    cos_l: f32,
    power: [f32; 3],
    widen: f32,
}

const LANES: usize = 8;
const DIR: usize = 0;
const HALF: usize = 3;
const COS_H: usize = 6;
const INV_COS_L2: usize = 7;
const POWER: usize = 8;
const WIDEN: usize = 11;
const FIELDS: usize = 12;

impl Lights {
    /// The pixel's lights, in any order.
    fn new(mut lights: Vec<Pair>) -> Lights {
        lights.sort_unstable_by(|a, b| b.cos_h.total_cmp(&a.cos_h));
        let len = lights.len();
        let padded = len.div_ceil(LANES) * LANES;
        // Padding: a light straight above with no power, which adds 0 and no NaN; its
        // cos θh of -1 keeps it after every light a reach admits.
        let mut data = vec![0f32; FIELDS * padded];
        for i in len..padded {
            data[(HALF + 2) * padded + i] = 1.0;
            data[COS_H * padded + i] = -1.0;
            data[INV_COS_L2 * padded + i] = 1.0;
            data[WIDEN * padded + i] = 1.0;
        }
        for (i, p) in lights.into_iter().enumerate() {
            for k in 0..3 {
                data[(DIR + k) * padded + i] = p.dir[k];
                data[(HALF + k) * padded + i] = p.half[k];
                data[(POWER + k) * padded + i] = p.power[k];
            }
            data[COS_H * padded + i] = p.cos_h;
            data[INV_COS_L2 * padded + i] = 1.0 / (p.cos_l * p.cos_l);
            data[WIDEN * padded + i] = p.widen;
        }
        Lights { len, data }
    }

    fn field(&self, k: usize) -> &[f32] {
        let padded = self.data.len() / FIELDS;
        &self.data[k * padded..(k + 1) * padded]
    }

    /// How many of the (sharpest-first) lights have cos θh ≥ `min_cos_h`.
    fn within(&self, min_cos_h: f32) -> usize {
        self.field(COS_H)[..self.len].partition_point(|c| *c >= min_cos_h)
    }
}

/// A pixel with its lights above the horizon that the object does not hide: the estimate's
/// own near the mirror direction (sharpest first, as far as the lobes followed with them reach) and
/// the merged ones.
struct Sample {
    normal: [f64; 3],
    view: [f64; 3],
    observed: [f64; 3],
    diffuse: [f64; 3],
    fine: Lights,
    coarse: Lights,
}

/// A lobe's shape: the grain's direction and the roughnesses along and across it.
#[derive(Clone, Copy, Debug)]
struct Shape {
    grain: [f64; 3],
    along: f64,
    across: f64,
}

/// The comparison on up to [`PIXELS`] pixels spread over the views' candidates; `None` with
/// too few pixels or no light. A first pass follows only sharp lobes with the estimate's own
/// lights, which is cheap; when it finds the photo may ask for anisotropy, a second pass
/// measures the lobe's shape with them for every roughness that can show it.
pub fn compare(views: &[ViewSamples], stop: &Stop) -> Option<Anisotropy> {
    let fit = Fit::build(views, DETECT_FINE_BELOW, true)?;
    let iso = fit.isotropic(None);
    let aniso = fit.anisotropic(iso.0, COARSE_DIRECTIONS, None);
    if aniso.1 > MAY_ASK * iso.1 || stop.requested() {
        return Some(fit.outcome(iso, aniso));
    }
    let fine = Fit::build(views, MEASURE_FINE_BELOW, true)?;
    let iso = fine.isotropic(Some(iso.0));
    let aniso = fine.anisotropic(iso.0, MEASURE_DIRECTIONS, Some(aniso.0));
    Some(fine.outcome(iso, aniso))
}

/// The best Lambert plus isotropic GGX fit on up to [`PIXELS`] pixels spread over the views'
/// candidates, under the views' lights as they are, already [`merged`] (each widening the
/// lobe by its spread, so a sharp lobe is followed too, if less closely): its α, its misfit
/// and the pixels compared; `None` with too few pixels or no light. [`crate::registration`]
/// compares it under turned lights, many times, which the merged lights keep cheap.
pub(crate) fn isotropic_fit(views: &[ViewSamples]) -> Option<(f64, f64, usize)> {
    let fit = Fit::build(views, 0.0, false)?;
    let (alpha, misfit) = fit.isotropic(None);
    Some((alpha, misfit, fit.samples.len()))
}

impl Fit {
    /// The pixels' samples, with the estimate's lights kept for lobes sharper than
    /// `fine_below`.
    /// The views' lights are merged first when `merge` is set; else they are taken as merged.
    fn build(views: &[ViewSamples], fine_below: f64, merge: bool) -> Option<Fit> {
        let total: usize = views.iter().map(|v| v.pixels.len()).sum();
        let mut samples = Vec::new();
        for v in views.iter().filter(|v| !v.pixels.is_empty()) {
            let share = (PIXELS * v.pixels.len()).div_ceil(total);
            let coarse = if merge {
                merged(v.lights)
            } else {
                v.lights.clone()
            };
            // A fit of the merged lights alone (`fine_below` 0) reads none of the estimate's.
            let seen_fine = (fine_below > 0.0).then(|| Seen::new(v.pixels, v.lights));
            let seen_coarse = Seen::new(v.pixels, &coarse);
            let pick = super::select::spread(v.pixels.len(), share);
            let picked: Vec<Sample> = pick
                .par_iter()
                .filter_map(|&i| {
                    let (px, o) = (&v.pixels[i], v.observed[i]);
                    let seen = seen_coarse.fresh(px);
                    let fine = match &seen_fine {
                        Some(seen) => {
                            pairs(px, v.lights, seen.fresh(px).as_deref(), reach(fine_below))
                        }
                        None => Lights::new(Vec::new()),
                    };
                    let diffuse = lambert(px, &coarse, seen.as_deref());
                    let coarse = pairs(px, &coarse, seen.as_deref(), f64::INFINITY);
                    (o.iter().all(|x| x.is_finite()) && coarse.len > 0).then(|| Sample {
                        normal: px.normal.map(f64::from),
                        view: px.view.map(f64::from),
                        observed: o,
                        diffuse,
                        fine,
                        coarse,
                    })
                })
                .collect();
            samples.extend(picked);
        }
        let fit = Fit::new(samples, fine_below);
        (fit.samples.len() >= MIN_PIXELS && fit.photo_sq > 0.0).then_some(fit)
    }

    /// The best isotropic lobe's α and misfit: from a log-spaced grid (or `start`), refined.
    fn isotropic(&self, start: Option<f64>) -> (f64, f64) {
        let iso = |a: f64| {
            let a = a.clamp(ALPHA_MIN, ALPHA_MAX);
            (
                a,
                self.misfit(Shape {
                    grain: [0.0, 0.0, 1.0],
                    along: a,
                    across: a,
                }),
            )
        };
        let ratio = (ALPHA_MAX / ALPHA_MIN).powf(1.0 / (ISO_ALPHAS - 1) as f64);
        let mut best = match start {
            Some(a) => iso(a),
            None => (0..ISO_ALPHAS)
                .map(|i| iso(ALPHA_MIN * ratio.powi(i as i32)))
                .fold((ALPHA_MIN, f64::INFINITY), better),
        };
        let mut step = ratio.ln() / 2.0;
        for _ in 0..REFINE_ROUNDS {
            best = [-step, step]
                .into_iter()
                .map(|s| iso(best.0 * s.exp()))
                .fold(best, better);
            step /= 2.0;
        }
        best
    }

    /// The best anisotropic lobe and its misfit: every grain direction with the lobe
    /// stretched either way about `iso_alpha` (or `start`), then a pattern search over the
    /// direction and both roughnesses.
    fn anisotropic(&self, iso_alpha: f64, directions: usize, start: Option<Shape>) -> (Shape, f64) {
        let s = (iso_alpha / COARSE_RATIO.sqrt()).max(ALPHA_MIN);
        let r = (iso_alpha * COARSE_RATIO.sqrt()).min(ALPHA_MAX);
        // Grains over the half sphere: a grain and its opposite are one grain.
        let mut best = half_sphere(directions)
            .into_iter()
            .flat_map(|g| {
                [
                    Shape {
                        grain: g,
                        along: s,
                        across: r,
                    },
                    Shape {
                        grain: g,
                        along: r,
                        across: s,
                    },
                ]
            })
            .chain(start)
            // The isotropic lobe itself: the search never ends worse than it.
            .chain([Shape {
                grain: [0.0, 0.0, 1.0],
                along: iso_alpha,
                across: iso_alpha,
            }])
            .map(|sh| (sh, self.misfit(sh)))
            .fold(
                (
                    Shape {
                        grain: [0.0, 0.0, 1.0],
                        along: s,
                        across: r,
                    },
                    f64::INFINITY,
                ),
                better,
            );
        // A compass search: the moves of the current step while one improves, then half
        // the step.
        let (mut turn, mut stretch) = (0.2f64, 0.35f64);
        let (mut halvings, mut moves) = (0, 0);
        while halvings < REFINE_ROUNDS && moves < MAX_MOVES {
            let shape = best.0;
            let (u, w) = tangent_frame(shape.grain);
            let mut tries = Vec::with_capacity(8);
            for sgn in [-1.0, 1.0] {
                for axis in [u, w] {
                    let grain = normalize(add(shape.grain, scale(axis, sgn * turn)));
                    tries.push(Shape { grain, ..shape });
                }
                let k = (sgn * stretch).exp();
                let along = (shape.along * k).clamp(ALPHA_MIN, ALPHA_MAX);
                let across = (shape.across * k).clamp(ALPHA_MIN, ALPHA_MAX);
                tries.push(Shape { along, ..shape });
                tries.push(Shape { across, ..shape });
            }
            let found = tries
                .into_iter()
                .map(|t| (t, self.misfit(t)))
                .fold(best, better);
            if found.1 < best.1 {
                best = found;
                moves += 1;
            } else {
                turn /= 2.0;
                stretch /= 2.0;
                halvings += 1;
            }
        }
        best
    }

    /// The comparison's record, named by the smooth direction.
    fn outcome(
        &self,
        (iso_alpha, iso_misfit): (f64, f64),
        (shape, misfit): (Shape, f64),
    ) -> Anisotropy {
        let smooth_along_axis = shape.along <= shape.across;
        let (diffuse, specular, _) = self.solve(shape);
        Anisotropy {
            isotropic_misfit: iso_misfit,
            isotropic_alpha: iso_alpha,
            anisotropic_misfit: misfit,
            axis: shape.grain,
            smooth_along_axis,
            grain: if smooth_along_axis {
                shape.grain
            } else {
                grain_across(shape.grain, self)
            },
            alpha_along: shape.along.min(shape.across),
            alpha_across: shape.along.max(shape.across),
            pixels: self.samples.len(),
            lobe: AnisotropicLobe {
                diffuse,
                specular,
                axis: shape.grain,
                alpha_t: shape.along,
                alpha_b: shape.across,
            },
            chosen: false,
        }
    }
}

/// The better (lower misfit) of two tries; the first on a tie.
fn better<T>(a: (T, f64), b: (T, f64)) -> (T, f64) {
    if b.1 < a.1 {
        b
    } else {
        a
    }
}

/// When the lobe is rough along the axis g and smooth across it, the smooth direction is
/// n × t, which is not one direction laid on the surface; the one named is n × g where the
/// pixels face on average.
fn grain_across(g: [f64; 3], fit: &Fit) -> [f64; 3] {
    let mean = fit.samples.iter().fold([0.0; 3], |a, s| add(a, s.normal));
    let n = normalize(mean);
    let across = cross(n, g);
    if dot(across, across) > 1e-12 {
        normalize(across)
    } else {
        tangent_frame(g).0
    }
}

/// The pixels' sums the weights are solved from, with the fixed Lambert column's.
struct Fit {
    samples: Vec<Sample>,
    /// Lobes sharper than this (their roughest α) are rendered with the estimate's lights.
    fine_below: f64,
    /// Per channel: Σ d², Σ d·o.
    dd: [f64; 3],
    d_o: [f64; 3],
    photo_sq: f64,
}

impl Fit {
    fn new(samples: Vec<Sample>, fine_below: f64) -> Fit {
        let (mut dd, mut d_o, mut photo_sq) = ([0.0; 3], [0.0; 3], 0.0);
        for s in &samples {
            for c in 0..3 {
                dd[c] += s.diffuse[c] * s.diffuse[c];
                d_o[c] += s.diffuse[c] * s.observed[c];
                photo_sq += s.observed[c] * s.observed[c];
            }
        }
        Fit {
            samples,
            fine_below,
            dd,
            d_o,
            photo_sq,
        }
    }

    /// The relative misfit of Lambert plus a lobe of this shape, with its weights solved.
    fn misfit(&self, shape: Shape) -> f64 {
        let (x, y, sums) = self.solve(shape);
        let explained: f64 = (0..3).map(|c| x[c] * self.d_o[c] + y[c] * sums[2][c]).sum();
        ((self.photo_sq - explained).max(0.0) / self.photo_sq).sqrt()
    }

    /// The weights of Lambert (x) and of a lobe of this shape (y) per channel, with the
    /// lobe's sums Σ s², Σ s·d, Σ s·o.
    fn solve(&self, shape: Shape) -> ([f64; 3], [f64; 3], [[f64; 3]; 3]) {
        // The chunks' sums are added in order, not in rayon's reduce tree, whose shape
        // follows the scheduling: the same photo must give the same figures to the bit,
        // whatever else runs beside.
        let chunks: Vec<[[f64; 3]; 3]> = self
            .samples
            .par_chunks(64)
            .map(|chunk| {
                let mut acc = [[0.0f64; 3]; 3];
                for s in chunk {
                    let spec = specular(s, shape, self.fine_below);
                    for c in 0..3 {
                        acc[0][c] += spec[c] * spec[c];
                        acc[1][c] += spec[c] * s.diffuse[c];
                        acc[2][c] += spec[c] * s.observed[c];
                    }
                }
                acc
            })
            .collect();
        let mut sums = [[0.0f64; 3]; 3];
        for chunk in &chunks {
            for (sum, part) in sums.iter_mut().flatten().zip(chunk.iter().flatten()) {
                *sum += part;
            }
        }
        let (mut x, mut y) = ([0.0; 3], [0.0; 3]);
        for c in 0..3 {
            (x[c], y[c]) = best_pair(self.dd[c], sums[0][c], sums[1][c], self.d_o[c], sums[2][c]);
        }
        (x, y, sums)
    }
}

/// The weights x, y ≥ 0 of x·d + y·s closest to o (least squares), from the sums
/// dd = Σ d², ss = Σ s², ds = Σ d·s, d_o = Σ d·o, s_o = Σ s·o.
fn best_pair(dd: f64, ss: f64, ds: f64, d_o: f64, s_o: f64) -> (f64, f64) {
    let det = dd * ss - ds * ds;
    if det > 1e-12 * dd * ss {
        let x = (ss * d_o - ds * s_o) / det;
        let y = (dd * s_o - ds * d_o) / det;
        if x >= 0.0 && y >= 0.0 {
            return (x, y);
        }
    }
    // One column alone: the one that explains more of Σ o² (ao²/aa).
    let one = |aa: f64, ao: f64| {
        if aa > 0.0 && ao > 0.0 {
            ao / aa
        } else {
            0.0
        }
    };
    let (x, y) = (one(dd, d_o), one(ss, s_o));
    if x * d_o >= y * s_o {
        (x, 0.0)
    } else {
        (0.0, y)
    }
}

/// The unit-weight lobe's radiance at a pixel, per channel: Σ power · D · G₂ / (4 cos θo)
/// (the cosine of the light cancels the BRDF's 1/cos θi). The lights' spread widens D, not
/// the shadowing, which varies slowly with the roughness.
#[inline]
fn specular(s: &Sample, shape: Shape, fine_below: f64) -> [f64; 3] {
    let rough = shape.along.max(shape.across);
    let (lights, count) = if rough < fine_below {
        let tan = reach(rough);
        let min_cos_h = (1.0 / (1.0 + tan * tan).sqrt()) as f32;
        (&s.fine, s.fine.within(min_cos_h))
    } else {
        (&s.coarse, s.coarse.len)
    };
    lobe_radiance(s.normal, s.view, lights, count, shape)
}

/// The unit-weight lobe's radiance at a point of normal `n` seen from `v`, from the first
/// `count` of `lights`.
#[inline]
fn lobe_radiance(
    n: [f64; 3],
    v: [f64; 3],
    lights: &Lights,
    count: usize,
    shape: Shape,
) -> [f64; 3] {
    let (t, b) = frame_at(shape.grain, n);
    let vz = dot(v, n);
    if vz <= 0.0 {
        return [0.0; 3];
    }
    let (at2, ab2) = (shape.along * shape.along, shape.across * shape.across);
    let lambda =
        |x: f64, y: f64, z: f64| ((1.0 + (at2 * x * x + ab2 * y * y) / (z * z)).sqrt() - 1.0) / 2.0;
    let lambda_v = lambda(dot(v, t), dot(v, b), vz);
    let (t, b) = (t.map(|x| x as f32), b.map(|x| x as f32));
    let (at2, ab2, lambda_v) = (at2 as f32, ab2 as f32, lambda_v as f32);
    let f = |k: usize| lights.field(k);
    let (dx, dy, dz) = (f(DIR), f(DIR + 1), f(DIR + 2));
    let (hx, hy, hz) = (f(HALF), f(HALF + 1), f(HALF + 2));
    let (cos_h, inv_cos_l2, widen) = (f(COS_H), f(INV_COS_L2), f(WIDEN));
    let (pr, pg, pb) = (f(POWER), f(POWER + 1), f(POWER + 2));
    let mut acc = [[0f32; LANES]; 3];
    // Lanes past `count` in the last chunk are lights just beyond the reach, or padding of
    // no power: either adds what it should.
    let (t0, t1, t2, b0, b1, b2) = (t[0], t[1], t[2], b[0], b[1], b[2]);
    for base in (0..count.div_ceil(LANES)).map(|c| c * LANES) {
        // Fixed-length views of the chunk: no bounds check inside, so the lanes vectorise.
        let lane = |v: &[f32]| -> [f32; LANES] { v[base..base + LANES].try_into().unwrap() };
        let (dx, dy, dz, hx, hy, hz) = (lane(dx), lane(dy), lane(dz), lane(hx), lane(hy), lane(hz));
        let (cos_h, inv_cos_l2, widen) = (lane(cos_h), lane(inv_cos_l2), lane(widen));
        let (pr, pg, pb) = (lane(pr), lane(pg), lane(pb));
        for j in 0..LANES {
            let (ax2, ay2) = (at2 + widen[j], ab2 + widen[j]);
            let x = hx[j] * t0 + hy[j] * t1 + hz[j] * t2;
            let y = hx[j] * b0 + hy[j] * b1 + hz[j] * b2;
            let k = x * x / ax2 + y * y / ay2 + cos_h[j] * cos_h[j];
            let d = 1.0 / (std::f32::consts::PI * (ax2 * ay2).sqrt() * k * k);
            let lx = dx[j] * t0 + dy[j] * t1 + dz[j] * t2;
            let ly = dx[j] * b0 + dy[j] * b1 + dz[j] * b2;
            let lambda_l =
                ((1.0 + (at2 * lx * lx + ab2 * ly * ly) * inv_cos_l2[j]).sqrt() - 1.0) / 2.0;
            let w = d / (1.0 + lambda_l + lambda_v);
            acc[0][j] += pr[j] * w;
            acc[1][j] += pg[j] * w;
            acc[2][j] += pb[j] * w;
        }
    }
    let out: [f32; 3] = std::array::from_fn(|c| acc[c].iter().sum());
    out.map(|x| x as f64 / (4.0 * vz))
}

/// A chosen lobe's radiance at each pixel under `lights`, in the pixels' order, rendered as
/// the fit renders it: every light the pixel sees, each widening the lobe by its spread. So a
/// map compressed to a few hundred lights shows a sharp highlight as a smooth one, not as
/// the lights' dots; with many lights it tends to [`crate::render::render_anisotropic`]'s
/// point lights (the test `a_widened_lobe_renders_as_point_lights_do` measures how close).
pub fn render_lobe(
    pixels: &[GeomPixel],
    lights: &LightSet,
    lobe: &AnisotropicLobe,
) -> Vec<[f64; 3]> {
    lobe_columns(pixels, lights, lobe)
        .into_iter()
        .map(|(d, s)| std::array::from_fn(|c| lobe.diffuse[c] * d[c] + lobe.specular[c] * s[c]))
        .collect()
}

/// Each pixel's two columns under `lights`: a white Lambert surface's radiance, and the
/// lobe's shape at unit weight, as [`render_lobe`] renders them.
fn lobe_columns(
    pixels: &[GeomPixel],
    lights: &LightSet,
    lobe: &AnisotropicLobe,
) -> Vec<([f64; 3], [f64; 3])> {
    let seen = Seen::new(pixels, lights);
    let shape = Shape {
        grain: lobe.axis,
        along: lobe.alpha_t,
        across: lobe.alpha_b,
    };
    pixels
        .par_iter()
        .map(|px| {
            let row = seen.fresh(px);
            let all = pairs(px, lights, row.as_deref(), f64::INFINITY);
            let (n, v) = (px.normal.map(f64::from), px.view.map(f64::from));
            (
                lambert(px, lights, row.as_deref()),
                lobe_radiance(n, v, &all, all.len, shape),
            )
        })
        .collect()
}

/// The lobe with its weights solved again on every pixel of the views, rendered as
/// [`render_lobe`] renders it (every light, the whole lobe), and its re-render of each pixel
/// (the views' in turn, RGB). The comparison solved them on a spread of the pixels with the
/// lobe followed only as far as 4α and Lambert under the merged lights; relit whole, a
/// rough lobe would carry the tail it was not fitted with.
pub fn refit(views: &[ViewSamples], lobe: &AnisotropicLobe) -> (AnisotropicLobe, Vec<f64>) {
    let columns: Vec<([f64; 3], [f64; 3])> = views
        .iter()
        .flat_map(|v| lobe_columns(v.pixels, v.lights, lobe))
        .collect();
    let observed = views.iter().flat_map(|v| v.observed.iter());
    let mut sums = [[0.0f64; 5]; 3];
    for ((d, s), o) in columns.iter().zip(observed) {
        for c in 0..3 {
            let sum = &mut sums[c];
            sum[0] += d[c] * d[c];
            sum[1] += s[c] * s[c];
            sum[2] += d[c] * s[c];
            sum[3] += d[c] * o[c];
            sum[4] += s[c] * o[c];
        }
    }
    let mut refitted = lobe.clone();
    for (c, [dd, ss, ds, d_o, s_o]) in sums.into_iter().enumerate() {
        (refitted.diffuse[c], refitted.specular[c]) = best_pair(dd, ss, ds, d_o, s_o);
    }
    let predicted = columns
        .iter()
        .flat_map(|(d, s)| {
            let w = &refitted;
            (0..3).map(move |c| w.diffuse[c] * d[c] + w.specular[c] * s[c])
        })
        .collect();
    (refitted, predicted)
}

/// The lights of `lights` above the pixel's horizon that its object lets through and whose
/// half vector is within `tan_h` (tan θh) of its normal, sharpest first.
fn pairs(px: &GeomPixel, lights: &LightSet, seen: Option<&[u64]>, tan_h: f64) -> Lights {
    let (n, v) = (px.normal, px.view);
    let min_cos_h = (1.0 / (1.0 + tan_h * tan_h).sqrt()) as f32;
    // A light whose half vector is within θh of the normal is within 2θh of the view's
    // mirror direction: the cheap test first.
    let cos_2h = 2.0 * min_cos_h * min_cos_h - 1.0;
    let mirror = sub32(mul32(n, 2.0 * dot32(n, v)), v);
    let mut out = Vec::new();
    for i in 0..lights.len() {
        let dir = lights.directions[i];
        let cos_l = dot32(dir, n);
        if cos_l <= 0.0
            || dot32(dir, mirror) < cos_2h
            || seen.is_some_and(|row| !is_seen(row, i as u32))
        {
            continue;
        }
        let hs = [dir[0] + v[0], dir[1] + v[1], dir[2] + v[2]];
        let len = dot32(hs, hs).sqrt();
        if len < 1e-6 {
            continue;
        }
        let half = mul32(hs, 1.0 / len);
        let cos_h = dot32(half, n);
        if cos_h <= 0.0 || cos_h < min_cos_h {
            continue;
        }
        let power = lights.radiance[i].map(|r| r * lights.solid_angle[i]);
        let spread = lights.spread[i];
        // A disc of radius R has a second moment of R²/2; the half vector moves half as
        // far as the light: α² + R²/8.
        let widen = spread * spread / 8.0;
        out.push(Pair {
            dir,
            half,
            cos_h,
            cos_l,
            power,
            widen,
        });
    }
    Lights::new(out)
}

/// The radiance of a white Lambert surface at the pixel, from the lights it sees.
fn lambert(px: &GeomPixel, lights: &LightSet, seen: Option<&[u64]>) -> [f64; 3] {
    let mut out = [0.0; 3];
    for i in 0..lights.len() {
        let cos = dot32(lights.directions[i], px.normal);
        if cos <= 0.0 || seen.is_some_and(|row| !is_seen(row, i as u32)) {
            continue;
        }
        for c in 0..3 {
            out[c] += (lights.radiance[i][c] * lights.solid_angle[i] * cos) as f64;
        }
    }
    out.map(|x| x / std::f64::consts::PI)
}

/// How far from the normal (tan θh) a lobe no rougher than `alpha` is followed: 4α holds 94%
/// of a GGX lobe's projected area (tan²θh/(α² + tan²θh) of it lies within θh).
fn reach(alpha: f64) -> f64 {
    REACH * alpha
}

/// The light set merged onto a [`GRID_U`] × [`GRID_V`] grid of directions ([`merged_onto`]).
pub(crate) fn merged(lights: &LightSet) -> LightSet {
    merged_onto(lights, GRID_U, GRID_V)
}

/// The light set merged onto a `grid_u` × `grid_v` grid of directions (azimuth by polar
/// angle): each cell's power, at its power-weighted mean direction, with the radius of the
/// disc whose second moment is that of its power's directions about that mean as its spread
/// (√(2m₂): `spread` is a disc's radius).
pub(crate) fn merged_onto(lights: &LightSet, grid_u: usize, grid_v: usize) -> LightSet {
    #[derive(Clone, Copy, Default)]
    struct Cell {
        power: [f64; 3],
        weight: f64,
        dir: [f64; 3],
        omega: f64,
        members: u32,
    }
    let cell_of = |d: [f64; 3]| {
        let u = (d[0].atan2(d[2]) / std::f64::consts::TAU + 0.5).clamp(0.0, 0.999_999);
        let v = (d[1].clamp(-1.0, 1.0).acos() / std::f64::consts::PI).clamp(0.0, 0.999_999);
        (v * grid_v as f64) as usize * grid_u + (u * grid_u as f64) as usize
    };
    let weight_of = |p: [f64; 3]| p[0] + p[1] + p[2];
    let mut cells = vec![Cell::default(); grid_u * grid_v];
    let mut members = Vec::with_capacity(lights.len());
    for i in 0..lights.len() {
        let d = lights.directions[i].map(f64::from);
        let omega = lights.solid_angle[i] as f64;
        let p: [f64; 3] = std::array::from_fn(|c| lights.radiance[i][c] as f64 * omega);
        let w = weight_of(p).max(0.0) + 1e-30;
        let k = cell_of(d);
        let cell = &mut cells[k];
        for c in 0..3 {
            cell.power[c] += p[c];
        }
        cell.weight += w;
        cell.dir = add(cell.dir, scale(d, w));
        cell.omega += omega;
        cell.members += 1;
        members.push((k, d, w, lights.spread[i] as f64));
    }
    let dirs: Vec<[f64; 3]> = cells
        .iter()
        .map(|c| {
            if c.members > 0 {
                normalize(c.dir)
            } else {
                [0.0, 1.0, 0.0]
            }
        })
        .collect();
    let mut m2 = vec![0.0f64; cells.len()];
    for (k, d, w, spread) in members {
        let angle = angle_between(d, dirs[k]);
        // A light's own footprint is a disc of radius `spread`: its second moment is r²/2.
        m2[k] += w * (angle * angle + spread * spread / 2.0);
    }
    let mut out = LightSet::default();
    for (k, c) in cells.iter().enumerate().filter(|(_, c)| c.members > 0) {
        out.directions.push(dirs[k].map(|x| x as f32));
        out.radiance
            .push(std::array::from_fn(|ch| (c.power[ch] / c.omega) as f32));
        out.solid_angle.push(c.omega as f32);
        // As a disc's radius, which the field holds: the disc with this second moment.
        out.spread.push((2.0 * m2[k] / c.weight).sqrt() as f32);
    }
    out
}

fn dot32(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn sub32(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn mul32(a: [f32; 3], k: f32) -> [f32; 3] {
    [a[0] * k, a[1] * k, a[2] * k]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::{fibonacci_sphere, sub};

    /// A room of point lights, evenly spread: a dim sky brighter above, and three bright
    /// windows, so that a highlight's shape shows at every part of a sphere.
    fn room(count: usize) -> LightSet {
        let windows: [([f64; 3], f64); 3] = [
            (normalize([0.3, 0.8, 0.5]), 40.0),
            (normalize([-0.7, 0.2, 0.7]), 25.0),
            (normalize([0.6, -0.3, 0.75]), 15.0),
        ];
        let mut set = LightSet::default();
        for d in fibonacci_sphere(count) {
            let window: f64 = windows
                .iter()
                .map(|(w, power)| power * (-(1.0 - dot(d, *w)) / 0.004).exp())
                .sum();
            let sky = 0.2 + 0.3 * d[1].max(0.0);
            set.directions.push(d.map(|x| x as f32));
            set.radiance
                .push([sky + window, sky + 0.9 * window, sky + 0.8 * window].map(|x| x as f32));
            set.solid_angle
                .push((4.0 * std::f64::consts::PI / count as f64) as f32);
            set.spread.push(0.0);
        }
        set
    }

    /// Pixels of a sphere seen straight on (an orthographic camera along +z).
    fn sphere(across: usize) -> Vec<GeomPixel> {
        let mut out = Vec::new();
        for y in 0..across {
            for x in 0..across {
                let u = (x as f64 + 0.5) / across as f64 * 2.0 - 1.0;
                let v = 1.0 - (y as f64 + 0.5) / across as f64 * 2.0;
                let r2 = u * u + v * v;
                if r2 < 0.95 {
                    out.push(GeomPixel {
                        x: x as u32,
                        y: y as u32,
                        normal: [u, v, (1.0 - r2).sqrt()].map(|c| c as f32),
                        view: [0.0, 0.0, 1.0],
                        shadow: None,
                    });
                }
            }
        }
        out
    }

    /// Lambert (albedo 0.2) plus an anisotropic GGX/Smith lobe (weight 0.8, no Fresnel),
    /// written out from its definition: the tangent is the grain laid on the surface. Kept
    /// apart from [`AnisotropicLobe::eval_local`] on purpose, as an independent statement
    /// of the model the fit must find.
    fn photo(
        pixels: &[GeomPixel],
        lights: &LightSet,
        grain: [f64; 3],
        ax: f64,
        ay: f64,
    ) -> Vec<[f64; 3]> {
        pixels
            .iter()
            .map(|p| {
                let n = p.normal.map(f64::from);
                let v = p.view.map(f64::from);
                let t = normalize(sub(grain, scale(n, dot(grain, n))));
                let b = cross(n, t);
                let local = |w: [f64; 3]| [dot(w, t), dot(w, b), dot(w, n)];
                let lambda = |w: [f64; 3]| {
                    ((1.0 + (ax * ax * w[0] * w[0] + ay * ay * w[1] * w[1]) / (w[2] * w[2])).sqrt()
                        - 1.0)
                        / 2.0
                };
                let mut out = [0.0; 3];
                for i in 0..lights.len() {
                    let l = lights.directions[i].map(f64::from);
                    let (ll, vl) = (local(l), local(v));
                    if ll[2] <= 0.0 {
                        continue;
                    }
                    let h = local(normalize(add(l, v)));
                    let k = h[0] * h[0] / (ax * ax) + h[1] * h[1] / (ay * ay) + h[2] * h[2];
                    let d = 1.0 / (std::f64::consts::PI * ax * ay * k * k);
                    let g2 = 1.0 / (1.0 + lambda(ll) + lambda(vl));
                    let f = 0.2 / std::f64::consts::PI + 0.8 * d * g2 / (4.0 * ll[2] * vl[2]);
                    for c in 0..3 {
                        out[c] +=
                            (lights.radiance[i][c] * lights.solid_angle[i]) as f64 * f * ll[2];
                    }
                }
                out
            })
            .collect()
    }

    fn compared(grain: [f64; 3], ax: f64, ay: f64) -> Anisotropy {
        let lights = room(4096);
        let pixels = sphere(64);
        let observed = photo(&pixels, &lights, grain, ax, ay);
        let views = [ViewSamples {
            pixels: &pixels,
            observed: &observed,
            lights: &lights,
        }];
        compare(&views, &Stop::default()).expect("enough pixels")
    }

    #[test]
    fn a_brushed_sphere_s_grain_and_stretch_are_found() {
        // The grain at 30° in the image, tipped 20° toward the camera.
        let truth = normalize([0.866 * 0.94, 0.5 * 0.94, 0.34]);
        let a = compared(truth, 0.06, 0.24);
        assert!(a.misfit_ratio() < 0.25, "{a:?}");
        // Laid on the sphere's front (the normal +z), the grain found and the true one.
        let flat = |g: [f64; 3]| normalize([g[0], g[1], 0.0]);
        let angle = dot(flat(a.grain), flat(truth))
            .abs()
            .min(1.0)
            .acos()
            .to_degrees();
        assert!(angle < 5.0, "grain {angle:.1}° off: {a:?}");
        let stretch = a.stretch() / 4.0;
        assert!(
            (0.8..1.25).contains(&stretch),
            "stretch {:.2} of 4: {a:?}",
            a.stretch()
        );
        // The weights the photo was made with: Lambert 0.2, the lobe 0.8.
        for c in 0..3 {
            assert!((a.lobe.diffuse[c] - 0.2).abs() < 0.03, "{a:?}");
            assert!((a.lobe.specular[c] - 0.8).abs() < 0.08, "{a:?}");
        }
    }

    #[test]
    fn an_isotropic_sphere_is_not_stretched() {
        let a = compared([1.0, 0.0, 0.0], 0.12, 0.12);
        assert!(a.misfit_ratio() > 0.85, "{a:?}");
        assert!(a.misfit_ratio() > 0.97 || a.stretch() < 1.5, "{a:?}");
        assert!(a.isotropic_misfit < 0.05, "{a:?}");
        assert!((0.1..0.14).contains(&a.isotropic_alpha), "{a:?}");
    }
}
