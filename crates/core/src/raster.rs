//! Linear RGB images: renders, photos decoded to linear radiance, and their files (float EXR,
//! tone-mapped sRGB PNG). sRGB decoding happens here, before the core sees a photo.

use std::path::Path;

use super::envmap::{write_exr, write_exr_with_white};
use super::error::{CoreError, Result};

#[derive(Clone, Debug, PartialEq)]
pub struct Raster {
    pub width: usize,
    pub height: usize,
    /// Row-major, linear RGB.
    pub pixels: Vec<[f32; 3]>,
}

/// Every 8-bit sRGB code decoded to linear: the table decoders of 8-bit images look up.
pub fn srgb8_to_linear() -> [f32; 256] {
    std::array::from_fn(|v| srgb_to_linear(v as f32 / 255.0))
}

/// sRGB transfer function, decoding (IEC 61966-2-1).
pub fn srgb_to_linear(v: f32) -> f32 {
    if v <= 0.04045 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

pub fn linear_to_srgb(v: f32) -> f32 {
    if v <= 0.0031308 {
        v * 12.92
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

impl Raster {
    pub fn black(width: usize, height: usize) -> Raster {
        Raster {
            width,
            height,
            pixels: vec![[0.0; 3]; width * height],
        }
    }

    pub fn get(&self, x: usize, y: usize) -> [f32; 3] {
        self.pixels[y * self.width + x]
    }

    pub fn set(&mut self, x: usize, y: usize, v: [f32; 3]) {
        self.pixels[y * self.width + x] = v;
    }

    /// Reads a photo as linear RGB: EXR as stored; PNG and JPEG decoded from sRGB.
    /// Non-finite EXR values are rejected with the pixel that holds them.
    pub fn read(path: &Path) -> Result<Raster> {
        Self::read_with_white(path).map(|(r, _)| r)
    }

    /// [`Raster::read`], with the photo's white level where the file knows it: 1.0 (the top
    /// code) for PNG and JPEG, the recorded level for an EXR that brdfd merged from a bracket
    /// ([`WHITE_LEVEL_ATTRIBUTE`](super::envmap::WHITE_LEVEL_ATTRIBUTE)), none for other EXRs.
    pub fn read_with_white(path: &Path) -> Result<(Raster, Option<f32>)> {
        let what = path.display().to_string();
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(|e| e.to_ascii_lowercase());
        if ext.as_deref() == Some("exr") {
            let super::envmap::ExrRgb {
                width: w,
                height: h,
                pixels: px,
                white,
            } = super::envmap::read_exr_rgb(path)?;
            for (i, p) in px.iter().enumerate() {
                if let Some(c) = p.iter().position(|v| !v.is_finite()) {
                    return Err(CoreError::NonFinite {
                        what,
                        x: i % w,
                        y: i / w,
                        channel: c,
                        value: p[c],
                    });
                }
            }
            return Ok((
                Raster {
                    width: w,
                    height: h,
                    pixels: px,
                },
                white,
            ));
        }
        let img = image::ImageReader::open(path)
            .map_err(|e| CoreError::io(path, e))?
            .with_guessed_format()
            .map_err(|e| CoreError::io(path, e))?
            .decode()
            .map_err(|e| CoreError::format(&what, format!("not a readable image: {e}")))?;
        let lut = srgb8_to_linear();
        let rgb = img.into_rgb8();
        Ok((
            Raster {
                width: rgb.width() as usize,
                height: rgb.height() as usize,
                pixels: rgb.pixels().map(|p| p.0.map(|v| lut[v as usize])).collect(),
            },
            Some(1.0),
        ))
    }

    pub fn write_exr(&self, path: &Path) -> Result<()> {
        write_exr(path, self.width, self.height, &self.pixels)
    }

    /// [`Raster::write_exr`], recording the white level a later [`Raster::read_with_white`]
    /// gives back.
    pub fn write_exr_with_white(&self, path: &Path, white: Option<f32>) -> Result<()> {
        write_exr_with_white(path, self.width, self.height, &self.pixels, white)
    }

    /// Exposure that maps the 99.5th percentile of the luminance to white: a stable choice
    /// for renders with a few bright highlights.
    pub fn auto_exposure(&self) -> f32 {
        let mut lum: Vec<f32> = self
            .pixels
            .iter()
            .map(|p| p[0] * 0.2126 + p[1] * 0.7152 + p[2] * 0.0722)
            .filter(|v| *v > 0.0)
            .collect();
        if lum.is_empty() {
            return 1.0;
        }
        let k = ((lum.len() as f64 * 0.995) as usize).min(lum.len() - 1);
        let (_, v, _) = lum.select_nth_unstable_by(k, f32::total_cmp);
        1.0 / v.max(1e-12)
    }

    /// sRGB 8-bit pixels after scaling by `exposure` and clipping.
    pub fn to_srgb8(&self, exposure: f32) -> image::RgbImage {
        image::RgbImage::from_fn(self.width as u32, self.height as u32, |x, y| {
            let p = self.get(x as usize, y as usize);
            image::Rgb(
                p.map(|v| (linear_to_srgb((v * exposure).clamp(0.0, 1.0)) * 255.0 + 0.5) as u8),
            )
        })
    }

    pub fn write_png(&self, path: &Path, exposure: f32) -> Result<()> {
        self.to_srgb8(exposure)
            .save(path)
            .map_err(|e| CoreError::format(path.display(), format!("could not write PNG: {e}")))
    }

    /// Relative RMSE of `self` against `truth` over the pixels of `truth` that are not black.
    pub fn relative_rmse(&self, truth: &Raster) -> f64 {
        let (mut num, mut den) = (0.0f64, 0.0f64);
        for (a, b) in self.pixels.iter().zip(&truth.pixels) {
            if b.iter().all(|v| *v == 0.0) {
                continue;
            }
            for c in 0..3 {
                num += ((a[c] - b[c]) as f64).powi(2);
                den += (b[c] as f64).powi(2);
            }
        }
        (num / den.max(f64::MIN_POSITIVE)).sqrt()
    }
}
