//! The operator's view of a capture: a progress bar per phase on a terminal, plain lines
//! otherwise. The same events arrive from an in-process flow or from the daemon's stream.

use std::collections::HashMap;
use std::io::{IsTerminal, Write};
use std::sync::Mutex;
use std::time::Duration;

use brdfd::rig::{Event, Progress};
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
                    phase.trim_end_matches(": DSLR bracket")
                )) {
                    d.finish_and_clear();
                }
            }
            Event::Message { text } => self.line(&text),
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
