//! Line I/O on a serial port, shared by the rig protocol and GRBL: writes whose failures say
//! whether the device went away, and reads of whole lines against a deadline.

use std::io::{ErrorKind, Read, Write};
use std::time::{Duration, Instant};

use serialport::SerialPort;

use crate::error::{Result, SerialError};

/// Longest line accepted; a device that sends more is not speaking either protocol.
const MAX_LINE: usize = 256;

/// A port and the bytes read from it that do not make a whole line yet.
pub(crate) struct LinePort {
    pub port: Box<dyn SerialPort>,
    /// The port's name, for errors.
    pub name: String,
    pending: Vec<u8>,
}

impl LinePort {
    pub fn new(port: Box<dyn SerialPort>, name: String) -> LinePort {
        LinePort {
            port,
            name,
            pending: Vec::new(),
        }
    }

    /// Drops what was read and not taken, and what the system holds unread.
    pub fn discard_input(&mut self) {
        self.pending.clear();
        let _ = self.port.clear(serialport::ClearBuffer::Input);
    }

    /// Reads what the system holds already, without waiting.
    pub fn take_available(&mut self) {
        let mut buf = [0u8; 256];
        // At most a few lines: a device that floods the port is read by read_line, which
        // refuses an overlong line.
        while self.pending.len() <= MAX_LINE && self.port.bytes_to_read().is_ok_and(|n| n > 0) {
            match self.port.read(&mut buf) {
                Ok(n) if n > 0 => self.pending.extend_from_slice(&buf[..n]),
                _ => return,
            }
        }
    }

    /// Writes `bytes` (for `what`, named in errors) and waits until they are sent.
    pub fn write(&mut self, bytes: &[u8], what: &str) -> Result<()> {
        let unplugged = || SerialError::Unplugged {
            port: self.name.clone(),
            command: what.into(),
        };
        let io = |e: std::io::Error| SerialError::Io {
            port: self.name.clone(),
            reason: format!("`{what}`: {e}"),
        };
        // EIO, ENXIO, ENODEV: the adapter (or the far end of a pseudo-terminal) is gone.
        self.port
            .write_all(bytes)
            .map_err(|e| if gone(&e) { unplugged() } else { io(e) })?;
        // serialport reports a failed tcdrain without its errno; apart from being interrupted
        // (which it retries, then calls a timeout), tcdrain fails only when the terminal has
        // gone away.
        self.port.flush().map_err(|e| {
            if e.kind() == ErrorKind::TimedOut {
                io(e)
            } else {
                unplugged()
            }
        })
    }

    /// The next line, without its CR LF, read for `cmd` by `deadline` (`timeout` is what the
    /// error says was waited).
    pub fn read_line(&mut self, cmd: &str, deadline: Instant, timeout: Duration) -> Result<String> {
        let mut buf = [0u8; 64];
        loop {
            if let Some(end) = self.pending.iter().position(|&b| b == b'\n') {
                let line: Vec<u8> = self.pending.drain(..=end).collect();
                let text = String::from_utf8_lossy(&line);
                return Ok(text.trim_end_matches(['\r', '\n']).to_string());
            }
            if self.pending.len() > MAX_LINE {
                let line = String::from_utf8_lossy(&self.pending).into_owned();
                self.pending.clear();
                return Err(SerialError::Protocol {
                    port: self.name.clone(),
                    command: cmd.into(),
                    line,
                });
            }
            if Instant::now() >= deadline {
                return Err(SerialError::Timeout {
                    port: self.name.clone(),
                    command: cmd.into(),
                    after: timeout,
                });
            }
            let unplugged = || SerialError::Unplugged {
                port: self.name.clone(),
                command: cmd.into(),
            };
            match self.port.read(&mut buf) {
                Ok(0) => return Err(unplugged()),
                Ok(n) => self.pending.extend_from_slice(&buf[..n]),
                Err(e) if e.kind() == ErrorKind::TimedOut || e.kind() == ErrorKind::Interrupted => {
                }
                // A USB adapter pulled out, or the other end of a pseudo-terminal closed.
                Err(e) if gone(&e) => return Err(unplugged()),
                Err(e) => {
                    return Err(SerialError::Io {
                        port: self.name.clone(),
                        reason: format!("`{cmd}`: {e}"),
                    })
                }
            }
        }
    }
}

/// An I/O error that means the device is no longer there: EIO (5), ENXIO (6), ENODEV (19),
/// or a broken connection.
fn gone(e: &std::io::Error) -> bool {
    matches!(e.raw_os_error(), Some(5 | 6 | 19))
        || matches!(
            e.kind(),
            ErrorKind::BrokenPipe | ErrorKind::NotConnected | ErrorKind::UnexpectedEof
        )
}
