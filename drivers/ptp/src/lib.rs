//! PTP (Picture Transfer Protocol, ISO 15740) for brdfd: the bench DSLR and the THETA's USB
//! link.
//!
//! - [`container`], [`dataset`], [`wire`]: the codec, strict about bounds; malformed input is
//!   an error with its byte offset.
//! - [`transport`]: USB (rusb), PTP/IP over TCP, and an in-memory USB pipe for tests.
//! - [`camera`]: the transaction engine (sessions, busy retries, timeouts, recovery).
//! - [`capture`]: generic and Nikon capture, exposure settings, brackets.
//!
//! Behaviour follows ISO 15740, CIPA DC-005 (PTP/IP) and what libgphoto2's `camlibs/ptp2`
//! documents about real cameras; no code is taken from either.

/// The most a buffer is given up front from a length the device declares (a data container's,
/// StartData's, ObjectInfo's size). The device may lie: beyond this, the buffer grows only as
/// bytes actually arrive.
pub const PREALLOCATE_MAX: usize = 16 << 20;

pub mod camera;
pub mod capture;
pub mod codes;
pub mod container;
pub mod dataset;
pub mod error;
pub mod transport;
pub mod wire;

pub use camera::{Camera, Timeouts};
pub use capture::{CaptureOptions, Captured, Exposure, ImageFormat, Target};
pub use error::{PtpError, Result};
