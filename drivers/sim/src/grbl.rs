//! A simulated GRBL 1.1 motion controller with a turntable on one of its axes, on a real
//! pseudo-terminal, following GRBL's documented serial interface:
//!
//! - the banner after a reset (Ctrl-X), and the Alarm lock at power-up when homing is enabled
//!   (a reset keeps the state and the position, unless it stops a move);
//! - `ok` for a line once it is parsed and queued, before its move ends; `error:N` for what
//!   it refuses (a word without a letter or a number, an unknown `$` command, an unsupported
//!   G-code, G-code while locked in Alarm, a feed move without a feed rate, homing disabled);
//! - moves that take time at the axis's maximum rate, `G4` dwells answered only when every
//!   queued move has run, and `?` answered at once, between or inside lines, with the
//!   position along the move;
//! - `$H` (homing), `$X` (unlock), `$I` (build info), `$G` (parser state), `$$` (settings);
//! - a reset while moving raises `ALARM:3` and loses the position.
//!
//! [`GrblFaults`] adds what goes wrong at a bench: a limit switch hit during a move
//! (`ALARM:1`, after which GRBL ignores every line until reset), a board that resets by itself
//! mid-move (a brown-out: only its banner says so), and a cable pulled.

use std::io::{Read, Write};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use serialport::{SerialPort, TTYPort};

/// The axes this controller has, in its status report's order (a four-axis build).
const AXES: [char; 4] = ['X', 'Y', 'Z', 'A'];
const BANNER: &str = "Grbl 1.1h ['$' for help]";
/// GRBL's line buffer: a longer line is refused with error:11.
const LINE_BUFFER: usize = 80;

#[derive(Debug, Clone)]
pub struct GrblConfig {
    /// Maximum rate of every axis, units (degrees) per second: `$110`–`$113` over 60.
    pub rate_per_s: f64,
    /// `$22`: homing enabled, so the controller starts locked in Alarm until `$H`.
    pub homing: bool,
    /// Where the home switch sits on the turntable's axis, in machine units: `$H` ends there.
    pub home_axis: char,
    /// Report `WPos:` and `WCO:` instead of `MPos:` (`$10=0`).
    pub work_positions: bool,
    /// The work coordinate offset (G54's, as a user's own jobs may have set it).
    pub work_offset: [f64; 4],
    /// A startup line (`$N0`), which GRBL runs, and reports as `>BLOCK:ok`, after homing.
    pub startup_line: Option<String>,
}

impl Default for GrblConfig {
    fn default() -> Self {
        GrblConfig {
            rate_per_s: 360.0,
            homing: false,
            home_axis: 'A',
            work_positions: false,
            work_offset: [0.0; 4],
            startup_line: None,
        }
    }
}

/// Faults, each used up as it fires.
#[derive(Debug, Clone, Default)]
pub struct GrblFaults {
    /// The next move hits a hard limit this far along: the controller stops there, pushes
    /// `ALARM:1`, and ignores every line (answering only `?`) until it is reset (Ctrl-X),
    /// after which it is locked in Alarm.
    pub limit_after: Option<f64>,
    /// The board resets this far along the next move (a brown-out, a DTR pulse): it prints
    /// its banner again and starts from position 0, as after power-up.
    pub reset_after: Option<f64>,
    /// Close the port on the next line, as if the USB cable were pulled.
    pub unplug_next: bool,
}

/// One queued move.
#[derive(Debug, Clone)]
struct Move {
    from: [f64; 4],
    to: [f64; 4],
    start: Instant,
    end: Instant,
}

impl Move {
    /// How far along the move is at `now`, in machine units.
    /// The share of the move done at `now`, in [0, 1].
    fn done(&self, now: Instant) -> f64 {
        let f = now.saturating_duration_since(self.start).as_secs_f64()
            / (self.end - self.start).as_secs_f64().max(1e-9);
        f.min(1.0)
    }

    fn along(&self, now: Instant) -> f64 {
        distance(&self.from, &self.to) * self.done(now)
    }

    fn at(&self, now: Instant) -> [f64; 4] {
        let f = self.done(now);
        std::array::from_fn(|i| self.from[i] + (self.to[i] - self.from[i]) * f)
    }
}

fn distance(a: &[f64; 4], b: &[f64; 4]) -> f64 {
    (0..4).map(|i| (b[i] - a[i]).powi(2)).sum::<f64>().sqrt()
}

#[derive(Debug)]
struct State {
    /// Where the machine stands once the moves that have ended are counted.
    position: [f64; 4],
    /// The planner's queue: the move under way first.
    moves: std::collections::VecDeque<Move>,
    alarm: bool,
    /// A homing cycle is under way (its move is the queue's).
    homing: bool,
    /// A critical alarm (a limit): lines are ignored until a reset.
    critical: bool,
    relative: bool,
    /// The modal motion: G0 (rapid) or G1 (at the feed rate).
    feed_motion: bool,
    feed: Option<f64>,
    /// A G4 or `$H` waiting for the moves to end (and a dwell's own time): when to answer.
    answer_at: Option<Instant>,
    faults: GrblFaults,
    log: Vec<String>,
    homings: usize,
}

impl State {
    /// Counts the moves that have ended by `now`.
    fn settle(&mut self, now: Instant) {
        while self.moves.front().is_some_and(|m| m.end <= now) {
            if let Some(m) = self.moves.pop_front() {
                self.position = m.to;
            }
        }
    }

    fn at(&self, now: Instant) -> [f64; 4] {
        match self.moves.iter().find(|m| m.end > now) {
            Some(m) if m.start <= now => m.at(now),
            Some(m) => m.from,
            None => self.moves.back().map_or(self.position, |m| m.to),
        }
    }

    fn busy(&self, now: Instant) -> bool {
        self.moves.back().is_some_and(|m| m.end > now)
    }

    /// Stops every move where it is, as a reset or an alarm does.
    fn halt(&mut self, now: Instant) {
        self.position = self.at(now);
        self.moves.clear();
        self.answer_at = None;
        self.homing = false;
    }

    /// The end of the queue, where a new move starts.
    fn queue_end(&self, now: Instant) -> (Instant, [f64; 4]) {
        match self.moves.back() {
            Some(m) if m.end > now => (m.end, m.to),
            _ => (now, self.at(now)),
        }
    }

    fn push_move(&mut self, to: [f64; 4], rate: f64, now: Instant) -> Instant {
        let (start, from) = self.queue_end(now);
        let end = start + Duration::from_secs_f64(distance(&from, &to) / rate);
        self.moves.push_back(Move {
            from,
            to,
            start,
            end,
        });
        end
    }
}

pub struct GrblPeer {
    /// The path of the end a client opens (`/dev/pts/N`).
    pub path: String,
    state: Arc<Mutex<State>>,
    thread: Option<JoinHandle<()>>,
}

impl GrblPeer {
    /// Makes a pseudo-terminal pair and runs the controller on one end. Returns the peer and
    /// the other end, opened, for the client. The controller has just booted: its banner is
    /// waiting on the line.
    pub fn start(config: GrblConfig) -> std::io::Result<(GrblPeer, TTYPort)> {
        let (mut device, client) = TTYPort::pair().map_err(std::io::Error::other)?;
        device
            .set_timeout(Duration::from_millis(5))
            .map_err(std::io::Error::other)?;
        let path = client.name().unwrap_or_default();
        let state = Arc::new(Mutex::new(State {
            position: [0.0; 4],
            moves: Default::default(),
            alarm: config.homing,
            homing: false,
            critical: false,
            relative: false,
            feed_motion: false,
            feed: None,
            answer_at: None,
            faults: GrblFaults::default(),
            log: Vec::new(),
            homings: 0,
        }));
        let shared = state.clone();
        let thread = std::thread::Builder::new()
            .name("sim-grbl".into())
            .spawn(move || serve(&mut device, &config, &shared))?;
        Ok((
            GrblPeer {
                path,
                state,
                thread: Some(thread),
            },
            client,
        ))
    }

    pub fn inject(&self, faults: GrblFaults) {
        self.lock().faults = faults;
    }

    /// The turntable axis's machine position now, degrees (not reduced to one turn).
    pub fn position(&self, axis: char) -> f64 {
        let s = self.lock();
        s.at(Instant::now())[axis_index(axis).unwrap_or(3)]
    }

    /// Lines received (real-time characters are not lines).
    pub fn log(&self) -> Vec<String> {
        self.lock().log.clone()
    }

    /// Homing cycles run.
    pub fn homings(&self) -> usize {
        self.lock().homings
    }

    /// Whether the controller has closed its end (after an unplug or when the client left).
    pub fn is_finished(&self) -> bool {
        self.thread.as_ref().is_none_or(|t| t.is_finished())
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }
}

fn axis_index(c: char) -> Option<usize> {
    AXES.iter().position(|a| *a == c.to_ascii_uppercase())
}

fn serve(port: &mut TTYPort, config: &GrblConfig, state: &Mutex<State>) {
    let lock = || state.lock().unwrap_or_else(|p| p.into_inner());
    let mut out = String::new();
    boot(&mut out, config.homing);
    let mut line = Vec::new();
    let mut queued: std::collections::VecDeque<String> = Default::default();
    let mut buf = [0u8; 64];
    loop {
        if !out.is_empty() {
            if port.write_all(out.as_bytes()).is_err() {
                return;
            }
            out.clear();
        }
        let n = match port.read(&mut buf) {
            Ok(0) => return,
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => 0,
            Err(_) => return,
        };
        let now = Instant::now();
        for &b in &buf[..n] {
            match b {
                // Real-time commands are picked out of the stream wherever they come.
                b'?' => out.push_str(&status(&lock(), config, now)),
                0x18 => {
                    let mut s = lock();
                    if s.busy(now) {
                        // A reset while moving loses the steps under way.
                        s.alarm = true;
                        out.push_str("ALARM:3\r\n");
                    }
                    // The state outlives a reset (an Idle controller stays Idle, its
                    // position kept); the modes go back to their defaults.
                    s.halt(now);
                    s.critical = false;
                    s.relative = false;
                    s.feed_motion = false;
                    let locked = s.alarm;
                    drop(s);
                    line.clear();
                    queued.clear();
                    boot(&mut out, locked);
                }
                b'\n' | b'\r' => {
                    if !line.is_empty() {
                        queued.push_back(String::from_utf8_lossy(&line).into_owned());
                        line.clear();
                    }
                }
                _ => line.push(b),
            }
        }
        strike(&mut lock(), config.homing, now, &mut out, &mut queued);
        lock().settle(now);
        // A dwell (or a homing cycle) holds the lines after it, as GRBL's serial buffer does.
        loop {
            {
                let mut s = lock();
                if let Some(at) = s.answer_at {
                    let now = Instant::now();
                    if now < at || s.busy(now) {
                        break;
                    }
                    s.answer_at = None;
                    if s.homing {
                        s.homing = false;
                        s.alarm = false;
                        s.homings += 1;
                        // The startup lines run after a successful homing cycle.
                        if let Some(block) = &config.startup_line {
                            out.push_str(&format!(">{block}:ok\r\n"));
                        }
                    }
                    out.push_str("ok\r\n");
                }
            }
            let Some(l) = queued.pop_front() else { break };
            if lock().faults.unplug_next {
                return;
            }
            if lock().critical {
                // Not even an error: GRBL waits for its reset.
                continue;
            }
            lock().log.push(l.clone());
            out.push_str(&execute(&l, config, &mut lock()));
        }
    }
}

/// The faults that strike during a move.
fn strike(
    s: &mut State,
    config_homing: bool,
    now: Instant,
    out: &mut String,
    queued: &mut std::collections::VecDeque<String>,
) {
    let Some(along) = s
        .moves
        .front()
        .filter(|m| m.end > now)
        .map(|m| m.along(now))
    else {
        return;
    };
    if s.faults.limit_after.is_some_and(|a| along >= a) {
        s.faults.limit_after = None;
        s.halt(now);
        s.alarm = true;
        s.critical = true;
        queued.clear();
        out.push_str("ALARM:1\r\n[MSG:Reset to continue]\r\n");
    } else if s.faults.reset_after.is_some_and(|a| along >= a) {
        s.faults.reset_after = None;
        s.halt(now);
        s.position = [0.0; 4];
        s.alarm = config_homing;
        s.relative = false;
        s.feed_motion = false;
        queued.clear();
        boot(out, config_homing);
    }
}

/// The banner a start or a reset prints, with the lock's message when it is locked.
fn boot(out: &mut String, locked: bool) {
    out.push_str(&format!("\r\n{BANNER}\r\n"));
    if locked {
        out.push_str("[MSG:'$H'|'$X' to unlock]\r\n");
    }
}

fn status(s: &State, config: &GrblConfig, now: Instant) -> String {
    let state = if s.homing {
        "Home"
    } else if s.alarm {
        "Alarm"
    } else if s.busy(now) {
        "Run"
    } else {
        "Idle"
    };
    let m = s.at(now);
    let list = |v: [f64; 4]| {
        v.iter()
            .map(|x| format!("{x:.3}"))
            .collect::<Vec<_>>()
            .join(",")
    };
    if config.work_positions {
        let w: [f64; 4] = std::array::from_fn(|i| m[i] - config.work_offset[i]);
        format!(
            "<{state}|WPos:{}|FS:0,0|WCO:{}>\r\n",
            list(w),
            list(config.work_offset)
        )
    } else {
        format!("<{state}|MPos:{}|FS:0,0>\r\n", list(m))
    }
}

/// Runs one line; what GRBL prints for it (`ok\r\n`, `error:N\r\n`, with any feedback),
/// or nothing yet for a dwell, which answers when it ends.
fn execute(line: &str, config: &GrblConfig, s: &mut State) -> String {
    let now = Instant::now();
    let err = |n: u32| format!("error:{n}\r\n");
    if line.len() > LINE_BUFFER {
        return err(11);
    }
    // Spaces are dropped and letters upper-cased; comments in () or after ; are removed.
    let mut text = String::new();
    let mut in_comment = false;
    for c in line.chars() {
        match c {
            '(' => in_comment = true,
            ')' => in_comment = false,
            ';' if !in_comment => break,
            c if in_comment || c.is_whitespace() => {}
            c => text.push(c.to_ascii_uppercase()),
        }
    }
    if text.is_empty() {
        return "ok\r\n".into();
    }
    if let Some(cmd) = text.strip_prefix('$') {
        return match cmd {
            "I" => "[VER:1.1h.20190825:brdfd-sim]\r\n[OPT:V,15,128]\r\nok\r\n".into(),
            "G" => format!(
                "[GC:G0 G54 G17 G21 {} G94 M5 M9 T0 F{} S0]\r\nok\r\n",
                if s.relative { "G91" } else { "G90" },
                s.feed.unwrap_or(0.0)
            ),
            "$" => {
                let rate = config.rate_per_s * 60.0;
                format!(
                    "$10={}\r\n$22={}\r\n$100=1.000\r\n$101=1.000\r\n$102=1.000\r\n$103=1.000\r\n$110={rate:.3}\r\n$111={rate:.3}\r\n$112={rate:.3}\r\n$113={rate:.3}\r\nok\r\n",
                    if config.work_positions { 0 } else { 1 },
                    u8::from(config.homing)
                )
            }
            "X" => {
                s.alarm = false;
                "[MSG:Caution: Unlocked]\r\nok\r\n".into()
            }
            "H" if !config.homing => err(5),
            "H" => {
                if s.busy(now) {
                    return err(8);
                }
                // The cycle runs to the switch, then answers.
                let mut to = s.at(now);
                to[axis_index(config.home_axis).unwrap_or(3)] = 0.0;
                s.push_move(to, config.rate_per_s, now);
                s.homing = true;
                s.answer_at = Some(now);
                String::new()
            }
            _ => err(3),
        };
    }
    if s.alarm {
        return err(9);
    }
    // Words: a letter and a number each.
    let mut words = Vec::new();
    let mut rest = text.as_str();
    while !rest.is_empty() {
        let letter = rest.chars().next().unwrap_or(' ');
        if !letter.is_ascii_alphabetic() {
            return err(1);
        }
        let body = &rest[1..];
        let end = body
            .find(|c: char| !(c.is_ascii_digit() || c == '.' || c == '-' || c == '+'))
            .unwrap_or(body.len());
        let Ok(value) = body[..end].parse::<f64>() else {
            return err(2);
        };
        words.push((letter, value));
        rest = &body[end..];
    }
    let mut motion = None;
    let mut dwell = None;
    let mut relative = s.relative;
    let mut target: [Option<f64>; 4] = [None; 4];
    let mut feed = s.feed;
    for (letter, value) in &words {
        match letter {
            // In tenths, as G-code numbers its commands (G38.2 is 382).
            'G' => match (*value * 10.0).round() as i64 {
                0 => motion = Some(0),
                10 => motion = Some(1),
                40 => dwell = Some(()),
                900 => relative = false,
                910 => relative = true,
                // Millimetres, units per minute, the first work coordinate system: GRBL's
                // defaults, accepted and kept.
                210 | 940 | 540 => {}
                _ => return err(20),
            },
            'F' => feed = Some(*value),
            'P' => {}
            'N' => {}
            c => match axis_index(*c) {
                Some(i) => target[i] = Some(*value),
                None => return err(20),
            },
        }
    }
    if dwell.is_some() {
        let p = words.iter().find(|(l, _)| *l == 'P').map(|(_, v)| *v);
        let Some(p) = p.filter(|p| *p >= 0.0) else {
            return err(28);
        };
        s.relative = relative;
        let (end, _) = s.queue_end(now);
        s.answer_at = Some(end + Duration::from_secs_f64(p));
        return String::new();
    }
    s.relative = relative;
    s.feed = feed;
    s.feed_motion = motion.map_or(s.feed_motion, |m| m == 1);
    if target.iter().all(Option::is_none) {
        return "ok\r\n".into();
    }
    let rate = match s.feed_motion {
        false => config.rate_per_s,
        true => match feed {
            Some(f) if f > 0.0 => (f / 60.0).min(config.rate_per_s),
            _ => return err(22),
        },
    };
    // The move starts where the queue ends.
    let (_, from) = s.queue_end(now);
    let to: [f64; 4] = std::array::from_fn(|i| match target[i] {
        Some(v) if relative => from[i] + v,
        Some(v) => v + config.work_offset[i],
        None => from[i],
    });
    s.push_move(to, rate, now);
    "ok\r\n".into()
}
