//! A remote-release cable on a serial adapter's modem line: DTR or RTS held active for the
//! exposure, as astronomy and time-lapse cables do. Needs no firmware; the cable's
//! optocoupler closes the camera's shutter contacts while the line is active.

use std::time::Duration;

use serialport::SerialPort;

use crate::controller::MAX_FIRE_MS;
use crate::error::{Result, SerialError};

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ControlLine {
    Dtr,
    Rts,
}

/// Settle time between pulses: a camera's release input needs the contacts open this long
/// before it sees the next press.
pub const RELEASE_GAP: Duration = Duration::from_millis(100);

pub struct ShutterCable {
    port: Box<dyn SerialPort>,
    name: String,
    line: ControlLine,
    /// Some cables close the contacts when the line is low; this inverts the level.
    active_low: bool,
}

impl ShutterCable {
    /// Takes the port and puts the line in its released state.
    pub fn new(
        port: Box<dyn SerialPort>,
        line: ControlLine,
        active_low: bool,
    ) -> Result<ShutterCable> {
        let name = port.name().unwrap_or_else(|| "serial port".into());
        let mut cable = ShutterCable {
            port,
            name,
            line,
            active_low,
        };
        cable.set(false)?;
        Ok(cable)
    }

    /// Holds the release for `ms` milliseconds (press, wait, release, settle).
    #[tracing::instrument(skip(self), fields(port = %self.name, line = ?self.line))]
    pub fn fire(&mut self, ms: u32) -> Result<()> {
        if !(1..=MAX_FIRE_MS).contains(&ms) {
            return Err(SerialError::InvalidArgument(format!(
                "a shutter pulse of {ms} ms is outside 1..={MAX_FIRE_MS} ms"
            )));
        }
        self.set(true)?;
        std::thread::sleep(Duration::from_millis(ms as u64));
        // Release even if the sleep was cut short: a line left active keeps the shutter open.
        self.set(false)?;
        std::thread::sleep(RELEASE_GAP);
        Ok(())
    }

    /// Holds the line released: what a keep-alive does, since a cable has nothing to answer.
    /// An adapter that was unplugged fails it.
    pub fn release(&mut self) -> Result<()> {
        self.set(false)
    }

    /// The port it is on.
    pub fn port_name(&self) -> &str {
        &self.name
    }

    pub fn line(&self) -> ControlLine {
        self.line
    }

    fn set(&mut self, pressed: bool) -> Result<()> {
        let level = pressed != self.active_low;
        let r = match self.line {
            ControlLine::Dtr => self.port.write_data_terminal_ready(level),
            ControlLine::Rts => self.port.write_request_to_send(level),
        };
        r.map_err(|e| SerialError::Io {
            port: self.name.clone(),
            reason: format!(
                "cannot drive {:?}: {} (a pseudo-terminal or a bare UART without modem lines cannot; use a USB serial adapter with DTR/RTS)",
                self.line, e.description
            ),
        })
    }
}

impl Drop for ShutterCable {
    fn drop(&mut self) {
        let _ = self.set(false);
    }
}
