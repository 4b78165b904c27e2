//! Devices from the selectors that name them. The CLI's device commands and the rig's workers
//! open devices the same way.

use std::time::Duration;

use brdfd_ptp::transport::ptpip::{Initiator, PtpIpTransport, DEFAULT_PORT};
use brdfd_ptp::transport::usb::{open_usb, UsbTransport};
use brdfd_ptp::transport::Transport;
use brdfd_ptp::{Camera, Timeouts};
use brdfd_serial::{ControlLine, GrblTurntable, RigController, RigTimeouts, ShutterCable};
use brdfd_theta::{Credentials, HttpTimeouts, Theta};

use super::devices::video::VideoCamera;
use super::error::DeviceError;
use super::roles::RigDevice;
use crate::selector::Selector;

/// How long a PTP/IP camera has to finish the handshake (the TCP connection itself has
/// `ptpip::CONNECT_TIMEOUT`, shorter, so that a dead address is told within 5 s).
const PTPIP_HANDSHAKE: Duration = Duration::from_secs(5);

/// Opens the PTP camera a selector names (`usb`, `usb:VVVV[:PPPP]`, `ptpip:HOST[:PORT]`).
pub fn ptp_camera(port: &Selector) -> Result<Camera, DeviceError> {
    let link: Box<dyn Transport> = match port {
        Selector::PtpIp(host) => {
            let addr = if host.contains(':') {
                host.clone()
            } else {
                format!("{host}:{DEFAULT_PORT}")
            };
            Box::new(PtpIpTransport::connect(
                addr.as_str(),
                Initiator::default(),
                PTPIP_HANDSHAKE,
            )?)
        }
        Selector::Usb { vendor, product } => {
            Box::new(UsbTransport::new(open_usb(*vendor, *product)?))
        }
        other => {
            return Err(DeviceError::WrongSelector(format!(
                "unknown camera port {:?}: {other} is not a PTP camera; use usb, usb:VVVV[:PPPP] or ptpip:HOST[:PORT]",
                other.to_string()
            )))
        }
    };
    Ok(Camera::open(link, Timeouts::default())?)
}

/// Opens a camera through the system's libgphoto2 (`gphoto2[:PORT]`), in a brdfd built with
/// the `gphoto2` feature; in one built without, says how to get it.
#[cfg(feature = "gphoto2")]
pub(crate) fn gphoto_camera(port: Option<&str>) -> Result<Box<dyn RigDevice>, DeviceError> {
    Ok(Box::new(brdfd_gphoto::GphotoCamera::open(port)?))
}

/// Opens a camera through the system's libgphoto2 (`gphoto2[:PORT]`), in a brdfd built with
/// the `gphoto2` feature; in one built without, says how to get it.
#[cfg(not(feature = "gphoto2"))]
pub(crate) fn gphoto_camera(port: Option<&str>) -> Result<Box<dyn RigDevice>, DeviceError> {
    Err(DeviceError::Cannot(format!(
        "gphoto2{}: this brdfd was built without libgphoto2; build it with `cargo install --path . --features gphoto2` (needs libgphoto2-dev, libclang-dev and pkg-config), or use brdfd's own PTP driver (usb, ptpip:HOST)",
        port.map(|p| format!(":{p}")).unwrap_or_default()
    )))
}

/// Opens the THETA a selector names: over HTTP, or over PTP (plain `usb` means the first
/// RICOH camera, not the first PTP camera: the DSLR may be plugged in too).
pub fn theta(
    port: &Selector,
    credentials: Option<Credentials>,
    timeouts: HttpTimeouts,
) -> Result<Theta, DeviceError> {
    match port {
        Selector::Osc(url) => Ok(Theta::connect_http(url, credentials, timeouts)?),
        Selector::Usb { vendor: None, .. } => Ok(Theta::from_ptp(ptp_camera(&Selector::Usb {
            vendor: Some(brdfd_theta::usb::RICOH_VENDOR),
            product: None,
        })?)?),
        Selector::Usb { .. } | Selector::PtpIp(_) => Ok(Theta::from_ptp(ptp_camera(port)?)?),
        other => Err(DeviceError::WrongSelector(format!(
            "{other} is not a THETA; use osc:http://HOST, usb or usb:05ca:PPPP"
        ))),
    }
}

/// Opens the V4L2 camera a selector names (`v4l:/dev/videoN`).
pub(crate) fn video_camera(port: &Selector) -> Result<VideoCamera, DeviceError> {
    match port {
        Selector::V4l(path) => Ok(VideoCamera::new(Box::new(
            brdfd_v4l::device::V4lCamera::open(path)?,
        ))),
        other => Err(DeviceError::WrongSelector(format!(
            "{other} is not a V4L2 camera; use v4l:/dev/videoN"
        ))),
    }
}

/// Opens a release cable on a serial adapter's DTR or RTS line, released.
pub fn cable(rts: bool, path: &str) -> Result<ShutterCable, DeviceError> {
    let line = if rts {
        ControlLine::Rts
    } else {
        ControlLine::Dtr
    };
    Ok(ShutterCable::new(brdfd_serial::open(path)?, line, false)?)
}

/// Opens a turntable or trigger box that speaks the brdfd rig protocol.
pub fn turntable(path: &str) -> Result<RigController, DeviceError> {
    Ok(RigController::open(path, RigTimeouts::default())?)
}

/// Opens a GRBL controller whose `axis` turns the table, homed if it is locked in Alarm (as
/// one with homing enabled is after power-up): the rig needs it to turn.
pub fn grbl(path: &str, axis: char) -> Result<GrblTurntable, DeviceError> {
    let mut table = GrblTurntable::open(path, axis, RigTimeouts::default())?;
    table.unlock_by_homing()?;
    Ok(table)
}

/// Timeouts for a simulated THETA on loopback: the real defaults, with faster polling.
pub fn loopback_timeouts() -> HttpTimeouts {
    HttpTimeouts {
        poll: Duration::from_millis(20),
        ..HttpTimeouts::default()
    }
}
