use std::time::Duration;

use crate::codes::rc;

pub type Result<T, E = PtpError> = std::result::Result<T, E>;

#[derive(Debug, thiserror::Error)]
pub enum PtpError {
    /// Bytes from the camera that do not parse. `offset` counts from the start of the
    /// container or dataset named by `what`.
    #[error("malformed {what} at byte {offset}: {reason}")]
    Malformed {
        what: &'static str,
        offset: usize,
        reason: String,
    },
    /// The camera answered an operation with a response code other than OK.
    #[error("camera answered {op:#06x} with {code:#06x} ({})", rc::name(*code))]
    Response { op: u16, code: u16 },
    #[error("timed out after {after:?} waiting for {what} (raise `{what}` in the rig's timeouts if the camera is slow)")]
    Timeout { what: &'static str, after: Duration },
    /// No TCP connection to a PTP/IP camera: nothing listens at the address, or nothing
    /// answers there.
    #[error("cannot connect to a PTP/IP camera at {addr}: {reason}. Check the address (PTP/IP's port is 15740), that the camera is on this network with its PTP/IP (PC connection) mode switched on, and that no firewall blocks the connection")]
    Connect { addr: String, reason: String },
    /// No USB access at all: libusb cannot start or list the bus.
    #[error("cannot use USB: libusb: {reason} (no USB access here? a container needs /dev/bus/usb passed in, and libusb needs /sys/bus/usb or udev to list devices)")]
    NoUsb { reason: String },
    /// A PTP/IP camera accepted the connection but did not finish the handshake in time.
    #[error("the camera at {addr} did not finish the PTP/IP handshake ({step}) within {after:?}: check that it is in PTP/IP (PC connection) mode, that no other program is connected to it, and confirm the pairing on its screen if it asks")]
    Handshake {
        addr: String,
        step: &'static str,
        after: Duration,
    },
    /// A failure, and the reset meant to recover from it failed too: both are said, the
    /// cause first, so that the reset's error does not hide what went wrong.
    #[error("{cause}; the reset that followed failed too: {reset}")]
    RecoveryFailed {
        cause: Box<PtpError>,
        reset: Box<PtpError>,
    },
    /// The camera halted (stalled) its bulk-in endpoint: over USB, how a camera abandons a
    /// transaction it cannot finish. The halt has been cleared; what it was sending is lost.
    #[error("the camera stalled its bulk-in endpoint during {during} and abandoned the transaction (the halt was cleared)")]
    Stalled { during: &'static str },
    /// The camera went away (unplugged, powered off, connection closed).
    #[error("camera disconnected during {during}")]
    Disconnected { during: &'static str },
    /// Another process has the USB interface.
    #[error("{device} is claimed by another process. On desktop Linux this is usually gvfs-gphoto2-volume-monitor, which mounts cameras automatically: run `pkill -f gvfs-gphoto2-volume-monitor` (or `systemctl --user mask gvfs-gphoto2-volume-monitor` to stop it for good), then unplug and replug the camera")]
    Claimed { device: String },
    #[error("no permission to open {device}: install config/udev/70-brdfd.rules (see its header) or run as a user in the plugdev group")]
    Permission { device: String },
    #[error("transport error: {0}")]
    Io(String),
    /// No camera on the bus answers to what was asked for: not plugged in, off, or not in
    /// PTP mode. The text says which camera was looked for.
    #[error("{0}")]
    NotFound(String),
    #[error("{0}")]
    Protocol(String),
    #[error("camera does not support {0}")]
    Unsupported(String),
}

impl PtpError {
    pub fn malformed(what: &'static str, offset: usize, reason: impl Into<String>) -> Self {
        PtpError::Malformed {
            what,
            offset,
            reason: reason.into(),
        }
    }

    /// Errors after which the link itself is suspect, so a reset and a retry may help.
    pub fn is_link_failure(&self) -> bool {
        matches!(
            self,
            PtpError::Io(_)
                | PtpError::Connect { .. }
                | PtpError::Disconnected { .. }
                | PtpError::Stalled { .. }
                | PtpError::Timeout { .. }
                | PtpError::Handshake { .. }
                | PtpError::RecoveryFailed { .. }
                | PtpError::Malformed { .. }
        )
    }

    /// `self`, the cause of a recovery, with the recovery's own failure added.
    pub fn and_recovery(self, reset: PtpError) -> PtpError {
        PtpError::RecoveryFailed {
            cause: Box::new(self),
            reset: Box::new(reset),
        }
    }

    pub fn response_code(&self) -> Option<u16> {
        match self {
            PtpError::Response { code, .. } => Some(*code),
            _ => None,
        }
    }
}

impl From<std::io::Error> for PtpError {
    fn from(e: std::io::Error) -> Self {
        use std::io::ErrorKind::*;
        match e.kind() {
            UnexpectedEof | ConnectionReset | ConnectionAborted | BrokenPipe | NotConnected => {
                PtpError::Disconnected { during: "I/O" }
            }
            _ => PtpError::Io(e.to_string()),
        }
    }
}
