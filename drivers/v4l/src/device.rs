//! A real V4L2 device through the `v4l` crate's ioctls: capabilities, formats, mmap streaming
//! with a poll timeout, and manual exposure, gain and white balance.

use std::io;
use std::time::Duration;

use v4l::buffer::Type;
use v4l::control::{Control, Value};
use v4l::io::mmap::Stream;
use v4l::io::traits::CaptureStream;
use v4l::video::Capture;
use v4l::{Device, FourCC};

use crate::{Applied, FrameSource, PixelFormat, RawFrame, Result, Settings, V4lError};

/// Control ids from linux/v4l2-controls.h (user class base 0x00980900, camera class base
/// 0x009a0900).
pub mod cid {
    pub const AUTO_WHITE_BALANCE: u32 = 0x0098_090C;
    pub const AUTOGAIN: u32 = 0x0098_0912;
    pub const GAIN: u32 = 0x0098_0913;
    pub const WHITE_BALANCE_TEMPERATURE: u32 = 0x0098_091A;
    pub const EXPOSURE_AUTO: u32 = 0x009A_0901;
    /// In units of 100 µs.
    pub const EXPOSURE_ABSOLUTE: u32 = 0x009A_0902;
    /// 1 lets the camera lower the frame rate to expose longer; 0 keeps it fixed.
    pub const EXPOSURE_AUTO_PRIORITY: u32 = 0x009A_0903;
}
/// EXPOSURE_AUTO's value for manual exposure.
const EXPOSURE_MANUAL: i64 = 1;
/// mmap buffers: enough that the driver never waits for us at 30 fps.
const BUFFERS: u32 = crate::STREAM_BUFFERS as u32;

pub struct V4lCamera {
    dev: Device,
    path: String,
    card: String,
    stream: Option<Stream<'static>>,
    format: Option<(PixelFormat, u32, u32)>,
}

fn io_error(path: &str, e: io::Error) -> V4lError {
    let path = path.to_string();
    match e.kind() {
        io::ErrorKind::NotFound => V4lError::Missing { path },
        io::ErrorKind::PermissionDenied => V4lError::Permission { path },
        _ if e.raw_os_error() == Some(16) => V4lError::Busy { path },
        _ => V4lError::Io {
            path,
            reason: e.to_string(),
        },
    }
}

impl V4lCamera {
    /// Opens a video capture node (`/dev/video0`).
    pub fn open(path: &str) -> Result<V4lCamera> {
        let dev = Device::with_path(path).map_err(|e| io_error(path, e))?;
        let caps = dev.query_caps().map_err(|e| io_error(path, e))?;
        use v4l::capability::Flags;
        let has = |f: Flags| caps.capabilities.intersects(f);
        if !has(Flags::VIDEO_CAPTURE) {
            // A driver makes several nodes; say which kind this one is.
            let what = if has(Flags::VIDEO_CAPTURE_MPLANE) {
                "a multi-planar capture node, which brdfd does not read"
            } else if has(Flags::VIDEO_OUTPUT | Flags::VIDEO_OUTPUT_MPLANE) {
                "a video output node"
            } else if has(Flags::META_CAPTURE | Flags::META_OUTPUT) {
                "a metadata node"
            } else {
                "no video capture"
            };
            return Err(V4lError::Unsupported {
                path: path.into(),
                reason: format!("{} is not a video capture device: {what}", caps.card),
            });
        }
        Ok(V4lCamera {
            dev,
            path: path.into(),
            card: caps.card,
            stream: None,
            format: None,
        })
    }

    fn io(&self, e: io::Error) -> V4lError {
        io_error(&self.path, e)
    }

    fn control(&self, id: u32) -> Option<i64> {
        match self.dev.control(id).ok()?.value {
            Value::Integer(v) => Some(v),
            Value::Boolean(b) => Some(b as i64),
            _ => None,
        }
    }

    /// Sets an integer control if the device has it, clamped and stepped to its range;
    /// returns the value read back.
    fn set(&self, id: u32, want: i64, notes: &mut Vec<String>, name: &str) -> Result<Option<i64>> {
        let controls = self.dev.query_controls().map_err(|e| self.io(e))?;
        let Some(d) = controls.iter().find(|d| d.id == id) else {
            notes.push(format!("no {name} control"));
            return Ok(None);
        };
        let step = d.step.max(1) as i64;
        let v = (d.minimum + ((want.clamp(d.minimum, d.maximum) - d.minimum) / step) * step)
            .clamp(d.minimum, d.maximum);
        self.dev
            .set_control(Control {
                id,
                value: Value::Integer(v),
            })
            .map_err(|e| V4lError::Io {
                path: self.path.clone(),
                reason: format!("setting {name} to {v}: {e}"),
            })?;
        Ok(self.control(id))
    }
}

impl FrameSource for V4lCamera {
    fn describe(&self) -> String {
        format!("{} ({})", self.card, self.path)
    }

    fn formats(&self) -> Result<Vec<(PixelFormat, u32, u32)>> {
        let mut out = Vec::new();
        for f in self.dev.enum_formats().map_err(|e| self.io(e))? {
            let Some(pf) = PixelFormat::from_fourcc(f.fourcc.repr) else {
                continue;
            };
            for size in self.dev.enum_framesizes(f.fourcc).map_err(|e| self.io(e))? {
                for d in size.size.to_discrete() {
                    out.push((pf, d.width, d.height));
                }
            }
        }
        Ok(out)
    }

    fn start(
        &mut self,
        format: PixelFormat,
        width: u32,
        height: u32,
    ) -> Result<(PixelFormat, u32, u32)> {
        self.stream = None;
        let want = v4l::Format::new(width, height, FourCC::new(&format.fourcc()));
        let got = self.dev.set_format(&want).map_err(|e| self.io(e))?;
        let pf =
            PixelFormat::from_fourcc(got.fourcc.repr).ok_or_else(|| V4lError::Unsupported {
                path: self.path.clone(),
                reason: format!("asked for {format:?}, the driver set {}", got.fourcc),
            })?;
        let stream =
            Stream::with_buffers(&self.dev, Type::VideoCapture, BUFFERS).map_err(|e| self.io(e))?;
        self.stream = Some(stream);
        self.format = Some((pf, got.width, got.height));
        Ok((pf, got.width, got.height))
    }

    fn apply(&mut self, s: &Settings) -> Result<Applied> {
        let mut a = Applied::default();
        let notes = &mut a.notes;
        if s.exposure_s.is_some() {
            if self
                .set(cid::EXPOSURE_AUTO, EXPOSURE_MANUAL, notes, "auto exposure")?
                .is_some()
            {
                notes.push("auto exposure off".into());
            }
            self.set(cid::EXPOSURE_AUTO_PRIORITY, 0, notes, "exposure priority")?;
        }
        if s.gain.is_some() && self.set(cid::AUTOGAIN, 0, notes, "auto gain")?.is_some() {
            notes.push("auto gain off".into());
        }
        if s.white_balance_k.is_some()
            && self
                .set(cid::AUTO_WHITE_BALANCE, 0, notes, "auto white balance")?
                .is_some()
        {
            notes.push("auto white balance off".into());
        }
        if let Some(t) = s.exposure_s {
            let units = (t * 1e4).round() as i64;
            a.exposure_s = self
                .set(cid::EXPOSURE_ABSOLUTE, units, notes, "exposure")?
                .map(|u| u as f64 / 1e4);
        }
        if let Some(g) = s.gain {
            a.gain = self.set(cid::GAIN, g, notes, "gain")?;
        }
        if let Some(k) = s.white_balance_k {
            a.white_balance_k = self.set(
                cid::WHITE_BALANCE_TEMPERATURE,
                k,
                notes,
                "white balance temperature",
            )?;
        }
        Ok(a)
    }

    fn next_frame(&mut self, timeout: Duration) -> Result<RawFrame> {
        let (format, width, height) = self.format.ok_or_else(|| V4lError::Io {
            path: self.path.clone(),
            reason: "next_frame before start".into(),
        })?;
        let path = self.path.clone();
        let stream = self.stream.as_mut().ok_or_else(|| V4lError::Io {
            path: path.clone(),
            reason: "not streaming".into(),
        })?;
        stream.set_timeout(timeout);
        let (buf, meta) = stream.next().map_err(|e| {
            if e.kind() == io::ErrorKind::TimedOut {
                V4lError::Timeout {
                    path: path.clone(),
                    after: timeout,
                }
            } else {
                io_error(&path, e)
            }
        })?;
        // The buffer is as large as the largest frame; only bytesused of it is this frame
        // (MJPG frames vary in size).
        let used = (meta.bytesused as usize).min(buf.len());
        Ok(RawFrame {
            format,
            width,
            height,
            sequence: meta.sequence,
            data: buf[..used].to_vec(),
        })
    }
}

/// A V4L2 node, as `brdfd devices` reports it.
#[derive(Debug, Clone)]
pub struct NodeInfo {
    pub path: String,
    pub name: String,
    /// Ok(formats) when it opens as a capture device, else why not.
    pub status: std::result::Result<Vec<(PixelFormat, u32, u32)>, String>,
}

/// Every `/dev/video*` node, with whether it opens and what it streams.
pub fn list_devices() -> Vec<NodeInfo> {
    v4l::context::enum_devices()
        .into_iter()
        .map(|node| {
            let path = node.path().display().to_string();
            let name = node.name().unwrap_or_default();
            let status = V4lCamera::open(&path)
                .and_then(|c| c.formats())
                .map_err(|e| e.to_string());
            NodeInfo { path, name, status }
        })
        .collect()
}
