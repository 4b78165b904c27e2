//! A simulated trigger box and turntable speaking the brdfd rig protocol (see
//! `brdfd-serial`), on a real pseudo-terminal: the client opens the other end as it would a
//! USB serial adapter, so the real serial code runs.
//!
//! The turntable moves at a finite speed and answers at rest; the shutter line is held for
//! the time asked. [`PeerFaults`] injects what goes wrong: no answer, a garbled answer, an
//! ERR, a turntable that slips, and an unplugged device.

use std::io::{Read, Write};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use serialport::{SerialPort, TTYPort};

#[derive(Debug, Clone)]
pub struct PeerConfig {
    /// What `ID?` reports.
    pub name: String,
    pub can_fire: bool,
    pub can_rotate: bool,
    /// Rotation speed, degrees per second.
    pub speed_deg_s: f64,
    /// What the shutter line is wired to: called with the pulse's length as the line goes
    /// active (a camera's remote socket shoots on the press).
    pub shutter_wired_to: Option<Wire>,
}

/// The far end of the shutter line.
#[derive(Clone)]
pub struct Wire(pub Arc<dyn Fn(u32) + Send + Sync>);

impl std::fmt::Debug for Wire {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Wire(..)")
    }
}

impl Default for PeerConfig {
    fn default() -> Self {
        PeerConfig {
            name: "brdfd-sim-turntable".into(),
            can_fire: true,
            can_rotate: true,
            speed_deg_s: 360.0,
            shutter_wired_to: None,
        }
    }
}

/// Faults, each used up as it fires.
#[derive(Debug, Clone, Default)]
pub struct PeerFaults {
    /// Say nothing to the next command.
    pub silent_next: bool,
    /// Answer the next command with line noise.
    pub garble_next: bool,
    /// Answer the next command `ERR <reason>`.
    pub error_next: Option<String>,
    /// The next rotation stops this many degrees short (a slipping belt).
    pub slip_deg: Option<f64>,
    /// Close the port on the next command, as if the USB cable were pulled.
    pub unplug_next: bool,
    /// Answer the next command this much later than it would (a device that was busy, or a
    /// slow rotation): the answer arrives after the host gave up on it.
    pub late_next: Option<Duration>,
    /// Send this line unasked after answering the next command (a device that speaks out of
    /// turn, or an answer the line doubled), where the host would take it for the answer to
    /// the command after.
    pub stray_next: Option<String>,
}

#[derive(Debug, Default)]
struct PeerState {
    position: f64,
    fires: Vec<u32>,
    faults: PeerFaults,
    log: Vec<String>,
}

pub struct SerialPeer {
    /// The path of the end a client opens (`/dev/pts/N`).
    pub path: String,
    state: Arc<Mutex<PeerState>>,
    thread: Option<JoinHandle<()>>,
}

impl SerialPeer {
    /// Makes a pseudo-terminal pair and serves the protocol on one end. Returns the peer and
    /// the other end, opened, for the client.
    pub fn start(config: PeerConfig) -> std::io::Result<(SerialPeer, TTYPort)> {
        let (mut device, client) = TTYPort::pair().map_err(std::io::Error::other)?;
        device
            .set_timeout(Duration::from_millis(20))
            .map_err(std::io::Error::other)?;
        let path = client.name().unwrap_or_default();
        let state = Arc::new(Mutex::new(PeerState::default()));
        let shared = state.clone();
        let thread = std::thread::Builder::new()
            .name("sim-serial".into())
            .spawn(move || serve(&mut device, &config, &shared))?;
        Ok((
            SerialPeer {
                path,
                state,
                thread: Some(thread),
            },
            client,
        ))
    }

    pub fn inject(&self, faults: PeerFaults) {
        self.lock().faults = faults;
    }

    /// Shutter pulses so far, in milliseconds.
    pub fn fires(&self) -> Vec<u32> {
        self.lock().fires.clone()
    }

    pub fn position(&self) -> f64 {
        self.lock().position
    }

    /// Commands received, one per line.
    pub fn log(&self) -> Vec<String> {
        self.lock().log.clone()
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, PeerState> {
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Whether the peer has closed its end (after an unplug fault or when the client left).
    pub fn is_finished(&self) -> bool {
        self.thread.as_ref().is_none_or(|t| t.is_finished())
    }
}

fn serve(port: &mut TTYPort, config: &PeerConfig, state: &Mutex<PeerState>) {
    let lock = || state.lock().unwrap_or_else(|p| p.into_inner());
    let mut pending = Vec::new();
    let mut buf = [0u8; 64];
    loop {
        match port.read(&mut buf) {
            Ok(0) => return,
            Ok(n) => pending.extend_from_slice(&buf[..n]),
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => continue,
            // The client closed its end.
            Err(_) => return,
        }
        while let Some(end) = pending.iter().position(|&b| b == b'\n') {
            let line: Vec<u8> = pending.drain(..=end).collect();
            let cmd = String::from_utf8_lossy(&line).trim().to_string();
            let faults = {
                let mut s = lock();
                s.log.push(cmd.clone());
                let mut f = std::mem::take(&mut s.faults);
                // A belt slips only while turning: the fault waits for a ROT.
                if !cmd.starts_with("ROT") {
                    s.faults.slip_deg = f.slip_deg.take();
                }
                f
            };
            if faults.unplug_next {
                return;
            }
            if faults.silent_next {
                continue;
            }
            if let Some(late) = faults.late_next {
                std::thread::sleep(late);
            }
            let reply = if faults.garble_next {
                "\u{fffd}\u{7}~~ 9600 baud? ~~".to_string()
            } else if let Some(reason) = faults.error_next {
                format!("ERR {reason}")
            } else {
                answer(&cmd, config, state, faults.slip_deg)
            };
            // A device's own log line, which the host must skip. A stray line goes out in
            // the same write as the answer, as a doubled line does: written apart, it could
            // come after the host's next command, where no protocol without sequence numbers
            // can tell it from that command's answer.
            let mut out = format!("# {cmd}\r\n{reply}\r\n");
            if let Some(line) = &faults.stray_next {
                out.push_str(&format!("{line}\r\n"));
            }
            let _ = port.write_all(out.as_bytes());
        }
    }
}

fn answer(cmd: &str, config: &PeerConfig, state: &Mutex<PeerState>, slip: Option<f64>) -> String {
    let lock = || state.lock().unwrap_or_else(|p| p.into_inner());
    let mut words = cmd.split_whitespace();
    let verb = words.next().unwrap_or("");
    let arg = words.next();
    match (verb, arg) {
        ("ID?", None) => {
            let mut caps = Vec::new();
            if config.can_fire {
                caps.push("FIRE");
            }
            if config.can_rotate {
                caps.push("ROT");
            }
            format!("OK {} 1 {}", config.name, caps.join(" "))
        }
        ("FIRE", Some(ms)) if config.can_fire => match ms.parse::<u32>() {
            Ok(ms @ 1..=60_000) => {
                if let Some(Wire(pressed)) = &config.shutter_wired_to {
                    pressed(ms);
                }
                std::thread::sleep(Duration::from_millis(ms as u64));
                lock().fires.push(ms);
                "OK".into()
            }
            _ => format!("ERR bad duration {ms}"),
        },
        ("ROT", Some(deg)) if config.can_rotate => match deg.parse::<f64>() {
            Ok(d) if d.is_finite() => {
                std::thread::sleep(Duration::from_secs_f64(d.abs() / config.speed_deg_s));
                let mut s = lock();
                let moved = d - slip.unwrap_or(0.0) * d.signum();
                s.position = (s.position + moved).rem_euclid(360.0);
                format!("OK {:.2}", s.position)
            }
            _ => format!("ERR bad angle {deg}"),
        },
        ("HOME", None) if config.can_rotate => {
            let at = lock().position;
            let travel = at.min(360.0 - at);
            std::thread::sleep(Duration::from_secs_f64(travel / config.speed_deg_s));
            lock().position = 0.0;
            "OK 0.00".into()
        }
        ("POS?", None) if config.can_rotate => format!("OK {:.2}", lock().position),
        _ => format!("ERR unknown command {cmd:?}"),
    }
}
