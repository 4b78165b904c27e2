//! The virtual bench as a camera's image source: the rendered radiance, exposed at the shot's
//! settings, clipped like a sensor, encoded as an sRGB JPEG with the EXIF exposure tags a real
//! camera writes. The simulated PTP camera serves these files.

use std::sync::OnceLock;

use brdfd_sim::{ImageSource, Shot};

use super::raw_file::{self, exif_ifd, RawDamage, RawFormat, ShotInfo};
use super::tiff::{self, ByteOrder, Ifd, Value};
use super::VirtualBench;
use brdfd_core::geometry::Camera;
use brdfd_core::raster::{linear_to_srgb, Raster};

/// Sensor response of the simulated cameras: a pixel value of 1.0 (white) at radiance 1 needs
/// an exposure factor (t·ISO/100/N²) of 1/SENSOR_GAIN. The rig calibration's default relative
/// scale between the two simulated cameras is 1 because both use it.
pub const SENSOR_GAIN: f64 = 1000.0;

/// Width of the simulated DSLR's sensor (a D5100's APS-C), millimetres: with the camera's
/// focal length in pixels, it gives the EXIF focal length a real camera writes.
pub const SENSOR_WIDTH_MM: f64 = 23.6;
/// The crop Nikon's DX bodies write their 35 mm equivalent focal length with: nominal, where
/// 36 mm over the D5100's 23.6 mm is 1.53.
const DX_CROP: f64 = 1.5;

pub struct BenchCamera {
    /// The scene, rendered at the first shot; `None` when the radiance was given.
    bench: Option<VirtualBench>,
    size: (usize, usize),
    /// The lens's focal length (mm), for EXIF; none for an orthographic camera.
    lens: Option<f64>,
    make: String,
    model: String,
    raw: RawFormat,
    raw_damage: Option<RawDamage>,
    radiance: OnceLock<Result<Raster, String>>,
}

impl BenchCamera {
    pub fn new(bench: VirtualBench, make: &str, model: &str) -> Self {
        let camera = bench.geometry.camera.clone();
        let mut c = Self::empty(&camera, make, model);
        c.bench = Some(bench);
        c
    }

    /// A camera whose scene is this radiance, as `camera` sees it (a photo rendered
    /// elsewhere: the pose board).
    pub fn of_radiance(radiance: Raster, camera: &Camera, make: &str, model: &str) -> Self {
        let c = Self::empty(camera, make, model);
        let _ = c.radiance.set(Ok(radiance));
        c
    }

    fn empty(camera: &Camera, make: &str, model: &str) -> Self {
        let size = camera.size();
        let lens = match camera {
            Camera::Pinhole { fx, .. } => Some(fx * SENSOR_WIDTH_MM / size.0 as f64),
            Camera::Orthographic { .. } => None,
        };
        BenchCamera {
            bench: None,
            size,
            lens,
            make: make.into(),
            model: model.into(),
            raw: RawFormat::Nef,
            raw_damage: None,
            radiance: OnceLock::new(),
        }
    }

    /// The RAW files it writes when the camera is set to RAW (NEF unless told).
    pub fn with_raw(mut self, raw: RawFormat) -> Self {
        self.raw = raw;
        self
    }

    /// Damages every RAW file it writes (a camera or card that writes bad files).
    pub fn with_raw_damage(mut self, damage: Option<RawDamage>) -> Self {
        self.raw_damage = damage;
        self
    }

    /// Renders the scene now, so that the first InitiateCapture answers as fast as a real
    /// camera's (clients such as gphoto2 wait only a few seconds for it).
    pub fn prepare(&self) -> Result<(), String> {
        self.radiance().map(|_| ())
    }

    /// Rendered once: every exposure of a bracket sees the same scene.
    fn radiance(&self) -> Result<&Raster, String> {
        self.radiance
            .get_or_init(|| match &self.bench {
                Some(bench) => bench.photo().map_err(|e| e.to_string()),
                None => Err("the simulated camera has no scene".into()),
            })
            .as_ref()
            .map_err(Clone::clone)
    }
}

impl ImageSource for BenchCamera {
    fn photo(&self, shot: &Shot) -> Result<Vec<u8>, String> {
        let r = self.radiance()?;
        let k = (shot.exposure_factor() * SENSOR_GAIN) as f32;
        let jpeg = expose_to_jpeg(r.width, r.height, &r.pixels, k)?;
        Ok(insert_app1(
            &jpeg,
            b"Exif\0\0",
            &exif_tiff(&self.make, &self.model, shot, self.lens),
        ))
    }

    fn raw(&self, shot: &Shot) -> Result<Option<(&'static str, Vec<u8>)>, String> {
        let r = self.radiance()?;
        let k = (shot.exposure_factor() * SENSOR_GAIN) as f32;
        let info = ShotInfo {
            make: &self.make,
            model: &self.model,
            shutter_s: shot.shutter_s,
            f_number: shot.f_number,
            iso: shot.iso,
        };
        // Each shot's noise is its own, and the same for the same shot.
        let seed = shot.sequence as u64;
        let (ext, mut file) = match self.raw {
            RawFormat::Nef => ("NEF", raw_file::nef(r, k, &raw_file::D5100, &info, seed)),
            RawFormat::Dng => ("DNG", raw_file::dng(r, k, &raw_file::D5100, &info, seed)),
            RawFormat::Dng12 => {
                let sensor = raw_file::D5100.at_12_bits();
                ("DNG", raw_file::dng(r, k, &sensor, &info, seed))
            }
        };
        if let Some(d) = self.raw_damage {
            raw_file::damage(&mut file, d);
        }
        Ok(Some((ext, file)))
    }

    fn dimensions(&self) -> (u32, u32) {
        (self.size.0 as u32, self.size.1 as u32)
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
    insert_app1(jpeg, b"Exif\0\0", &exif_tiff(make, model, shot, None))
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
/// With a lens, also its focal length.
fn exif_tiff(make: &str, model: &str, shot: &Shot, lens: Option<f64>) -> Vec<u8> {
    let info = ShotInfo {
        make,
        model,
        shutter_s: shot.shutter_s,
        f_number: shot.f_number,
        iso: shot.iso,
    };
    let mut ifd0 = Ifd::new();
    ifd0.set(0x010F, Value::Ascii(make.into()))
        .set(0x0110, Value::Ascii(model.into()))
        .set(0x8769, Value::Ifds(vec![exif_ifd(&info, lens_tags(lens))]));
    tiff::write(ByteOrder::Little, &ifd0)
}

/// FocalLength (mm, to 0.1) and FocalLengthIn35mmFilm (whole mm, the focal length times the
/// DX format's nominal crop of 1.5), as a Nikon DSLR writes them: no focal plane resolution.
fn lens_tags(focal_mm: Option<f64>) -> Vec<(u16, Value)> {
    let Some(focal_mm) = focal_mm else {
        return Vec::new();
    };
    vec![
        (
            0x920A,
            Value::Rational(vec![((focal_mm * 10.0).round() as u32, 10)]),
        ),
        (
            0xA405,
            Value::Short(vec![(focal_mm * DX_CROP).round() as u16]),
        ),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The EXIF the simulated cameras write is what radiometry reads back.
    #[test]
    fn exif_we_write_is_read_back_and_missing_exif_is_named() {
        let shot = brdfd_sim::Shot {
            shutter_s: 1.0 / 60.0,
            f_number: 5.6,
            iso: 400,
            raw: false,
            sequence: 1,
        };
        let jpeg = [0xFF, 0xD8, 0xFF, 0xD9];
        let with = insert_exif(&jpeg, "NIKON CORPORATION", "NIKON D5100", &shot);
        let e = brdfd_radiometry::exif_exposure(&with, "a.jpg").unwrap();
        assert!((e.shutter_s - 1.0 / 60.0).abs() < 1e-9 && e.f_number == 5.6 && e.iso == 400.0);
        let err = brdfd_radiometry::exif_exposure(&jpeg, "b.jpg")
            .unwrap_err()
            .to_string();
        assert!(err.starts_with("b.jpg: EXIF"), "{err}");
    }
}
