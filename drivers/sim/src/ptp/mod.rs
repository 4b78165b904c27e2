//! A simulated PTP camera: [`Responder`] holds the camera's state and answers operations;
//! [`usb`] serves it over the in-memory USB pipe and [`ptpip`] as a PTP/IP server.

mod profiles;
mod responder;
pub mod ptpip;
pub mod usb;

pub use profiles::Profile;
pub use responder::{Faults, Reply, Responder, SharedResponder, WireFault};
