//! Errors of the estimation core. Each variant says what was wrong and where; the `Display`
//! text ends with what the user can do about it where there is something to do.

use std::path::PathBuf;

/// Anything the estimation core can fail with.
#[derive(Debug, thiserror::Error)]
pub enum CoreError {
    /// The file could not be opened, read or written.
    #[error("{path}: {error}")]
    Io {
        path: PathBuf,
        error: std::io::Error,
    },
    /// The file was read but its contents are not what the format requires.
    /// `what` names the file (or the embedded resource); `reason` names the field or offset.
    #[error("{what}: {reason}")]
    Format { what: String, reason: String },
    /// Radiance that no camera could have measured (NaN or infinity), with the pixel where it
    /// was found. Re-export the map from its source; a NaN usually comes from a broken merge.
    #[error("{what}: non-finite radiance {value} at pixel (x={x}, y={y}), channel {channel}; re-export the map, a NaN usually comes from a failed HDR merge")]
    NonFinite {
        what: String,
        x: usize,
        y: usize,
        channel: usize,
        value: f32,
    },
    /// A parameter is out of its allowed range; the message names it.
    #[error("{0}")]
    Invalid(String),
    /// The caller asked the work to stop ([`crate::stop::Stop`]); nothing is wrong with it.
    #[error("cancelled")]
    Stopped,
}

impl CoreError {
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        CoreError::Io {
            path: path.into(),
            error: source,
        }
    }

    pub fn format(what: impl std::fmt::Display, reason: impl Into<String>) -> Self {
        CoreError::Format {
            what: what.to_string(),
            reason: reason.into(),
        }
    }
}

pub type Result<T, E = CoreError> = std::result::Result<T, E>;
