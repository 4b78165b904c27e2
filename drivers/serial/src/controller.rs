//! The host side of the brdfd rig protocol (see the crate docs): one command, one answer,
//! each with its own timeout, every answer checked.

use std::time::{Duration, Instant};

use serialport::SerialPort;

use crate::error::{Result, SerialError};
use crate::line::LinePort;

/// Reads wait at most this long at a time, so that deadlines are kept to about this precision.
pub(crate) const READ_SLICE: Duration = Duration::from_millis(50);
/// Longest shutter pulse the protocol allows, in milliseconds.
pub const MAX_FIRE_MS: u32 = 60_000;
/// How far (degrees) a turntable may stop from where it was asked before it is an error.
pub const POSITION_TOLERANCE_DEG: f64 = 0.5;

/// Timeouts of the rig protocol. An answer may take the command's own duration (a pulse, a
/// rotation) plus `answer`.
#[derive(Debug, Clone, Copy)]
pub struct RigTimeouts {
    /// For a command that does not move anything.
    pub answer: Duration,
    /// Slowest rotation speed to allow for, degrees per second.
    pub min_speed_deg_s: f64,
    /// A full homing run.
    pub home: Duration,
    /// How long a board has to start answering after the port is opened: opening the port
    /// resets an Arduino (its DTR line), and its bootloader, not the firmware, reads what
    /// comes in the first second or two.
    pub boot: Duration,
}

impl Default for RigTimeouts {
    fn default() -> Self {
        RigTimeouts {
            answer: Duration::from_secs(1),
            min_speed_deg_s: 10.0,
            home: Duration::from_secs(60),
            boot: Duration::from_secs(4),
        }
    }
}

/// What the device says it is (`ID?`).
#[derive(Debug, Clone, PartialEq)]
pub struct Identity {
    pub name: String,
    pub version: String,
    pub can_fire: bool,
    pub can_rotate: bool,
}

/// A trigger box and/or turntable on a serial port.
pub struct RigController {
    link: LinePort,
    pub identity: Identity,
    pub timeouts: RigTimeouts,
    /// What the device answered to `ID?`, to recognise it when resynchronising.
    id_answer: String,
    /// A command ended without its answer (a timeout, or a line that was not one): the answer
    /// may still come, and must not be taken for the next command's.
    out_of_step: bool,
}

impl RigController {
    /// Talks to the device on `port` (already open): discards stale input, then asks `ID?`.
    pub fn new(mut port: Box<dyn SerialPort>, timeouts: RigTimeouts) -> Result<RigController> {
        let name = port.name().unwrap_or_else(|| "serial port".into());
        port.set_timeout(READ_SLICE).map_err(|e| SerialError::Io {
            port: name.clone(),
            reason: e.to_string(),
        })?;
        // Bytes a device printed at boot, or a half answer from an earlier session, would be
        // read as the answer to our first command.
        let _ = port.clear(serialport::ClearBuffer::Input);
        let mut rig = RigController {
            link: LinePort::new(port, name),
            identity: Identity {
                name: String::new(),
                version: String::new(),
                can_fire: false,
                can_rotate: false,
            },
            timeouts,
            id_answer: String::new(),
            out_of_step: false,
        };
        let id = rig.first_identity()?;
        rig.id_answer = id.clone();
        let mut words = id.split_whitespace();
        let (Some(name), Some(version)) = (words.next(), words.next()) else {
            return Err(SerialError::Protocol {
                port: rig.link.name.clone(),
                command: "ID?".into(),
                line: format!("OK {id}"),
            });
        };
        let caps: Vec<&str> = words.collect();
        rig.identity = Identity {
            name: name.into(),
            version: version.into(),
            can_fire: caps.contains(&"FIRE"),
            can_rotate: caps.contains(&"ROT"),
        };
        tracing::info!(port = %rig.link.name, device = %name, version, ?caps, "rig controller");
        Ok(rig)
    }

    /// The first `ID?`'s answer, asked again until the board has booted: a question sent
    /// while an Arduino's bootloader runs is lost. One line that is no answer is asked past
    /// too: clearing the input may cut a line the booting firmware was printing (its
    /// `# … ready` without the `#`), and its rest then arrives first. A second is the
    /// device's answer: another protocol's, say.
    fn first_identity(&mut self) -> Result<String> {
        let start = Instant::now();
        let mut cut_line = true;
        loop {
            match self.exchange("ID?", self.timeouts.answer) {
                Err(SerialError::Timeout { .. }) if start.elapsed() < self.timeouts.boot => {
                    tracing::debug!(port = %self.link.name, "no answer to ID? yet: asking again");
                    self.link.discard_input();
                }
                Err(SerialError::Protocol { line, .. })
                    if cut_line && start.elapsed() < self.timeouts.boot =>
                {
                    tracing::debug!(port = %self.link.name, "{line:?} is no answer to ID?: asking again");
                    cut_line = false;
                    self.link.discard_input();
                }
                other => return other,
            }
        }
    }

    /// Opens `path` and identifies the device.
    pub fn open(path: &str, timeouts: RigTimeouts) -> Result<RigController> {
        RigController::new(crate::open(path)?, timeouts)
    }

    pub fn port_name(&self) -> &str {
        &self.link.name
    }

    /// Holds the shutter line for `ms` milliseconds; returns when the device has released it.
    #[tracing::instrument(skip(self), fields(port = %self.link.name))]
    pub fn fire(&mut self, ms: u32) -> Result<()> {
        self.require(self.identity.can_fire, "shutter output (FIRE)")?;
        if !(1..=MAX_FIRE_MS).contains(&ms) {
            return Err(SerialError::InvalidArgument(format!(
                "a shutter pulse of {ms} ms is outside 1..={MAX_FIRE_MS} ms"
            )));
        }
        let answer = self.command(
            &format!("FIRE {ms}"),
            Duration::from_millis(ms as u64) + self.timeouts.answer,
        )?;
        self.expect_empty("FIRE", &answer)
    }

    /// Turns by `deg` (positive is the device's positive direction); returns the position at
    /// rest, checked against where it should be.
    #[tracing::instrument(skip(self), fields(port = %self.link.name))]
    pub fn rotate(&mut self, deg: f64) -> Result<f64> {
        self.require(self.identity.can_rotate, "turntable (ROT)")?;
        if !deg.is_finite() || deg.abs() > 3600.0 {
            return Err(SerialError::InvalidArgument(format!(
                "a rotation of {deg}° is not a turn a turntable should make"
            )));
        }
        let start = self.position()?;
        let travel = Duration::from_secs_f64(deg.abs() / self.timeouts.min_speed_deg_s);
        let cmd = format!("ROT {deg:.2}");
        let answer = self.command(&cmd, travel + self.timeouts.answer)?;
        let pos = self.parse_position(&cmd, &answer)?;
        let expected = (start + deg).rem_euclid(360.0);
        let off = ((pos - expected + 180.0).rem_euclid(360.0) - 180.0).abs();
        if off > POSITION_TOLERANCE_DEG {
            return Err(SerialError::Device {
                port: self.link.name.clone(),
                command: cmd,
                reason: format!(
                    "stopped at {pos:.2}° instead of {expected:.2}° (missed steps or a slipping belt?)"
                ),
            });
        }
        Ok(pos)
    }

    /// Turns to the home switch; returns the position there.
    pub fn home(&mut self) -> Result<f64> {
        self.require(self.identity.can_rotate, "turntable (HOME)")?;
        let answer = self.command("HOME", self.timeouts.home)?;
        self.parse_position("HOME", &answer)
    }

    /// Asks `ID?` again: the question every device answers, whatever it can do. The answer
    /// must be the one the device gave when it was opened.
    pub fn identify(&mut self) -> Result<()> {
        let id = self.command("ID?", self.timeouts.answer)?;
        if id != self.id_answer {
            return Err(self.protocol("ID?", &format!("OK {id}")));
        }
        Ok(())
    }

    pub fn position(&mut self) -> Result<f64> {
        self.require(self.identity.can_rotate, "turntable (POS?)")?;
        let answer = self.command("POS?", self.timeouts.answer)?;
        self.parse_position("POS?", &answer)
    }

    fn require(&self, has: bool, what: &str) -> Result<()> {
        if has {
            Ok(())
        } else {
            Err(SerialError::Unsupported {
                port: self.link.name.clone(),
                name: self.identity.name.clone(),
                capability: what.into(),
            })
        }
    }

    fn expect_empty(&self, cmd: &str, answer: &str) -> Result<()> {
        if answer.is_empty() {
            Ok(())
        } else {
            Err(self.protocol(cmd, &format!("OK {answer}")))
        }
    }

    fn parse_position(&self, cmd: &str, answer: &str) -> Result<f64> {
        answer
            .parse::<f64>()
            .ok()
            .filter(|p| p.is_finite())
            .map(|p| p.rem_euclid(360.0))
            .ok_or_else(|| self.protocol(cmd, &format!("OK {answer}")))
    }

    fn protocol(&self, cmd: &str, line: &str) -> SerialError {
        SerialError::Protocol {
            port: self.link.name.clone(),
            command: cmd.into(),
            line: line.into(),
        }
    }

    /// Sends one command and returns what follows `OK` in its answer. A command that ends
    /// without its answer leaves the link out of step, and the next command resynchronises
    /// first ([`RigController::resync`]).
    fn command(&mut self, cmd: &str, timeout: Duration) -> Result<String> {
        if self.out_of_step {
            self.resync(cmd)?;
        } else {
            // Nothing is owed between commands: a line that came since the last answer was
            // said out of turn, and would be read as this command's answer.
            self.link.discard_input();
        }
        let answer = self.exchange(cmd, timeout);
        if matches!(
            answer,
            Err(SerialError::Timeout { .. } | SerialError::Protocol { .. })
        ) {
            self.out_of_step = true;
        }
        answer
    }

    /// Brings the link back in step before `cmd`: whatever is buffered is dropped, then `ID?`
    /// is sent and every line is skipped until the device's own identity comes back. The
    /// device answers in order, so a late answer to the command that timed out comes before
    /// it, and is dropped rather than read as `cmd`'s. It may take as long as the slowest
    /// command (a homing run).
    fn resync(&mut self, cmd: &str) -> Result<()> {
        tracing::debug!(port = %self.link.name, "resynchronising before `{cmd}`");
        self.link.discard_input();
        self.send("ID?")?;
        let wait = self.timeouts.home.max(self.timeouts.answer);
        let deadline = Instant::now() + wait;
        loop {
            let line = self.link.read_line(cmd, deadline, wait)?;
            if line.strip_prefix("OK ").map(str::trim) == Some(self.id_answer.as_str()) {
                self.out_of_step = false;
                return Ok(());
            }
            tracing::debug!(port = %self.link.name, "skipped while resynchronising: {line}");
        }
    }

    /// Writes one command line.
    fn send(&mut self, cmd: &str) -> Result<()> {
        tracing::debug!(port = %self.link.name, "> {cmd}");
        self.link.write(format!("{cmd}\n").as_bytes(), cmd)
    }

    /// Sends `cmd` and reads its answer.
    fn exchange(&mut self, cmd: &str, timeout: Duration) -> Result<String> {
        self.send(cmd)?;
        let deadline = Instant::now() + timeout;
        loop {
            let line = self.link.read_line(cmd, deadline, timeout)?;
            tracing::debug!(port = %self.link.name, "< {line}");
            if line.starts_with('#') || line.is_empty() {
                continue;
            }
            if line == "OK" {
                return Ok(String::new());
            }
            if let Some(rest) = line.strip_prefix("OK ") {
                return Ok(rest.trim().to_string());
            }
            if let Some(reason) = line.strip_prefix("ERR") {
                return Err(SerialError::Device {
                    port: self.link.name.clone(),
                    command: cmd.into(),
                    reason: reason.trim().to_string(),
                });
            }
            return Err(self.protocol(cmd, &line));
        }
    }
}
