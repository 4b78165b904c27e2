//! The API's OpenAPI description, served at `GET /api/v1/openapi.json`. It is generated from
//! the handlers' `#[utoipa::path]` attributes as [`super::api::router`] registers them
//! (utoipa-axum), so a route cannot exist without its description, nor the other way round.
//! What the middleware adds to every answer (401, 421, 415) is added here to every operation
//! by [`Guards`], the one place that mirrors it.

use serde::{Deserialize, Serialize};
use utoipa::openapi::path::Operation;
use utoipa::openapi::security::{
    ApiKey, ApiKeyValue, HttpAuthScheme, HttpBuilder, SecurityRequirement, SecurityScheme,
};
use utoipa::openapi::{ContentBuilder, OpenApi, Ref, ResponseBuilder};
use utoipa::{Modify, ToSchema};

use crate::session::State as SessionState;

/// Every error: a code for programs and a sentence for people.
#[derive(Serialize, ToSchema)]
pub struct ErrorBody {
    /// `not_found`, `bad_request`, `busy`, `not_done`, `not_running`, `unauthorized`,
    /// `unknown_host`, `unsupported_media_type`, `request_timeout`, `storage`, `internal`.
    pub error: String,
    /// What was wrong, and where.
    pub message: String,
}

/// `GET /health`.
#[derive(Serialize, ToSchema)]
pub struct Health {
    /// `brdfd <version>`.
    pub software: String,
    pub rig: RigSummary,
    /// The session capturing now, if any.
    pub busy: Option<String>,
}

#[derive(Serialize, ToSchema)]
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
#[derive(Serialize, ToSchema)]
pub struct Started {
    pub id: String,
    /// Where the session is stored on the daemon's machine.
    pub dir: String,
    /// Its event stream's path.
    pub events: String,
}

/// A session and its manifest (docs/formats.md).
#[derive(Serialize, ToSchema)]
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
    #[serde(default)]
    #[schema(minimum = 1)]
    pub view: Option<usize>,
}

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
        description = "The brdfd daemon's HTTP API (`brdfd serve`): devices, captures and their \
                       results. docs/api.md says more."
    ),
    components(schemas(ErrorBody, crate::rig::Event, super::api::ResultFile))
)]
pub struct ApiDoc;

/// Adds what the middleware answers to every operation: 401 (a daemon with a token), 421 (a
/// `Host` not its own), 415 on a POST without a JSON body; and the two ways to give the token.
/// Applied to the whole description once the routes are in it.
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
        let error = |what: &str| {
            ResponseBuilder::new()
                .description(what)
                .content(
                    "application/json",
                    ContentBuilder::new()
                        .schema(Some(Ref::from_schema_name("ErrorBody")))
                        .build(),
                )
                .build()
        };
        let add = |op: &mut Operation, status: &str, what: &str| {
            op.responses
                .responses
                .entry(status.to_string())
                .or_insert_with(|| error(what).into());
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
                );
                add(
                    op,
                    "421",
                    "`unknown_host`: the request's `Host` is not this daemon's",
                );
                if post {
                    add(
                        op,
                        "415",
                        "`unsupported_media_type`: a POST without `Content-Type: application/json`",
                    );
                }
            }
        }
    }
}
