//! A simulated V4L2 camera: a [`FrameSource`] whose frames come from an [`ImageSource`] (the
//! virtual bench), exposed at the controls set, with seeded sensor noise, delivered as YUYV or
//! MJPG as a UVC camera would. Controls behave like a UVC camera's: exposure in 100 µs
//! units within a range, gain and white balance clamped, auto modes on until switched off.

use std::sync::Arc;
use std::time::Duration;

use brdfd_v4l::{Applied, FrameSource, PixelFormat, RawFrame, Result, Settings, V4lError};

use crate::{ImageSource, Shot};

/// Exposure range of the simulated camera, in V4L2's 100 µs units (0.3 ms to 0.5 s).
const EXPOSURE_UNITS: (i64, i64) = (3, 5000);
/// Gain range; 100 is unity (ISO 100 in the image source's terms).
const GAIN: (i64, i64) = (0, 400);
const WHITE_BALANCE_K: (i64, i64) = (2800, 6500);
/// Auto exposure's choice, in seconds.
const AUTO_EXPOSURE_S: f64 = 1.0 / 60.0;
/// The simulated lens.
pub const F_NUMBER: f64 = 2.0;

/// Faults, each used up as it fires.
#[derive(Debug, Clone, Default)]
pub struct V4lFaults {
    /// Deliver no frame for the next request (the poll times out).
    pub stall_next: bool,
    /// Deliver the next frame with only this many bytes used.
    pub truncate_next: Option<usize>,
}

pub struct SimV4l {
    source: Arc<dyn ImageSource>,
    name: String,
    format: Option<(PixelFormat, u32, u32)>,
    exposure_units: Option<i64>,
    gain: i64,
    white_balance_k: Option<i64>,
    /// Standard deviation of the sensor noise, in 8-bit levels.
    pub noise_levels: f32,
    /// Time between frames.
    pub frame_interval: Duration,
    pub faults: V4lFaults,
    sequence: u32,
    rng: u64,
}

impl SimV4l {
    pub fn new(source: Arc<dyn ImageSource>, name: &str) -> SimV4l {
        SimV4l {
            source,
            name: name.into(),
            format: None,
            exposure_units: None,
            gain: 100,
            white_balance_k: None,
            noise_levels: 2.0,
            frame_interval: Duration::from_millis(5),
            faults: V4lFaults::default(),
            sequence: 0,
            rng: 0x9E37_79B9_7F4A_7C15,
        }
    }

    /// A normal deviate from a seeded generator (xorshift, then Box-Muller): frames differ
    /// from each other, and runs are repeatable.
    fn gaussian(&mut self) -> f32 {
        let mut next = || {
            self.rng ^= self.rng << 13;
            self.rng ^= self.rng >> 7;
            self.rng ^= self.rng << 17;
            ((self.rng >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        let (u, v) = (next(), next());
        ((-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()) as f32
    }

    fn shot(&self) -> Shot {
        Shot {
            shutter_s: self
                .exposure_units
                .map_or(AUTO_EXPOSURE_S, |u| u as f64 / 1e4),
            f_number: F_NUMBER,
            iso: self.gain.max(1) as u32,
            raw: false,
            sequence: self.sequence + 1,
        }
    }
}

/// BT.601 video-range RGB to YUYV, the inverse of what UVC hosts decode.
fn rgb_to_yuyv(rgb: &[u8], width: usize) -> Vec<u8> {
    let mut out = Vec::with_capacity(rgb.len() / 3 * 2);
    for row in rgb.chunks_exact(width * 3) {
        for pair in row.chunks_exact(6) {
            let yuv = |p: &[u8]| {
                let (r, g, b) = (p[0] as f32, p[1] as f32, p[2] as f32);
                let y = 16.0 + 0.256_788 * r + 0.504_129 * g + 0.097_906 * b;
                let u = 128.0 - 0.148_223 * r - 0.290_993 * g + 0.439_216 * b;
                let v = 128.0 + 0.439_216 * r - 0.367_788 * g - 0.071_427 * b;
                (y, u, v)
            };
            let (y0, u0, v0) = yuv(&pair[..3]);
            let (y1, u1, v1) = yuv(&pair[3..]);
            let q = |x: f32| x.round().clamp(0.0, 255.0) as u8;
            out.extend([q(y0), q((u0 + u1) / 2.0), q(y1), q((v0 + v1) / 2.0)]);
        }
    }
    out
}

impl FrameSource for SimV4l {
    fn describe(&self) -> String {
        format!("{} (simulated V4L2)", self.name)
    }

    fn formats(&self) -> Result<Vec<(PixelFormat, u32, u32)>> {
        let (w, h) = self.source.dimensions();
        Ok(vec![(PixelFormat::Mjpg, w, h), (PixelFormat::Yuyv, w, h)])
    }

    fn start(
        &mut self,
        format: PixelFormat,
        _width: u32,
        _height: u32,
    ) -> Result<(PixelFormat, u32, u32)> {
        // Like a driver, it sets the nearest size it has: its only one.
        let (w, h) = self.source.dimensions();
        self.format = Some((format, w, h));
        Ok((format, w, h))
    }

    fn apply(&mut self, s: &Settings) -> Result<Applied> {
        let mut a = Applied::default();
        if let Some(t) = s.exposure_s {
            let units = ((t * 1e4).round() as i64).clamp(EXPOSURE_UNITS.0, EXPOSURE_UNITS.1);
            self.exposure_units = Some(units);
            a.exposure_s = Some(units as f64 / 1e4);
            a.notes.push("auto exposure off".into());
        }
        if let Some(g) = s.gain {
            self.gain = g.clamp(GAIN.0, GAIN.1);
            a.gain = Some(self.gain);
            a.notes.push("auto gain off".into());
        }
        if let Some(k) = s.white_balance_k {
            // Steps of 10 K, as many UVC cameras have.
            let k = (k.clamp(WHITE_BALANCE_K.0, WHITE_BALANCE_K.1) / 10) * 10;
            self.white_balance_k = Some(k);
            a.white_balance_k = Some(k);
            a.notes.push("auto white balance off".into());
        }
        Ok(a)
    }

    fn next_frame(&mut self, timeout: Duration) -> Result<RawFrame> {
        let Some((format, width, height)) = self.format else {
            return Err(V4lError::Io {
                path: self.describe(),
                reason: "next_frame before start".into(),
            });
        };
        if std::mem::take(&mut self.faults.stall_next) {
            std::thread::sleep(timeout);
            return Err(V4lError::Timeout {
                path: self.describe(),
                after: timeout,
            });
        }
        std::thread::sleep(self.frame_interval);
        let jpeg = self
            .source
            .photo(&self.shot())
            .map_err(|reason| V4lError::Io {
                path: self.describe(),
                reason,
            })?;
        let clean = brdfd_v4l::decode(&RawFrame {
            format: PixelFormat::Mjpg,
            width,
            height,
            sequence: 0,
            data: jpeg,
        })
        .map_err(|reason| V4lError::Io {
            path: self.describe(),
            reason,
        })?;
        let mut rgb = clean.data;
        for v in rgb.iter_mut() {
            let n = self.gaussian() * self.noise_levels;
            *v = (*v as f32 + n).round().clamp(0.0, 255.0) as u8;
        }
        let mut data = match format {
            PixelFormat::Yuyv => rgb_to_yuyv(&rgb, width as usize),
            PixelFormat::Mjpg => {
                let mut out = Vec::new();
                image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, 90)
                    .encode(&rgb, width, height, image::ExtendedColorType::Rgb8)
                    .map_err(|e| V4lError::Io {
                        path: self.describe(),
                        reason: e.to_string(),
                    })?;
                out
            }
        };
        if let Some(n) = self.faults.truncate_next.take() {
            data.truncate(n);
        }
        self.sequence += 1;
        Ok(RawFrame {
            format,
            width,
            height,
            sequence: self.sequence,
            data,
        })
    }
}
