//! How much of the room each pixel of a part sees past the part itself: what report.html
//! draws as `visibility.png`, and what the flags read to tell light the part bounces onto
//! itself from a bad fit.

use image::{Rgb, RgbImage};

use brdfd_core::envmap::LightSet;
use brdfd_core::geometry::{GeomPixel, PixelGeometry};
use brdfd_core::raster::Raster;
use brdfd_core::render::visible_fraction;

/// The fraction of the light reaching each object pixel that the object itself lets through
/// ([`brdfd_core::render::visible_fraction`]), and its mean over the object.
pub struct Visibility {
    pub fraction: Raster,
    pub mean: f64,
    /// The normal at each of `fraction`'s pixels that is the object's.
    normals: Vec<Option<[f32; 3]>>,
    /// The photo's pixels per `fraction` pixel, across and down.
    step: usize,
}

/// Pixels across [`Visibility`]'s picture at most: a camera's 16 MP would take minutes to
/// work out and swell the report.
const VISIBILITY_SIZE: usize = 512;

impl Visibility {
    /// `None` for a shape that hides nothing from itself (the analytic ones, normal maps).
    /// Worked out on every n-th pixel of every n-th row, so that the picture is at most
    /// `VISIBILITY_SIZE` (512) across.
    pub fn of(geometry: &PixelGeometry, lights: &LightSet) -> Option<Visibility> {
        if geometry.pixels.iter().all(|p| p.shadow.is_none()) {
            return None;
        }
        let n = geometry
            .width
            .max(geometry.height)
            .div_ceil(VISIBILITY_SIZE);
        let geometry = PixelGeometry {
            width: geometry.width.div_ceil(n),
            height: geometry.height.div_ceil(n),
            pixels: geometry
                .pixels
                .iter()
                .filter(|p| (p.x as usize).is_multiple_of(n) && (p.y as usize).is_multiple_of(n))
                .map(|p| GeomPixel {
                    x: p.x / n as u32,
                    y: p.y / n as u32,
                    ..p.clone()
                })
                .collect(),
        };
        let fraction = visible_fraction(&geometry, lights);
        let mut normals = vec![None; geometry.width * geometry.height];
        for p in &geometry.pixels {
            normals[p.y as usize * geometry.width + p.x as usize] = Some(p.normal);
        }
        Some(Visibility::new(fraction, normals, n))
    }

    /// `fraction` (every `step`-th pixel of the photo's every `step`-th row), with the
    /// object's normal at each of its pixels (row by row, as `fraction`'s).
    pub fn new(fraction: Raster, normals: Vec<Option<[f32; 3]>>, step: usize) -> Visibility {
        assert_eq!(
            normals.len(),
            fraction.width * fraction.height,
            "a normal, or none, for each pixel of the fraction"
        );
        let (mut sum, mut count) = (0.0, 0usize);
        for (p, _) in normals.iter().enumerate().filter(|(_, n)| n.is_some()) {
            sum += f64::from(fraction.pixels[p][0]);
            count += 1;
        }
        Visibility {
            mean: sum / count.max(1) as f64,
            fraction,
            normals,
            step,
        }
    }

    /// The fraction and the normal at the photo's pixel (x, y): those of the pixel worked out
    /// at or above and left of it (at most `step` − 1 away), if it is the object's.
    pub fn at(&self, x: usize, y: usize) -> Option<(f32, [f32; 3])> {
        let (x, y) = (x / self.step, y / self.step);
        let f = &self.fraction;
        if x >= f.width || y >= f.height {
            return None;
        }
        self.normals[y * f.width + x].map(|n| (f.get(x, y)[0], n))
    }

    /// The fraction as grey levels: 255 for all the light, 128 for half. Not sRGB-encoded,
    /// which would show a half as three quarters and flatten the differences that matter.
    pub fn picture(&self) -> RgbImage {
        let f = &self.fraction;
        RgbImage::from_fn(f.width as u32, f.height as u32, |x, y| {
            let v = f.get(x as usize, y as usize)[0].clamp(0.0, 1.0);
            Rgb([(v * 255.0).round() as u8; 3])
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A photo's pixel reads the visibility worked out at or above and left of it, every
    /// 4th pixel of every 4th row here; off the object, or past the picture, nothing.
    #[test]
    fn a_photo_pixel_reads_the_visibility_worked_out_nearest_above_left_of_it() {
        let mut fraction = Raster::black(2, 2);
        fraction.set(1, 0, [0.25; 3]);
        fraction.set(0, 1, [0.75; 3]);
        let up = Some([0.0, 1.0, 0.0]);
        let v = Visibility::new(fraction, vec![None, up, up, None], 4);
        assert_eq!(v.at(5, 3), Some((0.25, [0.0, 1.0, 0.0])));
        assert_eq!(v.at(3, 7), Some((0.75, [0.0, 1.0, 0.0])));
        assert_eq!(v.at(3, 3), None, "off the object");
        assert_eq!(v.at(8, 0), None, "past the picture");
        // The mean is over the object's pixels only.
        assert!((v.mean - 0.5).abs() < 1e-9);
    }
}
