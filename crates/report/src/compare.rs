//! `compare.png`: the photo beside the estimate re-rendered under the same light, and their
//! signed difference. One glance shows whether the estimate looks like the material, and
//! where it does not (a missed highlight, a wrong tint), which the fit's one number hides.
//!
//! ```text
//! [ photo | estimate | error ]
//!                      ▔▔▔▔▔ colour bar: blue −25% … white 0 … red +25%
//! ```
//!
//! The photo and the estimate share one exposure (the photo's), so a brightness difference is
//! the estimate's. The error is the luminance difference (estimate − photo) per pixel, as a
//! fraction of the photo's RMS luminance over the pixels compared, on a fixed scale of ±25%.
//! Pixels the estimate was not compared on (background, clipped highlights) are black in
//! the estimate and error panels.

use std::path::Path;

use image::{Rgb, RgbImage};

use brdfd_core::error::{CoreError, Result};
use brdfd_core::estimate::Rerendered;
use brdfd_core::raster::{linear_to_srgb, Raster};

/// Longest side of one panel; larger photos are averaged down by a whole factor.
pub const PANEL_MAX: usize = 512;
/// The error a full blue or red stands for, as a fraction of the photo's RMS luminance.
pub const ERROR_SCALE: f32 = 0.25;
/// Pixels between panels, and the colour bar's height.
const GAP: u32 = 4;
const BAR: u32 = 8;

pub(crate) fn luminance(p: [f32; 3]) -> f32 {
    p[0] * 0.2126 + p[1] * 0.7152 + p[2] * 0.0722
}

/// A panel being averaged down: a sum and a count per output pixel.
struct Panel {
    width: usize,
    height: usize,
    factor: usize,
    sum: Vec<[f32; 3]>,
    count: Vec<u32>,
}

impl Panel {
    fn new(width: usize, height: usize, factor: usize) -> Panel {
        let (w, h) = (width.div_ceil(factor), height.div_ceil(factor));
        Panel {
            width: w,
            height: h,
            factor,
            sum: vec![[0.0; 3]; w * h],
            count: vec![0; w * h],
        }
    }

    fn add(&mut self, x: usize, y: usize, v: [f32; 3]) {
        let i = (y / self.factor) * self.width + x / self.factor;
        for c in 0..3 {
            self.sum[i][c] += v[c];
        }
        self.count[i] += 1;
    }

    /// [`Panel::add`] for a whole row of the image, `factor` pixels at a time: a photo of
    /// 16 megapixels took a fifth of a second pixel by pixel. The sums round as
    /// [`Panel::add`]'s do, in the same order.
    fn add_row(&mut self, y: usize, row: &[[f32; 3]]) {
        let start = (y / self.factor) * self.width;
        let cells = self.sum[start..start + self.width]
            .iter_mut()
            .zip(&mut self.count[start..start + self.width]);
        for ((sum, count), block) in cells.zip(row.chunks(self.factor)) {
            for v in block {
                for c in 0..3 {
                    sum[c] += v[c];
                }
            }
            *count += block.len() as u32;
        }
    }

    /// The averages; `None` where nothing was added. A lone empty pixel between two filled
    /// ones on its row (a candidate left out by the spread, not a region) takes their mean.
    fn averages(&self) -> Vec<Option<[f32; 3]>> {
        let mean =
            |i: usize| (self.count[i] > 0).then(|| self.sum[i].map(|s| s / self.count[i] as f32));
        let mut out: Vec<Option<[f32; 3]>> = (0..self.sum.len()).map(mean).collect();
        for y in 0..self.height {
            for x in 1..self.width.saturating_sub(1) {
                let i = y * self.width + x;
                if let (None, Some(l), Some(r)) = (mean(i), mean(i - 1), mean(i + 1)) {
                    out[i] = Some(std::array::from_fn(|c| 0.5 * (l[c] + r[c])));
                }
            }
        }
        out
    }
}

/// The diverging colour of a signed error `e` in [−1, 1]: blue, white at 0, red.
fn diverging(e: f32) -> [f32; 3] {
    let e = e.clamp(-1.0, 1.0);
    if e >= 0.0 {
        [1.0, 1.0 - e, 1.0 - e]
    } else {
        [1.0 + e, 1.0 + e, 1.0]
    }
}

fn srgb8(v: [f32; 3]) -> Rgb<u8> {
    Rgb(v.map(|x| (linear_to_srgb(x.clamp(0.0, 1.0)) * 255.0 + 0.5) as u8))
}

/// The comparison picture of view `view`: its photo, the estimate's re-render of the
/// candidates (`rerender`), and the signed error with its colour bar.
pub fn picture(photo: &Raster, rerender: &[Rerendered], view: usize) -> RgbImage {
    let factor = photo.width.max(photo.height).div_ceil(PANEL_MAX).max(1);
    let mut shot = Panel::new(photo.width, photo.height, factor);
    // At least 1: a photo no pixel wide has no rows to add, and `chunks` takes no 0.
    for (y, row) in photo.pixels.chunks(photo.width.max(1)).enumerate() {
        shot.add_row(y, row);
    }
    let mut estimate = Panel::new(photo.width, photo.height, factor);
    let mut observed = Panel::new(photo.width, photo.height, factor);
    let mut sum_sq = 0.0f64;
    let mut n = 0usize;
    for r in rerender.iter().filter(|r| r.view == view) {
        let (x, y) = (r.x as usize, r.y as usize);
        if x >= photo.width || y >= photo.height {
            continue;
        }
        estimate.add(x, y, r.predicted);
        observed.add(x, y, r.observed);
        sum_sq += (luminance(r.observed) as f64).powi(2);
        n += 1;
    }
    let rms = ((sum_sq / n.max(1) as f64).sqrt() as f32).max(f32::MIN_POSITIVE);
    let exposure = photo.auto_exposure();

    let (w, h) = (shot.width as u32, shot.height as u32);
    let mut img = RgbImage::from_pixel(3 * w + 2 * GAP, h + GAP + BAR, Rgb([40, 40, 40]));
    let shot = shot.averages();
    let estimate = estimate.averages();
    let observed = observed.averages();
    for y in 0..h {
        for x in 0..w {
            let i = (y * w + x) as usize;
            let black = Rgb([0, 0, 0]);
            let p = shot[i].map_or(black, |v| srgb8(v.map(|c| c * exposure)));
            img.put_pixel(x, y, p);
            let e = estimate[i].map_or(black, |v| srgb8(v.map(|c| c * exposure)));
            img.put_pixel(w + GAP + x, y, e);
            let d = match (estimate[i], observed[i]) {
                (Some(e), Some(o)) => {
                    srgb8(diverging((luminance(e) - luminance(o)) / rms / ERROR_SCALE))
                }
                _ => black,
            };
            img.put_pixel(2 * (w + GAP) + x, y, d);
        }
    }
    for x in 0..w {
        let e = 2.0 * x as f32 / (w.max(2) - 1) as f32 - 1.0;
        for y in h + GAP..h + GAP + BAR {
            img.put_pixel(2 * (w + GAP) + x, y, srgb8(diverging(e)));
        }
    }
    img
}

/// Marks `points` (photo coordinates: the chosen pixels) with small green squares on the
/// photo and estimate panels of a [`picture`] of `photo`.
pub fn mark(img: &mut RgbImage, photo: &Raster, points: &[(u32, u32)]) {
    let factor = photo.width.max(photo.height).div_ceil(PANEL_MAX).max(1) as u32;
    let w = photo.width.div_ceil(factor as usize) as u32;
    let h = photo.height.div_ceil(factor as usize) as u32;
    for &(x, y) in points {
        let (cx, cy) = (x / factor, y / factor);
        for panel in [0, w + GAP] {
            for d in -3i32..=3 {
                for (dx, dy) in [(d, -3), (d, 3), (-3, d), (3, d)] {
                    let (px, py) = (cx as i32 + dx, cy as i32 + dy);
                    if px >= 0 && py >= 0 && (px as u32) < w && (py as u32) < h {
                        img.put_pixel(panel + px as u32, py as u32, Rgb([0, 230, 0]));
                    }
                }
            }
        }
    }
}

/// Writes [`picture`] of the first view to `path`.
pub fn write(path: &Path, photo: &Raster, rerender: &[Rerendered]) -> Result<()> {
    picture(photo, rerender, 0)
        .save(path)
        .map_err(|e| CoreError::format(path.display(), format!("could not write PNG: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_row_added_at_once_sums_as_its_pixels_one_by_one() {
        // 1100 across, in blocks of 3: the last block of each row holds two pixels.
        let (w, h, factor) = (1100, 4, 3);
        let pixel = |x: usize, y: usize| [(x * 7 + y) as f32 * 0.1, x as f32, 1.0 / (1 + y) as f32];
        let (mut by_row, mut by_pixel) = (Panel::new(w, h, factor), Panel::new(w, h, factor));
        for y in 0..h {
            let row: Vec<[f32; 3]> = (0..w).map(|x| pixel(x, y)).collect();
            by_row.add_row(y, &row);
            for x in 0..w {
                by_pixel.add(x, y, pixel(x, y));
            }
        }
        assert_eq!(by_row.count, by_pixel.count);
        assert_eq!(by_row.sum, by_pixel.sum);
        // Two pixels of each of the first three rows.
        assert_eq!(by_row.count[by_row.width - 1], 2 * factor as u32);
    }

    fn rerendered(x: u32, y: u32, predicted: f32, observed: f32) -> Rerendered {
        Rerendered {
            view: 0,
            x,
            y,
            predicted: [predicted; 3],
            observed: [observed; 3],
        }
    }

    #[test]
    fn the_error_panel_is_red_where_the_estimate_is_brighter_and_blue_where_darker() {
        let mut photo = Raster::black(4, 1);
        for x in 0..4 {
            photo.set(x, 0, [0.5; 3]);
        }
        // x = 0: 25% of the RMS too bright (full red); x = 1: as bright; x = 2: 25% too dark
        // (full blue); x = 3: not compared.
        let r = [
            rerendered(0, 0, 0.625, 0.5),
            rerendered(1, 0, 0.5, 0.5),
            rerendered(2, 0, 0.375, 0.5),
        ];
        let img = picture(&photo, &r, 0);
        let error = |x: u32| img.get_pixel(2 * (4 + GAP) + x, 0).0;
        assert_eq!(error(0), [255, 0, 0]);
        assert_eq!(error(1), [255, 255, 255]);
        assert_eq!(error(2), [0, 0, 255]);
        assert_eq!(error(3), [0, 0, 0], "not compared: black");
        // Photo and estimate share the photo's exposure: equal values, equal pixels.
        assert_eq!(img.get_pixel(1, 0), img.get_pixel(4 + GAP + 1, 0));
        // The colour bar runs from blue to red under the error panel.
        assert_eq!(img.get_pixel(2 * (4 + GAP), 1 + GAP).0, [0, 0, 255]);
        assert_eq!(img.get_pixel(2 * (4 + GAP) + 3, 1 + GAP).0, [255, 0, 0]);
    }

    #[test]
    fn a_lone_pixel_the_spread_left_out_is_filled_but_a_region_is_not() {
        let mut photo = Raster::black(7, 1);
        for x in 0..7 {
            photo.set(x, 0, [1.0; 3]);
        }
        // Candidates at 0, 2 (a lone gap at 1) and 6 (a gap of 3 to 5).
        let r = [
            rerendered(0, 0, 1.0, 1.0),
            rerendered(2, 0, 1.0, 1.0),
            rerendered(6, 0, 1.0, 1.0),
        ];
        let img = picture(&photo, &r, 0);
        let estimate = |x: u32| img.get_pixel(7 + GAP + x, 0).0;
        assert_ne!(estimate(1), [0, 0, 0]);
        assert_eq!(estimate(4), [0, 0, 0]);
    }

    #[test]
    fn a_large_photo_is_averaged_down_to_the_panel_size() {
        let photo = Raster::black(2 * PANEL_MAX + 1, 10);
        let img = picture(&photo, &[], 0);
        // Factor 3: 1025 → 342 pixels per panel.
        assert_eq!(img.width(), 3 * 342 + 2 * GAP);
        assert_eq!(img.height(), 4 + GAP + BAR);
    }
}
