//! V4L2 cameras for brdfd: the fallback object camera when no PTP DSLR is present, and the
//! THETA V/Z1's UVC live-streaming mode as a panorama source.
//!
//! - [`FrameSource`]: the seam. [`device::V4lCamera`] is a real `/dev/video*` device (mmap
//!   streaming, poll with a timeout, frames sliced to `bytesused`, manual controls through
//!   V4L2 ioctls); `brdfd-sim` has a simulated source serving rendered frames. Tests here
//!   cannot see a `/dev/video*`, so they run against the simulated source; the ioctl path
//!   compiles everywhere and runs wherever a device exists (`brdfd v4l` and `brdfd devices`).
//! - [`decode()`]: YUYV (BT.601, limited range, as UVC cameras send it) and MJPG to RGB8.
//! - [`capture`]: sets the camera up and grabs N frames to average (the averaging itself is
//!   radiometry, in `brdfd_radiometry`, where the sRGB decoding is).

pub mod decode;
pub mod device;

use std::time::Duration;

pub use decode::{decode, Rgb8Frame};

pub type Result<T> = std::result::Result<T, V4lError>;

#[derive(Debug, thiserror::Error)]
pub enum V4lError {
    /// No such device node.
    #[error("{path} does not exist: is the camera plugged in? `brdfd devices` lists V4L2 devices")]
    Missing { path: String },
    /// The node exists but this user may not open it.
    #[error("no permission to open {path}: add yourself to the video group, or install config/udev/70-brdfd.rules")]
    Permission { path: String },
    /// Another program streams from it.
    #[error(
        "{path} is busy: another program (a browser, a video call) is using the camera; close it"
    )]
    Busy { path: String },
    /// Not a capture device, or no format we can decode.
    #[error("{path}: {reason}")]
    Unsupported { path: String, reason: String },
    /// No frame in time.
    #[error("{path}: no frame within {after:?}; is the camera streaming (a lens cap does not stop frames, a sleeping THETA does)?")]
    Timeout { path: String, after: Duration },
    /// A frame that does not decode.
    #[error("{path}: frame {sequence} ({format}, {bytes} bytes) does not decode: {reason}")]
    Decode {
        path: String,
        sequence: u32,
        format: String,
        bytes: usize,
        reason: String,
    },
    #[error("{path}: {reason}")]
    Io { path: String, reason: String },
}

/// Pixel formats we stream. YUYV is preferred for measurement: it is not compressed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PixelFormat {
    Yuyv,
    Mjpg,
}

impl PixelFormat {
    pub fn fourcc(self) -> [u8; 4] {
        match self {
            PixelFormat::Yuyv => *b"YUYV",
            PixelFormat::Mjpg => *b"MJPG",
        }
    }

    pub fn from_fourcc(f: [u8; 4]) -> Option<PixelFormat> {
        match &f {
            b"YUYV" => Some(PixelFormat::Yuyv),
            b"MJPG" => Some(PixelFormat::Mjpg),
            _ => None,
        }
    }
}

/// One frame as the device delivered it, sliced to `bytesused`.
#[derive(Debug, Clone)]
pub struct RawFrame {
    pub format: PixelFormat,
    pub width: u32,
    pub height: u32,
    /// The driver's frame counter.
    pub sequence: u32,
    pub data: Vec<u8>,
}

/// Manual settings to apply; None leaves a setting as it is.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Settings {
    /// Exposure time in seconds (V4L2 counts in 100 µs units).
    pub exposure_s: Option<f64>,
    /// Sensor gain in the device's own units.
    pub gain: Option<i64>,
    /// White balance colour temperature, kelvin.
    pub white_balance_k: Option<i64>,
}

/// What the device reports after [`FrameSource::apply`]; None where it has no such control.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Applied {
    pub exposure_s: Option<f64>,
    pub gain: Option<i64>,
    pub white_balance_k: Option<i64>,
    /// Auto modes that were switched off, and controls the device lacks.
    pub notes: Vec<String>,
}

/// A source of video frames: a V4L2 device, or a simulated one.
pub trait FrameSource: Send {
    /// "HD Pro Webcam C920 (/dev/video0)".
    fn describe(&self) -> String;
    /// Formats and sizes offered, for choosing.
    fn formats(&self) -> Result<Vec<(PixelFormat, u32, u32)>>;
    /// Starts streaming in this format and size; returns what the device actually set.
    fn start(
        &mut self,
        format: PixelFormat,
        width: u32,
        height: u32,
    ) -> Result<(PixelFormat, u32, u32)>;
    /// Switches auto exposure, gain and white balance off and applies the settings.
    fn apply(&mut self, settings: &Settings) -> Result<Applied>;
    /// The next frame, waiting at most `timeout`.
    fn next_frame(&mut self, timeout: Duration) -> Result<RawFrame>;
}

/// How long to wait for one frame. UVC cameras at long exposures deliver a few frames a
/// second; a THETA waking up takes longer.
pub const FRAME_TIMEOUT: Duration = Duration::from_secs(3);
/// Frames thrown away after a settings change: UVC cameras apply controls a few frames late.
pub const SETTLE_FRAMES: usize = 3;
/// Buffers a stream keeps queued: frames exposed before a settings change can wait in all of
/// them, so a change on a running stream throws these away too ([`grab`]).
pub const STREAM_BUFFERS: usize = 4;

/// Picks the format to stream: YUYV (uncompressed) at the largest size offered, else MJPG at
/// the largest size.
pub fn choose_format(offered: &[(PixelFormat, u32, u32)]) -> Option<(PixelFormat, u32, u32)> {
    let best = |f: PixelFormat| {
        offered
            .iter()
            .copied()
            .filter(|(g, _, _)| *g == f)
            .max_by_key(|&(_, w, h)| w as u64 * h as u64)
    };
    best(PixelFormat::Yuyv).or_else(|| best(PixelFormat::Mjpg))
}

/// Sets the source up and grabs `count` decoded frames after letting the settings settle.
pub fn capture(
    src: &mut dyn FrameSource,
    settings: &Settings,
    count: usize,
) -> Result<(Applied, Vec<Rgb8Frame>)> {
    start(src)?;
    grab(src, settings, count)
}

/// Starts streaming in the format [`choose_format`] picks.
pub fn start(src: &mut dyn FrameSource) -> Result<(PixelFormat, u32, u32)> {
    let offered = src.formats()?;
    let (f, w, h) = choose_format(&offered).ok_or_else(|| V4lError::Unsupported {
        path: src.describe(),
        reason: "offers neither YUYV nor MJPG".into(),
    })?;
    src.start(f, w, h)
}

/// On a streaming source: applies the settings, lets them settle, and grabs `count` decoded
/// frames. A bracket calls it once per exposure, on the running stream: the frames queued
/// before the change are thrown away with the settling ones.
pub fn grab(
    src: &mut dyn FrameSource,
    settings: &Settings,
    count: usize,
) -> Result<(Applied, Vec<Rgb8Frame>)> {
    let applied = src.apply(settings)?;
    tracing::info!(source = %src.describe(), ?applied, "V4L2 capture");
    for _ in 0..STREAM_BUFFERS + SETTLE_FRAMES {
        src.next_frame(FRAME_TIMEOUT)?;
    }
    let mut frames = Vec::with_capacity(count);
    for _ in 0..count {
        let raw = src.next_frame(FRAME_TIMEOUT)?;
        frames.push(decode(&raw).map_err(|reason| V4lError::Decode {
            path: src.describe(),
            sequence: raw.sequence,
            format: format!("{:?}", raw.format),
            bytes: raw.data.len(),
            reason,
        })?);
    }
    Ok((applied, frames))
}
