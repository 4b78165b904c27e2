//! Radiometry between the cameras and the estimation core: camera files to linear values,
//! exposure from EXIF, and the HDR merge of an exposure bracket. JPEG is decoded here (its
//! tone curve assumed sRGB), RAW files in [`raw`]; both give a [`Frame`].

pub mod averaged;
pub mod isolated;
pub mod panorama;
pub mod raw;
pub mod tiff;

use std::io::Cursor;

use rayon::prelude::*;

use brdfd_core::raster::{srgb8_to_linear, Raster};

#[derive(Debug, thiserror::Error)]
pub enum RadiometryError {
    #[error("{file}: {reason}")]
    Decode { file: String, reason: String },
    #[error("{file}: EXIF has no {tag}; cannot tell the exposure")]
    MissingExif { file: String, tag: &'static str },
    #[error("HDR merge: {0}")]
    Merge(String),
    /// Files the core reads itself (Radiance, OpenEXR).
    #[error(transparent)]
    Core(#[from] brdfd_core::CoreError),
}

impl RadiometryError {
    /// A file that could not be decoded, and why.
    pub(crate) fn decode(file: &str, reason: impl std::fmt::Display) -> RadiometryError {
        RadiometryError::Decode {
            file: file.into(),
            reason: reason.to_string(),
        }
    }
}

/// Which white balance a decoded RAW frame carries.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum WhiteBalance {
    /// The multipliers the camera recorded in the file for the shot.
    #[default]
    AsShot,
    /// Fixed multipliers (red, green, blue) from the rig, for every file alike.
    Fixed([f32; 3]),
}

/// Exposure as a camera recorded it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Exposure {
    pub shutter_s: f64,
    pub f_number: f64,
    pub iso: f64,
}

impl Exposure {
    /// t·ISO/100/N²: pixel values divided by this (and the sensor gain) are radiance.
    pub fn factor(&self) -> f64 {
        self.shutter_s * self.iso / 100.0 / (self.f_number * self.f_number)
    }
}

/// One decoded exposure: values in [0, 1], linear, and how it was exposed.
pub struct Frame {
    /// 1 is where the camera clips (a RAW sensor's white level, a JPEG's 255).
    pub values: Raster,
    pub exposure: Exposure,
    /// Multipliers (red, green, blue) that white-balance `values`: a RAW file's, kept apart
    /// so that clipping is judged on what the sensor recorded. 1 for files the camera
    /// balanced itself (JPEG, video).
    pub white_balance: [f32; 3],
}

/// Reads ExposureTime, FNumber and ISO from a file's EXIF.
pub fn exif_exposure(bytes: &[u8], file: &str) -> Result<Exposure, RadiometryError> {
    let exif = exif::Reader::new()
        .read_from_container(&mut Cursor::new(bytes))
        .map_err(|e| RadiometryError::Decode {
            file: file.into(),
            reason: format!("EXIF: {e}"),
        })?;
    let rational = |tag: exif::Tag, name: &'static str| match exif
        .get_field(tag, exif::In::PRIMARY)
        .map(|f| &f.value)
    {
        Some(exif::Value::Rational(v)) if !v.is_empty() && v[0].denom != 0 => Ok(v[0].to_f64()),
        _ => Err(RadiometryError::MissingExif {
            file: file.into(),
            tag: name,
        }),
    };
    let iso = exif
        .get_field(exif::Tag::PhotographicSensitivity, exif::In::PRIMARY)
        .and_then(|f| f.value.get_uint(0))
        .ok_or(RadiometryError::MissingExif {
            file: file.into(),
            tag: "ISO (PhotographicSensitivity)",
        })?;
    Ok(Exposure {
        shutter_s: rational(exif::Tag::ExposureTime, "ExposureTime")?,
        f_number: rational(exif::Tag::FNumber, "FNumber")?,
        iso: iso as f64,
    })
}

/// A lens's focal length as a file's EXIF gives it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ExifFocal {
    pub mm: f64,
    /// The sensor's pixels per millimetre (FocalPlaneXResolution), where the file says.
    pub px_per_mm: Option<f64>,
    /// The focal length on 35 mm film (FocalLengthIn35mmFilm), which Nikon and most others
    /// write where they write no focal plane resolution.
    pub mm_35: Option<f64>,
}

impl ExifFocal {
    /// The focal length in pixels of a photo `width` wide, and how it was found: from the
    /// sensor's width if given (`sensor_width_mm`), else the focal plane's resolution, else
    /// the 35 mm equivalent (taken over a frame 36 mm wide). `None` when none is known.
    pub fn focal_px(&self, width: u32, sensor_width_mm: Option<f64>) -> Option<(f64, String)> {
        let w = width as f64;
        if let Some(s) = sensor_width_mm {
            return Some((
                self.mm * w / s,
                format!("on a sensor {s} mm wide (--sensor-width-mm)"),
            ));
        }
        if let Some(per_mm) = self.px_per_mm {
            return Some((
                self.mm * per_mm,
                format!(
                    "on a sensor {:.2} mm wide (its focal plane resolution)",
                    w / per_mm
                ),
            ));
        }
        self.mm_35.map(|f35| {
            (
                f35 * w / 36.0,
                format!(
                    "{f35} mm on 35 mm film, a nominal figure good to a percent or two (--sensor-width-mm gives the sensor's own width)"
                ),
            )
        })
    }
}

/// FocalLength, and FocalPlaneXResolution in pixels per millimetre, from a file's EXIF; `None`
/// if it has no focal length.
pub fn exif_focal(bytes: &[u8]) -> Option<ExifFocal> {
    let exif = exif::Reader::new()
        .read_from_container(&mut Cursor::new(bytes))
        .ok()?;
    let rational = |tag: exif::Tag| match exif.get_field(tag, exif::In::PRIMARY).map(|f| &f.value) {
        Some(exif::Value::Rational(v)) if !v.is_empty() && v[0].denom != 0 => {
            Some(v[0].to_f64()).filter(|x| x.is_finite() && *x > 0.0)
        }
        _ => None,
    };
    let mm = rational(exif::Tag::FocalLength)?;
    // FocalPlaneResolutionUnit: 2 inches (the default), 3 centimetres; 4 and 5 (mm, µm) are
    // written by some cameras though not in the standard.
    let unit_mm = match exif
        .get_field(exif::Tag::FocalPlaneResolutionUnit, exif::In::PRIMARY)
        .and_then(|f| f.value.get_uint(0))
        .unwrap_or(2)
    {
        3 => Some(10.0),
        4 => Some(1.0),
        5 => Some(1e-3),
        2 => Some(25.4),
        _ => None,
    };
    let px_per_mm = rational(exif::Tag::FocalPlaneXResolution)
        .zip(unit_mm)
        .map(|(r, unit)| r / unit);
    let mm_35 = exif
        .get_field(exif::Tag::FocalLengthIn35mmFilm, exif::In::PRIMARY)
        .and_then(|f| f.value.get_uint(0))
        .filter(|v| *v > 0)
        .map(f64::from);
    Some(ExifFocal {
        mm,
        px_per_mm,
        mm_35,
    })
}

/// An sRGB JPEG (as cameras write them) to linear values, with its EXIF exposure.
pub fn decode_jpeg(bytes: &[u8], file: &str) -> Result<Frame, RadiometryError> {
    let exposure = exif_exposure(bytes, file)?;
    let img = image::load_from_memory_with_format(bytes, image::ImageFormat::Jpeg)
        .map_err(|e| RadiometryError::Decode {
            file: file.into(),
            reason: format!("JPEG: {e}"),
        })?
        .to_rgb8();
    let lut = srgb8_to_linear();
    let pixels = img
        .pixels()
        .map(|p| {
            [
                lut[p.0[0] as usize],
                lut[p.0[1] as usize],
                lut[p.0[2] as usize],
            ]
        })
        .collect();
    Ok(Frame {
        values: Raster {
            width: img.width() as usize,
            height: img.height() as usize,
            pixels,
        },
        exposure,
        white_balance: [1.0; 3],
    })
}

/// Averages video frames of one exposure in linear light (sRGB decoded first), which
/// lowers the sensor noise by the square root of their number. Frames must share a size.
pub fn average_frames(
    frames: &[brdfd_v4l::Rgb8Frame],
    exposure: Exposure,
    source: &str,
) -> Result<Frame, RadiometryError> {
    let first = frames
        .first()
        .ok_or_else(|| RadiometryError::Merge(format!("{source}: no frames to average")))?;
    let (w, h) = (first.width as usize, first.height as usize);
    let lut = srgb8_to_linear();
    let mut sum = vec![[0.0f32; 3]; w * h];
    for f in frames {
        if (f.width as usize, f.height as usize) != (w, h) || f.data.len() != w * h * 3 {
            return Err(RadiometryError::Merge(format!(
                "{source}: frames differ in size ({w}×{h} and {}×{})",
                f.width, f.height
            )));
        }
        for (acc, px) in sum.iter_mut().zip(f.data.chunks_exact(3)) {
            for c in 0..3 {
                acc[c] += lut[px[c] as usize];
            }
        }
    }
    let n = frames.len() as f32;
    Ok(Frame {
        values: Raster {
            width: w,
            height: h,
            pixels: sum.into_iter().map(|p| p.map(|v| v / n)).collect(),
        },
        exposure,
        white_balance: [1.0; 3],
    })
}

/// What averaging left of the noise: over the pixels whose average is well exposed (between
/// [`DARK`] and [`SATURATED`]), the median of the standard error of the mean relative to the
/// mean, in linear light. `None` for fewer than two frames or no such pixel.
pub fn averaging_noise(frames: &[brdfd_v4l::Rgb8Frame]) -> Option<f32> {
    let n = frames.len();
    let first = frames.first()?;
    if n < 2 || frames.iter().any(|f| f.data.len() != first.data.len()) {
        return None;
    }
    let lut = srgb8_to_linear();
    // Every 7th value: the median of a few ten thousand is as good as of all.
    let mut relative: Vec<f32> = (0..first.data.len())
        .step_by(7)
        .filter_map(|i| {
            let (mut sum, mut sq) = (0.0f32, 0.0f32);
            for f in frames {
                let v = lut[f.data[i] as usize];
                sum += v;
                sq += v * v;
            }
            let mean = sum / n as f32;
            if !(DARK..SATURATED).contains(&mean) {
                return None;
            }
            let variance = ((sq - sum * mean) / (n - 1) as f32).max(0.0);
            Some((variance / n as f32).sqrt() / mean)
        })
        .collect();
    if relative.is_empty() {
        return None;
    }
    let mid = relative.len() / 2;
    Some(*relative.select_nth_unstable_by(mid, f32::total_cmp).1)
}

/// Puts a camera's gain (its value per unit of exposure per unit of radiance, per channel)
/// into each frame's channel multipliers, so that [`merge_hdr`] with a gain of 1 gives
/// radiance in the bench's unit. Clipping is still judged on the values as recorded.
pub fn with_gain(frames: &mut [Frame], gain: [f64; 3]) {
    for f in frames {
        for (b, g) in f.white_balance.iter_mut().zip(gain) {
            *b = (*b as f64 / g) as f32;
        }
    }
}

/// Values above this are treated as saturated, below `DARK` as noise.
pub const SATURATED: f32 = 0.95;
pub const DARK: f32 = 0.01;

/// The merged radiance at and above which [`merge_hdr`] had only clipped frames: a value
/// there is the shortest exposure's lower bound, not a measurement. Every usable frame gives
/// less (its value is under [`SATURATED`] and its scale at most the shortest exposure's).
///
/// With white balance, each channel clips at its own level; this is the lowest of them.
pub fn merged_white_level(frames: &[Frame], gain: f64) -> Option<f32> {
    frames
        .iter()
        .map(|f| {
            let balance = f
                .white_balance
                .iter()
                .copied()
                .fold(f32::INFINITY, f32::min);
            f.exposure.factor() * gain / balance as f64
        })
        .min_by(f64::total_cmp)
        .map(|factor| (SATURATED as f64 / factor) as f32)
}

/// Merges a bracket into radiance: each frame's values divided by its exposure factor and
/// `gain`, averaged with a hat weight that is zero at saturation and near black. A pixel no
/// frame exposed well takes the nearest frame's estimate (the darkest frame for highlights,
/// the brightest for shadows), so nothing is left undefined.
///
/// Camera files are lossy: JPEG ringing and chroma subsampling leave values just under white
/// beside and inside clipped highlights, which a threshold on the value alone takes as good.
/// So a frame is used for a pixel only if the radiance seen by the shortest exposure that
/// registers the pixel (the least likely to clip) would not have saturated it. The rule is
/// per channel: applied across channels (JPEG mixes them through chroma) it pushes the dim
/// channel of a coloured highlight into frames where it sits at the noise floor, which
/// measured worse (blue +6% on grace's bright band, against +3% per channel). Measured on
/// the THETA round trip of grace (tests/theta.rs), this is what keeps small bright sources
/// from coming out several per cent dark.
pub fn merge_hdr(frames: &[Frame], gain: f64) -> Result<Raster, RadiometryError> {
    let first = frames
        .first()
        .ok_or_else(|| RadiometryError::Merge("no frames".into()))?;
    let (w, h) = (first.values.width, first.values.height);
    if let Some(f) = frames
        .iter()
        .find(|f| f.values.width != w || f.values.height != h)
    {
        return Err(RadiometryError::Merge(format!(
            "frames differ in size ({w}×{h} and {}×{})",
            f.values.width, f.values.height
        )));
    }
    // Per frame and channel: what turns a value into radiance.
    let scale: Vec<[f32; 3]> = frames
        .iter()
        .map(|f| {
            f.white_balance
                .map(|b| (b as f64 / (f.exposure.factor() * gain)) as f32)
        })
        .collect();
    // Frames from the shortest exposure (largest scale) to the longest.
    let mut order: Vec<usize> = (0..frames.len()).collect();
    order.sort_by(|&a, &b| {
        let f = |k: usize| 1.0 / frames[k].exposure.factor();
        f(b).total_cmp(&f(a))
    });
    let (darkest, brightest) = (order[0], order[order.len() - 1]);
    let mut out = Raster::black(w, h);
    out.pixels.par_iter_mut().enumerate().for_each(|(i, px)| {
        for c in 0..3 {
            let reference = order
                .iter()
                .map(|&k| (frames[k].values.pixels[i][c], scale[k][c]))
                .find(|&(v, _)| v > DARK)
                .map(|(v, s)| v * s);
            let (mut sum, mut wsum) = (0.0f32, 0.0f32);
            for (f, s) in frames.iter().zip(&scale) {
                let (v, s) = (f.values.pixels[i][c], s[c]);
                let would_clip = reference.is_some_and(|r| r / s >= SATURATED);
                if v > DARK && v < SATURATED && !would_clip {
                    let wt = 1.0 - (2.0 * v - 1.0).abs();
                    sum += wt * v * s;
                    wsum += wt;
                }
            }
            px[c] = if wsum > 0.0 {
                sum / wsum
            } else {
                let bright = frames[darkest].values.pixels[i][c] >= SATURATED;
                let k = if bright { darkest } else { brightest };
                frames[k].values.pixels[i][c] * scale[k][c]
            };
        }
    });
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(v: f32, shutter_s: f64) -> Frame {
        let mut r = Raster::black(1, 1);
        r.pixels[0] = [v; 3];
        Frame {
            values: r,
            exposure: Exposure {
                shutter_s,
                f_number: 1.0,
                iso: 100.0,
            },
            white_balance: [1.0; 3],
        }
    }

    #[test]
    fn merge_ignores_saturated_frames_and_undoes_exposure() {
        // Radiance 2: 0.2 at 0.1 s, 0.8 at 0.4 s, clipped at 1.6 s.
        let bracket = [frame(0.2, 0.1), frame(0.8, 0.4), frame(1.0, 1.6)];
        let m = merge_hdr(&bracket, 1.0).unwrap();
        assert!((m.pixels[0][0] - 2.0).abs() < 1e-5, "{:?}", m.pixels[0]);
        assert!(m.pixels[0][0] < merged_white_level(&bracket, 1.0).unwrap());
        // Everything saturated: the shortest exposure's lower bound.
        let m = merge_hdr(&[frame(1.0, 0.1), frame(1.0, 0.4)], 1.0).unwrap();
        // That lower bound is what the white level flags: 0.95 / 0.1.
        let white = merged_white_level(&[frame(1.0, 0.1), frame(1.0, 0.4)], 1.0).unwrap();
        assert!((white - 9.5).abs() < 1e-5, "{white}");
        assert!(m.pixels[0].iter().all(|v| *v >= white), "{:?}", m.pixels[0]);
        assert!((m.pixels[0][0] - 10.0).abs() < 1e-4);
    }

    #[test]
    fn merge_ignores_values_under_white_that_must_have_clipped() {
        // Radiance 2: 0.2 at 0.1 s. At 0.8 s it would be 1.6, clipped; JPEG ringing beside a
        // highlight reads 0.9 there. The value alone looks usable (hat weight 0.2), and would
        // pull the merge to 1.71; the short frame says it clipped.
        let m = merge_hdr(&[frame(0.2, 0.1), frame(0.9, 0.8)], 1.0).unwrap();
        assert!((m.pixels[0][0] - 2.0).abs() < 1e-5, "{:?}", m.pixels[0]);
    }
}
