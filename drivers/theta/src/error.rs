//! Errors of the THETA driver. Each says what was being done, what the camera (or the network)
//! answered, and what the operator can do about it.

use std::time::Duration;

use brdfd_ptp::PtpError;

pub type Result<T> = std::result::Result<T, ThetaError>;

#[derive(Debug, thiserror::Error)]
pub enum ThetaError {
    /// Nothing answered in time. Check that the camera is on, awake and on this network.
    #[error("{what}: no answer from the THETA at {camera} within {after:?}; check that it is on and that this machine is on its Wi-Fi (access-point mode: 192.168.1.1)")]
    Timeout {
        what: String,
        camera: String,
        after: Duration,
    },
    /// No connection could be made: nothing listens at the address, or nothing answers
    /// there. Check the address, that the camera's Wi-Fi is on in the mode the address
    /// belongs to, and that no firewall is in the way.
    #[error("{what}: cannot connect to the THETA at {camera}: {reason}. Check the address (in access-point mode the THETA is http://192.168.1.1 and this machine must be on the camera's own Wi-Fi; in client mode it is the address your router gave the camera), that the camera's Wi-Fi is on and in that mode, and that no firewall blocks the connection")]
    NoConnection {
        what: String,
        camera: String,
        reason: String,
    },
    /// The connection dropped, or failed other than in connecting.
    #[error("{what}: cannot talk to the THETA at {camera}: {reason}")]
    Unreachable {
        what: String,
        camera: String,
        reason: String,
    },
    /// The camera refused the command; `code` is the API's error code.
    #[error(
        "{what}: the THETA answered {code} (HTTP {status}): {message}{}",
        help_for(code)
    )]
    Command {
        what: String,
        code: String,
        message: String,
        status: u16,
    },
    /// An HTTP status without the API's error object.
    #[error("{what}: HTTP {status} from the THETA: {body}")]
    Http {
        what: String,
        status: u16,
        body: String,
    },
    /// The answer is not the API's JSON.
    #[error("{what}: the THETA's answer is not THETA Web API JSON: {reason}")]
    Malformed { what: String, reason: String },
    /// The camera wants credentials, or refused the ones given.
    #[error("{what}: {reason}. In client mode the THETA's user is THETAxx<serial> (for example THETAYL00165759) and the password its serial number, unless it was changed; give the user with --user and the password with --password-file or BRDFD_THETA_PASSWORD")]
    Auth { what: String, reason: String },
    /// A file URL that does not point at the camera: never followed.
    #[error("refusing to download {url}: it is not on the camera ({camera})")]
    ForeignUrl { url: String, camera: String },
    /// A download ended early (after retries).
    #[error("download of {url} failed after {attempts} attempts: {reason}")]
    Download {
        url: String,
        attempts: u32,
        reason: String,
    },
    /// The camera cannot do what was asked (model or firmware).
    #[error("{0}")]
    Unsupported(String),
    /// The USB (PTP) link.
    #[error(transparent)]
    Ptp(#[from] PtpError),
}

fn help_for(code: &str) -> &'static str {
    match code {
        "disabledCommand" => " (the camera is busy or in the wrong mode: wait for the current shot to finish, and set it to still-image mode)",
        "serviceUnavailable" => " (the camera is waking up or busy; it did not recover within the retry budget: press its shutter or power button once and try again)",
        "canceledShooting" => " (the shot was cancelled on the camera)",
        "invalidParameterValue" => " (this model or firmware does not accept that value)",
        _ => "",
    }
}
