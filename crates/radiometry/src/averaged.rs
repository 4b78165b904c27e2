//! The V4L2 fallback camera's stored exposures: its video frames averaged in linear light
//! per exposure (video frames are many and noisy), each average an OpenEXR file whose header
//! records the exposure time the camera applied, the frames averaged and their noise.

use brdfd_core::envmap::{exr_bytes, read_exr_rgb_bytes, ExrAttribute};
use brdfd_core::raster::Raster;

use super::{average_frames, averaging_noise, Exposure, Frame, RadiometryError};

/// EXR attributes of a fallback exposure: the exposure time the camera applied, seconds; the
/// frames averaged; and their noise (the median relative standard error of the average).
const EXPOSURE_ATTRIBUTE: &str = "brdfdExposureSeconds";
const FRAMES_ATTRIBUTE: &str = "brdfdFramesAveraged";
const NOISE_ATTRIBUTE: &str = "brdfdRelativeNoise";

/// The fallback's exposure: no aperture or gain of its own to account for, only the time.
fn exposure(shutter_s: f64) -> Exposure {
    Exposure {
        shutter_s,
        f_number: 1.0,
        iso: 100.0,
    }
}

/// One exposure's frames averaged in linear light, as the EXR the session stores: with its
/// exposure time, the frames averaged and their noise in its header. Also the noise.
pub fn averaged_exr(
    frames: &[brdfd_v4l::Rgb8Frame],
    applied_s: f64,
    name: &str,
) -> Result<(Vec<u8>, Option<f32>), RadiometryError> {
    let average = average_frames(frames, exposure(applied_s), name)?;
    let noise = averaging_noise(frames);
    let v = &average.values;
    let mut attributes = vec![
        (EXPOSURE_ATTRIBUTE, ExrAttribute::F32(applied_s as f32)),
        (FRAMES_ATTRIBUTE, ExrAttribute::F32(frames.len() as f32)),
    ];
    if let Some(n) = noise {
        attributes.push((NOISE_ATTRIBUTE, ExrAttribute::F32(n)));
    }
    Ok((exr_bytes(v.width, v.height, &v.pixels, &attributes)?, noise))
}

/// A fallback bracket as stored: its averages (values per second of exposure), the frames
/// each averaged, and the median of their recorded noise.
pub struct FallbackBracket {
    pub frames: Vec<Frame>,
    pub averaged: usize,
    pub noise: Option<f32>,
}

impl FallbackBracket {
    /// Reads a bracket's stored averages, each `(file name, bytes)`.
    pub fn read(files: &[(String, Vec<u8>)]) -> Result<FallbackBracket, RadiometryError> {
        let (mut noise, mut averaged) = (Vec::new(), 0);
        let frames = files
            .iter()
            .map(|(name, bytes)| {
                let (rgb, attributes) = read_exr_rgb_bytes(bytes, name)?;
                let shutter_s = attributes
                    .get(EXPOSURE_ATTRIBUTE)
                    .copied()
                    .filter(|t| t.is_finite() && *t > 0.0)
                    .ok_or_else(|| RadiometryError::Decode {
                        file: name.clone(),
                        reason: format!("no exposure time ({EXPOSURE_ATTRIBUTE}) in its header"),
                    })?;
                noise.extend(attributes.get(NOISE_ATTRIBUTE).copied());
                averaged = attributes
                    .get(FRAMES_ATTRIBUTE)
                    .map_or(averaged, |n| *n as usize);
                Ok(Frame {
                    values: Raster {
                        width: rgb.width,
                        height: rgb.height,
                        pixels: rgb.pixels,
                    },
                    exposure: exposure(shutter_s as f64),
                    white_balance: [1.0; 3],
                })
            })
            .collect::<Result<Vec<_>, RadiometryError>>()?;
        noise.sort_by(f32::total_cmp);
        Ok(FallbackBracket {
            frames,
            averaged,
            noise: noise.get(noise.len() / 2).copied(),
        })
    }
}
