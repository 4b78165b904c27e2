//! The rig's errors, and why a capture failed as a code a client can act on
//! ([`FailureCode`]): another program holds the camera, the disk is full, a device went away.
//!
//! - [`RigError`]: what a flow (a capture, a calibration) failed on: the typed error of the
//!   layer that failed, kept as the source of each step it failed in ([`StepExt::step`]).
//! - [`DeviceError`]: what a device in one of its roles, or its worker, failed on.
//! - [`RigFileError`]: a rig file a calibration writes; [`PoseRefused`]: a `calibrate pose`
//!   request's mistakes.
//!
//! The flow records a failure's code in the manifest beside the reason, and the daemon's event
//! stream ends with it. The drivers' typed errors say which ([`RigError::code`]), found
//! anywhere in the error's chain under the flow's steps. The daemon says an error to its
//! clients in words; the command line puts its own contexts around it. Every other module of
//! the rig imports this one, and it imports none of theirs but the configuration files' and
//! the sessions' own errors.

use std::path::PathBuf;

use brdfd_core::CoreError;
use brdfd_ptp::PtpError;
use brdfd_radiometry::RadiometryError;
use brdfd_serial::SerialError;
use brdfd_theta::ThetaError;
use brdfd_v4l::V4lError;

pub use brdfd_api::event::FailureCode;

use crate::config::ConfigError;
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
    /// What the simulated rig failed on ([`crate::simulation`]): its renderer's own error.
    #[error(transparent)]
    Simulator(Box<dyn std::error::Error + Send + Sync>),
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

    /// What a transparent variant holds: another layer's error, said as its own.
    fn transparent(&self) -> Option<&(dyn std::error::Error + 'static)> {
        Some(match self {
            RigError::Device(e) => e,
            RigError::Session(e) => e,
            RigError::Config(e) => e,
            RigError::RigFile(e) => e,
            RigError::Core(e) => e,
            RigError::Radiometry(e) => e,
            RigError::Pose(e) => e,
            RigError::Simulator(e) => e.as_ref(),
            RigError::Refused(e) => e,
            RigError::Io(e) => e,
            RigError::Plan(e) => e,
            RigError::Json(e) => e,
            RigError::Toml(e) => e,
            RigError::TomlWrite(e) => e,
            RigError::Invalid(_)
            | RigError::Cancelled
            | RigError::Unrecorded { .. }
            | RigError::In { .. } => return None,
        })
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
        failure_code(self)
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

/// A device that could not be opened for a job: its role and selector, what went wrong, and
/// its code, kept from the opener's typed error (the worker keeps the words for its status,
/// and a job may be refused long after the error was seen).
#[derive(Debug, Clone, thiserror::Error)]
#[error("the {role} ({selector}) could not be opened: {message}")]
pub struct DeviceUnavailable {
    pub role: String,
    pub selector: String,
    pub message: String,
    pub code: FailureCode,
}

/// What went wrong with a device in one of its roles (`crate::roles`): its driver's typed
/// error, its worker's, or the device's own words. [`DeviceError::code`] is the code a
/// capture that failed on it records.
#[derive(Debug, thiserror::Error)]
pub enum DeviceError {
    #[error(transparent)]
    Ptp(#[from] PtpError),
    #[error(transparent)]
    Theta(#[from] ThetaError),
    #[error(transparent)]
    Serial(#[from] SerialError),
    #[error(transparent)]
    V4l(#[from] V4lError),
    /// libgphoto2's, for a camera driven through it.
    #[cfg(feature = "gphoto2")]
    #[error(transparent)]
    Gphoto(#[from] brdfd_gphoto::GphotoError),
    /// The device could not be opened for the job.
    #[error(transparent)]
    Unavailable(#[from] DeviceUnavailable),
    /// A selector that names no device of the kind asked for.
    #[error("{0}")]
    WrongSelector(String),
    /// What the device cannot do, in words: a role it cannot play, a control it lacks.
    #[error("{0}")]
    Cannot(String),
    /// The rig's shutter did not fire the object camera.
    #[error("the rig's shutter {selector} did not fire the DSLR")]
    ShutterFailed {
        selector: String,
        #[source]
        cause: Box<DeviceError>,
    },
    /// A step of the device's work, and what failed in it.
    #[error("{step}")]
    During {
        step: &'static str,
        #[source]
        cause: Box<DeviceError>,
    },
    /// The capture was cancelled while the device worked.
    #[error("cancelled")]
    Cancelled,
    /// The capture stopped taking what the camera sent.
    #[error("the capture stopped taking files")]
    Abandoned,
    /// The device's thread ended before the job answered.
    #[error("the {0} worker stopped during the job")]
    WorkerStopped(String),
}

impl DeviceError {
    /// This error, as the cause of a failed `step`.
    pub fn during(self, step: &'static str) -> DeviceError {
        DeviceError::During {
            step,
            cause: Box::new(self),
        }
    }

    /// The code a failure of this error's says, if it says one.
    pub fn code(&self) -> Option<FailureCode> {
        match self {
            DeviceError::Ptp(p) => ptp_code(p),
            DeviceError::Theta(t) => theta_code(t),
            DeviceError::Serial(s) => serial_code(s),
            DeviceError::V4l(v) => v4l_code(v),
            DeviceError::Unavailable(d) => Some(d.code).filter(|c| *c != FailureCode::Failed),
            DeviceError::ShutterFailed { cause, .. } | DeviceError::During { cause, .. } => {
                cause.code()
            }
            _ => None,
        }
    }
}

/// `e` and its causes, as one line (what `anyhow` writes for `{:#}`): for a message that
/// passes a typed error on in words.
pub fn said(e: &(dyn std::error::Error + 'static)) -> String {
    let mut text = e.to_string();
    let mut cause = e.source();
    while let Some(c) = cause {
        text.push_str(": ");
        text.push_str(&c.to_string());
        cause = c.source();
    }
    text
}

/// The code of a capture's failure `e`: the first cause in its chain, from the outside in,
/// that a driver or the worker typed; else a full disk anywhere in it; else
/// [`FailureCode::Failed`]. A cancelled capture is the caller's to tell (its error is the
/// cancel's, wherever the capture stopped).
pub(crate) fn failure_code(e: &(dyn std::error::Error + 'static)) -> FailureCode {
    chain(e)
        .find_map(typed_code)
        .or_else(|| disk_full(e).then_some(FailureCode::DiskFull))
        .unwrap_or(FailureCode::Failed)
}

/// Whether `e` is a cancellation, by itself or through a cause: the capture's, the device's
/// or the core's stop (each says "cancelled", which another error's words may say too).
pub fn is_cancellation(e: &(dyn std::error::Error + 'static)) -> bool {
    chain(e).any(|c| {
        matches!(c.downcast_ref::<RigError>(), Some(RigError::Cancelled))
            || matches!(
                c.downcast_ref::<DeviceError>(),
                Some(DeviceError::Cancelled)
            )
            || matches!(c.downcast_ref::<CoreError>(), Some(CoreError::Stopped))
            || matches!(
                c.downcast_ref::<RadiometryError>(),
                Some(RadiometryError::Core(CoreError::Stopped))
            )
    })
}

/// `e`, then each of its causes, each as its own type: a step's cause is boxed
/// (`Box<RigError>`), and a box's `source` is its content's, which would leave the content
/// itself out of a plain walk of `source`; a transparent variant of [`RigError`] (a lower
/// layer's error) is likewise its content. So a caller looks for a `DeviceError` or a
/// `CoreError` as itself, wherever it sits.
pub fn chain<'a>(
    e: &'a (dyn std::error::Error + 'static),
) -> impl Iterator<Item = &'a (dyn std::error::Error + 'static)> {
    std::iter::successors(Some(unboxed(e)), |c| c.source().map(unboxed))
}

fn unboxed<'a>(e: &'a (dyn std::error::Error + 'static)) -> &'a (dyn std::error::Error + 'static) {
    if let Some(b) = e.downcast_ref::<Box<RigError>>() {
        return unboxed(b.as_ref());
    }
    if let Some(b) = e.downcast_ref::<Box<DeviceError>>() {
        return b.as_ref();
    }
    // A transparent variant's `source` is its content's source, which would leave the content
    // itself out of the walk: the chain holds the content instead.
    if let Some(inner) = e.downcast_ref::<RigError>().and_then(RigError::transparent) {
        return unboxed(inner);
    }
    e
}

/// Whether a full disk (ENOSPC) caused `e`, wherever in its chain: a session file's error, a
/// plain I/O error, or the core's (whose I/O error is a field, not a source).
pub fn disk_full(e: &(dyn std::error::Error + 'static)) -> bool {
    const ENOSPC: i32 = 28;
    let core_full = |c: &CoreError| matches!(c, CoreError::Io { error, .. } if error.raw_os_error() == Some(ENOSPC));
    chain(e).any(|c| {
        c.downcast_ref::<std::io::Error>()
            .and_then(std::io::Error::raw_os_error)
            == Some(ENOSPC)
            || c.downcast_ref::<CoreError>().is_some_and(core_full)
            || c.to_string().contains("the disk is full")
    })
}

/// The code one cause says, if it is a typed device error that says one. The rig's own
/// errors hold a driver's error inside [`DeviceError`]; a bare one is a link of the chain only
/// where a caller put it under contexts of its own (the command line, the tests).
fn typed_code(cause: &(dyn std::error::Error + 'static)) -> Option<FailureCode> {
    if let Some(d) = cause.downcast_ref::<DeviceError>() {
        return d.code();
    }
    if let Some(d) = cause.downcast_ref::<DeviceUnavailable>() {
        return Some(d.code).filter(|c| *c != FailureCode::Failed);
    }
    if let Some(p) = cause.downcast_ref::<PtpError>() {
        return ptp_code(p);
    }
    if let Some(t) = cause.downcast_ref::<ThetaError>() {
        return theta_code(t);
    }
    if let Some(s) = cause.downcast_ref::<SerialError>() {
        return serial_code(s);
    }
    if let Some(v) = cause.downcast_ref::<V4lError>() {
        return v4l_code(v);
    }
    None
}

fn theta_code(t: &ThetaError) -> Option<FailureCode> {
    match t {
        ThetaError::Timeout { .. } => Some(FailureCode::DeviceTimeout),
        ThetaError::NoConnection { .. } | ThetaError::Unreachable { .. } => {
            Some(FailureCode::DeviceMissing)
        }
        // The THETA over USB speaks PTP.
        ThetaError::Ptp(p) => ptp_code(p),
        _ => None,
    }
}

fn serial_code(s: &SerialError) -> Option<FailureCode> {
    match s {
        SerialError::Missing { .. } => Some(FailureCode::DeviceMissing),
        SerialError::Permission { .. } => Some(FailureCode::DevicePermission),
        SerialError::Busy { .. } => Some(FailureCode::DeviceBusy),
        SerialError::Unplugged { .. } => Some(FailureCode::DeviceLost),
        SerialError::Timeout { .. } | SerialError::GrblTimeout { .. } => {
            Some(FailureCode::DeviceTimeout)
        }
        _ => None,
    }
}

fn v4l_code(v: &V4lError) -> Option<FailureCode> {
    match v {
        V4lError::Missing { .. } => Some(FailureCode::DeviceMissing),
        V4lError::Permission { .. } => Some(FailureCode::DevicePermission),
        V4lError::Busy { .. } => Some(FailureCode::DeviceBusy),
        V4lError::Timeout { .. } => Some(FailureCode::DeviceTimeout),
        _ => None,
    }
}

fn ptp_code(p: &PtpError) -> Option<FailureCode> {
    match p {
        PtpError::Claimed { .. } => Some(FailureCode::DeviceBusy),
        PtpError::Permission { .. } => Some(FailureCode::DevicePermission),
        PtpError::NotFound(_) | PtpError::Connect { .. } => Some(FailureCode::DeviceMissing),
        PtpError::Disconnected { .. } => Some(FailureCode::DeviceLost),
        PtpError::Timeout { .. } => Some(FailureCode::DeviceTimeout),
        // A reset that failed after a stall or timeout: the cause's code.
        PtpError::RecoveryFailed { cause, .. } => ptp_code(cause),
        _ => None,
    }
}

/// A field of a [`PoseRequest`](crate::calibrate_pose::PoseRequest) that a refusal names.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Field {
    SensorWidth,
    /// [`PhotosFrom::Camera`](crate::calibrate_pose::PhotosFrom::Camera)'s `turn_deg`.
    Turn,
    /// [`PhotosFrom`](crate::calibrate_pose::PhotosFrom)'s `views`.
    Views,
    /// [`PhotosFrom::Files`](crate::calibrate_pose::PhotosFrom::Files)'s `board`, `object` and `empty`.
    BoardPhotos,
    ObjectPhotos,
    EmptyPhotos,
    RefineObject,
    Force,
}

impl Field {
    /// The request's own name for it.
    pub fn name(self) -> &'static str {
        match self {
            Field::SensorWidth => "`sensor_width_mm`",
            Field::Turn => "`turn_deg`",
            Field::Views => "`views`",
            Field::BoardPhotos => "the board's photos (`board`)",
            Field::ObjectPhotos => "the object's photos (`object`)",
            Field::EmptyPhotos => "the empty bench's photos (`empty`)",
            Field::RefineObject => "`refine_object`",
            Field::Force => "`force`",
        }
    }
}

/// Why a calibration was refused: a mistake in its request, said before anything is shot, or
/// a fit too poor to write. Its words name the request's fields ([`Field::name`]); whoever
/// took the request names them its own way ([`PoseRefused::said_with`]): the command line
/// by its flags.
#[derive(Debug, Clone, PartialEq)]
pub enum PoseRefused {
    /// The rig file's object camera is orthographic.
    Orthographic {
        rig_file: PathBuf,
    },
    SensorWidth(f64),
    Turn(f64),
    /// Photos of the object without the board's from where the camera stood for them.
    ObjectWithoutBoard,
    /// The object's placement asked for from photos, without the object's.
    RefineWithoutObject,
    /// Not one photo of the empty bench per photo of the object.
    Unpaired {
        object: usize,
        empty: usize,
    },
    /// More than one view asked of photos taken already.
    ViewsOfPhotos,
    /// The object's placement asked for, and the rig file's object is no mesh.
    NoMesh {
        rig_file: PathBuf,
    },
    /// The board's fit is poor, and the rig file was to be written: why.
    PoorFit(String),
}

impl PoseRefused {
    /// What was refused, with each field named by `name`.
    pub fn said_with(&self, name: impl Fn(Field) -> &'static str) -> String {
        use Field::*;
        match self {
            PoseRefused::Orthographic { rig_file } => format!(
                "{}: the object camera is orthographic: a pose from a board needs a pinhole camera ([geometry.camera] type = \"pinhole\", with fx, fy, cx, cy)",
                rig_file.display()
            ),
            PoseRefused::SensorWidth(s) => format!(
                "{} must be a positive number of millimetres, not {s}",
                name(SensorWidth)
            ),
            PoseRefused::Turn(t) => format!(
                "{} must be a number of degrees between 0 and 80, not {t}",
                name(Turn)
            ),
            PoseRefused::ObjectWithoutBoard => format!(
                "{} goes with {} (the board's photos from the camera as it stood for the object's); without them, {} photographs both",
                name(ObjectPhotos),
                name(BoardPhotos),
                name(RefineObject)
            ),
            PoseRefused::RefineWithoutObject => format!(
                "with {}, {} needs the object's photos and the empty bench's: {} and {}",
                name(BoardPhotos),
                name(RefineObject),
                name(ObjectPhotos),
                name(EmptyPhotos)
            ),
            PoseRefused::Unpaired { object, empty } => format!(
                "{object} {} and {empty} {}: each photo of the object needs one of the empty bench at its exposure",
                name(ObjectPhotos),
                name(EmptyPhotos)
            ),
            PoseRefused::ViewsOfPhotos => format!(
                "{} turns the board on the turntable; {} takes photos of the board as it stands, and solves from the one that shows the most of it",
                name(Views),
                name(BoardPhotos)
            ),
            PoseRefused::NoMesh { rig_file } => format!(
                "{}: {} aligns the object's mesh with its silhouette, and [geometry.shape] is no mesh",
                rig_file.display(),
                name(RefineObject)
            ),
            PoseRefused::PoorFit(why) => format!(
                "{why}; the rig file is left as it is ({} writes it anyway)",
                name(Force)
            ),
        }
    }
}

impl std::fmt::Display for PoseRefused {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.said_with(Field::name))
    }
}

impl std::error::Error for PoseRefused {}

/// Why a rig file could not be opened for a calibration, or written.
#[derive(Debug, thiserror::Error)]
pub enum RigFileError {
    #[error("reading {}", path.display())]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{} is not TOML", path.display())]
    NotToml {
        path: PathBuf,
        #[source]
        source: toml_edit::TomlError,
    },
    /// The table of `[geometry]` the calibration's `what` goes into is not there.
    #[error("{} has no [geometry.{table}] table to write the {what} into", path.display())]
    NoTable {
        path: PathBuf,
        table: String,
        what: String,
    },
    #[error("{}: geometry.{table} is not a table", path.display())]
    NotATable { path: PathBuf, table: String },
    /// What would be written is not a rig brdfd reads.
    #[error("the rig as written")]
    Written(#[source] ConfigError),
    #[error("keeping {}", path.display())]
    Backup {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error(transparent)]
    Write(#[from] SessionError),
    #[error("a pose is written for a pinhole camera")]
    NotPinhole,
    #[error("an object's placement is written for a mesh")]
    NotMesh,
}

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
        assert_eq!(said(&e), format!("view 2: turning to view 2: {words}"));
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

    /// A cancellation is told by its type wherever it sits under the steps, not by its
    /// words: an error that only says "cancelled" is not one.
    #[test]
    fn a_cancellation_is_known_by_its_type_under_the_steps() {
        let under_steps = |e: RigError| {
            Err::<(), _>(e)
                .step("view 2: object bracket")
                .step("view 2")
                .unwrap_err()
        };
        assert!(is_cancellation(&under_steps(RigError::Cancelled)));
        assert!(is_cancellation(&under_steps(RigError::Core(
            CoreError::Stopped
        ))));
        assert!(is_cancellation(&under_steps(RigError::Radiometry(
            RadiometryError::Core(CoreError::Stopped)
        ))));
        let device = Err::<(), _>(DeviceError::Cancelled)
            .step("downloading the bracket")
            .unwrap_err();
        assert!(is_cancellation(&under_steps(device)));
        assert!(!is_cancellation(&under_steps(RigError::invalid(
            "cancelled"
        ))));
        assert!(!is_cancellation(&RigError::invalid("no pixels")));
    }
    use anyhow::Context as _;
    use std::time::Duration;

    /// A device's error `e` as the flow returns it: under the steps a capture adds on its
    /// way out.
    fn code_of(e: impl Into<DeviceError>) -> FailureCode {
        use crate::error::StepExt as _;
        let e = Err::<(), _>(e.into())
            .step("view1: object bracket")
            .step("the rig's DSLR")
            .unwrap_err();
        e.code()
    }

    /// `e` as the command line holds it: under contexts of its own.
    fn code_under_contexts(e: impl std::error::Error + Send + Sync + 'static) -> FailureCode {
        let e = Err::<(), _>(e)
            .context("view1: object bracket")
            .context("the rig's DSLR")
            .unwrap_err();
        failure_code(e.as_ref())
    }

    #[test]
    fn a_drivers_typed_error_gives_the_failure_its_code() {
        let port = || "/dev/ttyACM0".to_string();
        assert_eq!(
            code_of(PtpError::Claimed {
                device: "usb:001,004".into()
            }),
            FailureCode::DeviceBusy
        );
        assert_eq!(
            code_of(PtpError::Disconnected {
                during: "GetObject"
            }),
            FailureCode::DeviceLost
        );
        assert_eq!(
            code_of(PtpError::Timeout {
                what: "capture",
                after: Duration::from_secs(30)
            }),
            FailureCode::DeviceTimeout
        );
        assert_eq!(
            code_of(ThetaError::Ptp(PtpError::Permission {
                device: "usb:001,005".into()
            })),
            FailureCode::DevicePermission
        );
        assert_eq!(
            code_of(SerialError::Busy { port: port() }),
            FailureCode::DeviceBusy
        );
        assert_eq!(
            code_of(SerialError::Unplugged {
                port: port(),
                command: "TURN 30".into()
            }),
            FailureCode::DeviceLost
        );
        assert_eq!(
            code_of(V4lError::Missing {
                path: "/dev/video9".into()
            }),
            FailureCode::DeviceMissing
        );
        assert_eq!(
            code_of(PtpError::NotFound(
                "no PTP camera on USB matching 04b0:0429".into()
            )),
            FailureCode::DeviceMissing
        );
        // A failure no driver typed has the plain code.
        assert_eq!(
            failure_code(anyhow::anyhow!("the estimate has no pixels").as_ref()),
            FailureCode::Failed
        );
    }

    /// A role's error keeps its driver's code under the steps and the shutter around it,
    /// and says them all in one line.
    #[test]
    fn a_device_error_keeps_its_drivers_code_under_the_steps_around_it() {
        let lost = DeviceError::from(PtpError::Disconnected {
            during: "GetObject",
        });
        assert_eq!(lost.code(), Some(FailureCode::DeviceLost));
        let busy = DeviceError::from(SerialError::Busy {
            port: "/dev/ttyACM0".into(),
        });
        let busy_words = busy.to_string();
        let shutter = DeviceError::ShutterFailed {
            selector: "serial:/dev/ttyACM0".into(),
            cause: Box::new(busy.during("pressing the release")),
        };
        assert_eq!(shutter.code(), Some(FailureCode::DeviceBusy));
        assert_eq!(
            said(&shutter),
            format!(
                "the rig's shutter serial:/dev/ttyACM0 did not fire the DSLR: pressing the release: {busy_words}"
            )
        );
        assert_eq!(code_of(shutter), FailureCode::DeviceBusy);
        // The device's own words and the worker's say no code of their own.
        assert_eq!(
            DeviceError::Cannot("no exposure control".into()).code(),
            None
        );
        assert_eq!(code_of(DeviceError::Abandoned), FailureCode::Failed);
    }

    #[test]
    fn a_full_disk_is_found_under_any_context() {
        let full = std::io::Error::from_raw_os_error(28);
        assert_eq!(code_under_contexts(full), FailureCode::DiskFull);
    }

    #[test]
    fn a_device_that_could_not_be_opened_keeps_its_openers_code() {
        let e = DeviceUnavailable {
            role: "dslr".into(),
            selector: "usb:04b0:0429".into(),
            message: "claimed by another process".into(),
            code: FailureCode::DeviceBusy,
        };
        assert_eq!(code_of(e), FailureCode::DeviceBusy);
    }

    /// A driver's error under the command line's contexts, without the rig's wrapper, says
    /// its code too.
    #[test]
    fn a_bare_drivers_error_under_contexts_says_its_code() {
        assert_eq!(
            code_under_contexts(SerialError::Busy {
                port: "/dev/ttyACM0".into()
            }),
            FailureCode::DeviceBusy
        );
        assert_eq!(
            code_under_contexts(PtpError::Disconnected {
                during: "GetObject"
            }),
            FailureCode::DeviceLost
        );
    }
}
