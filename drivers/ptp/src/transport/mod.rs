//! How containers reach a camera. The transaction engine (`crate::camera`) speaks to a
//! [`Transport`]; USB ([`usb`]), PTP/IP ([`ptpip`]) and the in-memory pipe of the tests
//! ([`memory`]) implement it, so every test runs the same engine and framing code as a bench.

pub mod memory;
pub mod ptpip;
pub mod usb;

use std::time::Duration;

use crate::container::Message;
use crate::error::Result;

/// Bytes moved so far and the total of the current data phase.
pub type Progress<'a> = &'a mut dyn FnMut(u64, u64);

pub trait Transport: Send {
    /// Runs one transaction's phases: the operation request, the host-to-device data phase
    /// if `data_out` is given, then receives the device-to-host data phase if the camera
    /// sends one, and the response. `response_timeout` bounds the wait for each piece from
    /// the camera (capture operations need a long one).
    fn transact(
        &mut self,
        op: &Message,
        data_out: Option<&[u8]>,
        response_timeout: Duration,
        progress: Progress,
    ) -> Result<(Option<Vec<u8>>, Message)>;

    /// The next event, or `None` if none arrives within `timeout`.
    fn poll_event(&mut self, timeout: Duration) -> Result<Option<Message>>;

    /// Brings a wedged link back: a USB class Device Reset, a new PTP/IP connection. The
    /// camera's session is gone afterwards.
    fn reset(&mut self) -> Result<()>;

    /// Where the camera is, for messages ("usb:04b0:0429 bus 1 addr 5", "ptpip:host:port").
    fn describe(&self) -> String;
}
