//! A PTP camera (a DSLR on USB or PTP/IP) as the rig's object camera: aperture and ISO held
//! through the bracket, the files the rig asks for, and each exposure fired over PTP
//! (InitiateCapture, or Nikon's own) or by the rig's shutter on the camera's remote socket.

use brdfd_ptp::{codes::rc, Camera, CaptureOptions, Captured, Exposure, ImageFormat, PtpError};

use crate::config::DslrFiles;
use crate::error::{said, DeviceError};
use crate::roles::{Bytes, CameraSettings, Exposed, Fire, ObjectCamera, Output, RigDevice};
use crate::Device;

impl Device for Camera {
    fn identity(&self) -> String {
        format!("{} (serial {})", self.describe(), self.info.serial_number)
    }
    fn keep_alive(&mut self) -> Result<(), DeviceError> {
        self.storage_ids()?;
        Ok(())
    }
}

impl RigDevice for Camera {
    fn object_camera(&mut self) -> Option<&mut (dyn ObjectCamera + 'static)> {
        Some(self)
    }
}

impl ObjectCamera for Camera {
    fn prepare(&mut self, s: &CameraSettings) -> Result<Vec<String>, DeviceError> {
        let applied = self.set_exposure(&Exposure {
            shutter_s: None,
            f_number: s.f_number,
            iso: s.iso,
        })?;
        let mut lines = vec![format!(
            "DSLR: {} ({}), f/{} ISO {}",
            self.describe(),
            self.info.serial_number,
            applied.f_number.unwrap_or(0.0),
            applied.iso.unwrap_or(0)
        )];
        if let Some(want) = s.files {
            lines.extend(set_files(self, want)?);
        }
        Ok(lines)
    }

    fn expose(&mut self, seconds: f64, progress: Bytes) -> Result<Exposed, DeviceError> {
        let applied_s = self.set_shutter(seconds)?;
        let files = self.capture_all(&CaptureOptions::default(), &mut |_, d, t| progress(d, t))?;
        Ok(exposed(applied_s, files))
    }

    fn expose_fired_by(
        &mut self,
        seconds: f64,
        fire: Fire,
        progress: Bytes,
    ) -> Option<Result<Exposed, DeviceError>> {
        Some((|| {
            let applied_s = self.set_shutter(seconds)?;
            // A shot fired from outside is stored on the card, where it is listed; the card
            // keeps its copy (brdfd deletes nothing from it).
            let opts = CaptureOptions {
                target: brdfd_ptp::Target::Card,
                delete_after: false,
            };
            let files = self.capture_fired(
                &mut || {
                    fire().map_err(|e| PtpError::Protocol(format!("the shutter: {}", said(&e))))
                },
                &opts,
                &mut |_, d, t| progress(d, t),
            )?;
            Ok(exposed(applied_s, files))
        })())
    }
}

fn exposed(applied_s: f64, files: Vec<Captured>) -> Exposed {
    Exposed {
        applied_s,
        output: Output::Files(
            files
                .into_iter()
                .map(|f| (f.info.filename, f.data))
                .collect(),
        ),
    }
}

/// Sets the camera to make the files the rig asks for. A camera that cannot be set so keeps
/// shooting as set on its body, and the merge takes what comes: RAW files if any, JPEGs
/// otherwise. Either way the operator is told.
fn set_files(cam: &mut Camera, want: DslrFiles) -> Result<Option<String>, DeviceError> {
    let format = match want {
        DslrFiles::RawJpeg => ImageFormat::RawJpeg,
        DslrFiles::Raw => ImageFormat::Raw,
        DslrFiles::Jpeg => ImageFormat::Jpeg,
    };
    Ok(match cam.set_format(format) {
        Ok(applied) if applied == format => None,
        Ok(applied) => Some(format!(
            "DSLR: asked for {format:?} files, the camera applied {applied:?}"
        )),
        Err(PtpError::Unsupported(what)) => Some(format!(
            "DSLR: {what} is not offered; it shoots as set on its body (the merge uses its RAW files if any, else its JPEGs, their tone curve taken as sRGB)"
        )),
        Err(PtpError::Response {
            code: rc::DEVICE_PROP_NOT_SUPPORTED,
            ..
        }) => Some("DSLR: it has no image-quality property; it shoots as set on its body".into()),
        Err(e) => return Err(e.into()),
    })
}
