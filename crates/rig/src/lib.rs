//! brdfd's capture rig: its devices, each on a worker thread, and the capture flow that turns
//! a material on the bench into a session on disk, with the files that describe a rig and the
//! sessions it writes. The CLI runs the flow in-process; the daemon (`brdfd-daemon`, `brdfd
//! serve`) runs the same flow on devices it keeps open between captures. It sits above the
//! core, the radiometry, pose and report crates and the drivers, and below the simulated rig
//! (`brdfd-simrig`), the daemon and the binary (docs/architecture.md).
//!
//! - [`config`]: the daemon, rig and material files, validated.
//! - [`session`]: sessions on disk (manifest state machine, raw files with sha256, atomic
//!   writes).
//! - [`selector`]: the strings that name devices (`usb:04b0:0429`, `osc:http://...`, ...).
//! - [`roles`]: what the capture asks of its devices: an object camera, a light probe, a
//!   turntable, a shutter, each a trait with optional abilities.
//! - [`plan`]: whether the capture can run a rig file (`config check` asks the same).
//! - [`calibrate`]: each camera's gain from a target of known albedo; [`calibrate_pose`]:
//!   the object camera's pose (and the object's placement) from photos of the bench, written
//!   into the rig file ([`rig_file`]: a rig file rewritten with its comments kept).
//! - [`devices`]: the rig's devices in their roles, and the role traits for PTP, THETA, V4L2
//!   and serial devices.
//! - [`worker`]: one thread per device, with keep-alive and re-opening.
//! - [`open`]: devices from their selectors (`usb:04b0:0429`, `osc:http://...`, `serial:...`).
//! - [`simulation`]: the seam the simulated rig (`brdfd-simrig`) fills: its devices, which
//!   speak the real protocols on loopback, and its virtual bench. A program provides it once.
//! - `stage.rs`: the hands on the bench, which place the sample, show it turned to the
//!   cameras and judge the estimate against what they know of the truth: a real bench's
//!   operator and turntable, or the simulated rig's virtual bench. The flow asks them through
//!   one trait ([`simulation::Stage`]), and has no simulated branch of its own.
//! - [`settings`]: a capture's settings, resolved from the plan, the preset and the rig
//!   before a session exists.
//! - [`flow`]: the capture itself, as resumable steps; [`error`]: what it failed on, and
//!   why, as a code.
//! - [`light`]: the light probe's bracket; [`object`]: the object camera's views, shot on
//!   the DSLR or the V4L2 fallback and merged; [`turning`]: the object turned between views.

pub mod calibrate;
pub mod calibrate_pose;
pub mod config;
pub mod devices;
pub mod error;
pub mod flow;
pub mod light;
pub mod object;
pub mod open;
pub mod plan;
pub mod pose;
mod prepare;
pub mod rig_file;
pub mod roles;
pub mod selector;
pub mod session;
pub mod settings;
pub mod simulation;
mod stage;
pub mod turning;
pub mod worker;

use crate::error::{Result, RigError};
use std::sync::Arc;
use std::time::Duration;

pub use brdfd_api::event::{Event, Summary, SummaryFlag, SummaryMaterial};
pub use brdfd_api::plan::{some_whole_number, whole_number, PixelCount, Plan, MAX_VIEWS};
use brdfd_core::stop::Stop;
pub use devices::Devices;
pub use worker::{Device, DeviceStatus, Worker};

/// The summary of a stored result (`result/coefficients.json`), if it can be read.
pub fn stored_summary(coefficients_json: &std::path::Path) -> Option<Summary> {
    let r = brdfd_report::results::StoredResult::read(coefficients_json).ok()?;
    let exports = r.exports.clone().unwrap_or_default();
    let anisotropic_lobe = matches!(r.chosen_lobe(), Ok(Some(_)));
    Some(Summary {
        anisotropic_lobe,
        verdict: r.verdict,
        verdict_text: r.verdict_text,
        fit_verdict: brdfd_core::estimate::fit_verdict(r.fit_error.unwrap_or(f64::NAN)),
        model: r.model,
        columns: r.columns,
        coefficients: r.coefficients,
        fit_error: r.fit_error,
        relight_error: r.relight_error,
        fallback: r.fallback,
        export_relight_error: exports.relight_error,
        export_verdict: exports.verdict,
        mtlx_relight_error: exports.mtlx_relight_error,
        mtlx_verdict: exports.mtlx_verdict,
        flags: r
            .flags
            .into_iter()
            .map(|f| SummaryFlag {
                reason: f.reason,
                text: f.text,
            })
            .collect(),
        materials: r
            .materials
            .map(|m| summary_materials(&m))
            .unwrap_or_default(),
    })
}

/// The materials of a part split into two, as the summary carries them.
pub(crate) fn summary_materials(
    m: &brdfd_report::materials::MaterialsRecord,
) -> Vec<SummaryMaterial> {
    m.parts
        .iter()
        .map(|p| SummaryMaterial {
            folder: p.folder.clone(),
            share: p.share,
            fit_error: p.fit_error.is_finite().then_some(p.fit_error),
            fit_verdict: brdfd_core::estimate::fit_verdict(p.fit_error),
        })
        .collect()
}

pub trait Progress: Send + Sync {
    fn event(&self, e: Event);
}

impl<F: Fn(Event) + Send + Sync> Progress for F {
    fn event(&self, e: Event) {
        self(e)
    }
}

/// Asks a running capture to stop at its next frame boundary, or at the core's next check
/// in an estimate ([`Cancel::stop`]). What was captured is kept, and the session can be
/// resumed.
#[derive(Clone, Default)]
pub struct Cancel(Stop);

impl Cancel {
    pub fn cancel(&self) {
        self.0.request();
    }
    pub fn is_cancelled(&self) -> bool {
        self.0.requested()
    }
    pub fn check(&self) -> Result<()> {
        if self.is_cancelled() {
            return Err(RigError::Cancelled);
        }
        Ok(())
    }
    /// The same request, as the estimation core and the exports see it.
    pub fn stop(&self) -> Stop {
        self.0.clone()
    }
}

/// The operator's part in a capture: turning the object by hand between views, on a rig with
/// no turntable. The CLI asks on its terminal; the daemon waits for `POST .../continue`.
pub trait Operator: Send + Sync {
    /// Asks for view `view`'s turn (`announce` sends the request out, once an answer can be
    /// taken) and returns once the operator says it is done; an error if the capture is
    /// cancelled meanwhile or no operator can answer.
    fn wait(&self, view: usize, announce: &dyn Fn(), cancel: &Cancel) -> Result<()>;
}

/// A go-ahead given from elsewhere (the daemon's API) to a capture waiting on this thread.
#[derive(Clone, Default)]
pub struct GoAhead(Arc<(std::sync::Mutex<GoState>, std::sync::Condvar)>);

#[derive(Default)]
struct GoState {
    /// The view whose turn is awaited.
    waiting: Option<usize>,
    given: bool,
}

impl GoAhead {
    /// Gives the go-ahead to the capture waiting for a turn (for view `view`, if given):
    /// false if none waits, or it waits for another view.
    pub fn give(&self, view: Option<usize>) -> bool {
        let (state, ready) = &*self.0;
        let mut s = state.lock().expect("go-ahead");
        match s.waiting {
            Some(w) if view.is_none_or(|v| v == w) => {
                s.given = true;
                ready.notify_all();
                true
            }
            _ => false,
        }
    }

    /// The view whose turn is awaited now, if any.
    pub fn waiting(&self) -> Option<usize> {
        self.0 .0.lock().expect("go-ahead").waiting
    }
}

impl Operator for GoAhead {
    fn wait(&self, view: usize, announce: &dyn Fn(), cancel: &Cancel) -> Result<()> {
        let (state, ready) = &*self.0;
        *state.lock().expect("go-ahead") = GoState {
            waiting: Some(view),
            given: false,
        };
        // Announced once an answer is taken, and not under the lock (a client may answer at
        // once).
        announce();
        let mut s = state.lock().expect("go-ahead");
        while !s.given && !cancel.is_cancelled() {
            // Woken by `give`; the timeout is for noticing a cancel.
            s = ready
                .wait_timeout(s, Duration::from_millis(100))
                .expect("go-ahead")
                .0;
        }
        let given = s.given;
        *s = GoState::default();
        if given {
            Ok(())
        } else {
            cancel.check()
        }
    }
}

/// How often an idle device is spoken to. A THETA V sleeps after 3 minutes unless told
/// otherwise; a Nikon's USB session survives idling, but a cheap request tells us early when
/// a cable was pulled.
pub const KEEP_ALIVE: Duration = Duration::from_secs(20);
