//! A V4L2 camera (or the simulated one) as the rig's object camera, the fallback when no DSLR
//! answers: it streams, so each exposure is a run of frames at a manual exposure time, gain
//! and white balance, which the flow averages in linear light.

use crate::error::DeviceError;
use crate::roles::{Bytes, CameraSettings, Exposed, ObjectCamera, Output, RigDevice};
use crate::Device;

/// A video camera on its worker, with the settings its bracket holds.
pub struct VideoCamera {
    pub source: Box<dyn brdfd_v4l::FrameSource>,
    /// What [`ObjectCamera::prepare`] was given; each exposure applies it with its time.
    held: CameraSettings,
}

impl VideoCamera {
    pub fn new(source: Box<dyn brdfd_v4l::FrameSource>) -> VideoCamera {
        VideoCamera {
            source,
            held: CameraSettings::default(),
        }
    }
}

impl Device for VideoCamera {
    fn identity(&self) -> String {
        self.source.describe()
    }
    fn keep_alive(&mut self) -> Result<(), DeviceError> {
        self.source.formats()?;
        Ok(())
    }
}

impl RigDevice for VideoCamera {
    fn object_camera(&mut self) -> Option<&mut (dyn ObjectCamera + 'static)> {
        Some(self)
    }
}

impl ObjectCamera for VideoCamera {
    fn prepare(&mut self, s: &CameraSettings) -> Result<Vec<String>, DeviceError> {
        let src = self.source.as_mut();
        let (format, w, h) = brdfd_v4l::start(src)?;
        self.held = s.clone();
        Ok(vec![format!(
            "fallback camera: {}, {format:?} {w}×{h}, {} frames per exposure",
            src.describe(),
            s.frames.max(1)
        )])
    }

    fn expose(&mut self, seconds: f64, _progress: Bytes) -> Result<Exposed, DeviceError> {
        let src = self.source.as_mut();
        let settings = brdfd_v4l::Settings {
            exposure_s: Some(seconds),
            gain: self.held.gain,
            white_balance_k: self.held.white_balance_k,
        };
        let (applied, frames) = brdfd_v4l::grab(src, &settings, self.held.frames.max(1))?;
        // Without a manual exposure time the camera stays on auto exposure, and no frame's
        // exposure is known: there is no bracket to merge.
        let Some(applied_s) = applied.exposure_s else {
            return Err(DeviceError::Cannot(format!(
                "the fallback camera {} has no manual exposure control ({}), so it cannot shoot a bracket",
                src.describe(),
                applied.notes.join(", ")
            )));
        };
        Ok(Exposed {
            applied_s,
            output: Output::Frames(frames),
        })
    }
}
