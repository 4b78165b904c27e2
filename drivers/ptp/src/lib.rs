//! PTP (Picture Transfer Protocol, ISO 15740) for brdfd: the bench DSLR and the THETA's USB
//! link.
//!
//! - [`container`], [`dataset`], [`wire`]: the codec, strict about bounds; malformed input is
//!   an error with its byte offset.
//! - [`transport`]: USB (rusb), PTP/IP over TCP, and an in-memory USB pipe for tests.
//! - [`camera`]: the transaction engine (sessions, busy retries, timeouts, recovery).
//! - [`capture`]: generic and Nikon capture, exposure settings, brackets.
//! - [`canon`]: Canon EOS remote release, its GetEvent records and exposure codes.
//! - [`sony`]: Sony Alpha's SDIO control: connection, property list, buttons, memory.
//! - [`exposure`]: the nominal shutter speeds, f-numbers and ISOs vendors encode.
//!
//! Behaviour follows ISO 15740, CIPA DC-005 (PTP/IP) and what libgphoto2's `camlibs/ptp2`
//! documents about real cameras; no code is taken from either.

/// The most a buffer is given up front from a length the device declares (a data container's,
/// StartData's, ObjectInfo's size). The device may lie: beyond this, the buffer grows only as
/// bytes actually arrive.
pub const PREALLOCATE_MAX: usize = 16 << 20;

/// The largest data phase brdfd accepts, bytes: above any still image a camera writes (a
/// 150 MP uncompressed RAW is about 300 MB). A camera that announces more is refused before a
/// byte of it is read.
pub const MAX_OBJECT_BYTES: u64 = 512 << 20;

/// The slowest data phase allowed for, bytes a second: below any camera's link (USB 2 and
/// Wi-Fi move megabytes a second). With [`MAX_OBJECT_BYTES`] it bounds every data phase by a
/// deadline brdfd sets, not the camera ([`data_deadline`]).
pub const MIN_DATA_RATE: f64 = 250_000.0;

/// How long a data phase of `bytes` may take in all: the response timeout, and the bytes at
/// [`MIN_DATA_RATE`]. At most about 36 minutes (a 512 MiB object); a 25 MB RAW file, 100 s.
pub fn data_deadline(response_timeout: std::time::Duration, bytes: u64) -> std::time::Duration {
    response_timeout + std::time::Duration::from_secs_f64(bytes as f64 / MIN_DATA_RATE)
}

/// Refuses a data phase larger than [`MAX_OBJECT_BYTES`].
pub(crate) fn check_object_size(bytes: u64, during: &str) -> Result<()> {
    if bytes > MAX_OBJECT_BYTES {
        return Err(PtpError::Protocol(format!(
            "the camera announced {bytes} bytes in {during}, more than the {} MiB brdfd accepts \
             for one object",
            MAX_OBJECT_BYTES >> 20
        )));
    }
    Ok(())
}

pub mod camera;
pub mod canon;
pub mod capture;
pub mod codes;
pub mod container;
pub mod dataset;
pub mod error;
pub mod exposure;
pub mod sony;
pub mod transport;
pub mod wire;

pub use camera::{Camera, Timeouts};
pub use capture::{CaptureOptions, Captured, Exposure, ImageFormat, Target};
pub use error::{PtpError, Result};
