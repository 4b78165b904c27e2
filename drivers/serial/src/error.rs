//! Errors of the serial devices, each with what the operator can do.

use std::time::Duration;

pub type Result<T> = std::result::Result<T, SerialError>;

#[derive(Debug, thiserror::Error)]
pub enum SerialError {
    /// No such port: the device is not plugged in, or the name is wrong.
    #[error("serial port {port} does not exist: is the trigger box or turntable plugged in? `brdfd devices` lists the ports")]
    Missing { port: String },
    /// The port exists but this user may not open it.
    #[error("no permission to open {port}: add yourself to the dialout group, or install config/udev/70-brdfd.rules (instructions in its header)")]
    Permission { port: String },
    /// Another program has the port open.
    #[error("{port} is in use by another program (a serial monitor, ModemManager?); close it and try again")]
    Busy { port: String },
    /// The device went away while we talked to it.
    #[error("{port} stopped answering during `{command}`: the device was unplugged or reset")]
    Unplugged { port: String, command: String },
    /// No answer in time.
    #[error("`{command}` on {port}: no answer within {after:?}; check the baud rate (115200) and that the firmware speaks the brdfd rig protocol")]
    Timeout {
        port: String,
        command: String,
        after: Duration,
    },
    /// The device refused the command.
    #[error("`{command}` on {port}: the device answered ERR {reason}")]
    Device {
        port: String,
        command: String,
        reason: String,
    },
    /// An answer that is not the protocol.
    #[error("`{command}` on {port}: unexpected answer {line:?} (expected OK or ERR)")]
    Protocol {
        port: String,
        command: String,
        line: String,
    },
    /// The device lacks what was asked (no turntable on a trigger box).
    #[error("{port}: the device ({name}) has no {capability}")]
    Unsupported {
        port: String,
        name: String,
        capability: String,
    },
    /// A GRBL controller refused a line, raised an alarm, or is not where or how it should be.
    #[error("`{command}` on {port} (GRBL): {reason}")]
    Grbl {
        port: String,
        command: String,
        reason: String,
    },
    /// No answer from a GRBL controller in time.
    #[error("`{command}` on {port}: no answer within {after:?}; check that the controller runs GRBL 1.1 at 115200 baud and that the axis turns")]
    GrblTimeout {
        port: String,
        command: String,
        after: Duration,
    },
    /// A value out of the protocol's range, refused before sending.
    #[error("{0}")]
    InvalidArgument(String),
    #[error("{port}: {reason}")]
    Io { port: String, reason: String },
}

impl SerialError {
    pub(crate) fn from_open(port: &str, e: serialport::Error) -> SerialError {
        let port = port.to_string();
        match e.kind() {
            serialport::ErrorKind::NoDevice => SerialError::Missing { port },
            serialport::ErrorKind::Io(std::io::ErrorKind::NotFound) => {
                SerialError::Missing { port }
            }
            serialport::ErrorKind::Io(std::io::ErrorKind::PermissionDenied) => {
                SerialError::Permission { port }
            }
            _ if e.description.contains("Permission denied") => SerialError::Permission { port },
            _ if e.description.contains("busy") || e.description.contains("locked") => {
                SerialError::Busy { port }
            }
            _ => SerialError::Io {
                port,
                reason: e.description,
            },
        }
    }
}
