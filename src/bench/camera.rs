//! The virtual bench as a camera's image source: the rendered radiance, exposed at the shot's
//! settings, clipped like a sensor, encoded as an sRGB JPEG with the EXIF exposure tags a real
//! camera writes. The simulated PTP camera serves these files.

use std::sync::OnceLock;

use brdfd_sim::{ImageSource, Shot};

use super::VirtualBench;
use crate::core::raster::{linear_to_srgb, Raster};

/// Sensor response of the simulated cameras: a pixel value of 1.0 (white) at radiance 1 needs
/// an exposure factor (t·ISO/100/N²) of 1/SENSOR_GAIN. The rig calibration's default relative
/// scale between the two simulated cameras is 1 because both use it.
pub const SENSOR_GAIN: f64 = 1000.0;

pub struct BenchCamera {
    bench: VirtualBench,
    make: String,
    model: String,
    radiance: OnceLock<Result<Raster, String>>,
}

impl BenchCamera {
    pub fn new(bench: VirtualBench, make: &str, model: &str) -> Self {
        BenchCamera {
            bench,
            make: make.into(),
            model: model.into(),
            radiance: OnceLock::new(),
        }
    }

    /// Renders the scene now, so that the first InitiateCapture answers as fast as a real
    /// camera's (clients such as gphoto2 wait only a few seconds for it).
    pub fn prepare(&self) -> Result<(), String> {
        self.radiance().map(|_| ())
    }

    /// Rendered once: every exposure of a bracket sees the same scene.
    fn radiance(&self) -> Result<&Raster, String> {
        self.radiance
            .get_or_init(|| self.bench.photo().map_err(|e| e.to_string()))
            .as_ref()
            .map_err(Clone::clone)
    }
}

impl ImageSource for BenchCamera {
    fn photo(&self, shot: &Shot) -> Result<Vec<u8>, String> {
        let r = self.radiance()?;
        let k = (shot.exposure_factor() * SENSOR_GAIN) as f32;
        let jpeg = expose_to_jpeg(r.width, r.height, &r.pixels, k)?;
        Ok(insert_exif(&jpeg, &self.make, &self.model, shot))
    }

    fn dimensions(&self) -> (u32, u32) {
        let (w, h) = self.bench.geometry.camera.size();
        (w as u32, h as u32)
    }

    fn ready(&self) -> bool {
        self.radiance.get().is_some()
    }
}

/// What a sensor with an sRGB JPEG pipeline records of linear `radiance` scaled by `k`:
/// clipped at white, sRGB-encoded to 8 bits, JPEG at quality 95.
pub fn expose_to_jpeg(
    width: usize,
    height: usize,
    radiance: &[[f32; 3]],
    k: f32,
) -> Result<Vec<u8>, String> {
    let mut img = image::RgbImage::new(width as u32, height as u32);
    for (p, v) in img.pixels_mut().zip(radiance) {
        for c in 0..3 {
            p.0[c] = (linear_to_srgb((v[c] * k).clamp(0.0, 1.0)) * 255.0).round() as u8;
        }
    }
    let mut jpeg = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 95)
        .encode_image(&img)
        .map_err(|e| format!("JPEG encoding: {e}"))?;
    Ok(jpeg)
}

/// Puts an APP1 Exif segment (Make, Model, ExposureTime, FNumber, ISO) after the SOI marker.
pub fn insert_exif(jpeg: &[u8], make: &str, model: &str, shot: &Shot) -> Vec<u8> {
    insert_app1(jpeg, b"Exif\0\0", &exif_tiff(make, model, shot))
}

/// Puts an APP1 segment (`header` then `payload`) right after the SOI marker, ahead of any
/// APP1 already there. The payload must fit one segment (64 KiB).
pub fn insert_app1(jpeg: &[u8], header: &[u8], payload: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(jpeg.len() + header.len() + payload.len() + 4);
    out.extend_from_slice(&jpeg[..2]);
    out.extend_from_slice(&[0xFF, 0xE1]);
    out.extend_from_slice(&((header.len() + payload.len() + 2) as u16).to_be_bytes());
    out.extend_from_slice(header);
    out.extend_from_slice(payload);
    out.extend_from_slice(&jpeg[2..]);
    out
}

/// A little-endian TIFF structure: IFD0 (Make, Model, Exif pointer), then the Exif IFD.
fn exif_tiff(make: &str, model: &str, shot: &Shot) -> Vec<u8> {
    // Exposure time as 1/n or n/1 seconds, as cameras write it.
    let exposure = if shot.shutter_s >= 1.0 {
        ((shot.shutter_s * 10.0).round() as u32, 10)
    } else {
        (10_000, (10_000.0 / shot.shutter_s).round() as u32)
    };
    let fnum = ((shot.f_number * 100.0).round() as u32, 100);
    let ascii = |s: &str| {
        let mut v = s.as_bytes().to_vec();
        v.push(0);
        v
    };
    let (make, model) = (ascii(make), ascii(model));
    const IFD0: u32 = 8;
    let ifd0_len = 2 + 3 * 12 + 4;
    let exif_ifd = IFD0 + ifd0_len;
    let exif_len = 2 + 3 * 12 + 4;
    let mut extra = exif_ifd + exif_len;
    let mut tail = Vec::new();
    let mut place = |bytes: &[u8], tail: &mut Vec<u8>| {
        let at = extra;
        tail.extend_from_slice(bytes);
        if bytes.len() % 2 == 1 {
            tail.push(0);
        }
        extra = exif_ifd + exif_len + tail.len() as u32;
        at
    };
    let make_at = place(&make, &mut tail);
    let model_at = place(&model, &mut tail);
    let rational = |(n, d): (u32, u32)| [n.to_le_bytes(), d.to_le_bytes()].concat();
    let exp_at = place(&rational(exposure), &mut tail);
    let fnum_at = place(&rational(fnum), &mut tail);

    let mut t = b"II*\0".to_vec();
    t.extend_from_slice(&IFD0.to_le_bytes());
    let entry = |t: &mut Vec<u8>, tag: u16, ty: u16, count: u32, value: u32| {
        t.extend_from_slice(&tag.to_le_bytes());
        t.extend_from_slice(&ty.to_le_bytes());
        t.extend_from_slice(&count.to_le_bytes());
        t.extend_from_slice(&value.to_le_bytes());
    };
    t.extend_from_slice(&3u16.to_le_bytes());
    entry(&mut t, 0x010F, 2, make.len() as u32, make_at);
    entry(&mut t, 0x0110, 2, model.len() as u32, model_at);
    entry(&mut t, 0x8769, 4, 1, exif_ifd);
    t.extend_from_slice(&0u32.to_le_bytes());
    t.extend_from_slice(&3u16.to_le_bytes());
    entry(&mut t, 0x829A, 5, 1, exp_at);
    entry(&mut t, 0x829D, 5, 1, fnum_at);
    entry(&mut t, 0x8827, 3, 1, shot.iso.min(65535));
    t.extend_from_slice(&0u32.to_le_bytes());
    t.extend_from_slice(&tail);
    t
}
