//! A camera driven through the system's libgphoto2 (the `gphoto2` feature) as the rig's object
//! camera: for the bodies brdfd's own PTP driver has no flow for. Aperture and ISO are held
//! through the bracket, each exposure is fired by libgphoto2 or by the rig's shutter, and the
//! files come as libgphoto2 reports them.

use std::time::Duration;

use brdfd_gphoto::{Exposure, GphotoCamera};

use crate::error::DeviceError;
use crate::roles::{Bytes, CameraSettings, Exposed, Fire, ObjectCamera, Output, RigDevice};
use crate::Device;

/// How long after an exposure fired from outside its files may take to be announced.
const FIRED_FILES_WAIT: Duration = Duration::from_secs(10);

impl Device for GphotoCamera {
    fn identity(&self) -> String {
        match self.serial() {
            Some(s) => format!("{} (serial {s}) through libgphoto2", self.model()),
            None => format!("{} through libgphoto2", self.model()),
        }
    }
    fn keep_alive(&mut self) -> Result<(), DeviceError> {
        Ok(GphotoCamera::keep_alive(self)?)
    }
}

impl RigDevice for GphotoCamera {
    fn object_camera(&mut self) -> Option<&mut (dyn ObjectCamera + 'static)> {
        Some(self)
    }
}

impl ObjectCamera for GphotoCamera {
    fn prepare(&mut self, s: &CameraSettings) -> Result<Vec<String>, DeviceError> {
        let applied = self.set_exposure(&Exposure {
            shutter_s: None,
            f_number: s.f_number,
            iso: s.iso,
        })?;
        let mut lines = vec![format!(
            "DSLR: {} on {} through libgphoto2, f/{} ISO {}",
            self.model(),
            self.port(),
            applied.f_number.unwrap_or(0.0),
            applied.iso.unwrap_or(0)
        )];
        if let Some(want) = s.files {
            // libgphoto2's image-format choices are each vendor's own words ("RAW + Large
            // Fine JPEG", "NEF+Fine"): the body shoots as set on it, and the merge takes its
            // RAW files if any, else its JPEGs.
            lines.push(format!(
                "DSLR: asked for {want:?} files; through libgphoto2 it shoots as set on its body (the merge uses its RAW files if any, else its JPEGs)"
            ));
        }
        Ok(lines)
    }

    fn expose(&mut self, seconds: f64, progress: Bytes) -> Result<Exposed, DeviceError> {
        let applied_s = self.set_shutter(seconds)?;
        let files = self.capture(progress)?;
        Ok(Exposed {
            applied_s,
            output: Output::Files(files),
        })
    }

    fn expose_fired_by(
        &mut self,
        seconds: f64,
        fire: Fire,
        progress: Bytes,
    ) -> Option<Result<Exposed, DeviceError>> {
        Some((|| {
            let applied_s = self.set_shutter(seconds)?;
            self.forget_pending_events()?;
            fire()?;
            let files = self.files_of_fired_shot(
                Duration::from_secs_f64(applied_s) + FIRED_FILES_WAIT,
                progress,
            )?;
            Ok(Exposed {
                applied_s,
                output: Output::Files(files),
            })
        })())
    }
}
