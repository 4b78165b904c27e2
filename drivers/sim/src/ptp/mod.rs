//! A simulated PTP camera: [`Responder`] holds the camera's state and answers operations;
//! [`usb`] serves it over the in-memory USB pipe, `functionfs` as a real USB gadget (Linux),
//! and [`ptpip`] as a PTP/IP server. `canon` and `sony` are the simulated EOS and Alpha
//! bodies' own state.

mod canon;
#[cfg(target_os = "linux")]
pub mod functionfs;
mod profiles;
pub mod ptpip;
mod responder;
mod sony;
pub mod usb;

pub use profiles::Profile;
pub use responder::{Faults, Reply, Responder, SharedResponder, WireFault};
