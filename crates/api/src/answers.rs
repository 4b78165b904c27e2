//! The daemon's answers (`brdfd serve`'s HTTP API, docs/api.md), and its errors with their
//! codes. The daemon writes them and the CLI reads them back.

use serde::{Deserialize, Serialize};

use crate::session::{Manifest, State};

/// Every error: an RFC 9457 problem (`application/problem+json`), with brdfd's code for
/// programs (`error`) and its sentence for people (`message`, the same as `detail`) as
/// extension members, as before the standard members came. The CLI reads it back.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct ErrorBody {
    /// `about:blank`: a daemon on a bench has no stable address to name its problem types
    /// by, so the type is the status's own (RFC 9457 §4.2.1), and `error` says which problem
    /// of that status this is.
    #[serde(rename = "type")]
    #[cfg_attr(feature = "schema", schema(example = "about:blank"))]
    pub kind: String,
    /// The status's reason phrase (`Conflict`, `Not Found`, ...).
    pub title: String,
    /// The HTTP status of the answer.
    #[cfg_attr(feature = "schema", schema(minimum = 400, maximum = 599))]
    pub status: u16,
    /// What was wrong, and where.
    pub detail: String,
    /// Which problem this is, for programs.
    pub error: ErrorCode,
    /// `detail` again, under the name brdfd's clients have read since before RFC 9457.
    pub message: String,
}

/// brdfd's code for an error: what a program matches on (the HTTP status groups several).
/// `not_found`: no such session, file or route. `bad_request`: the request is malformed (its
/// body, a parameter, a header). `invalid_plan`: the plan is well formed but the rig cannot
/// run it. `busy`: another capture is running. `already_done`: the session is done already.
/// `not_resumable`: the session cannot be resumed. `not_done`: the session has no results
/// yet. `not_running`: the session is not the capture running now. `not_waiting`: the capture
/// waits for no hand turn (of that view). `unauthorized`: no token, or a wrong one.
/// `unknown_host`: a host this daemon does not answer for. `method_not_allowed`: the route
/// does not answer that method. `unsupported_media_type`: a body that is not JSON.
/// `range_not_satisfiable`: a byte range outside the file. `request_timeout`: the request
/// took too long to arrive. `too_many_attempts`: too many failed tokens from this address.
/// `too_many_streams`: too many event streams are open. `storage`: the daemon could not read
/// or write its sessions. `internal`: anything else gone wrong in the daemon.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[serde(rename_all = "snake_case")]
pub enum ErrorCode {
    /// No such session, file or route.
    NotFound,
    /// The request is malformed: its body, a parameter, a header.
    BadRequest,
    /// The plan is well formed but the rig cannot run it.
    InvalidPlan,
    /// Another capture is running.
    Busy,
    /// The session is done already.
    AlreadyDone,
    /// The session cannot be resumed (its state, or what it lacks).
    NotResumable,
    /// The session has no results yet.
    NotDone,
    /// The session is not the capture running now.
    NotRunning,
    /// The capture waits for no hand turn (of that view).
    NotWaiting,
    /// No token, or a wrong one.
    Unauthorized,
    /// The request names a host this daemon does not answer for.
    UnknownHost,
    /// The route does not answer that method.
    MethodNotAllowed,
    /// A body that is not JSON.
    UnsupportedMediaType,
    /// A byte range outside the file.
    RangeNotSatisfiable,
    /// The request took too long to arrive.
    RequestTimeout,
    /// Too many failed tokens from this address: wait.
    TooManyAttempts,
    /// Too many event streams are open.
    TooManyStreams,
    /// The daemon could not read or write its sessions.
    Storage,
    /// Anything else gone wrong in the daemon.
    Internal,
}

/// The media type of every error answer.
pub const PROBLEM: &str = "application/problem+json";

/// `GET /health`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct Health {
    /// `brdfd <version>`.
    pub software: String,
    pub rig: RigSummary,
    /// The session capturing now, if any.
    pub busy: Option<String>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct RigSummary {
    /// Whether the devices are brdfd's simulators (`brdfd serve --simulate`).
    pub simulated: bool,
}

/// `GET /materials`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct Materials {
    /// Names a plan's `material` can take besides the simulator's own materials.
    pub presets: Vec<String>,
}

/// A session in the list.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct SessionItem {
    pub id: String,
    pub state: State,
    pub material: String,
    /// RFC 3339, UTC.
    pub created: String,
    /// Whether this is the capture the daemon is running now (its state then moves on).
    pub running: bool,
}

/// A capture that was started or resumed.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct Started {
    pub id: String,
    /// Where the session is stored on the daemon's machine.
    pub dir: String,
    /// Its event stream's path.
    pub events: String,
}

/// A session and its manifest (docs/formats.md).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct SessionDetail {
    pub id: String,
    pub dir: String,
    #[cfg_attr(feature = "schema", schema(value_type = Object))]
    pub manifest: Manifest,
    /// The view whose hand turn the running capture waits for (`POST .../continue`), if it
    /// waits.
    pub waiting_for_view: Option<usize>,
}

/// `POST /sessions/{id}/cancel`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct Cancelling {
    pub id: String,
    pub cancelling: bool,
}

/// The body of `POST /sessions/{id}/continue`: `{}`, or the view whose turn is done (then
/// only that view's wait is answered).
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct ContinueRequest {
    #[serde(default, deserialize_with = "crate::plan::some_whole_number")]
    #[cfg_attr(feature = "schema", schema(minimum = 1, maximum = 360))] // plan::MAX_VIEWS
    pub view: Option<usize>,
}

/// `POST /sessions/{id}/cancel` and `.../resume`: `{}`, nothing else.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[serde(deny_unknown_fields)]
pub struct Empty {}

/// `POST /sessions/{id}/continue`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct Continuing {
    pub id: String,
    pub continuing: bool,
}
