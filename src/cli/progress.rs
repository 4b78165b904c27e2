//! The operator's view of a capture: a progress bar per phase on a terminal, plain lines
//! otherwise. The same events arrive from an in-process flow or from the daemon's stream.

use brdfd_rig::error::RigError;
use std::collections::HashMap;
use std::io::{IsTerminal, Write};
use std::sync::Mutex;
use std::time::Duration;

use brdfd_rig::{Cancel, Event, Operator, Progress};
use indicatif::{MultiProgress, ProgressBar, ProgressDrawTarget, ProgressStyle};

pub struct Bars {
    multi: MultiProgress,
    bars: Mutex<HashMap<String, ProgressBar>>,
}

impl Bars {
    pub fn new() -> Bars {
        // Bars only where someone watches; logs and tests get the lines alone.
        let target = if std::io::stderr().is_terminal() {
            ProgressDrawTarget::stderr()
        } else {
            ProgressDrawTarget::hidden()
        };
        Bars {
            multi: MultiProgress::with_draw_target(target),
            bars: Mutex::new(HashMap::new()),
        }
    }

    /// The phases started and not yet done: what a stop waits for.
    pub fn under_way(&self) -> Vec<String> {
        // Called from a signal's handler, which must not panic: a poisoned lock gives none.
        let Ok(bars) = self.bars.lock() else {
            return Vec::new();
        };
        let mut phases: Vec<String> = bars.keys().cloned().collect();
        // A download's bar rides along its bracket's; the bracket is the step.
        phases.retain(|p| !p.ends_with(": download"));
        phases.sort();
        phases
    }

    fn line(&self, text: &str) {
        if self.multi.is_hidden() {
            // A reader that went away (`| head`) must not stop the capture with a panic.
            let _ = writeln!(std::io::stdout(), "{text}");
        } else {
            let _ = self.multi.println(text);
        }
    }

    fn bar(&self, phase: &str, total: u64, bytes: bool) -> ProgressBar {
        let mut bars = self.bars.lock().expect("bars");
        bars.entry(phase.to_string())
            .or_insert_with(|| {
                // The spinner turns while a device or the simulator works between updates.
                let template = if bytes {
                    "{spinner} {prefix:<46} [{bar:30}] {bytes}/{total_bytes}"
                } else {
                    "{spinner} {prefix:<46} [{bar:30}] {pos}/{len} {elapsed}"
                };
                let b = self.multi.add(ProgressBar::new(total));
                b.set_style(
                    ProgressStyle::with_template(template)
                        .expect("a valid template")
                        .progress_chars("=> "),
                );
                b.set_prefix(phase.to_string());
                b.enable_steady_tick(Duration::from_millis(200));
                b
            })
            .clone()
    }
}

impl Progress for Bars {
    fn event(&self, e: Event) {
        match e {
            Event::PhaseStarted { phase, total } => {
                self.bar(&phase, total, false);
            }
            Event::Progress { phase, done, total } => {
                let b = self.bar(&phase, total, phase.ends_with("download"));
                b.set_length(total);
                b.set_position(done);
                if done >= total && phase.ends_with("download") {
                    // One download bar per frame would pile up; the last frame's stays.
                    b.set_position(total);
                }
            }
            Event::PhaseDone { phase, seconds, .. } => {
                let b = self.bar(&phase, 1, false);
                b.set_position(b.length().unwrap_or(1));
                // The phase's own time, frozen: a finished bar is never drawn again (it leaves
                // the map), so its clock cannot run on to the end of the capture.
                b.set_style(
                    ProgressStyle::with_template("  {prefix:<46} [{bar:30}] {pos}/{len} {msg}")
                        .expect("a valid template")
                        .progress_chars("=> "),
                );
                b.finish_with_message(format!("{seconds:.2} s"));
                self.bars.lock().expect("bars").remove(&phase);
                if let Some(d) = self.bars.lock().expect("bars").remove(&format!(
                    "{}: download",
                    phase.trim_end_matches(": object bracket")
                )) {
                    d.finish_and_clear();
                }
            }
            Event::Message { text } => self.line(&text),
            Event::WaitingForOperator { text, .. } => self.line(&text),
            Event::Warning { text } => {
                self.multi.suspend(|| eprintln!("  warning: {text}"));
            }
            Event::Finished { .. } => {
                for (_, b) in self.bars.lock().expect("bars").drain() {
                    b.finish();
                }
            }
        }
    }
}

/// The operator at this terminal, for a capture that needs the object turned by hand: asked
/// on the terminal, answering with Enter.
pub struct Terminal;

/// How often a wait for Enter checks whether it is still needed.
const STILL_NEEDED_EVERY: Duration = Duration::from_millis(200);

/// Standard input's lines, read by one thread for the whole run: a wait that ends without a
/// line (cancelled, answered elsewhere) must not leave a reader behind that takes the next
/// Enter. Each item is what `read_line` returned; the thread ends at end of input.
fn stdin_lines() -> &'static Mutex<std::sync::mpsc::Receiver<std::io::Result<usize>>> {
    static LINES: std::sync::OnceLock<Mutex<std::sync::mpsc::Receiver<std::io::Result<usize>>>> =
        std::sync::OnceLock::new();
    LINES.get_or_init(|| {
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || loop {
            let mut line = String::new();
            let r = std::io::stdin().read_line(&mut line);
            let end = !matches!(r, Ok(n) if n > 0);
            if tx.send(r).is_err() || end {
                return;
            }
        });
        Mutex::new(rx)
    })
}

impl Terminal {
    /// Waits for Enter once the object is turned, after saying `hint`, while `still_needed`
    /// says so: true once Enter is pressed, false once the wait is no longer needed
    /// (answered elsewhere).
    pub fn enter<E: From<RigError>>(
        hint: &str,
        still_needed: &dyn Fn() -> Result<bool, E>,
    ) -> Result<bool, E> {
        Terminal::ask(
            &format!("press Enter once it is turned ({hint})"),
            "no one can say the object is turned: standard input is closed. A capture of several views on a rig with no turntable needs someone at the terminal (or a client that calls the API's `continue`)",
            still_needed,
        )
    }

    /// Says `prompt` and waits for Enter while `still_needed` says so; `closed` is the error
    /// when no one can answer (standard input is closed). Its errors are the rig's, as a
    /// flow's operator gives them, or whatever `still_needed`'s are.
    pub fn ask<E: From<RigError>>(
        prompt: &str,
        closed: &str,
        still_needed: &dyn Fn() -> Result<bool, E>,
    ) -> Result<bool, E> {
        let closed = || E::from(RigError::invalid(closed));
        let lines = stdin_lines().lock().expect("stdin lines");
        // Lines typed before the question do not answer it.
        while let Ok(r) = lines.try_recv() {
            if !matches!(r, Ok(n) if n > 0) {
                return Err(closed());
            }
        }
        eprintln!("  {prompt}");
        loop {
            match lines.recv_timeout(STILL_NEEDED_EVERY) {
                Ok(Ok(n)) if n > 0 => return Ok(true),
                Ok(Err(e)) => {
                    return Err(E::from(RigError::from(e).step("reading standard input")))
                }
                Ok(Ok(_)) | Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => {
                    return Err(closed())
                }
                Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {
                    if !still_needed()? {
                        return Ok(false);
                    }
                }
            }
        }
    }
}

impl Operator for Terminal {
    fn wait(&self, _view: usize, announce: &dyn Fn(), cancel: &Cancel) -> Result<(), RigError> {
        announce();
        Terminal::enter("Ctrl-C stops; the session can be resumed", &|| {
            cancel.check().map(|()| true)
        })
        .map(|_| ())
    }
}
