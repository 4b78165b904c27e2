//! Why a capture failed, as a code a client can act on ([`FailureCode`]): another program
//! holds the camera, the disk is full, a device went away. The flow records it in the
//! manifest beside the reason, and the daemon's event stream ends with it. The drivers' typed
//! errors say which; they are found anywhere in the error's chain, under the flow's context.

use brdfd_ptp::PtpError;
use brdfd_serial::SerialError;
use brdfd_theta::ThetaError;
use brdfd_v4l::V4lError;

pub use brdfd_api::event::FailureCode;

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

/// The code of a capture's failure `e`: the first cause in its chain, from the outside in,
/// that a driver or the worker typed; else a full disk anywhere in it; else
/// [`FailureCode::Failed`]. A cancelled capture is the caller's to tell (its error is the
/// cancel's, wherever the capture stopped).
pub fn failure_code(e: &anyhow::Error) -> FailureCode {
    e.chain()
        .find_map(typed_code)
        .or_else(|| disk_full(e).then_some(FailureCode::DiskFull))
        .unwrap_or(FailureCode::Failed)
}

/// Whether a full disk (ENOSPC) caused `e`, wherever in its chain: a session file's error, a
/// plain I/O error, or the core's (whose I/O error is a field, not a source).
pub fn disk_full(e: &anyhow::Error) -> bool {
    const ENOSPC: i32 = 28;
    e.chain().any(|c| {
        c.downcast_ref::<std::io::Error>()
            .and_then(std::io::Error::raw_os_error)
            == Some(ENOSPC)
            || matches!(
                c.downcast_ref::<brdfd_core::CoreError>(),
                Some(brdfd_core::CoreError::Io { error, .. }) if error.raw_os_error() == Some(ENOSPC)
            )
            || c.to_string().contains("the disk is full")
    })
}

/// The code one cause says, if it is a typed device error that says one.
fn typed_code(cause: &(dyn std::error::Error + 'static)) -> Option<FailureCode> {
    if let Some(d) = cause.downcast_ref::<DeviceUnavailable>() {
        return Some(d.code).filter(|c| *c != FailureCode::Failed);
    }
    if let Some(p) = cause.downcast_ref::<PtpError>() {
        return ptp_code(p);
    }
    if let Some(t) = cause.downcast_ref::<ThetaError>() {
        return match t {
            ThetaError::Timeout { .. } => Some(FailureCode::DeviceTimeout),
            ThetaError::NoConnection { .. } | ThetaError::Unreachable { .. } => {
                Some(FailureCode::DeviceMissing)
            }
            // The THETA over USB speaks PTP.
            ThetaError::Ptp(p) => ptp_code(p),
            _ => None,
        };
    }
    if let Some(s) = cause.downcast_ref::<SerialError>() {
        return match s {
            SerialError::Missing { .. } => Some(FailureCode::DeviceMissing),
            SerialError::Permission { .. } => Some(FailureCode::DevicePermission),
            SerialError::Busy { .. } => Some(FailureCode::DeviceBusy),
            SerialError::Unplugged { .. } => Some(FailureCode::DeviceLost),
            SerialError::Timeout { .. } | SerialError::GrblTimeout { .. } => {
                Some(FailureCode::DeviceTimeout)
            }
            _ => None,
        };
    }
    if let Some(v) = cause.downcast_ref::<V4lError>() {
        return match v {
            V4lError::Missing { .. } => Some(FailureCode::DeviceMissing),
            V4lError::Permission { .. } => Some(FailureCode::DevicePermission),
            V4lError::Busy { .. } => Some(FailureCode::DeviceBusy),
            V4lError::Timeout { .. } => Some(FailureCode::DeviceTimeout),
            _ => None,
        };
    }
    None
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

#[cfg(test)]
mod tests {
    use super::*;
    use anyhow::Context as _;
    use std::time::Duration;

    /// `e` as the flow sees it: under the contexts a capture adds on its way out.
    fn code_of(e: impl std::error::Error + Send + Sync + 'static) -> FailureCode {
        let e = Err::<(), _>(e)
            .context("view1: object bracket")
            .context("the rig's DSLR")
            .unwrap_err();
        failure_code(&e)
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
            failure_code(&anyhow::anyhow!("the estimate has no pixels")),
            FailureCode::Failed
        );
    }

    #[test]
    fn a_full_disk_is_found_under_any_context() {
        let full = std::io::Error::from_raw_os_error(28);
        assert_eq!(code_of(full), FailureCode::DiskFull);
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
}
