//! The API's OpenAPI description, served at `GET /api/v1/openapi.json`. It is generated from
//! the handlers' `#[utoipa::path]` attributes as [`super::api::router`] registers them
//! (utoipa-axum), so a route cannot exist without its description, nor the other way round.
//! What the middleware adds to every answer (401, 421, 429, 415) is added here to every
//! operation by [`Guards`], the one place that mirrors it; it also gives every error its
//! media type, `application/problem+json`.

use serde::{Deserialize, Serialize};
use utoipa::openapi::header::HeaderBuilder;
use utoipa::openapi::path::Operation;
use utoipa::openapi::schema::{ObjectBuilder, Type};
use utoipa::openapi::security::{
    ApiKey, ApiKeyValue, HttpAuthScheme, HttpBuilder, SecurityRequirement, SecurityScheme,
};
use utoipa::openapi::{ContentBuilder, OpenApi, Ref, RefOr, ResponseBuilder};
use utoipa::{Modify, ToSchema};

use crate::session::State as SessionState;

/// Every error: an RFC 9457 problem (`application/problem+json`), with brdfd's code for
/// programs (`error`) and its sentence for people (`message`, the same as `detail`) as
/// extension members, as before the standard members came. The CLI reads it back.
#[derive(Serialize, Deserialize, ToSchema)]
pub struct ErrorBody {
    /// `about:blank`: a daemon on a bench has no stable address to name its problem types
    /// by, so the type is the status's own (RFC 9457 §4.2.1), and `error` says which problem
    /// of that status this is.
    #[serde(rename = "type")]
    #[schema(example = "about:blank")]
    pub kind: String,
    /// The status's reason phrase (`Conflict`, `Not Found`, ...).
    pub title: String,
    /// The HTTP status of the answer.
    #[schema(minimum = 400, maximum = 599)]
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
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
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
#[derive(Serialize, Deserialize, ToSchema)]
pub struct Health {
    /// `brdfd <version>`.
    pub software: String,
    pub rig: RigSummary,
    /// The session capturing now, if any.
    pub busy: Option<String>,
}

#[derive(Serialize, Deserialize, ToSchema)]
pub struct RigSummary {
    /// Whether the devices are brdfd's simulators (`brdfd serve --simulate`).
    pub simulated: bool,
}

/// `GET /materials`.
#[derive(Serialize, ToSchema)]
pub struct Materials {
    /// Names a plan's `material` can take besides the simulator's own materials.
    pub presets: Vec<&'static str>,
}

/// A session in the list.
#[derive(Serialize, ToSchema)]
pub struct SessionItem {
    pub id: String,
    pub state: SessionState,
    pub material: String,
    /// RFC 3339, UTC.
    pub created: String,
    /// Whether this is the capture the daemon is running now (its state then moves on).
    pub running: bool,
}

/// A capture that was started or resumed.
#[derive(Serialize, Deserialize, ToSchema)]
pub struct Started {
    pub id: String,
    /// Where the session is stored on the daemon's machine.
    pub dir: String,
    /// Its event stream's path.
    pub events: String,
}

/// A session and its manifest (docs/formats.md).
#[derive(Serialize, Deserialize, ToSchema)]
pub struct SessionDetail {
    pub id: String,
    pub dir: String,
    #[schema(value_type = Object)]
    pub manifest: crate::session::Manifest,
    /// The view whose hand turn the running capture waits for (`POST .../continue`), if it
    /// waits.
    pub waiting_for_view: Option<usize>,
}

/// `POST /sessions/{id}/cancel`.
#[derive(Serialize, ToSchema)]
pub struct Cancelling {
    pub id: String,
    pub cancelling: bool,
}

/// The body of `POST /sessions/{id}/continue`: `{}`, or the view whose turn is done (then
/// only that view's wait is answered).
#[derive(Deserialize, ToSchema, Default)]
#[serde(deny_unknown_fields)]
pub struct ContinueRequest {
    #[serde(default, deserialize_with = "crate::rig::some_whole_number")]
    #[schema(minimum = 1, maximum = 360)] // rig::MAX_VIEWS
    pub view: Option<usize>,
}

/// `POST /sessions/{id}/cancel` and `.../resume`: `{}`, nothing else.
#[derive(Deserialize, ToSchema, Default)]
#[serde(deny_unknown_fields)]
pub struct Empty {}

/// `POST /sessions/{id}/continue`.
#[derive(Serialize, ToSchema)]
pub struct Continuing {
    pub id: String,
    pub continuing: bool,
}

/// One server-sent event of a session's stream (the fields of the `text/event-stream`
/// format).
#[derive(ToSchema)]
pub struct StreamEvent {
    /// `<run>-<place>`: given back as `Last-Event-ID`, the stream resumes after it.
    pub id: String,
    /// The event type; brdfd sends none (`message`), the type is in `data`.
    pub event: Option<String>,
    /// An `Event` (see the schema of that name) as JSON.
    pub data: String,
}

/// A file's bytes, as stored.
#[derive(ToSchema)]
#[schema(value_type = String, format = Binary)]
pub struct FileBytes(pub Vec<u8>);

#[derive(utoipa::OpenApi)]
#[openapi(
    info(
        title = "brdfd",
        version = env!("CARGO_PKG_VERSION"),
        description = "The brdfd daemon's HTTP API (`brdfd serve`): devices, captures and their \
                       results. docs/api.md says more.",
        license(name = "MIT", identifier = "MIT"),
    ),
    components(schemas(ErrorBody, crate::rig::Event, super::api::ResultFile))
)]
pub struct ApiDoc;

/// Adds what the middleware answers to every operation: 401 (a daemon with a token), 429
/// (an address locked out for wrong tokens), 421 (a `Host` not its own), 415 on a POST
/// without a JSON body; the two ways to give the token; and `application/problem+json` as
/// every error's media type. Applied to the whole description once the routes are in it.
pub struct Guards;

impl Modify for Guards {
    fn modify(&self, api: &mut OpenApi) {
        let components = api.components.get_or_insert_with(Default::default);
        components.add_security_scheme(
            "token",
            SecurityScheme::Http(HttpBuilder::new().scheme(HttpAuthScheme::Bearer).build()),
        );
        components.add_security_scheme(
            "signed_in",
            SecurityScheme::ApiKey(ApiKey::Cookie(ApiKeyValue::new(super::web::COOKIE))),
        );
        // With a token configured, one of the two is needed; without, neither (`{}`).
        api.security = Some(vec![
            SecurityRequirement::new("token", Vec::<String>::new()),
            SecurityRequirement::new("signed_in", Vec::<String>::new()),
            SecurityRequirement::default(),
        ]);
        let error = |what: &str, header: Option<(&str, &str)>| {
            let mut response = ResponseBuilder::new().description(what).content(
                PROBLEM,
                ContentBuilder::new()
                    .schema(Some(Ref::from_schema_name("ErrorBody")))
                    .build(),
            );
            if let Some((name, says)) = header {
                let header = HeaderBuilder::new()
                    .schema(Some(ObjectBuilder::new().schema_type(Type::String)))
                    .description(Some(says))
                    .build();
                response = response.header(name, header);
            }
            response.build()
        };
        let add = |op: &mut Operation, status: &str, what: &str, header| {
            op.responses
                .responses
                .entry(status.to_string())
                .or_insert_with(|| error(what, header).into());
        };
        for item in api.paths.paths.values_mut() {
            let ops = [
                item.get.as_mut(),
                item.post.as_mut(),
                item.put.as_mut(),
                item.delete.as_mut(),
                item.patch.as_mut(),
            ];
            for (op, post) in ops
                .into_iter()
                .zip([false, true, false, false, false])
                .filter_map(|(op, post)| op.map(|op| (op, post)))
            {
                add(
                    op,
                    "401",
                    "`unauthorized`: the daemon has a token and none was given",
                    Some((
                        "WWW-Authenticate",
                        "`Bearer realm=\"brdfd\"` (RFC 9110 §11.6.1)",
                    )),
                );
                add(
                    op,
                    "429",
                    "`too_many_attempts`: this address gave wrong tokens, and must wait",
                    Some(("Retry-After", "seconds to wait")),
                );
                add(
                    op,
                    "421",
                    "`unknown_host`: the request's `Host` is not this daemon's",
                    None,
                );
                if post {
                    add(
                        op,
                        "415",
                        "`unsupported_media_type`: a POST without `Content-Type: application/json`",
                        None,
                    );
                }
                problems(op);
            }
        }
    }
}

/// Every answer of `op` whose body is an [`ErrorBody`] as [`PROBLEM`]: the handlers' own
/// errors are declared with `body = ErrorBody`, which utoipa gives `application/json`.
fn problems(op: &mut Operation) {
    for response in op.responses.responses.values_mut() {
        let RefOr::T(response) = response else {
            continue;
        };
        let is_problem = match response.content.get("application/json") {
            Some(RefOr::T(c)) => {
                matches!(&c.schema, Some(RefOr::Ref(r)) if r.ref_location.ends_with("/ErrorBody"))
            }
            _ => false,
        };
        if is_problem {
            if let Some(content) = response.content.shift_remove("application/json") {
                response.content.insert(PROBLEM.to_string(), content);
            }
        }
    }
}
