//! Serial devices at the bench: a trigger box and turntable that speak the line protocol
//! below ([`RigController`]), a turntable on a GRBL G-code controller ([`GrblTurntable`]),
//! and a remote-release cable driven by the DTR or RTS line ([`ShutterCable`]), which needs
//! no firmware.
//!
//! Both run on the `serialport` crate. Tests and the simulator use a pseudo-terminal pair, so
//! the same serial code path runs there as on a USB serial adapter.
//!
//! # The brdfd rig protocol (version 1)
//!
//! A lab can flash any microcontroller with a UART (an Arduino, a Pico) to speak it;
//! `firmware/` holds firmware for an ATmega328P (Arduino Uno or Nano) with a stepper driver.
//!
//! - 115200 baud, 8 data bits, no parity, 1 stop bit, no flow control.
//! - The host sends one command per line, in ASCII, ended by LF (CR LF is accepted).
//! - The device answers every command with exactly one line: `OK`, `OK <value>`, or
//!   `ERR <reason>`. Lines that start with `#` are the device's own log and are ignored.
//! - Positions are degrees in [0, 360), decimal, with at least 0.1° resolution.
//!
//! | command | answer | meaning |
//! |---|---|---|
//! | `ID?` | `OK <name> <version> <capability>...` | who it is; capabilities are `FIRE` and `ROT` |
//! | `FIRE <ms>` | `OK` | hold the shutter line for `ms` (1 to 60000) milliseconds, answer when released |
//! | `ROT <deg>` | `OK <pos>` | turn by `deg` (signed decimal), answer at rest with the new position |
//! | `HOME` | `OK <pos>` | turn to the home switch, answer at rest (0 unless the switch is offset) |
//! | `POS?` | `OK <pos>` | the current position |
//!
//! Example exchange: `ID?` → `OK brdfd-turntable 1 FIRE ROT`; `ROT 45` → `OK 45.0`;
//! `FIRE 200` → `OK`; `ROT -90` → `OK 315.0`.

mod cable;
mod controller;
mod error;
mod grbl;
mod line;

pub use cable::{ControlLine, ShutterCable};
pub use controller::{Identity, RigController, RigTimeouts};
pub use error::{Result, SerialError};
pub use grbl::{looks_like_grbl, GrblIdentity, GrblStatus, GrblTurntable, GRBL_BAUD_RATE};

/// Default line settings of the protocol.
pub const BAUD_RATE: u32 = 115_200;

/// Opens a serial port with the protocol's settings, with errors that say what to do.
pub fn open(path: &str) -> Result<Box<dyn serialport::SerialPort>> {
    serialport::new(path, BAUD_RATE)
        .timeout(controller::READ_SLICE)
        .open()
        .map_err(|e| SerialError::from_open(path, e))
}

/// A serial port the system lists.
#[derive(Debug, Clone)]
pub struct PortInfo {
    pub path: String,
    /// "USB 2341:0043 Arduino Uno (serial 7573...)", "PCI", "Bluetooth", "unknown".
    pub kind: String,
    pub usb_ids: Option<(u16, u16)>,
}

/// The serial ports present (USB adapters, on-board UARTs, pseudo-terminals are not listed).
pub fn list_ports() -> Result<Vec<PortInfo>> {
    // serialport lists from sysfs (brdfd builds it without libudev), and panics where there
    // is no /sys/class/tty, as in some containers: say so instead.
    #[cfg(target_os = "linux")]
    if !std::path::Path::new("/sys/class/tty").is_dir() {
        return Err(SerialError::Io {
            port: "(listing ports)".into(),
            reason: "/sys/class/tty is missing (no sysfs here?)".into(),
        });
    }
    let ports = serialport::available_ports().map_err(|e| SerialError::Io {
        port: "(listing ports)".into(),
        reason: e.to_string(),
    })?;
    Ok(ports
        .into_iter()
        .map(|p| {
            let (kind, usb_ids) = match p.port_type {
                serialport::SerialPortType::UsbPort(u) => (
                    format!(
                        "USB {:04x}:{:04x} {}{}",
                        u.vid,
                        u.pid,
                        u.product.unwrap_or_default(),
                        u.serial_number
                            .map(|s| format!(" (serial {s})"))
                            .unwrap_or_default()
                    ),
                    Some((u.vid, u.pid)),
                ),
                serialport::SerialPortType::PciPort => ("PCI".into(), None),
                serialport::SerialPortType::BluetoothPort => ("Bluetooth".into(), None),
                serialport::SerialPortType::Unknown => ("unknown".into(), None),
            };
            PortInfo {
                path: p.port_name,
                kind,
                usb_ids,
            }
        })
        .collect())
}
