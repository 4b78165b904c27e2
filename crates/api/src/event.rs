//! What a running capture reports as it goes, ending with its result in brief.

use serde::{Deserialize, Serialize};

pub use crate::failure::FailureCode;
use crate::session::State;

/// What the flow reports as it goes; the CLI draws progress bars from it, the daemon sends it
/// to its event stream. Serialised as `{"type": "phase_started", ...}`.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
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
        state: State,
        /// Boxed: the summary is most of the event's size, and the other events are small.
        result: Option<Box<Summary>>,
        error: Option<String>,
        /// Failed because it was cancelled (what was captured is kept; a resume continues).
        #[serde(default)]
        cancelled: bool,
        /// Why it failed, for programs (`error` says it for people); absent when it did not.
        #[serde(
            default,
            skip_serializing_if = "Option::is_none",
            deserialize_with = "FailureCode::read_lenient"
        )]
        code: Option<FailureCode>,
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
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct Summary {
    /// `hybrid`, `analytic` or `basis`.
    pub model: String,
    /// Whether the estimate relights with an anisotropic GGX lobe it chose over `model`, for
    /// a surface with a grain (`coefficients.json`'s `anisotropy.lobe`): `fit_error` is then
    /// the lobe's, and the exports carry its stretch.
    #[serde(default)]
    pub anisotropic_lobe: bool,
    /// Names of the coefficients, in their order.
    pub columns: Vec<String>,
    /// The coefficients; `null` for one that is not a number (JSON has no NaN).
    pub coefficients: Vec<Option<f64>>,
    /// The verdict on the estimate, `good`, `fair` or `poor`: the worst of its judged figures
    /// (the fit, a simulation's relit error, the steadiness, the conditioning) and of its
    /// flags, as the command line's summary opens with it. Absent in results written before
    /// it was kept.
    #[serde(default)]
    pub verdict: Option<String>,
    /// The verdict in words, with what to do when it is not good.
    #[serde(default)]
    pub verdict_text: Option<String>,
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
    /// How far `material.mtlx` relights from the estimate under the same light, rendered with
    /// OpenPBR's own BRDF; absent for an anisotropic lobe, and in results written before.
    #[serde(default)]
    pub mtlx_relight_error: Option<f64>,
    /// That figure in words, as `export_verdict`.
    #[serde(default)]
    pub mtlx_verdict: Option<String>,
    /// The assumptions of brdfd's model that the photo says are broken (`coefficients.json`'s
    /// `flags`); empty when none is.
    #[serde(default)]
    pub flags: Vec<SummaryFlag>,
    /// When the part was split into two materials (`coefficients.json`'s `materials`), each
    /// material's results, share and fit; empty for one material. The fit and exports above
    /// are then of the one BRDF fitted to the whole part, and `verdict` is the split's.
    #[serde(default)]
    pub materials: Vec<SummaryMaterial>,
}

/// One material of a part split into two: its own results' folder
/// (`/sessions/{id}/result/{folder}/{file}`), its share of the part's pixels, and how well its
/// estimate re-renders them.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct SummaryMaterial {
    pub folder: String,
    pub share: f64,
    /// Relative RMSE; `null` if not a number.
    pub fit_error: Option<f64>,
    /// The fit in words, with its threshold.
    pub fit_verdict: String,
}

/// A broken assumption of the model, as the photo shows it: `reason` for programs
/// (`interreflection`: the part seems to light itself; `several_materials`: the photo's
/// colour departs from the estimate's from place to place; `anisotropy`: the highlights are
/// stretched across a grain; `misregistration`: the light is turned from where the map's yaw
/// or the pose put it), `text` for people (the figure,
/// its threshold, and what it means for the estimate).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct SummaryFlag {
    pub reason: String,
    pub text: String,
}

impl Summary {
    /// Coefficients as the summary carries them: a number, or `None` where there is none.
    pub fn numbers(values: &[f64]) -> Vec<Option<f64>> {
        values.iter().map(|v| v.is_finite().then_some(*v)).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_failure_code_is_written_as_its_name() {
        for code in FailureCode::ALL {
            let json = serde_json::to_value(code).unwrap();
            assert_eq!(json, code.name());
            assert_eq!(serde_json::from_value::<FailureCode>(json).unwrap(), code);
        }
    }

    #[test]
    fn a_code_from_a_newer_brdfd_reads_as_failed() {
        let finished = |code: &str| {
            let text = format!(
                r#"{{"type": "finished", "session": "s", "state": "failed", "result": null, "error": "x"{code}}}"#
            );
            match serde_json::from_str::<Event>(&text).unwrap() {
                Event::Finished { code, .. } => code,
                e => panic!("{e:?}"),
            }
        };
        assert_eq!(
            finished(r#", "code": "device_busy""#),
            Some(FailureCode::DeviceBusy)
        );
        assert_eq!(
            finished(r#", "code": "lens_fogged""#),
            Some(FailureCode::Failed)
        );
        assert_eq!(finished(""), None);
    }
}
