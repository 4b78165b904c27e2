//! The sharp part of a lobe, integrated over the map itself (issue 38).
//!
//! The renderers sum a BRDF over lights, each of which stands for a cell of the map. A lobe
//! narrower than a light's cell sees that cell as a point: a mirror-like material showed the
//! lights as a grid of spots. So a renderer can split the BRDF at a cap about a light's
//! spacing, θh < θc:
//!
//! ```text
//!     f = f′ + (f − f′),   f′ = f with its peak cut flat inside the cap (f at θc, same θd, φd)
//! ```
//!
//! The lights render f′, which varies no faster than they can follow. f − f′ is zero outside
//! the cap, and is integrated per pixel over the map itself: rings of half vectors, each a few
//! θh bins wide, each sample read from a mip pyramid at the level whose texel is the sample's
//! share of the ring (filtered importance sampling, Colbert and Křivánek 2007), bilinearly
//! within the two nearest levels and blended between them. The split is
//! exact (both parts integrate the same map); only the quadrature of each part differs.
//!
//! Every renderer splits so: `render_full` (`brdfd render --gltf`, checked against Mitsuba)
//! at each band's own θh ([`Cap::each_sample`]); the table renderers (the fitting matrix,
//! previews, the simulated photos) once per spoke, with θd and φd read at the ring's middle
//! ([`Cap::each_spoke`]). The rings a lobe holds next to nothing in are left out
//! ([`Cap::pruned_for`]), and a lobe that holds next to nothing in the whole cap is rendered by
//! the lights alone ([`Cap::needed_by`]).

use std::sync::Arc;

use super::bivariate::{ThetaHBinning, N_THETA_H};
use super::envmap::{EnvMap, LightSet};
use super::geometry::GeomPixel;

/// The footprint that sets the lights' spacing: this quantile of their footprints, weighted
/// by power, so that the small lights of a map's bright parts (the ones a mirror shows)
/// decide.
const SPACING_QUANTILE: f64 = 0.9;
/// The cap's radius in θh, in lights' spacings: a light's footprint-smoothed disc of f′ then
/// reaches no sharper a peak than its neighbours' discs overlap. A wider cap leaves less to
/// the lights, but its rings, at a fixed number of samples, read ever coarser levels of the
/// map: measured against Mitsuba 3, a cap of a whole GGX lobe of α 0.1 was worse than this.
const CAP_PER_SPACING: f64 = 0.75;
/// The share of a lobe's light inside the cap, above its value at the cap's edge, below
/// which the lights render it well enough alone ([`Cap::needed_by`]).
const NEEDED: f64 = 0.002;
/// The widest cap, in θh: a very coarse light set would otherwise make the per-pixel part as
/// costly as the lights.
const MAX_CAP: f64 = 0.2;
/// Most samples on one ring of the cap.
const MAX_SPOKES: usize = 8;

/// An equirectangular map as a mip pyramid, in a light set's frame (its yaw).
pub struct SkyMap {
    levels: Vec<EnvMap>,
    yaw: f32,
    /// Solid angle of a level-0 texel at the equator.
    texel_sr: f32,
}

impl std::fmt::Debug for SkyMap {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let base = &self.levels[0];
        write!(
            f,
            "SkyMap({}×{}, {} levels, yaw {})",
            base.width,
            base.height,
            self.levels.len(),
            self.yaw
        )
    }
}

impl PartialEq for SkyMap {
    fn eq(&self, other: &SkyMap) -> bool {
        self.yaw == other.yaw && self.levels[0].pixels == other.levels[0].pixels
    }
}

impl SkyMap {
    /// The pyramid of `map` turned by `yaw` (as [`EnvMap::lights`] turns it): each level the
    /// area-weighted half of the one before, down to a few texels.
    pub fn new(map: &EnvMap, yaw: f64) -> SkyMap {
        let mut levels = vec![map.clone()];
        loop {
            let last = &levels[levels.len() - 1];
            if last.width < 8 || last.height < 4 {
                break;
            }
            let next = last.downsample(last.width / 2, last.height / 2);
            levels.push(next);
        }
        let texel_sr = 2.0 * std::f32::consts::PI * std::f32::consts::PI
            / (map.width as f32 * map.height as f32);
        SkyMap {
            levels,
            yaw: yaw as f32,
            texel_sr,
        }
    }

    /// The map's radiance towards unit `d`, filtered over about `footprint` steradians.
    pub fn radiance(&self, d: [f32; 3], footprint: f32) -> [f32; 3] {
        let (u, v, level) = self.place(d, footprint);
        self.read(u, v, level)
    }

    /// Where [`SkyMap::radiance`] reads: the map's (u, v) in [0, 1) towards unit `d`, and
    /// the (fractional) mip level of a `footprint` steradians wide. Arithmetic alone, so
    /// that [`Cap::each_spoke`] runs it over a ring's spokes in SIMD lanes.
    #[inline(always)]
    fn place(&self, d: [f32; 3], footprint: f32) -> (f32, f32, f32) {
        let pi = std::f32::consts::PI;
        let phi = fast_atan2(d[0], -d[2]);
        let u = fract((phi + self.yaw) / (2.0 * pi) + 0.5);
        let y = d[1].clamp(-1.0, 1.0);
        let v = fast_atan2((1.0 - y * y).max(0.0).sqrt(), y) / pi;
        let top = (self.levels.len() - 1) as f32;
        let level = (0.5 * fast_log2((footprint / self.texel_sr).max(1.0))).min(top);
        (u, v, level)
    }

    /// The map at (u, v) and mip `level` ([`SkyMap::place`]).
    #[inline(always)]
    fn read(&self, u: f32, v: f32, level: f32) -> [f32; 3] {
        // A blend of the two nearest levels, not the nearest alone: that cost a fifth less
        // of the preview's time, but moved the evaluation's relight medians from 0.1092 to
        // 0.1110 (MERL) and from 0.019 to 0.023 (GGX). Not negative: `as` truncates, which is
        // the floor here.
        let l0 = level as usize;
        let t = level - l0 as f32;
        let a = bilinear(&self.levels[l0], u, v);
        if t <= 0.0 {
            return a;
        }
        let b = bilinear(&self.levels[(l0 + 1).min(self.levels.len() - 1)], u, v);
        std::array::from_fn(|c| a[c] + t * (b[c] - a[c]))
    }
}

/// x − ⌊x⌋, in [0, 1), without libm's `fmodf` (what `rem_euclid` calls).
#[inline(always)]
fn fract(x: f32) -> f32 {
    let f = x - (x as i64) as f32;
    if f < 0.0 {
        f + 1.0
    } else if f >= 1.0 {
        0.0
    } else {
        f
    }
}

/// atan2(y, x) in (−π, π] by a polynomial (Abramowitz & Stegun 4.4.49, |error| ≤ 1e-5 rad,
/// a thousandth of a texel of a 4k map): the map lookups are most of the cap's cost, and
/// `atan2` and `acos` were most of theirs.
#[inline(always)]
pub(crate) fn fast_atan2(y: f32, x: f32) -> f32 {
    let (ax, ay) = (x.abs(), y.abs());
    let atan01 = |z: f32| {
        let z2 = z * z;
        z * (0.999_866
            + z2 * (-0.330_299_5 + z2 * (0.180_141 + z2 * (-0.085_133 + z2 * 0.020_835_1))))
    };
    let a = if ax >= ay {
        if ax == 0.0 {
            0.0
        } else {
            atan01(ay / ax)
        }
    } else {
        std::f32::consts::FRAC_PI_2 - atan01(ax / ay)
    };
    let a = if x < 0.0 { std::f32::consts::PI - a } else { a };
    if y < 0.0 {
        -a
    } else {
        a
    }
}

/// log₂ of a positive finite x, to about 0.01: the mip level only needs to be near.
#[inline(always)]
fn fast_log2(x: f32) -> f32 {
    let bits = x.to_bits();
    let exponent = ((bits >> 23) & 0xff) as f32 - 127.0;
    let m = f32::from_bits((bits & 0x007f_ffff) | 0x3f80_0000); // in [1, 2)
                                                                // A quadratic through log₂ at 1, 1.5 and 2.
    exponent + (m - 1.0) * (1.3466 - 0.3466 * (m - 1.0))
}

/// A map read between texel centres: around in u, clamped at the poles.
#[inline(always)]
fn bilinear(map: &EnvMap, u: f32, v: f32) -> [f32; 3] {
    // u in [0, 1), so x ≥ −0.5 and y ≥ 0: truncation and a step back give the floors without
    // libm's `floorf`, a call per lookup in the cap's innermost loop.
    let x = u * map.width as f32 - 0.5;
    let y = (v * map.height as f32 - 0.5).clamp(0.0, (map.height - 1) as f32);
    let x0 = if x < 0.0 { -1.0 } else { (x as i64) as f32 };
    let y0 = (y as usize) as f32;
    let (tx, ty) = (x - x0, y - y0);
    let xa = if x0 < 0.0 {
        map.width - 1
    } else {
        (x0 as usize).min(map.width - 1)
    };
    // Around without `%`, an integer division per lookup.
    let xb = if xa + 1 == map.width { 0 } else { xa + 1 };
    let ya = y0 as usize;
    let yb = (ya + 1).min(map.height - 1);
    let p = |x: usize, y: usize| map.pixels[y * map.width + x];
    let (a, b, c, d) = (p(xa, ya), p(xb, ya), p(xa, yb), p(xb, yb));
    std::array::from_fn(|k| {
        let top = a[k] + tx * (b[k] - a[k]);
        let bottom = c[k] + tx * (d[k] - c[k]);
        top + ty * (bottom - top)
    })
}

/// One bin of a ring: its θh (the middle of its solid angle) and its share of the ring.
#[derive(Clone)]
pub struct Band {
    /// The θh bin (below [`Cap::bins`]).
    pub bin: usize,
    cos: f32,
    sin: f32,
    /// The half-vector solid angle of the bin, per spoke.
    pub share: f32,
}

/// One ring of half vectors: spokes evenly around the cap's normal, each read from the map
/// once at the ring's middle θh, and that light given to each θh bin the ring spans, at the
/// bin's own θh (the map is as good as constant across a ring, f need not be).
#[derive(Clone)]
struct Ring {
    cos: f32,
    sin: f32,
    /// How many spokes the ring has (at most [`MAX_SPOKES`]).
    spokes: usize,
    /// The spokes' directions about the cap's normal, (cos, sin) as two columns padded to
    /// [`MAX_SPOKES`], so that [`SpokeLanes`] reads a whole ring at once.
    spoke_cos: [f32; MAX_SPOKES],
    spoke_sin: [f32; MAX_SPOKES],
    /// The whole ring's half-vector solid angle per spoke: the map's filter.
    share: f32,
    bands: Vec<Band>,
}

/// The cap of a light set: its θh bins, and the rings that integrate them over the map.
pub struct Cap {
    /// Bins `0..bins` are the cap; f′ takes bin `bins`' value there.
    pub bins: usize,
    binning: ThetaHBinning,
    rings: Vec<Ring>,
    map: Arc<SkyMap>,
}

/// One sample of the cap for one pixel.
pub struct CapSample {
    /// The incoming direction ωi (unit, world frame).
    pub dir: [f32; 3],
    /// The half vector.
    pub h: [f32; 3],
    /// The θh bin (below [`Cap::bins`]).
    pub bh: usize,
    /// The map's radiance × n·ωi × the sample's solid angle, per channel.
    pub weight: [f32; 3],
}

/// One spoke of a ring for one pixel, as the table renderers take it: the direction, half
/// vector, cosine and light at the ring's middle θh, and the bins the ring spans. A table's
/// cell differs across a ring only in θh; its θd and φd move by less than the ring is wide
/// (a degree or two), so they are read once per spoke, and the bins take their own θh.
pub struct Spoke<'a> {
    /// The ring's index, for [`Cap::ring_sums`].
    pub ring: usize,
    /// The incoming direction ωi at the ring's middle (unit, world frame).
    pub dir: [f32; 3],
    /// The half vector there.
    pub h: [f32; 3],
    /// The map's radiance × n·ωi × 4 (h·v) (dωi per unit of half-vector solid angle), per
    /// channel: times a band's share it is that band's weight.
    pub weight: [f32; 3],
    pub bands: &'a [Band],
}

impl Cap {
    /// The cap for `lights` on `binning`'s θh bins, or `None` for a set made without a map
    /// (a few lights placed by hand), whose lights are all there is.
    ///
    /// Its samples are about square: a ring spans as many θh bins as it takes to be as wide
    /// as its spokes are apart, and never narrower than a texel of the map. MERL's bins are
    /// far finer than a map near the peak, and a ring per bin cost the preview 2.7 s.
    pub fn of(lights: &LightSet, binning: ThetaHBinning) -> Option<Cap> {
        let map = lights.map.clone()?;
        let theta_c = CAP_PER_SPACING * light_spacing(lights);
        let bins = (1..N_THETA_H)
            .find(|b| binning.lower_edge(*b) >= theta_c.min(MAX_CAP))
            .unwrap_or(N_THETA_H - 1);
        let texel = 2.0 * std::f64::consts::PI / map.levels[0].width as f64;
        let tau = 2.0 * std::f64::consts::PI;
        let mut rings = Vec::new();
        let mut first = 0;
        while first < bins {
            let lo = binning.lower_edge(first);
            // In ωi a ring has twice the half vector's radius and width.
            let mut last = first + 1;
            while last < bins {
                let hi = binning.lower_edge(last);
                let mid = ((lo * lo + hi * hi) / 2.0).sqrt();
                let apart = (2.0 * tau * mid.sin() / MAX_SPOKES as f64).max(texel);
                if 2.0 * (hi - lo) >= apart {
                    break;
                }
                last += 1;
            }
            let hi = binning.lower_edge(last);
            let theta = ((lo * lo + hi * hi) / 2.0).sqrt();
            let spacing = (2.0 * (hi - lo)).max(texel);
            let spokes = ((2.0 * tau * theta.sin() / spacing).ceil() as usize).clamp(1, MAX_SPOKES);
            // A phase per ring, so that spokes of neighbouring rings do not line up.
            let phase = (rings.len() as f64 * 0.618_034).fract();
            let bands = (first..last)
                .map(|bin| {
                    let (a, b) = (binning.lower_edge(bin), binning.lower_edge(bin + 1));
                    let mid = ((a * a + b * b) / 2.0).sqrt();
                    Band {
                        bin,
                        cos: mid.cos() as f32,
                        sin: mid.sin() as f32,
                        share: (tau * (a.cos() - b.cos()) / spokes as f64) as f32,
                    }
                })
                .collect();
            let (mut spoke_cos, mut spoke_sin) = ([0.0; MAX_SPOKES], [0.0; MAX_SPOKES]);
            for k in 0..spokes {
                let a = tau * (k as f64 + phase) / spokes as f64;
                (spoke_cos[k], spoke_sin[k]) = (a.cos() as f32, a.sin() as f32);
            }
            rings.push(Ring {
                cos: theta.cos() as f32,
                sin: theta.sin() as f32,
                spokes,
                spoke_cos,
                spoke_sin,
                share: (tau * (lo.cos() - hi.cos()) / spokes as f64) as f32,
                bands,
            });
            first = last;
        }
        Some(Cap {
            bins,
            binning,
            rings,
            map,
        })
    }

    /// Whether any of bivariate `columns` (channel-planar, as
    /// [`crate::bivariate::Bivariate::values`]) has a peak inside the cap worth its cost:
    /// what the cap holds of f − f′, against all of f, weighted by each θh bin's solid angle,
    /// is above 0.2% (`NEEDED`) in some θd column up to 80°. A broad lobe's render then costs
    /// what it did.
    pub fn needed_by(&self, columns: &[&[f64]]) -> bool {
        let areas = self.areas();
        columns.iter().any(|col| {
            any_theta_d_column(col, |f| {
                let edge = f(self.bins);
                let peak: f64 = (0..self.bins)
                    .map(|ih| (f(ih) - edge).abs() * areas[ih])
                    .sum();
                let all: f64 = (0..N_THETA_H).map(|ih| f(ih).abs() * areas[ih]).sum();
                peak > NEEDED * all
            })
        })
    }

    /// The cap without the rings that hold next to nothing of `columns`' peaks: each ring's
    /// largest share of a θd column's light (as [`Cap::needed_by`] weighs them), and the
    /// least of them left out while together they stay below `NEEDED`. A lobe that needs the
    /// cap but is wider than its middle (a metallic paint under the preview's 512 lights)
    /// left a third of its samples reading the map for less than 0.1% of its light.
    pub fn pruned_for(&self, columns: &[&[f64]]) -> Cap {
        let areas = self.areas();
        let mut shares = vec![0f64; self.rings.len()];
        for col in columns {
            any_theta_d_column(col, |f| {
                let edge = f(self.bins);
                let all: f64 = (0..N_THETA_H).map(|ih| f(ih).abs() * areas[ih]).sum();
                for (ring, share) in self.rings.iter().zip(shares.iter_mut()) {
                    let peak: f64 = ring
                        .bands
                        .iter()
                        .map(|band| (f(band.bin) - edge) * areas[band.bin])
                        .sum();
                    *share = share.max(peak.abs() / all.max(f64::MIN_POSITIVE));
                }
                false
            });
        }
        let mut order: Vec<usize> = (0..self.rings.len()).collect();
        order.sort_by(|a, b| shares[*a].total_cmp(&shares[*b]));
        let mut left_out = vec![false; self.rings.len()];
        let mut dropped = 0.0;
        for r in order {
            dropped += shares[r];
            if dropped >= NEEDED {
                break;
            }
            left_out[r] = true;
        }
        Cap {
            bins: self.bins,
            binning: self.binning,
            rings: self
                .rings
                .iter()
                .zip(&left_out)
                .filter(|(_, out)| !**out)
                .map(|(ring, _)| ring.clone())
                .collect(),
            map: self.map.clone(),
        }
    }

    /// Each θh bin's solid angle over 2π (the cap's rings span whole bins).
    fn areas(&self) -> Vec<f64> {
        (0..N_THETA_H)
            .map(|ih| {
                let hi = if ih + 1 < N_THETA_H {
                    self.binning.lower_edge(ih + 1)
                } else {
                    std::f64::consts::FRAC_PI_2
                };
                self.binning.lower_edge(ih).cos() - hi.cos()
            })
            .collect()
    }

    /// How many rings the cap has.
    pub fn rings(&self) -> usize {
        self.rings.len()
    }

    /// A bivariate vector's peak above its cap edge, f − f′, summed over each ring's bands
    /// with their shares: `sums[(ring·N_THETA_D + θd bin)·3 + channel]`. A spoke reads θd once
    /// for all its ring's bands, so times the spoke's weight this is its whole share of the
    /// cap, one read where the bands took one each (a third of the sharp preview's time).
    pub fn ring_sums(&self, values: &[f64]) -> Vec<f32> {
        use super::bivariate::{GRID_CELLS, N_THETA_D};
        let mut sums = vec![0f32; self.rings.len() * N_THETA_D * 3];
        for (r, ring) in self.rings.iter().enumerate() {
            for jd in 0..N_THETA_D {
                for c in 0..3 {
                    let f = |ih: usize| values[c * GRID_CELLS + ih * N_THETA_D + jd];
                    let edge = f(self.bins);
                    sums[(r * N_THETA_D + jd) * 3 + c] =
                        ring.bands
                            .iter()
                            .map(|band| (f(band.bin) - edge) * band.share as f64)
                            .sum::<f64>() as f32;
                }
            }
        }
        sums
    }

    /// The cap's edge θc: the lower edge of bin [`Cap::bins`].
    pub fn edge(&self, binning: ThetaHBinning) -> f64 {
        binning.lower_edge(self.bins)
    }

    /// How many map samples one pixel takes.
    pub fn samples(&self) -> usize {
        self.rings.iter().map(|r| r.spokes).sum()
    }

    /// The cap's spokes for a pixel (normal n, view v), those above its horizon: what the
    /// table renderers read ([`Spoke`]).
    #[inline]
    pub fn each_spoke(&self, px: &GeomPixel, mut f: impl FnMut(&Spoke)) {
        let (n, v) = (px.normal, px.view);
        let (t, b) = frame(n);
        let mut lanes = SpokeLanes::default();
        for (index, ring) in self.rings.iter().enumerate() {
            lanes.compute(ring, &self.map, [n, v, t, b]);
            for k in 0..ring.spokes {
                let (hv, cos) = (lanes.hv[k], lanes.cos[k]);
                if hv <= 0.0 || cos <= 0.0 {
                    continue;
                }
                let l = self.map.read(lanes.u[k], lanes.v[k], lanes.level[k]);
                f(&Spoke {
                    ring: index,
                    dir: lanes.dir.map(|d| d[k]),
                    h: lanes.h.map(|h| h[k]),
                    weight: l.map(|x| x * cos * 4.0 * hv),
                    bands: &ring.bands,
                });
            }
        }
    }

    /// The cap's samples for a pixel (normal n, view v), those above its horizon, each band
    /// of a ring at its own θh: what the renderer that evaluates a BRDF itself reads.
    #[inline]
    pub fn each_sample(&self, px: &GeomPixel, mut f: impl FnMut(CapSample)) {
        let (n, v) = (px.normal, px.view);
        let (t, b) = frame(n);
        for ring in &self.rings {
            for k in 0..ring.spokes {
                let (c, s) = (ring.spoke_cos[k], ring.spoke_sin[k]);
                let toward: [f32; 3] = std::array::from_fn(|k| c * t[k] + s * b[k]);
                let reflect = |cos: f32, sin: f32| {
                    let h: [f32; 3] = std::array::from_fn(|k| cos * n[k] + sin * toward[k]);
                    let hv = dot(h, v);
                    let dir: [f32; 3] = std::array::from_fn(|k| 2.0 * hv * h[k] - v[k]);
                    (h, hv, dir)
                };
                let (_, hv, dir) = reflect(ring.cos, ring.sin);
                if hv <= 0.0 {
                    continue;
                }
                // dωi = 4 (h·v) dωh.
                let l = self.map.radiance(dir, 4.0 * hv * ring.share);
                for band in &ring.bands {
                    let (h, hv, dir) = reflect(band.cos, band.sin);
                    let cos = dot(n, dir);
                    if hv <= 0.0 || cos <= 0.0 {
                        continue;
                    }
                    let solid_angle = 4.0 * hv * band.share;
                    f(CapSample {
                        dir,
                        h,
                        bh: band.bin,
                        weight: l.map(|x| x * cos * solid_angle),
                    });
                }
            }
        }
    }
}

/// One ring's spokes at one pixel, a column per quantity: the half vector, ωi, h·v, n·ωi and
/// where the map is read. The spokes of a ring are as many as an AVX2 register holds
/// ([`MAX_SPOKES`]), and this is arithmetic alone, so the compiler works out a ring at once;
/// the map's texels are then read spoke by spoke. The same operations as one spoke at a time
/// (no FMA), so the same numbers to the bit; padding lanes are computed and never read.
#[derive(Default)]
struct SpokeLanes {
    h: [[f32; MAX_SPOKES]; 3],
    dir: [[f32; MAX_SPOKES]; 3],
    hv: [f32; MAX_SPOKES],
    cos: [f32; MAX_SPOKES],
    u: [f32; MAX_SPOKES],
    v: [f32; MAX_SPOKES],
    level: [f32; MAX_SPOKES],
}

impl SpokeLanes {
    /// `ring`'s spokes for a pixel with normal n, view v and tangent frame (t, b), given as
    /// `[n, v, t, b]`.
    #[inline(always)]
    fn compute(&mut self, ring: &Ring, map: &SkyMap, frame: [[f32; 3]; 4]) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2, checked just above.
            return unsafe { self.compute_avx2(ring, map, frame) };
        }
        self.compute_lanes(ring, map, frame)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn compute_avx2(&mut self, ring: &Ring, map: &SkyMap, frame: [[f32; 3]; 4]) {
        self.compute_lanes(ring, map, frame)
    }

    #[inline(always)]
    fn compute_lanes(&mut self, ring: &Ring, map: &SkyMap, [n, v, t, b]: [[f32; 3]; 4]) {
        for k in 0..MAX_SPOKES {
            let (c, s) = (ring.spoke_cos[k], ring.spoke_sin[k]);
            let h: [f32; 3] =
                std::array::from_fn(|i| ring.cos * n[i] + ring.sin * (c * t[i] + s * b[i]));
            let hv = dot(h, v);
            let dir: [f32; 3] = std::array::from_fn(|i| 2.0 * hv * h[i] - v[i]);
            // dωi = 4 (h·v) dωh.
            let (u, tex_v, level) = map.place(dir, 4.0 * hv * ring.share);
            for i in 0..3 {
                self.h[i][k] = h[i];
                self.dir[i][k] = dir[i];
            }
            self.hv[k] = hv;
            self.cos[k] = dot(n, dir);
            (self.u[k], self.v[k], self.level[k]) = (u, tex_v, level);
        }
    }
}

/// Whether `test` holds for any θd column up to 80° of any channel of bivariate `values`
/// (channel-planar), given that column's f by θh bin. Beyond 80° a column is grazing light
/// the renders weigh by almost nothing.
fn any_theta_d_column(values: &[f64], mut test: impl FnMut(&dyn Fn(usize) -> f64) -> bool) -> bool {
    use super::bivariate::{GRID_CELLS, N_THETA_D};
    (0..3).any(|c| {
        let plane = &values[c * GRID_CELLS..(c + 1) * GRID_CELLS];
        (0..N_THETA_D * 8 / 9).any(|jd| test(&|ih: usize| plane[ih * N_THETA_D + jd]))
    })
}

/// How far apart a set's lights are, in θh: a light of angular radius R moves the half
/// vector over R/2, and neighbours are about 2R apart. The radius is the [`SPACING_QUANTILE`]
/// of the lights' spreads, weighted by power.
fn light_spacing(lights: &LightSet) -> f64 {
    let mut by_size: Vec<(f64, f64)> = (0..lights.len())
        .map(|i| {
            let spread = lights.spread.get(i).map_or_else(
                || (lights.solid_angle[i] as f64 / std::f64::consts::PI).sqrt(),
                |s| *s as f64,
            );
            let l = lights.radiance[i];
            let power = (l[0] + l[1] + l[2]) as f64 * lights.solid_angle[i] as f64;
            (spread, power.max(0.0))
        })
        .collect();
    by_size.sort_by(|a, b| a.0.total_cmp(&b.0));
    let total: f64 = by_size.iter().map(|(_, p)| p).sum();
    let mut seen = 0.0;
    for (radius, power) in &by_size {
        seen += power;
        if seen >= SPACING_QUANTILE * total {
            return *radius;
        }
    }
    by_size.last().map_or(0.0, |(radius, _)| *radius)
}

/// Any tangent frame about unit `n`.
fn frame(n: [f32; 3]) -> ([f32; 3], [f32; 3]) {
    let helper = if n[1].abs() < 0.9 {
        [0.0, 1.0, 0.0]
    } else {
        [1.0, 0.0, 0.0]
    };
    let t = normalize(cross(helper, n));
    (t, cross(n, t))
}

#[inline(always)]
fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn normalize(a: [f32; 3]) -> [f32; 3] {
    let l = dot(a, a).sqrt();
    a.map(|x| x / l)
}

/// The directions (wi, wo) moved to the cap's edge: the same θd and φd, and the same φh,
/// with θh = `theta_c`; `None` when θh is already at or beyond it. Local frame, normal +Z.
/// This is where f′ reads f for a BRDF given as a function of directions.
pub fn to_cap_edge(wi: [f64; 3], wo: [f64; 3], theta_c: f64) -> Option<([f64; 3], [f64; 3])> {
    let hs = [wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2]];
    let len = (hs[0] * hs[0] + hs[1] * hs[1] + hs[2] * hs[2]).sqrt();
    if len < 1e-12 {
        return None;
    }
    let h = hs.map(|c| c / len);
    let theta_h = h[2].clamp(-1.0, 1.0).acos();
    if theta_h >= theta_c {
        return None;
    }
    let phi_h = h[1].atan2(h[0]);
    // wi in the half vector's frame: rotate by −φh about z, then by −θh about y.
    let rot_z = |d: [f64; 3], a: f64| {
        let (s, c) = a.sin_cos();
        [c * d[0] - s * d[1], s * d[0] + c * d[1], d[2]]
    };
    let rot_y = |d: [f64; 3], a: f64| {
        let (s, c) = a.sin_cos();
        [c * d[0] + s * d[2], d[1], -s * d[0] + c * d[2]]
    };
    let back = |d: [f64; 3]| rot_z(rot_y(rot_y(rot_z(d, -phi_h), -theta_h), theta_c), phi_h);
    Some((back(wi), back(wo)))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn uniform_map(value: f32, width: usize, height: usize) -> EnvMap {
        EnvMap {
            width,
            height,
            pixels: vec![[value; 3]; width * height],
            clamped_negatives: 0,
        }
    }

    #[test]
    fn a_uniform_map_reads_the_same_at_every_level_and_place() {
        let sky = SkyMap::new(&uniform_map(2.5, 64, 32), 0.3);
        for d in [[0.0, 1.0, 0.0], [0.6, 0.0, 0.8], [0.0, -1.0, 0.0]] {
            for footprint in [1e-6, 1e-3, 0.1, 10.0] {
                let l = sky.radiance(d, footprint);
                assert!(l.iter().all(|x| (x - 2.5).abs() < 1e-5), "{l:?}");
            }
        }
    }

    #[test]
    fn the_map_is_read_where_its_lights_point() {
        // One bright texel: the light set says where it is, and the map must agree.
        let mut map = uniform_map(0.0, 32, 16);
        map.pixels[5 * 32 + 20] = [1.0, 2.0, 3.0];
        let yaw = 0.7;
        let lights = map.lights(yaw);
        let sky = SkyMap::new(&map, yaw);
        let i = 5 * 32 + 20;
        let at = sky.radiance(lights.directions[i], 1e-9);
        assert!((at[2] - 3.0).abs() < 1e-3, "{at:?}");
        let beside = sky.radiance(lights.directions[i + 2], 1e-9);
        assert_eq!(beside, [0.0; 3]);
    }

    #[test]
    fn the_fast_functions_are_near_the_exact_ones() {
        for i in 0..2000 {
            let a = i as f32 / 2000.0 * std::f32::consts::TAU - std::f32::consts::PI + 1e-4;
            let (y, x) = (a.sin() * 3.0, a.cos() * 3.0);
            assert!((fast_atan2(y, x) - y.atan2(x)).abs() < 2e-5, "{a}");
        }
        for x in [1.0f32, 1.3, 2.0, 7.7, 1e3, 3e7] {
            assert!((fast_log2(x) - x.log2()).abs() < 0.02, "{x}");
        }
    }

    /// A ring's spokes worked out in lanes give each spoke what it gets worked out alone: the
    /// same direction, half vector and light to the bit, and the same spokes left out below
    /// the horizon, at pixels facing every way.
    #[test]
    fn the_spokes_in_lanes_are_the_spokes_one_by_one() {
        let (w, h) = (64, 32);
        let pixels: Vec<[f32; 3]> = (0..w * h)
            .map(|i| {
                [
                    (i % 7) as f32 + 0.5,
                    (i % 11) as f32 * 0.3,
                    (i % 5) as f32 + 1.0,
                ]
            })
            .collect();
        let lights = EnvMap::from_pixels(w, h, pixels, "test map")
            .unwrap()
            .lights(0.4);
        let cap = Cap::of(&lights, ThetaHBinning::Sqrt).expect("a map's cap");
        let mut compared = 0;
        for i in 0..400 {
            let (a, z) = (i as f32 * 2.399_963, 1.0 - 2.0 * (i as f32 + 0.5) / 400.0);
            let r = (1.0 - z * z).sqrt();
            let normal = [r * a.cos(), z, r * a.sin()];
            let view = normalize([0.2, 0.1 * z, 1.0]);
            let px = GeomPixel {
                x: 0,
                y: 0,
                normal,
                view,
                shadow: None,
            };
            let mut expected = Vec::new();
            let (t, b) = frame(normal);
            for (index, ring) in cap.rings.iter().enumerate() {
                for (c, s) in ring.spoke_cos.iter().zip(&ring.spoke_sin).take(ring.spokes) {
                    let h: [f32; 3] = std::array::from_fn(|k| {
                        ring.cos * normal[k] + ring.sin * (c * t[k] + s * b[k])
                    });
                    let hv = dot(h, view);
                    let dir: [f32; 3] = std::array::from_fn(|k| 2.0 * hv * h[k] - view[k]);
                    let cos = dot(normal, dir);
                    if hv <= 0.0 || cos <= 0.0 {
                        continue;
                    }
                    let l = cap.map.radiance(dir, 4.0 * hv * ring.share);
                    expected.push((index, dir, h, l.map(|x| x * cos * 4.0 * hv)));
                }
            }
            let mut got = Vec::new();
            cap.each_spoke(&px, |s| got.push((s.ring, s.dir, s.h, s.weight)));
            assert_eq!(got, expected, "pixel {i}");
            compared += got.len();
        }
        assert!(compared > 500, "only {compared} spokes compared");
    }

    #[test]
    fn the_cap_edge_keeps_theta_d_and_phi_d() {
        let wi = [0.05f64, 0.02, 1.0];
        let wo = [-0.03f64, -0.01, 1.0];
        let norm = |d: [f64; 3]| {
            let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            d.map(|c| c / l)
        };
        let (wi, wo) = (norm(wi), norm(wo));
        let (a, b) = to_cap_edge(wi, wo, 0.1).expect("inside the cap");
        let h = norm([a[0] + b[0], a[1] + b[1], a[2] + b[2]]);
        assert!((h[2].acos() - 0.1).abs() < 1e-9);
        let dot = |x: [f64; 3], y: [f64; 3]| x[0] * y[0] + x[1] * y[1] + x[2] * y[2];
        let h0 = norm([wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2]]);
        assert!((dot(a, h) - dot(wi, h0)).abs() < 1e-12, "θd kept");
        assert!(to_cap_edge(wi, wo, 0.001).is_none());
    }
}
