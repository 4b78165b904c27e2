//! The capture rig: its devices, each on a worker thread, and the capture flow that turns a
//! material on the bench into a session on disk. The CLI runs the flow in-process; the daemon
//! (`brdfd serve`) runs the same flow on devices it keeps open between captures.
//!
//! - [`roles`]: what the capture asks of its devices: an object camera, a light probe, a
//!   turntable, a shutter, each a trait with optional abilities.
//! - [`plan`]: whether the capture can run a rig file (`config check` asks the same).
//! - [`calibrate`]: each camera's gain from a target of known albedo.
//! - [`devices`]: the rig's devices in their roles, and the role traits for PTP, THETA, V4L2
//!   and serial devices.
//! - [`worker`]: one thread per device, with keep-alive and re-opening.
//! - [`open`]: devices from their selectors (`usb:04b0:0429`, `osc:http://...`, `serial:...`).
//! - [`simulated`]: the simulated rig, whose devices speak the real protocols on loopback.
//! - [`settings`]: a capture's settings, resolved from the plan, the preset and the rig
//!   before a session exists.
//! - [`flow`]: the capture itself, as resumable steps.
//! - [`light`]: the light probe's bracket; [`object`]: the object camera's views, shot on
//!   the DSLR or the V4L2 fallback and merged; [`turning`]: the object turned between views.

pub mod calibrate;
pub mod devices;
pub mod flow;
pub mod light;
pub mod object;
pub mod open;
pub mod plan;
pub mod pose;
pub mod roles;
pub mod settings;
pub mod simulated;
pub mod turning;
pub mod worker;

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use serde::{Deserialize, Serialize};

use brdfd_core::estimate::Model;
use brdfd_core::solve::{ColourChoice, Solver};
use brdfd_core::stop::Stop;
pub use devices::Devices;
pub use worker::{Device, DeviceStatus, Worker};

/// What a capture was asked to do. Stored in the session's manifest, so that a resume
/// repeats it; also the body of the daemon's "start a capture" request.
#[derive(Debug, Clone, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct Plan {
    /// A preset in config/materials, a MERL name, or an alias (gold, chrome, paint, ...).
    // The pattern is `config::validate_name`'s rule, which `validate` applies.
    #[schema(pattern = "^[a-z0-9][a-z0-9-]{0,63}$")]
    pub material: String,
    /// Image size of the simulated camera (ignored on a hardware rig).
    #[serde(default = "default_size", deserialize_with = "whole_number")]
    #[schema(minimum = 8, maximum = 8192, default = 256)]
    pub size: usize,
    /// Pixels to estimate from: a number or "all"; the preset's, else 20.
    // The pattern is what `validate` accepts (`pixels_rule`).
    #[serde(default)]
    #[schema(pattern = "^(all|[1-9][0-9]{0,8})$")]
    pub pixels: Option<String>,
    /// The BRDF model: "hybrid", "analytic" or "basis"; the preset's, else hybrid.
    #[serde(default)]
    pub model: Option<Model>,
    /// How the coefficients are solved: "prior" or "least-squares"; the preset's, else prior.
    #[serde(default)]
    pub solve: Option<Solver>,
    /// How colour is modelled: "joint", "per-channel" or "auto"; the preset's, else auto.
    #[serde(default)]
    pub colour: Option<ColourChoice>,
    /// DSLR shutter speeds, seconds; the preset's, else the rig's.
    #[serde(default)]
    #[schema(schema_with = bracket_schema)]
    pub bracket: Vec<f64>,
    /// Turntable views (1: no turntable); the rig's `[turntable]` plan, else 1.
    #[serde(default, deserialize_with = "some_whole_number")]
    #[schema(minimum = 1, maximum = 360)] // MAX_VIEWS
    pub views: Option<usize>,
    /// Turntable step between views, degrees; the rig's, else 30.
    #[serde(default)]
    pub turn: Option<f64>,
    /// Simulated rig only: the environment map and NBRDF file of the scene, by file name in
    /// the daemon's `scenes` folder.
    // A path is refused (`daemon::scene_names`): the pattern says so.
    #[serde(default)]
    #[schema(value_type = Option<String>, pattern = "^[^/]+$")]
    pub env: Option<PathBuf>,
    #[serde(default)]
    #[schema(value_type = Option<String>, pattern = "^[^/]+$")]
    pub nbrdf: Option<PathBuf>,
    /// Simulated rig only: the sample is the material's projection onto the basis (its best
    /// K-term approximation) rather than the material itself. Its coefficients are then known
    /// exactly, which checks the capture chain apart from the model's own error.
    #[serde(default)]
    pub in_span: bool,
}

fn default_size() -> usize {
    256
}

/// The plan's `bracket` in the API's description: [`crate::config::MAX_BRACKET`] shutter
/// speeds at most, each above 0 and at most [`crate::config::MAX_EXPOSURE_S`] seconds, as
/// [`Plan::validate`] requires.
fn bracket_schema() -> utoipa::openapi::Array {
    use utoipa::openapi::schema::{ArrayBuilder, ObjectBuilder, Type};
    let speed = ObjectBuilder::new()
        .schema_type(Type::Number)
        .exclusive_minimum(Some(0.0))
        .maximum(Some(crate::config::MAX_EXPOSURE_S));
    ArrayBuilder::new()
        .items(speed)
        .max_items(Some(crate::config::MAX_BRACKET))
        .description(Some(
            "DSLR shutter speeds, seconds; the preset's, else the rig's.",
        ))
        .build()
}

/// A count given as a JSON number: `5` or `5.0` alike. JSON Schema's `integer` is any number
/// without a fraction (a client's JSON library may write 5 as `5.0`), where serde takes only
/// the former.
pub fn whole_number<'de, D: serde::Deserializer<'de>>(d: D) -> Result<usize, D::Error> {
    let n = serde_json::Number::deserialize(d)?;
    if let Some(n) = n.as_u64() {
        return usize::try_from(n).map_err(serde::de::Error::custom);
    }
    match n.as_f64() {
        // Up to u32::MAX, which every count a plan holds is far below, and which an f64 holds
        // exactly.
        Some(f) if f >= 0.0 && f.fract() == 0.0 && f <= u32::MAX as f64 => Ok(f as usize),
        _ => Err(serde::de::Error::custom(format!(
            "expected a whole number, not {n}"
        ))),
    }
}

/// [`whole_number`] for an optional field (`null` or absent is `None`).
pub fn some_whole_number<'de, D: serde::Deserializer<'de>>(
    d: D,
) -> Result<Option<usize>, D::Error> {
    #[derive(Deserialize)]
    struct Whole(#[serde(deserialize_with = "whole_number")] usize);
    Ok(Option::<Whole>::deserialize(d)?.map(|w| w.0))
}

impl Plan {
    /// On a simulated rig, the material must be one the simulator can render: a shipped
    /// preset, an alias or embedded test material, or one of the plan's NBRDF file. Checked
    /// before a session exists, so that a typo leaves nothing behind.
    pub fn check_simulated_material(&self) -> anyhow::Result<()> {
        let preset =
            crate::config::MaterialPreset::embedded(&self.material).map_err(anyhow::Error::msg)?;
        let name = preset
            .as_ref()
            .map_or(self.material.as_str(), |p| p.simulate_as.as_str());
        let merl = crate::bench::resolve_material(name);
        if crate::bench::embedded_materials().get(merl).is_ok() {
            return Ok(());
        }
        if let Some(path) = &self.nbrdf {
            let set = brdfd_core::nbrdf::NbrdfSet::read(path)?;
            set.get(merl)?;
            return Ok(());
        }
        let embedded = crate::bench::embedded_materials();
        anyhow::bail!(
            "the simulator has no material {:?}. Use a preset ({}), a short name ({}), a test \
             material ({}), or give --nbrdf FILE holding it",
            self.material,
            crate::config::preset_names().join(", "),
            crate::bench::aliases().join(", "),
            embedded.names().join(", ")
        )
    }

    /// Checks what can be checked before any device moves.
    pub fn validate(&self) -> anyhow::Result<()> {
        crate::config::validate_name("material", &self.material).map_err(anyhow::Error::msg)?;
        if let Some(views) = self.views {
            anyhow::ensure!(
                (1..=MAX_VIEWS).contains(&views),
                "views must be 1 to {MAX_VIEWS}, not {views}"
            );
        }
        if let Some(turn) = self.turn {
            anyhow::ensure!(
                turn.is_finite(),
                "turn must be a number of degrees, not {turn}"
            );
        }
        anyhow::ensure!(
            (8..=8192).contains(&self.size),
            "size {} is outside 8..=8192",
            self.size
        );
        if let Some(p) = &self.pixels {
            pixels_rule(p)?;
        }
        use crate::config::{MAX_BRACKET, MAX_EXPOSURE_S};
        anyhow::ensure!(
            self.bracket.len() <= MAX_BRACKET,
            "bracket has {} shutter speeds; at most {MAX_BRACKET}",
            self.bracket.len()
        );
        anyhow::ensure!(
            self.bracket
                .iter()
                .all(|s| s.is_finite() && *s > 0.0 && *s <= MAX_EXPOSURE_S),
            "bracket shutter speeds must be seconds above 0, at most {MAX_EXPOSURE_S}"
        );
        Ok(())
    }
}

/// A plan's `pixels`: `all`, or a count from 1 written plainly (no sign, no leading zero, at
/// most nine digits), the pattern the API's description gives it.
fn pixels_rule(p: &str) -> anyhow::Result<()> {
    let plain = !p.is_empty()
        && p.len() <= 9
        && !p.starts_with('0')
        && p.bytes().all(|b| b.is_ascii_digit());
    anyhow::ensure!(
        p == "all" || plain,
        "pixels takes `all` or a count from 1 (at most nine digits), not {p:?}"
    );
    flow::parse_pixels(p).map(|_| ())
}

/// Turntable views at most: one per degree, more than any bench turns for one estimate, and a
/// bound on what a plan or rig file can make the capture allocate and shoot.
pub const MAX_VIEWS: usize = 360;

/// What the flow reports as it goes; the CLI draws progress bars from it, the daemon sends it
/// to its event stream. Serialised as `{"type": "phase_started", ...}`.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, utoipa::ToSchema)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum Event {
    /// A phase began: `total` units (frames, or 1 for one piece of work).
    PhaseStarted { phase: String, total: u64 },
    /// Work done in a phase so far.
    Progress {
        phase: String,
        done: u64,
        total: u64,
    },
    /// A phase ended: its wall time, and of that the devices' own time.
    PhaseDone {
        phase: String,
        seconds: f64,
        device_seconds: f64,
    },
    /// A line for the operator.
    Message { text: String },
    /// The capture waits for the operator: turn the object by hand to `degrees` for view
    /// `view` (from 1), then say so (the CLI's Enter, the API's `continue`).
    WaitingForOperator {
        text: String,
        view: usize,
        degrees: f64,
    },
    /// Something the operator should look at; the capture goes on.
    Warning { text: String },
    /// The end: the session's final state, with the result or the error.
    Finished {
        session: String,
        state: crate::session::State,
        /// Boxed: the summary is most of the event's size, and the other events are small.
        result: Option<Box<Summary>>,
        error: Option<String>,
        /// Failed because it was cancelled (what was captured is kept; a resume continues).
        #[serde(default)]
        cancelled: bool,
    },
}

impl Event {
    /// The phases `events` started and did not end, in the order they started: what a stop
    /// waits for, said to the operator who asked for it.
    pub fn under_way(events: &[Event]) -> Vec<String> {
        let mut open: Vec<String> = Vec::new();
        for e in events {
            match e {
                Event::PhaseStarted { phase, .. } => open.push(phase.clone()),
                Event::PhaseDone { phase, .. } => open.retain(|p| p != phase),
                Event::Finished { .. } => open.clear(),
                _ => {}
            }
        }
        open
    }
}

/// A finished estimate in brief, as the `finished` event carries it: the model, its columns
/// and coefficients, and how it fits (the whole record is `result/coefficients.json`).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq, utoipa::ToSchema)]
pub struct Summary {
    /// `hybrid`, `analytic` or `basis`.
    pub model: String,
    /// Names of the coefficients, in their order.
    pub columns: Vec<String>,
    /// The coefficients; `null` for one that is not a number (JSON has no NaN).
    pub coefficients: Vec<Option<f64>>,
    /// How well the estimate re-renders the photo (relative RMSE; `null` if not a number).
    pub fit_error: Option<f64>,
    /// The fit in words: `good`, `fair` or `poor`, with its threshold.
    pub fit_verdict: String,
    /// A simulated capture's relit error against the truth, under light it was not fitted to.
    pub relight_error: Option<f64>,
    /// When the V4L2 fallback camera shot any view: which, and what averaging left of its
    /// noise.
    #[serde(default)]
    pub fallback: Option<String>,
    /// How far `material.gltf` relights from the estimate under light its fit did not see.
    #[serde(default)]
    pub export_relight_error: Option<f64>,
    /// That figure in words (`faithful`, `close` or `approximate`), with its threshold.
    #[serde(default)]
    pub export_verdict: Option<String>,
}

impl Summary {
    /// The summary of a stored result (`result/coefficients.json`), if it can be read.
    pub fn read(coefficients_json: &std::path::Path) -> Option<Summary> {
        let text = std::fs::read_to_string(coefficients_json).ok()?;
        let v: serde_json::Value = serde_json::from_str(&text).ok()?;
        let fit = v["fit_error"].as_f64();
        Some(Summary {
            model: v["model"].as_str()?.to_string(),
            columns: serde_json::from_value(v["columns"].clone()).ok()?,
            coefficients: serde_json::from_value(v["coefficients"].clone()).ok()?,
            fit_error: fit,
            fit_verdict: brdfd_core::estimate::fit_verdict(fit.unwrap_or(f64::NAN)),
            relight_error: v["relight_error"].as_f64(),
            fallback: v["fallback"].as_str().map(str::to_string),
            export_relight_error: v["exports"]["relight_error"].as_f64(),
            export_verdict: v["exports"]["verdict"].as_str().map(str::to_string),
        })
    }

    /// Coefficients as the summary carries them: a number, or `None` where there is none.
    pub fn numbers(values: &[f64]) -> Vec<Option<f64>> {
        values.iter().map(|v| v.is_finite().then_some(*v)).collect()
    }
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
    pub fn check(&self) -> anyhow::Result<()> {
        anyhow::ensure!(!self.is_cancelled(), "cancelled");
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
    fn wait(&self, view: usize, announce: &dyn Fn(), cancel: &Cancel) -> anyhow::Result<()>;
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
    fn wait(&self, view: usize, announce: &dyn Fn(), cancel: &Cancel) -> anyhow::Result<()> {
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
