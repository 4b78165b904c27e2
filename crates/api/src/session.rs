//! A session's manifest as stored in `manifest.json` and served by the daemon: its state and
//! history, the rig and plan it ran, its devices, and each capture step's files
//! (docs/formats.md). Reading and writing it on disk is the rig's (`brdfd_rig::session`).

use serde::{Deserialize, Serialize};

/// Where a session is in its life (see [`State::may_become`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[serde(rename_all = "kebab-case")]
pub enum State {
    Created,
    Capturing,
    Captured,
    Estimating,
    Done,
    Failed,
}

impl State {
    /// Whether a session in this state may go to `next`. A session is captured, then
    /// estimated, then done; any step before done may fail, and a failed session is resumed
    /// by capturing again (its complete steps are kept). A failed session may record another
    /// failure (a resume that fails before it starts). Done is final.
    pub fn may_become(self, next: State) -> bool {
        use State::*;
        matches!(
            (self, next),
            (Created | Failed, Capturing)
                | (Capturing, Captured)
                | (Captured, Estimating)
                | (Estimating, Done)
                | (Created | Capturing | Captured | Estimating | Failed, Failed)
        )
    }

    /// The state's name as the manifest and the API write it.
    pub fn name(self) -> &'static str {
        match self {
            State::Created => "created",
            State::Capturing => "capturing",
            State::Captured => "captured",
            State::Estimating => "estimating",
            State::Done => "done",
            State::Failed => "failed",
        }
    }
}

impl std::fmt::Display for State {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.pad(self.name())
    }
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Transition {
    pub state: State,
    pub at: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
    /// A failure's cause, for programs (absent in sessions written before it was recorded).
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "crate::failure::FailureCode::read_lenient"
    )]
    pub code: Option<crate::failure::FailureCode>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RawFile {
    /// Name under `raw/`: `<step>-a<attempt>-<frame>-<the device's name>`.
    pub name: String,
    pub sha256: String,
    pub bytes: u64,
    /// The name the device gave the file. Cameras reuse names (after a card change, or when
    /// they shoot to memory), so it is kept here and the stored name carries a frame index.
    /// Absent in sessions written before it was recorded.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub device_name: Option<String>,
}

impl RawFile {
    /// The name the device gave the file, as far as the session knows it: recorded, or read
    /// from the stored name of an older session (`<step>-a<attempt>-<name>`).
    pub fn device_name(&self, step: &Step) -> &str {
        if let Some(n) = &self.device_name {
            return n;
        }
        self.name
            .strip_prefix(&format!("{}-a{}-", step.name, step.attempt))
            .unwrap_or(&self.name)
    }
}

/// One capture step's attempt.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Step {
    pub name: String,
    pub attempt: u32,
    pub complete: bool,
    pub files: Vec<RawFile>,
    /// What the step needs to be used later (exposures, turntable angle, device identity).
    #[serde(default)]
    pub meta: serde_json::Value,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Manifest {
    pub id: String,
    pub material: String,
    pub created: String,
    pub software: String,
    pub state: State,
    pub history: Vec<Transition>,
    /// The rig file and material preset as used (TOML text).
    pub rig: String,
    #[serde(default)]
    pub preset: Option<String>,
    /// Options of the capture that a resume must repeat (pixels, views, ...).
    #[serde(default)]
    pub options: serde_json::Value,
    pub devices: Vec<String>,
    pub steps: Vec<Step>,
    /// Wall time of each phase of the last run, split into brdfd's own work and the
    /// devices' (for simulated devices: rendering and simulated exposure time).
    #[serde(default)]
    pub phases: Vec<PhaseTime>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PhaseTime {
    pub name: String,
    pub seconds: f64,
    /// Of `seconds`, the time the devices spent (exposing, rendering) rather than brdfd.
    pub device_seconds: f64,
}
