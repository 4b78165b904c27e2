//! What a flow of the rig (a capture, a calibration) failed on: the typed error of the layer
//! that failed, kept as the source of each step it failed in, and the code a client acts on
//! ([`RigError::code`]). The daemon says it to its clients in words; the command line puts
//! its own contexts around it.

use brdfd_core::CoreError;
use brdfd_radiometry::RadiometryError;

use crate::calibrate_pose::PoseRefused;
use crate::config::ConfigError;
use crate::failure::{DeviceError, FailureCode};
use crate::rig_file::RigFileError;
use crate::session::SessionError;

#[derive(Debug, thiserror::Error)]
pub enum RigError {
    #[error(transparent)]
    Device(#[from] DeviceError),
    #[error(transparent)]
    Session(#[from] SessionError),
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error(transparent)]
    RigFile(#[from] RigFileError),
    #[error(transparent)]
    Core(#[from] CoreError),
    #[error(transparent)]
    Radiometry(#[from] RadiometryError),
    #[error(transparent)]
    Pose(#[from] brdfd_pose::PoseError),
    #[error(transparent)]
    Photo(#[from] brdfd_bench::PhotoError),
    #[error(transparent)]
    Refused(#[from] PoseRefused),
    /// A file's error whose step names the file.
    #[error(transparent)]
    Io(#[from] std::io::Error),
    /// What the rig, the plan or the bench does not allow, in words.
    #[error("{0}")]
    Invalid(String),
    /// The capture was cancelled.
    #[error("cancelled")]
    Cancelled,
    #[error(transparent)]
    Plan(#[from] brdfd_api::plan::PlanError),
    #[error(transparent)]
    Json(#[from] serde_json::Error),
    #[error(transparent)]
    Toml(#[from] toml_edit::TomlError),
    #[error(transparent)]
    TomlWrite(#[from] toml::ser::Error),
    /// A capture's failure that its manifest could not record.
    #[error("{unrecorded}")]
    Unrecorded {
        unrecorded: Unrecorded,
        #[source]
        cause: Box<RigError>,
    },
    /// A step of a flow, and what failed in it.
    #[error("{step}")]
    In {
        step: String,
        #[source]
        cause: Box<RigError>,
    },
}

pub type Result<T, E = RigError> = std::result::Result<T, E>;

impl RigError {
    /// An error in words.
    pub fn invalid(words: impl Into<String>) -> RigError {
        RigError::Invalid(words.into())
    }

    /// This error as the cause of a failed `step`.
    pub fn step(self, step: impl Into<String>) -> RigError {
        RigError::In {
            step: step.into(),
            cause: Box::new(self),
        }
    }

    /// The failure the manifest could not record, if this error carries one under its steps.
    pub fn unrecorded(&self) -> Option<&Unrecorded> {
        match self {
            RigError::Unrecorded { unrecorded, .. } => Some(unrecorded),
            RigError::In { cause, .. } => cause.unrecorded(),
            _ => None,
        }
    }

    /// The code of a capture that failed on this error: the first a device error says from
    /// the outside in, else a full disk anywhere in it, else [`FailureCode::Failed`].
    pub fn code(&self) -> FailureCode {
        crate::failure::failure_code(self)
    }
}

/// A failure the manifest could not record (the disk full, no file descriptor left), in the
/// error [`execute`](crate::flow::execute) returns: the daemon records it once it can
/// ([`record_failure`](crate::flow::record_failure)).
#[derive(Debug, Clone)]
pub struct Unrecorded {
    /// What the manifest should say.
    pub reason: String,
    /// Its code.
    pub code: FailureCode,
    /// Why it could not.
    pub error: String,
}

impl std::fmt::Display for Unrecorded {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "the failure could not be recorded in the manifest ({})",
            self.error
        )
    }
}

/// Names the step a result failed in: `.step("view 2: object bracket")`.
pub trait StepExt<T> {
    fn step(self, step: impl Into<String>) -> Result<T>;
    fn with_step(self, step: impl FnOnce() -> String) -> Result<T>;
}

impl<T, E: Into<RigError>> StepExt<T> for std::result::Result<T, E> {
    fn step(self, step: impl Into<String>) -> Result<T> {
        self.map_err(|e| RigError::In {
            step: step.into(),
            cause: Box::new(e.into()),
        })
    }

    fn with_step(self, step: impl FnOnce() -> String) -> Result<T> {
        self.map_err(|e| RigError::In {
            step: step(),
            cause: Box::new(e.into()),
        })
    }
}

/// What is missing, in the step's words: `.step("no turntable")`.
impl<T> StepExt<T> for Option<T> {
    fn step(self, step: impl Into<String>) -> Result<T> {
        self.ok_or_else(|| RigError::Invalid(step.into()))
    }

    fn with_step(self, step: impl FnOnce() -> String) -> Result<T> {
        self.ok_or_else(|| RigError::Invalid(step()))
    }
}

/// Returns early with [`RigError::Invalid`] in the words given: the rig's `bail!`.
macro_rules! refuse {
    ($($words:tt)*) => {
        return Err($crate::error::RigError::Invalid(format!($($words)*)))
    };
}
pub(crate) use refuse;

#[cfg(test)]
mod tests {
    use super::*;

    /// A device's code reaches the flow's error through the steps around it, and the steps
    /// are said in one line, outermost first.
    #[test]
    fn a_steps_cause_keeps_its_code_and_its_words() {
        let busy = DeviceError::from(brdfd_serial::SerialError::Busy {
            port: "/dev/ttyACM0".into(),
        });
        let words = busy.to_string();
        let e = Err::<(), _>(busy)
            .step("turning to view 2")
            .step("view 2")
            .unwrap_err();
        assert_eq!(e.code(), FailureCode::DeviceBusy);
        assert_eq!(
            crate::failure::said(&e),
            format!("view 2: turning to view 2: {words}")
        );
        assert_eq!(RigError::invalid("no pixels").code(), FailureCode::Failed);
        // A full disk under the steps, as the flow's own writes and the core's say it.
        let full = || std::io::Error::from_raw_os_error(28);
        let io = Err::<(), _>(full()).step("writing result/coefficients.json");
        assert_eq!(
            io.step("results").unwrap_err().code(),
            FailureCode::DiskFull
        );
        let core = CoreError::Io {
            path: "result/brdf.binary".into(),
            error: full(),
        };
        let core = Err::<(), _>(core).step("results").unwrap_err();
        assert_eq!(core.code(), FailureCode::DiskFull);
    }
}
