//! A turntable on a G-code motion controller that speaks GRBL 1.1's serial interface: a
//! stepper on an Arduino with a CNC shield running stock GRBL (the turntable on X, Y or Z),
//! or a four-axis build (grblHAL, grbl-Mega-5X) with the turntable on A. The axis is set in
//! degrees (`$100`–`$103` steps per degree), so a G-code unit is a degree.
//!
//! What the host relies on, all of it GRBL's documented interface:
//!
//! - A line is answered `ok` when it is parsed and queued, or `error:N`; a move's `ok` comes
//!   before the move ends. `G4 P0.01` (a dwell) is answered only once every queued move has
//!   run, which is how the host waits for the table to stop.
//! - `?` is a real-time command: no line end, answered at once with a status report,
//!   `<Idle|MPos:0.000,0.000,0.000,45.000|FS:0,0>` (or `WPos:` beside a `WCO:` offset).
//! - Ctrl-X resets the controller, which then prints its banner, `Grbl 1.1h ['$' for help]`;
//!   with homing enabled it starts in the Alarm state and wants `$H` (a homing cycle).
//! - `ALARM:N` is pushed when something stops the machine (a limit switch, a reset while
//!   moving); `[MSG:…]` and `[…]` lines are feedback.
//!
//! GRBL drives steppers open loop: the position it reports is the one it commanded, so a
//! stalled motor is not seen (the rig protocol's firmware cannot see it either). The position
//! check catches a controller that moved less than asked (an alarm, a reset, a limit).

use std::time::{Duration, Instant};

use serialport::SerialPort;

use crate::controller::{RigTimeouts, POSITION_TOLERANCE_DEG, READ_SLICE};
use crate::error::{Result, SerialError};
use crate::line::LinePort;

/// GRBL's own default baud rate (1.1; 0.8 and older used 9600).
pub const GRBL_BAUD_RATE: u32 = 115_200;
/// The dwell that waits for every queued move to finish.
const SYNC: &str = "G4 P0.01";

/// The axis letters GRBL and its forks report, in the order of a status report's positions.
const AXES: [char; 6] = ['X', 'Y', 'Z', 'A', 'B', 'C'];

/// What the controller said it is, and how it is set up.
#[derive(Debug, Clone, PartialEq)]
pub struct GrblIdentity {
    /// "Grbl 1.1h", from the banner.
    pub banner: String,
    /// The axis the turntable is on.
    pub axis: char,
}

/// A status report (`<State|MPos:…|…>`), as far as the turntable needs it.
#[derive(Debug, Clone, PartialEq)]
pub struct GrblStatus {
    /// `Idle`, `Run`, `Hold:0`, `Alarm`, `Home`, `Door:1`, ...
    pub state: String,
    /// The turntable axis's position, degrees (not reduced to one turn).
    pub position: f64,
}

/// A turntable on a GRBL controller.
pub struct GrblTurntable {
    link: LinePort,
    pub identity: GrblIdentity,
    pub timeouts: RigTimeouts,
    /// The last work coordinate offset a status report gave (`WPos = MPos − WCO`).
    wco: Option<Vec<f64>>,
}

impl GrblTurntable {
    /// Talks to the controller on `port` (already open): resets it and reads its banner.
    /// A controller locked in its Alarm state stays locked: [`GrblTurntable::unlock_by_homing`]
    /// is for a capture that needs it to turn.
    pub fn new(
        mut port: Box<dyn SerialPort>,
        axis: char,
        timeouts: RigTimeouts,
    ) -> Result<GrblTurntable> {
        let name = port.name().unwrap_or_else(|| "serial port".into());
        let axis = axis.to_ascii_uppercase();
        if !AXES.contains(&axis) {
            return Err(SerialError::InvalidArgument(format!(
                "{axis:?} is not an axis GRBL reports: use one of X, Y, Z, A, B, C"
            )));
        }
        port.set_timeout(READ_SLICE).map_err(|e| SerialError::Io {
            port: name.clone(),
            reason: e.to_string(),
        })?;
        let mut table = GrblTurntable {
            link: LinePort::new(port, name),
            identity: GrblIdentity {
                banner: String::new(),
                axis,
            },
            timeouts,
            wco: None,
        };
        table.link.discard_input();
        table.identity.banner = table.reset()?;
        // The axis must be in the status report.
        table.status()?;
        tracing::info!(port = %table.link.name, banner = %table.identity.banner, axis = %axis, "GRBL turntable");
        Ok(table)
    }

    /// Opens `path` at GRBL's baud rate and talks to the controller there.
    pub fn open(path: &str, axis: char, timeouts: RigTimeouts) -> Result<GrblTurntable> {
        let port = serialport::new(path, GRBL_BAUD_RATE)
            .timeout(READ_SLICE)
            .open()
            .map_err(|e| SerialError::from_open(path, e))?;
        GrblTurntable::new(port, axis, timeouts)
    }

    pub fn port_name(&self) -> &str {
        &self.link.name
    }

    /// Homes a controller that is locked in its Alarm state (as one with homing enabled is
    /// after power-up), so that it turns; whether it was locked.
    pub fn unlock_by_homing(&mut self) -> Result<bool> {
        if self.status()?.state != "Alarm" {
            return Ok(false);
        }
        tracing::info!(port = %self.link.name, "GRBL is locked in Alarm: homing ($H)");
        self.home_cycle()?;
        Ok(true)
    }

    /// Asks for a status report (`?`).
    pub fn status(&mut self) -> Result<GrblStatus> {
        self.drain()?;
        self.link.write(b"?", "?")?;
        let deadline = Instant::now() + self.timeouts.answer;
        loop {
            let line = self.read_line("?", deadline, self.timeouts.answer)?;
            if line.starts_with('<') {
                return self.parse_status(&line);
            }
            self.unasked("?", &line)?;
        }
    }

    /// The turntable's position, degrees in [0, 360).
    pub fn position(&mut self) -> Result<f64> {
        Ok(self.status()?.position.rem_euclid(360.0))
    }

    /// Turns by `deg` (positive is the axis's positive direction) with a rapid move, waits
    /// for the table to stop, and returns the position at rest, checked against where it
    /// should be.
    #[tracing::instrument(skip(self), fields(port = %self.link.name))]
    pub fn rotate(&mut self, deg: f64) -> Result<f64> {
        if !deg.is_finite() || deg.abs() > 3600.0 {
            return Err(SerialError::InvalidArgument(format!(
                "a rotation of {deg}° is not a turn a turntable should make"
            )));
        }
        let start = self.status()?;
        if start.state != "Idle" {
            return Err(self.not_idle("turn", &start.state));
        }
        let axis = self.identity.axis;
        // In the axis's own units (G21: a startup line may have set G20, inches, which would
        // scale the turn by 25.4), relative for this block only: the controller is left in
        // absolute mode, as a user's own G-code expects it.
        let cmd = format!("G21 G91 G0 {axis}{deg:.3}");
        self.command(&cmd, self.timeouts.answer)?;
        self.command("G90", self.timeouts.answer)?;
        let travel = Duration::from_secs_f64(deg.abs() / self.timeouts.min_speed_deg_s);
        self.wait_for_motion(travel)?;
        let end = self.status()?;
        let expected = start.position + deg;
        if (end.position - expected).abs() > POSITION_TOLERANCE_DEG || end.state != "Idle" {
            return Err(self.refused(
                &cmd,
                format!(
                    "the controller stopped at {:.2}° ({}) instead of {:.2}°",
                    end.position.rem_euclid(360.0),
                    end.state,
                    expected.rem_euclid(360.0)
                ),
            ));
        }
        Ok(end.position.rem_euclid(360.0))
    }

    /// Runs the controller's homing cycle (`$H`); returns the position at the switch.
    pub fn home(&mut self) -> Result<f64> {
        self.home_cycle()?;
        self.position()
    }

    fn home_cycle(&mut self) -> Result<()> {
        match self.command("$H", self.timeouts.home) {
            Err(SerialError::Grbl { reason, .. })
                if reason.split_whitespace().next() == Some("error:5") =>
            {
                Err(self.refused(
                    "$H",
                    "error:5: homing is not enabled ($22=0); if the controller is locked in \
                     its Alarm state, find why it raised the alarm, then unlock it with $X in \
                     a serial terminal"
                        .into(),
                ))
            }
            other => other,
        }
    }

    fn refused(&self, command: &str, reason: String) -> SerialError {
        SerialError::Grbl {
            port: self.link.name.clone(),
            command: command.into(),
            reason,
        }
    }

    /// `error:N` in answer to `cmd`, with what GRBL means by it.
    fn error_code(&self, cmd: &str, code: &str) -> SerialError {
        self.refused(cmd, format!("error:{code} ({})", error_meaning(code)))
    }

    fn not_idle(&self, what: &str, state: &str) -> SerialError {
        let hint = match state.split(':').next().unwrap_or(state) {
            "Alarm" => {
                "after finding what raised the alarm, home it (`brdfd serial home`, $H) or \
                 unlock it ($X)"
            }
            "Door" => "the safety door input is open",
            "Hold" => "it is in a feed hold: resume it with ~",
            "Sleep" => "it is asleep: reset it",
            _ => "wait for it to finish, or reset it",
        };
        self.refused(
            what,
            format!("the controller is in state {state}, not Idle: {hint}"),
        )
    }

    /// Resets the controller (Ctrl-X) and returns its banner ("Grbl 1.1h"), once the line
    /// has gone quiet.
    fn reset(&mut self) -> Result<String> {
        // A soft reset makes any GRBL print its banner now, whether or not opening the port
        // reset the board; one that is still in its bootloader prints it when it starts.
        self.link.write(b"\x18", "reset (Ctrl-X)")?;
        let banner = self.banner()?;
        self.settle()?;
        Ok(banner)
    }

    /// Waits for the banner that follows a reset.
    fn banner(&mut self) -> Result<String> {
        let what = "reset (Ctrl-X)";
        let wait = self.timeouts.boot.max(self.timeouts.answer);
        let deadline = Instant::now() + wait;
        loop {
            let line = match self.read_line(what, deadline, wait) {
                Err(SerialError::GrblTimeout { port, .. }) => {
                    return Err(SerialError::GrblTimeout {
                        port,
                        command: format!(
                            "{what}: no GRBL banner (\"Grbl 1.1h ['$' for help]\"); is this a GRBL controller at {GRBL_BAUD_RATE} baud?"
                        ),
                        after: wait,
                    })
                }
                other => other?,
            };
            if let Some(banner) = grbl_banner(&line) {
                return Ok(banner);
            }
            tracing::debug!(port = %self.link.name, "before the banner: {line}");
        }
    }

    /// Reads until the line has been quiet for a moment: a controller that had booted by
    /// itself before the reset printed its banner twice, and the second must not be read
    /// as a reset during the first command. Startup lines and the lock's message come here.
    fn settle(&mut self) -> Result<()> {
        let quiet = Duration::from_millis(250).min(self.timeouts.boot);
        loop {
            match self.read_line("reset (Ctrl-X)", Instant::now() + quiet, quiet) {
                Ok(line) => tracing::debug!(port = %self.link.name, "after the banner: {line}"),
                Err(SerialError::GrblTimeout { .. }) => return Ok(()),
                Err(e) => return Err(e),
            }
        }
    }

    /// Reads what came since the last exchange, whole lines only: an alarm pushed in between
    /// is reported, not thrown away, and a late `ok` is dropped.
    fn drain(&mut self) -> Result<()> {
        self.link.take_available();
        let now = Instant::now();
        loop {
            match self.read_line("(between commands)", now, Duration::ZERO) {
                Ok(line) if line == "ok" => {
                    tracing::debug!(port = %self.link.name, "a late ok, dropped")
                }
                Ok(line) => self.unasked("(between commands)", &line)?,
                Err(SerialError::GrblTimeout { .. }) => return Ok(()),
                Err(e) => return Err(e),
            }
        }
    }

    /// Sends one line and waits for its `ok`; `error:N` and `ALARM:N` are errors that say
    /// what GRBL means by them.
    fn command(&mut self, cmd: &str, timeout: Duration) -> Result<()> {
        self.drain()?;
        tracing::debug!(port = %self.link.name, "> {cmd}");
        self.link.write(format!("{cmd}\n").as_bytes(), cmd)?;
        let deadline = Instant::now() + timeout;
        loop {
            let line = self.read_line(cmd, deadline, timeout)?;
            tracing::debug!(port = %self.link.name, "< {line}");
            if line == "ok" {
                return Ok(());
            }
            if let Some(code) = line.strip_prefix("error:") {
                return Err(self.error_code(cmd, code));
            }
            self.unasked(cmd, &line)?;
        }
    }

    /// Waits for every queued move to end: `G4 P0.01` is answered only then. The time
    /// allowed is the turn at the slowest speed expected; when it runs out, a status report
    /// says whether the table is still turning (a controller slower than that, or
    /// accelerating), and the wait goes on while it is.
    fn wait_for_motion(&mut self, travel: Duration) -> Result<()> {
        self.drain()?;
        self.link.write(format!("{SYNC}\n").as_bytes(), SYNC)?;
        let mut deadline = Instant::now() + travel + self.timeouts.answer;
        let mut asked = false;
        let mut last: Option<f64> = None;
        loop {
            let line = match self.read_line(SYNC, deadline, travel + self.timeouts.answer) {
                Err(SerialError::GrblTimeout { .. }) if !asked => {
                    self.link.write(b"?", "?")?;
                    asked = true;
                    deadline = Instant::now() + self.timeouts.answer;
                    continue;
                }
                other => other?,
            };
            if line == "ok" {
                return Ok(());
            }
            if let Some(code) = line.strip_prefix("error:") {
                return Err(self.error_code(SYNC, code));
            }
            if line.starts_with('<') {
                let status = self.parse_status(&line)?;
                let moved = last.is_some_and(|p| (p - status.position).abs() > 1e-6);
                if matches!(status.state.as_str(), "Run" | "Jog" | "Home") || moved {
                    // Still turning: wait as long again for the next sign of it.
                    asked = false;
                    deadline = Instant::now() + self.timeouts.answer;
                }
                last = Some(status.position);
                continue;
            }
            self.unasked(SYNC, &line)?;
        }
    }

    /// A line that does not answer `cmd`: feedback, status reports and startup lines that
    /// ran are skipped; an alarm or a reset ends the command.
    fn unasked(&mut self, cmd: &str, line: &str) -> Result<()> {
        if let Some(code) = line.strip_prefix("ALARM:") {
            let mut reason = format!("ALARM:{code} ({})", alarm_meaning(code));
            // A limit is a critical alarm: GRBL then ignores every line until it is reset.
            // The reset releases it into its (answering) Alarm lock.
            if matches!(code.trim(), "1" | "2") {
                self.reset()?;
                reason.push_str("; brdfd reset the controller, which stays locked until homed");
            }
            return Err(self.refused(cmd, reason));
        }
        if grbl_banner(line).is_some() {
            return Err(SerialError::Unplugged {
                port: self.link.name.clone(),
                command: cmd.into(),
            });
        }
        // A startup line ($N0, $N1) GRBL runs after homing: `>G21:ok`, or `>…:error:N`.
        if let Some(startup) = line.strip_prefix('>') {
            if let Some((block, code)) = startup.split_once(":error:") {
                return Err(self.refused(
                    cmd,
                    format!(
                        "its startup line {block:?} failed with error:{code} ({}); fix it with $N0= or $N1=",
                        error_meaning(code)
                    ),
                ));
            }
            return Ok(());
        }
        if line.starts_with('[') || line.starts_with('<') {
            return Ok(());
        }
        tracing::debug!(port = %self.link.name, "not GRBL's, skipped: {line:?}");
        Ok(())
    }

    fn parse_status(&mut self, line: &str) -> Result<GrblStatus> {
        let bad = || SerialError::Grbl {
            port: self.link.name.clone(),
            command: "?".into(),
            reason: format!("a status report brdfd cannot read: {line:?}"),
        };
        let inner = line
            .strip_prefix('<')
            .and_then(|l| l.strip_suffix('>'))
            .ok_or_else(bad)?;
        let mut fields = inner.split('|');
        let state = fields.next().filter(|s| !s.is_empty()).ok_or_else(bad)?;
        let numbers = |v: &str| -> Option<Vec<f64>> {
            v.split(',')
                .map(|x| x.parse::<f64>().ok().filter(|x| x.is_finite()))
                .collect()
        };
        let (mut machine, mut work) = (None, None);
        for field in fields {
            if let Some(v) = field.strip_prefix("MPos:") {
                machine = Some(numbers(v).ok_or_else(bad)?);
            } else if let Some(v) = field.strip_prefix("WPos:") {
                work = Some(numbers(v).ok_or_else(bad)?);
            } else if let Some(v) = field.strip_prefix("WCO:") {
                self.wco = Some(numbers(v).ok_or_else(bad)?);
            }
        }
        let index = AXES
            .iter()
            .position(|a| *a == self.identity.axis)
            .unwrap_or(0);
        // Positions are the machine's: a work offset set by hand (G92, G10) changes WPos, not
        // where the table stands.
        let position = match (machine, work) {
            (Some(m), _) => m.get(index).copied(),
            (None, Some(w)) => {
                let offset = self.wco.as_ref().and_then(|o| o.get(index)).unwrap_or(&0.0);
                w.get(index).map(|w| w + offset)
            }
            (None, None) => None,
        };
        let Some(position) = position else {
            return Err(SerialError::Unsupported {
                port: self.link.name.clone(),
                name: self.identity.banner.clone(),
                capability: format!(
                    "{} axis in its status report ({line}); name the axis the turntable is on, as in grbl:x:{}",
                    self.identity.axis, self.link.name
                ),
            });
        };
        Ok(GrblStatus {
            state: state.to_string(),
            position,
        })
    }

    /// The next line that says something: GRBL ends its lines with CR LF, and a reset's
    /// banner starts with an empty line. A timeout is GRBL's, told as such.
    fn read_line(&mut self, cmd: &str, deadline: Instant, timeout: Duration) -> Result<String> {
        loop {
            let line = match self.link.read_line(cmd, deadline, timeout) {
                Err(SerialError::Timeout {
                    port,
                    command,
                    after,
                }) => {
                    return Err(SerialError::GrblTimeout {
                        port,
                        command,
                        after,
                    })
                }
                Err(SerialError::Protocol {
                    port,
                    command,
                    line,
                }) => {
                    return Err(SerialError::Grbl {
                        port,
                        command,
                        reason: format!("a line longer than GRBL sends: {line:?}"),
                    })
                }
                other => other?,
            };
            let line = line.trim();
            if !line.is_empty() {
                return Ok(line.to_string());
            }
        }
    }
}

/// Whether a line a device sent is GRBL's: its banner, or a status report. GRBL answers the
/// rig protocol's `ID?` so (the `?` is its real-time status question), which is how a port
/// survey tells a G-code controller from a bare adapter.
pub fn looks_like_grbl(line: &str) -> bool {
    grbl_banner(line).is_some()
        || (line.starts_with('<') && (line.contains("|MPos:") || line.contains("|WPos:")))
}

/// "Grbl 1.1h" from a banner line (`Grbl 1.1h ['$' for help]`); grblHAL prints
/// `GrblHAL 1.1f ['$' or '$HELP' for help]`.
fn grbl_banner(line: &str) -> Option<String> {
    let (head, _) = line.split_once(" [").unwrap_or((line, ""));
    let mut words = head.split_whitespace();
    let name = words.next()?;
    let version = words.next()?;
    (name.eq_ignore_ascii_case("grbl") || name.eq_ignore_ascii_case("grblhal"))
        .then(|| format!("{name} {version}"))
}

/// What GRBL 1.1 means by `error:N`, for the codes a turntable can meet.
fn error_meaning(code: &str) -> &'static str {
    match code.trim().parse::<u32>().unwrap_or(0) {
        1 => "a G-code word without its letter",
        2 => "a G-code value missing or not a number",
        3 => "a '$' command GRBL does not know",
        5 => "homing is not enabled in the settings ($22)",
        8 => "a '$' command GRBL runs only when Idle",
        9 => "G-code is locked out while the controller is in Alarm or jogging: home ($H) or unlock ($X)",
        11 => "the line is longer than GRBL accepts",
        15 => "the move exceeds the machine's travel (soft limits)",
        20 => "a G-code this GRBL does not support (is the axis compiled in?)",
        22 => "no feed rate set",
        26 => "no axis word for the motion",
        33 => "the motion's target is invalid",
        _ => "see GRBL's error code table",
    }
}

/// What GRBL 1.1 means by `ALARM:N`.
fn alarm_meaning(code: &str) -> &'static str {
    match code.trim().parse::<u32>().unwrap_or(0) {
        1 => "a hard limit switch was hit; the position is lost: home again",
        2 => "the move would exceed the machine's travel (soft limit)",
        3 => "the controller was reset while moving; the position is lost: home again",
        6 => "homing failed: the controller was reset during the cycle",
        7 => "homing failed: the safety door opened",
        8 => "homing failed: the switch stayed pressed after pulling off",
        9 => "homing failed: the home switch was not found within the travel",
        _ => "see GRBL's alarm code table",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn banners_of_grbl_and_its_forks_are_recognised() {
        assert_eq!(
            grbl_banner("Grbl 1.1h ['$' for help]").as_deref(),
            Some("Grbl 1.1h")
        );
        assert_eq!(
            grbl_banner("GrblHAL 1.1f ['$' or '$HELP' for help]").as_deref(),
            Some("GrblHAL 1.1f")
        );
        assert_eq!(grbl_banner("ok"), None);
        assert_eq!(grbl_banner("[MSG:'$H'|'$X' to unlock]"), None);
    }
}
