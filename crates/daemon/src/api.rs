//! The daemon's HTTP API, version 1. Every body is JSON; errors are RFC 9457 problems
//! (`application/problem+json`: `type`, `title`, `status`, `detail`), which also carry
//! `{"error": "<code>", "message": "<what was wrong>"}`.
//!
//! | method and path | answer |
//! |---|---|
//! | `GET /api/v1/openapi.json` | this API's OpenAPI 3.1 description ([`openapi()`]); needs no token |
//! | `GET /api/v1/health` | `{"software", "rig": {"simulated"}, "busy": id or null}` |
//! | `GET /api/v1/materials` | `{"presets": [...]}`: the material presets a capture can name |
//! | `GET /api/v1/devices` | `[{"role", "selector", "state": "closed"/"open"/"lost", "identity", "last_error", "opened"}]` |
//! | `GET /api/v1/sessions` | `[{"id", "state", "material", "created", "running"}]`, oldest first |
//! | `POST /api/v1/sessions` | body: a plan (`{"material": "gold", "pixels": "20", "views": 1, ...}`); 202 `{"id", "dir", "events"}` and `Location`; 409 `busy`; 400 `bad_request`; 422 `invalid_plan` |
//! | `GET /api/v1/sessions/{id}` | `{"id", "dir", "manifest", "waiting_for_view"}`: where it is stored, its manifest, and the view whose hand turn it waits for |
//! | `GET /api/v1/sessions/{id}/events` | Server-Sent Events, one JSON [`Event`] each with its place as `id`, from the session's first (after `Last-Event-ID` if given); ends after `finished` |
//! | `GET /api/v1/sessions/{id}/result` | `coefficients.json`; 409 `not_done` until the session is done |
//! | `GET /api/v1/sessions/{id}/result/{file}` | `report.html`, `coefficients.json`, `preview.png`, `preview.json`, `compare.png`, `preview.exr`, `brdf-bivariate.exr`, `brdf-sigma.exr`, `brdf.binary`, `material.gltf`, `material.mtlx`, `light.hdr`, `visibility.png`, `object.gltf`, `materials.png`, `materials-mask.png`; with `ETag` (`If-None-Match`: 304) and one byte range (`Range`: 206, or 416) |
//! | `GET /api/v1/sessions/{id}/result/{material}/{file}` | when the part was split into two materials: `material-1` or `material-2`, then one of the files above, that material's |
//! | `POST /api/v1/sessions/{id}/cancel` | 202; 409 `not_running` |
//! | `POST /api/v1/sessions/{id}/continue` | the object is turned by hand, as the `waiting_for_operator` event asked: 202; 409 `not_waiting` |
//! | `POST /api/v1/sessions/{id}/resume` | 202 as for a new capture; 409 `busy`, `already_done`, `not_resumable` |
//!
//! With a token configured, every request needs `Authorization: Bearer <token>`, or the
//! cookie the web page's sign-in sets ([`web`]) (401 `unauthorized` with `WWW-Authenticate`
//! otherwise). Every POST needs `Content-Type: application/json`, its body or not (415
//! `unsupported_media_type` otherwise). A method a route lacks gets 405 with `Allow`.

use std::convert::Infallible;
use std::sync::Arc;

use axum::extract::{DefaultBodyLimit, Path, Request, State};
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::middleware::Next;
use axum::response::sse::{Event as SseEvent, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use futures_util::stream::{self, Stream};
use utoipa::{Modify as _, OpenApi as _};
use utoipa_axum::{router::OpenApiRouter, routes};

use super::openapi::{
    self, ApiDoc, Cancelling, ContinueRequest, Continuing, Empty, ErrorBody, ErrorCode, FileBytes,
    Guards, Health, Materials, RigSummary, SessionDetail, SessionItem, Started, StreamEvent,
};
use super::{web, Daemon, StartError};
use brdfd_rig::session::{Session, State as SessionState};
use brdfd_rig::{Event, Plan};

pub type Shared = Arc<Daemon>;

/// An error answer: its status, code and message.
struct ApiError(StatusCode, ErrorCode, String);

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let ApiError(status, code, message) = self;
        let body = ErrorBody {
            kind: "about:blank".into(),
            title: status.canonical_reason().unwrap_or("Error").into(),
            status: status.as_u16(),
            detail: message.clone(),
            error: code,
            message,
        };
        let mut response = (status, Json(body)).into_response();
        response.headers_mut().insert(
            header::CONTENT_TYPE,
            HeaderValue::from_static(openapi::PROBLEM),
        );
        response
    }
}

type ApiResult<T> = Result<T, ApiError>;

fn not_found(e: impl std::fmt::Display) -> ApiError {
    ApiError(StatusCode::NOT_FOUND, ErrorCode::NotFound, e.to_string())
}

fn bad_request(e: impl std::fmt::Display) -> ApiError {
    ApiError(
        StatusCode::BAD_REQUEST,
        ErrorCode::BadRequest,
        e.to_string(),
    )
}

/// The API's routes, each registered with its OpenAPI description ([`openapi`]), and each
/// through [`guarded`].
fn api() -> OpenApiRouter<Shared> {
    OpenApiRouter::with_openapi(ApiDoc::openapi())
        .routes(guarded(routes!(health)))
        .routes(guarded(routes!(devices)))
        .routes(guarded(routes!(materials)))
        .routes(guarded(routes!(list, start)))
        .routes(guarded(routes!(show)))
        .routes(guarded(routes!(events)))
        .routes(guarded(routes!(result)))
        .routes(guarded(routes!(result_file)))
        .routes(guarded(routes!(material_file)))
        .routes(guarded(routes!(cancel)))
        .routes(guarded(routes!(continue_capture)))
        .routes(guarded(routes!(resume)))
}

/// A route's methods with the JSON check on its POST ([`require_json_posts`]) and 405 for the
/// methods it lacks. The check is on the route's methods, not on the router: there it ran
/// before the method was routed, and a POST to a GET-only route got 415 where RFC 9110 says
/// 405 (with `Allow`, which axum adds to the fallback's answer).
fn guarded(
    (schemas, paths, methods): utoipa_axum::router::UtoipaMethodRouter<Shared>,
) -> utoipa_axum::router::UtoipaMethodRouter<Shared> {
    let methods = methods
        .route_layer(axum::middleware::from_fn(require_json_posts))
        .fallback(method_not_allowed);
    (schemas, paths, methods)
}

/// 405 as a problem, for a method a route lacks (axum adds `Allow`).
async fn method_not_allowed(method: axum::http::Method) -> ApiError {
    ApiError(
        StatusCode::METHOD_NOT_ALLOWED,
        ErrorCode::MethodNotAllowed,
        format!("this route does not answer {method}; `Allow` lists what it answers"),
    )
}

/// The OpenAPI description of everything under `/api/v1`, as `GET /api/v1/openapi.json`
/// serves it. Its `info` is [`ApiDoc`]'s: the outer router starts from it, because a bare
/// `OpenApiRouter::new()` brings utoipa-axum's own (its name, version and author).
pub fn openapi() -> utoipa::openapi::OpenApi {
    let mut description = OpenApiRouter::<Shared>::with_openapi(ApiDoc::openapi())
        .nest(API, api())
        .into_openapi();
    Guards.modify(&mut description);
    description
}

/// Where the API lives.
pub const API: &str = "/api/v1";

pub fn router(daemon: Shared) -> Router {
    let description: Arc<str> = openapi()
        .to_pretty_json()
        .expect("the OpenAPI description serialises")
        .into();
    let (api, _) = api().split_for_parts();
    let api = api
        .layer(axum::middleware::map_response(problem_for_plain_errors))
        .layer(axum::middleware::from_fn_with_state(
            daemon.clone(),
            require_token,
        ))
        .layer(axum::middleware::from_fn_with_state(
            daemon.clone(),
            require_own_host,
        ));
    // The web page and the API's description: they need no token (they hold no data), but
    // the host check, as every answer does.
    let page = Router::new()
        .route(
            &format!("{API}/openapi.json"),
            // Part of the API, so its errors are problems too.
            get(move || async move {
                (
                    [(header::CONTENT_TYPE, "application/json")],
                    description.to_string(),
                )
            })
            .fallback(method_not_allowed),
        )
        .route("/", get(web::index))
        .route("/app.js", get(web::script))
        .route("/app.css", get(web::style))
        .route("/viewer.html", get(web::viewer))
        .route("/viewer.js", get(web::viewer_script))
        .route("/vendor/three/{file}", get(web::three))
        .route("/maps", get(web::map_names))
        .route("/maps/{file}", get(web::map))
        .route(
            "/login",
            post(web::login).layer(DefaultBodyLimit::max(web::MAX_LOGIN_BYTES)),
        )
        .layer(axum::middleware::from_fn_with_state(
            daemon.clone(),
            require_own_host,
        ));
    Router::new()
        .nest(API, api)
        .merge(page)
        .fallback(|| async {
            not_found("no such endpoint; the API is under /api/v1 (docs/api.md)")
        })
        .with_state(daemon)
}

/// The client's address, as the server recorded it for the connection.
pub(crate) fn peer_ip(extensions: &axum::http::Extensions) -> Option<std::net::IpAddr> {
    extensions
        .get::<axum::extract::ConnectInfo<std::net::SocketAddr>>()
        .map(|c| c.0.ip())
}

/// 429 while an address is locked out for wrong tokens ([`super::throttle`]).
pub(crate) fn locked_out(wait: std::time::Duration) -> Response {
    let seconds = wait.as_secs_f64().ceil().max(1.0) as u64;
    let mut response = ApiError(
        StatusCode::TOO_MANY_REQUESTS,
        ErrorCode::TooManyAttempts,
        format!(
            "too many wrong tokens from this address; try again in {seconds} s (the token is \
             the `token` in the daemon's brdfd.toml)"
        ),
    )
    .into_response();
    response
        .headers_mut()
        .insert(header::RETRY_AFTER, seconds.into());
    response
}

async fn require_token(State(d): State<Shared>, req: Request, next: Next) -> Response {
    if let Some(token) = &d.token {
        let ip = peer_ip(req.extensions());
        if let Some(Err(wait)) = ip.map(|ip| d.throttle.check(ip)) {
            return locked_out(wait);
        }
        let given = req
            .headers()
            .get(header::AUTHORIZATION)
            .and_then(|v| v.to_str().ok())
            .and_then(|v| v.strip_prefix("Bearer "))
            .map(|g| g.as_bytes().to_vec())
            // The web page's sign-in cookie (see [`web`]).
            .or_else(|| web::token_from_cookie(req.headers()));
        let guessed = given.is_some();
        let ok = given.is_some_and(|g| web::same_secret(&g, token.as_bytes()));
        // Only a token given counts: a page loading before its sign-in guesses nothing.
        if let (Some(ip), true) = (ip, guessed) {
            if ok {
                d.throttle.succeeded(ip);
            } else {
                d.throttle.failed(ip);
            }
        }
        if !ok {
            let mut response = ApiError(
                StatusCode::UNAUTHORIZED,
                ErrorCode::Unauthorized,
                "this daemon requires `Authorization: Bearer <token>` (the token in its brdfd.toml), or, in a browser, signing in on its page at /"
                    .into(),
            )
            .into_response();
            // RFC 9110 §11.6.1: a 401 names the scheme that would succeed.
            response.headers_mut().insert(
                header::WWW_AUTHENTICATE,
                HeaderValue::from_static(r#"Bearer realm="brdfd""#),
            );
            return response;
        }
    }
    next.run(req).await
}

/// Refuses a request that names another host than this daemon's. Why: after DNS rebinding, a
/// web page's own name (`evil.example`) resolves to the bench PC, and the browser lets the
/// page read what it fetches there; the request still says `Host: evil.example`. An IP
/// address, `localhost` and brdfd.toml's `hosts` are this daemon's; a request without `Host`
/// (not a browser's) passes.
async fn require_own_host(State(d): State<Shared>, req: Request, next: Next) -> Response {
    if let Some(host) = req.headers().get(header::HOST) {
        let host = host.to_str().unwrap_or("");
        if !is_own_host(host, &d.hosts) {
            return ApiError(
                StatusCode::MISDIRECTED_REQUEST,
                ErrorCode::UnknownHost,
                format!(
                    "this daemon does not answer to the host {host:?}: reach it by IP address or localhost, or add the name to `hosts` in its brdfd.toml"
                ),
            )
            .into_response();
        }
    }
    next.run(req).await
}

/// An error axum answers itself (a path segment that is not UTF-8, say) as a problem like
/// the API's own, its text as the detail: every error of the API is `application/problem+json`.
async fn problem_for_plain_errors(response: Response) -> Response {
    let status = response.status();
    let problem = response
        .headers()
        .get(header::CONTENT_TYPE)
        .is_some_and(|v| v.as_bytes() == openapi::PROBLEM.as_bytes());
    if !(status.is_client_error() || status.is_server_error()) || problem {
        return response;
    }
    // axum's own messages are a line; a longer body is not read, and the status's phrase
    // stands in for it.
    const MAX_TEXT: usize = 4096;
    let text = axum::body::to_bytes(response.into_body(), MAX_TEXT)
        .await
        .map(|b| String::from_utf8_lossy(&b).trim().to_string())
        .unwrap_or_default();
    let code = if status == StatusCode::NOT_FOUND {
        ErrorCode::NotFound
    } else if status.is_client_error() {
        ErrorCode::BadRequest
    } else {
        ErrorCode::Internal
    };
    let text = if text.is_empty() {
        status.canonical_reason().unwrap_or("error").to_string()
    } else {
        text
    };
    ApiError(status, code, text).into_response()
}

/// Whether a `Host` header's value (name or address, with or without a port) is this
/// daemon's: an IP address, `localhost`, or one of `hosts` (case-insensitive).
pub fn is_own_host(host: &str, hosts: &[String]) -> bool {
    let name = if let Some(rest) = host.strip_prefix('[') {
        // [v6]:port
        match rest.split_once(']') {
            Some((addr, _)) => return addr.parse::<std::net::Ipv6Addr>().is_ok(),
            None => return false,
        }
    } else {
        host.rsplit_once(':').map_or(host, |(name, _)| name)
    };
    let name = name.trim_end_matches('.');
    name.parse::<std::net::Ipv4Addr>().is_ok()
        || name.eq_ignore_ascii_case("localhost")
        || hosts
            .iter()
            .any(|h| h.trim_end_matches('.').eq_ignore_ascii_case(name))
}

/// Refuses a POST whose `Content-Type` is not JSON. Why: a web page open in the bench user's
/// browser may send a cross-site "simple request" (a form, or `text/plain`) to a daemon on
/// localhost without asking first; a JSON content type makes the browser ask (a CORS
/// preflight), which this daemon never grants. So no page can start, cancel or resume a capture.
/// This, not the sign-in cookie's `SameSite`, is what guards the API against other pages: a
/// page on another port of the same host counts as the same site and sends the cookie. Never
/// answer CORS, and never relax this check.
async fn require_json_posts(req: Request, next: Next) -> Response {
    if req.method() == axum::http::Method::POST {
        let json = req
            .headers()
            .get(header::CONTENT_TYPE)
            .and_then(|v| v.to_str().ok())
            .and_then(|v| v.split(';').next())
            .is_some_and(|v| v.trim().eq_ignore_ascii_case("application/json"));
        if !json {
            return ApiError(
                StatusCode::UNSUPPORTED_MEDIA_TYPE,
                ErrorCode::UnsupportedMediaType,
                "every POST needs `Content-Type: application/json` (with a JSON body, `{}` if there is nothing to say), so that a web page cannot send one across sites".into(),
            )
            .into_response();
        }
    }
    next.run(req).await
}

/// The daemon's software, its rig, and the capture running now.
#[utoipa::path(get, path = "/health", responses((status = 200, description = "the daemon's health", body = Health)))]
async fn health(State(d): State<Shared>) -> Json<Health> {
    Json(Health {
        software: format!("brdfd {}", env!("CARGO_PKG_VERSION")),
        rig: RigSummary {
            simulated: d.rig.simulated,
        },
        busy: d.busy(),
    })
}

/// The rig's devices and their state.
#[utoipa::path(get, path = "/devices", responses((status = 200, description = "each device of the rig", body = Vec<brdfd_rig::DeviceStatus>)))]
async fn devices(State(d): State<Shared>) -> Json<Vec<brdfd_rig::DeviceStatus>> {
    Json(d.devices())
}

/// The material presets a capture can name.
#[utoipa::path(get, path = "/materials", responses((status = 200, description = "the presets", body = Materials)))]
async fn materials() -> Json<Materials> {
    Json(Materials {
        presets: brdfd_rig::config::preset_names()
            .into_iter()
            .map(str::to_string)
            .collect(),
    })
}

/// The stored sessions, oldest first.
#[utoipa::path(
    get,
    path = "/sessions",
    responses(
        (status = 200, description = "the sessions, oldest first", body = Vec<SessionItem>),
        (status = 500, description = "`storage`: the state directory cannot be read", body = ErrorBody),
    )
)]
async fn list(State(d): State<Shared>) -> ApiResult<Json<Vec<SessionItem>>> {
    let all = Session::list(&d.state_dir).map_err(|e| {
        ApiError(
            StatusCode::INTERNAL_SERVER_ERROR,
            ErrorCode::Storage,
            d.relative(&e.to_string()),
        )
    })?;
    let busy = d.busy();
    Ok(Json(
        all.into_iter()
            .map(|m| d.shown(m))
            .map(|m| SessionItem {
                running: busy.as_deref() == Some(m.id.as_str()),
                id: m.id,
                state: m.state,
                material: m.material,
                created: m.created,
            })
            .collect(),
    ))
}

/// 202 for a capture started or resumed, with the session's address in `Location` (the
/// resource that tells how it goes, RFC 9110 §15.3.3).
fn started(s: Session) -> Response {
    let id = s.manifest().id.clone();
    let events = format!("{API}/sessions/{id}/events");
    let location = format!("{API}/sessions/{id}");
    let dir = s.dir.display().to_string();
    (
        StatusCode::ACCEPTED,
        [(header::LOCATION, location)],
        Json(Started { id, dir, events }),
    )
        .into_response()
}

fn start_error(e: StartError) -> ApiError {
    let (status, code) = match e {
        StartError::Busy(_) => (StatusCode::CONFLICT, ErrorCode::Busy),
        StartError::Invalid(_) => (StatusCode::BAD_REQUEST, ErrorCode::BadRequest),
        // RFC 9110 §15.5.21: the plan is well-formed, and names what this daemon cannot use.
        StartError::Unusable(_) => (StatusCode::UNPROCESSABLE_ENTITY, ErrorCode::InvalidPlan),
        StartError::NotFound(_) => (StatusCode::NOT_FOUND, ErrorCode::NotFound),
        // The request is right; the session's state is what refuses it (RFC 9110 §15.5.10).
        StartError::Done(_) => (StatusCode::CONFLICT, ErrorCode::AlreadyDone),
        StartError::NotResumable(..) => (StatusCode::CONFLICT, ErrorCode::NotResumable),
        StartError::Storage(_) => (StatusCode::INTERNAL_SERVER_ERROR, ErrorCode::Storage),
    };
    ApiError(status, code, e.to_string())
}

/// A plan's size at most: a plan is a few hundred bytes.
const MAX_PLAN_BYTES: usize = 64 * 1024;

/// Time a client has to send a plan once its request's head is in: a body sent a byte at a
/// time would otherwise hold the connection busy, where the connection cap cannot close it.
const PLAN_READ_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(10);

/// Starts a capture from a plan.
#[utoipa::path(
    post,
    path = "/sessions",
    request_body = brdfd_rig::Plan,
    responses(
        (status = 202, description = "started; follow `events`", body = Started, headers(
            ("Location" = String, description = "the session's address: `/api/v1/sessions/{id}`"),
        )),
        (status = 400, description = "`bad_request`: the plan is not valid JSON, or breaks a rule of its schema", body = ErrorBody),
        (status = 408, description = "`request_timeout`: the plan did not arrive in time", body = ErrorBody),
        (status = 409, description = "`busy`: a capture is running", body = ErrorBody),
        (status = 422, description = "`invalid_plan`: the plan names what this daemon does not have (a material, a scene file), or asks what its rig cannot do", body = ErrorBody),
        (status = 500, description = "`storage`, `internal`: the daemon could not create the session or start the capture's thread", body = ErrorBody),
    )
)]
async fn start(State(d): State<Shared>, body: axum::body::Body) -> ApiResult<Response> {
    let plan: Plan = json_body(body, "the plan").await?;
    on_capture_thread(move || d.start_capture(plan)).await
}

/// Starts or resumes a capture off the async runtime (opening a session and its devices
/// blocks): 202 with where to follow it, or why not.
async fn on_capture_thread(
    launch: impl FnOnce() -> Result<Session, StartError> + Send + 'static,
) -> ApiResult<Response> {
    let s = tokio::task::spawn_blocking(launch)
        .await
        .map_err(|e| {
            ApiError(
                StatusCode::INTERNAL_SERVER_ERROR,
                ErrorCode::Internal,
                e.to_string(),
            )
        })?
        .map_err(start_error)?;
    Ok(started(s))
}

/// Resumes a session that stopped: from its last complete step.
#[utoipa::path(
    post,
    path = "/sessions/{id}/resume",
    params(("id" = String, Path, description = "the session's id")),
    request_body(content = Empty, description = "`{}`", content_type = "application/json"),
    responses(
        (status = 202, description = "resumed; follow `events`", body = Started, headers(
            ("Location" = String, description = "the session's address: `/api/v1/sessions/{id}`"),
        )),
        (status = 400, description = "`bad_request`: the body is not `{}`", body = ErrorBody),
        (status = 404, description = "`not_found`: no such session", body = ErrorBody),
        (status = 408, description = "`request_timeout`: the body did not arrive in time", body = ErrorBody),
        (status = 409, description = "`busy`: a capture is running; `already_done`: the session is done; `not_resumable`: its files changed since, or the rig no longer fits its plan", body = ErrorBody),
        (status = 500, description = "`storage`, `internal`: the daemon could not read the session or start the capture's thread", body = ErrorBody),
    )
)]
async fn resume(
    State(d): State<Shared>,
    Path(id): Path<String>,
    body: axum::body::Body,
) -> ApiResult<Response> {
    let Empty {} = json_body(body, "the request").await?;
    on_capture_thread(move || d.resume(&id)).await
}

/// The session `id`; 404 if there is none (an id that is not a session's name names none).
fn open(d: &Daemon, id: &str) -> ApiResult<Session> {
    Session::open(&d.state_dir, id).map_err(|e| match e {
        e if e.names_no_session(id) => {
            not_found(format!("no session {id:?}; GET {API}/sessions lists them"))
        }
        e => ApiError(
            StatusCode::INTERNAL_SERVER_ERROR,
            ErrorCode::Storage,
            d.relative(&e.to_string()),
        ),
    })
}

/// A session: where it is stored, and its manifest.
#[utoipa::path(
    get,
    path = "/sessions/{id}",
    params(("id" = String, Path, description = "the session's id")),
    responses(
        (status = 200, description = "the session", body = SessionDetail),
        (status = 404, description = "`not_found`: no such session", body = ErrorBody),
    )
)]
async fn show(State(d): State<Shared>, Path(id): Path<String>) -> ApiResult<Json<SessionDetail>> {
    let s = open(&d, &id)?;
    let waiting_for_view = d.waiting_for(&id);
    Ok(Json(SessionDetail {
        id,
        dir: s.dir.display().to_string(),
        manifest: d.shown(s.into_manifest()),
        waiting_for_view,
    }))
}

/// A request's JSON object, read within [`PLAN_READ_TIMEOUT`] and [`MAX_PLAN_BYTES`] (an
/// empty body is `{}`). Parsed here rather than by the Json extractor, so that the error names
/// the field in our own error shape; and only an object, because serde also builds a struct
/// from an array of its fields in order, which no schema here allows.
async fn json_body<T: serde::de::DeserializeOwned>(
    body: axum::body::Body,
    what: &str,
) -> ApiResult<T> {
    let body = tokio::time::timeout(
        PLAN_READ_TIMEOUT,
        axum::body::to_bytes(body, MAX_PLAN_BYTES),
    )
    .await
    .map_err(|_| {
        ApiError(
            StatusCode::REQUEST_TIMEOUT,
            ErrorCode::RequestTimeout,
            format!(
                "{what} did not arrive within {} s",
                PLAN_READ_TIMEOUT.as_secs()
            ),
        )
    })?
    .map_err(|e| bad_request(format!("{what} (at most {MAX_PLAN_BYTES} bytes): {e}")))?;
    let body: &[u8] = if body.iter().all(u8::is_ascii_whitespace) {
        b"{}"
    } else {
        &body
    };
    let value: serde_json::Value =
        serde_json::from_slice(body).map_err(|e| bad_request(format!("{what}: {e}")))?;
    if !value.is_object() {
        let kind = match value {
            serde_json::Value::Array(_) => "an array",
            serde_json::Value::String(_) => "a string",
            serde_json::Value::Number(_) => "a number",
            serde_json::Value::Bool(_) => "a boolean",
            _ => "null",
        };
        return Err(bad_request(format!(
            "{what} must be a JSON object, not {kind}"
        )));
    }
    serde_json::from_value(value).map_err(|e| bad_request(format!("{what}: {e}")))
}

/// Tells the running capture that the operator has turned the object by hand, as its
/// `waiting_for_operator` event asked (a rig with no turntable, several views).
#[utoipa::path(
    post,
    path = "/sessions/{id}/continue",
    params(("id" = String, Path, description = "the session's id")),
    request_body(content = ContinueRequest, content_type = "application/json"),
    responses(
        (status = 202, description = "the capture goes on", body = Continuing),
        (status = 400, description = "`bad_request`: the body is not `{}` or `{\"view\": N}`", body = ErrorBody),
        (status = 408, description = "`request_timeout`: the body did not arrive in time", body = ErrorBody),
        (status = 409, description = "`not_waiting`: the session is not waiting for the operator now", body = ErrorBody),
    )
)]
async fn continue_capture(
    State(d): State<Shared>,
    Path(id): Path<String>,
    body: axum::body::Body,
) -> ApiResult<Response> {
    let request: ContinueRequest = json_body(body, "the request").await?;
    if d.proceed(&id, request.view) {
        let body = Continuing {
            id,
            continuing: true,
        };
        Ok((StatusCode::ACCEPTED, Json(body)).into_response())
    } else {
        Err(ApiError(
            StatusCode::CONFLICT,
            ErrorCode::NotWaiting,
            match request.view {
                Some(v) => format!("session {id} is not waiting for view {v} to be turned now"),
                None => format!("session {id} is not waiting for the operator now"),
            },
        ))
    }
}

/// Cancels the running capture; it stops at the next step and can be resumed.
#[utoipa::path(
    post,
    path = "/sessions/{id}/cancel",
    params(("id" = String, Path, description = "the session's id")),
    request_body(content = Empty, description = "`{}`", content_type = "application/json"),
    responses(
        (status = 202, description = "the capture stops at its next step", body = Cancelling),
        (status = 400, description = "`bad_request`: the body is not `{}`", body = ErrorBody),
        (status = 408, description = "`request_timeout`: the body did not arrive in time", body = ErrorBody),
        (status = 404, description = "`not_found`: there is no such session", body = ErrorBody),
        (status = 409, description = "`not_running`: the session is not capturing now", body = ErrorBody),
    )
)]
async fn cancel(
    State(d): State<Shared>,
    Path(id): Path<String>,
    body: axum::body::Body,
) -> ApiResult<Response> {
    let Empty {} = json_body(body, "the request").await?;
    if d.cancel(&id) {
        let body = Cancelling {
            id,
            cancelling: true,
        };
        Ok((StatusCode::ACCEPTED, Json(body)).into_response())
    } else {
        // A session that does not exist is not found, as for a resume; one that does is not
        // running.
        open(&d, &id)?;
        Err(ApiError(
            StatusCode::CONFLICT,
            ErrorCode::NotRunning,
            format!("session {id} is not capturing now"),
        ))
    }
}

fn done(d: &Daemon, id: &str) -> ApiResult<Session> {
    let s = open(d, id)?;
    if s.manifest().state != SessionState::Done {
        return Err(ApiError(
            StatusCode::CONFLICT,
            ErrorCode::NotDone,
            format!("session {id} is {:?}, not done", s.manifest().state),
        ));
    }
    Ok(s)
}

/// A finished session's `coefficients.json` (docs/formats.md).
#[utoipa::path(
    get,
    path = "/sessions/{id}/result",
    params(("id" = String, Path, description = "the session's id")),
    responses(
        (status = 200, description = "`coefficients.json`", body = Object, content_type = "application/json", headers(
            ("ETag" = String, description = "the file's strong validator"),
            ("Accept-Ranges" = String, description = "`bytes`"),
        )),
        (status = 206, description = "the bytes `Range` asked for, as `Content-Range` says", body = FileBytes, content_type = "application/json", headers(
            ("ETag" = String, description = "the file's strong validator"),
            ("Content-Range" = String, description = "`bytes FIRST-LAST/LENGTH`"),
        )),
        (status = 304, description = "not modified: `If-None-Match` named the file's `ETag`", headers(
            ("ETag" = String, description = "the file's strong validator"),
        )),
        (status = 404, description = "`not_found`: no such session, or no result file", body = ErrorBody),
        (status = 409, description = "`not_done`: the session is not done", body = ErrorBody),
        (status = 416, description = "`range_not_satisfiable`: `Range` starts past the file's end", body = ErrorBody, headers(
            ("Content-Range" = String, description = "`bytes */LENGTH`"),
        )),
    )
)]
async fn result(
    State(d): State<Shared>,
    Path(id): Path<String>,
    headers: HeaderMap,
) -> ApiResult<Response> {
    serve_result(&d, &id, None, ResultFile::Coefficients, &headers).await
}

/// The result files the API serves. A fixed list, so a file name from a request never reaches
/// the file system unchecked; the OpenAPI description lists the same names.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, utoipa::ToSchema)]
pub enum ResultFile {
    #[serde(rename = "report.html")]
    Report,
    #[serde(rename = "preview.png")]
    PreviewPng,
    #[serde(rename = "preview.json")]
    PreviewScale,
    #[serde(rename = "preview.exr")]
    PreviewExr,
    #[serde(rename = "compare.png")]
    Compare,
    #[serde(rename = "visibility.png")]
    Visibility,
    #[serde(rename = "coefficients.json")]
    Coefficients,
    #[serde(rename = "brdf-bivariate.exr")]
    Bivariate,
    #[serde(rename = "brdf-sigma.exr")]
    Sigma,
    #[serde(rename = "brdf.binary")]
    Merl,
    #[serde(rename = "material.gltf")]
    Gltf,
    #[serde(rename = "material.mtlx")]
    MaterialX,
    #[serde(rename = "light.hdr")]
    Light,
    #[serde(rename = "object.gltf")]
    Object,
    #[serde(rename = "materials.png")]
    MaterialsPicture,
    #[serde(rename = "materials-mask.png")]
    MaterialsMask,
}

impl ResultFile {
    pub const ALL: [ResultFile; 16] = [
        ResultFile::Report,
        ResultFile::PreviewPng,
        ResultFile::PreviewScale,
        ResultFile::PreviewExr,
        ResultFile::Compare,
        ResultFile::Visibility,
        ResultFile::Coefficients,
        ResultFile::Bivariate,
        ResultFile::Sigma,
        ResultFile::Merl,
        ResultFile::Gltf,
        ResultFile::MaterialX,
        ResultFile::Light,
        ResultFile::Object,
        ResultFile::MaterialsPicture,
        ResultFile::MaterialsMask,
    ];

    pub fn named(name: &str) -> Option<ResultFile> {
        ResultFile::ALL.into_iter().find(|f| f.name() == name)
    }

    pub fn name(self) -> &'static str {
        match self {
            ResultFile::Report => "report.html",
            ResultFile::PreviewPng => "preview.png",
            ResultFile::PreviewScale => "preview.json",
            ResultFile::PreviewExr => "preview.exr",
            ResultFile::Compare => "compare.png",
            ResultFile::Visibility => "visibility.png",
            ResultFile::Coefficients => "coefficients.json",
            ResultFile::Bivariate => "brdf-bivariate.exr",
            ResultFile::Sigma => "brdf-sigma.exr",
            ResultFile::Merl => "brdf.binary",
            ResultFile::Gltf => "material.gltf",
            ResultFile::MaterialX => "material.mtlx",
            ResultFile::Light => "light.hdr",
            ResultFile::Object => "object.gltf",
            ResultFile::MaterialsPicture => "materials.png",
            ResultFile::MaterialsMask => "materials-mask.png",
        }
    }

    fn media_type(self) -> &'static str {
        match self {
            ResultFile::PreviewPng
            | ResultFile::Compare
            | ResultFile::Visibility
            | ResultFile::MaterialsPicture
            | ResultFile::MaterialsMask => "image/png",
            ResultFile::PreviewExr | ResultFile::Bivariate | ResultFile::Sigma => "image/x-exr",
            ResultFile::Merl => "application/octet-stream",
            ResultFile::Coefficients | ResultFile::PreviewScale => "application/json",
            ResultFile::Report => "text/html; charset=utf-8",
            // glTF's registered media type; MaterialX has none, and is XML.
            ResultFile::Gltf | ResultFile::Object => "model/gltf+json",
            ResultFile::MaterialX => "application/xml",
            ResultFile::Light => "image/vnd.radiance",
        }
    }
}

/// A result file's route: `path`, its parameters, and what its 404 means; the answers are
/// the same for the whole part's files and for each material's (the files, their ranges and
/// validators, and the errors).
macro_rules! result_file_route {
    ($path:literal, ($($param:tt)*), $not_found:literal, $handler:item) => {
        #[utoipa::path(
            get,
            path = $path,
            params($($param)*),
            responses(
                (status = 200, description = "the file", content(
                    (FileBytes = "image/png"),
                    (FileBytes = "image/x-exr"),
                    (FileBytes = "image/vnd.radiance"),
                    (FileBytes = "application/octet-stream"),
                    (Object = "application/json"),
                    (String = "text/html"),
                    (Object = "model/gltf+json"),
                    (String = "application/xml"),
                ), headers(
                    ("ETag" = String, description = "the file's strong validator"),
                    ("Accept-Ranges" = String, description = "`bytes`"),
                )),
                (status = 206, description = "the bytes `Range` asked for, as `Content-Range` says, in the file's media type", content(
                    (FileBytes = "image/png"),
                    (FileBytes = "image/x-exr"),
                    (FileBytes = "image/vnd.radiance"),
                    (FileBytes = "application/octet-stream"),
                    (FileBytes = "application/json"),
                    (FileBytes = "text/html"),
                    (FileBytes = "model/gltf+json"),
                    (FileBytes = "application/xml"),
                ), headers(
                    ("ETag" = String, description = "the file's strong validator"),
                    ("Content-Range" = String, description = "`bytes FIRST-LAST/LENGTH`"),
                )),
                (status = 304, description = "not modified: `If-None-Match` named the file's `ETag`", headers(
                    ("ETag" = String, description = "the file's strong validator"),
                )),
                (status = 404, description = $not_found, body = ErrorBody),
                (status = 409, description = "`not_done`: the session is not done", body = ErrorBody),
                (status = 416, description = "`range_not_satisfiable`: `Range` starts past the file's end", body = ErrorBody, headers(
                    ("Content-Range" = String, description = "`bytes */LENGTH`"),
                )),
            )
        )]
        $handler
    };
}

result_file_route!(
    "/sessions/{id}/result/{file}",
    (
        ("id" = String, Path, description = "the session's id"),
        ("file" = ResultFile, Path, description = "the file"),
    ),
    "`not_found`: no such session, or no such file in its result (`brdf-sigma.exr` with an uncertainty band, `compare.png` with a photo, `light.hdr` with a capture's map, `object.gltf` on a mesh, `materials.png` and `materials-mask.png` on a part split into materials)",
    /// One of a finished session's result files (docs/formats.md).
    async fn result_file(
        State(d): State<Shared>,
        Path((id, file)): Path<(String, String)>,
        headers: HeaderMap,
    ) -> ApiResult<Response> {
        let file =
            ResultFile::named(&file).ok_or_else(|| not_found(format!("no result file {file:?}")))?;
        serve_result(&d, &id, None, file, &headers).await
    }
);

/// One material's folder of a result split into materials (`material-1`, `material-2`):
/// a fixed list, as [`ResultFile`] is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, utoipa::ToSchema)]
pub enum MaterialFolder {
    #[serde(rename = "material-1")]
    First,
    #[serde(rename = "material-2")]
    Second,
}

impl MaterialFolder {
    pub const ALL: [MaterialFolder; 2] = [MaterialFolder::First, MaterialFolder::Second];

    pub fn named(name: &str) -> Option<MaterialFolder> {
        MaterialFolder::ALL.into_iter().find(|f| f.name() == name)
    }

    pub fn name(self) -> &'static str {
        match self {
            MaterialFolder::First => "material-1",
            MaterialFolder::Second => "material-2",
        }
    }
}

result_file_route!(
    "/sessions/{id}/result/{material}/{file}",
    (
        ("id" = String, Path, description = "the session's id"),
        ("material" = MaterialFolder, Path, description = "the material's folder"),
        ("file" = ResultFile, Path, description = "the file"),
    ),
    "`not_found`: no such session, its part was not split into materials, or no such file in the material's result",
    /// One of a material's result files, when the session's part was split into two materials
    /// (docs/formats.md): the same files as the whole part's, in the material's folder.
    async fn material_file(
        State(d): State<Shared>,
        Path((id, material, file)): Path<(String, String, String)>,
        headers: HeaderMap,
    ) -> ApiResult<Response> {
        let folder = MaterialFolder::named(&material)
            .ok_or_else(|| not_found(format!("no material folder {material:?}")))?;
        let file =
            ResultFile::named(&file).ok_or_else(|| not_found(format!("no result file {file:?}")))?;
        serve_result(&d, &id, Some(folder), file, &headers).await
    }
);

/// Bytes a result file is read and sent in: 40 clients that ask for the 35 MB BRDF table and
/// never read it hold a chunk each, not the file (the server's write timeout drops them).
const FILE_CHUNK: usize = 64 * 1024;

/// A finished session's result file, as download tools and browsers expect a file to be
/// served (RFC 9110 §13, §14): a strong `ETag` from its size and modification time
/// (`If-None-Match` gives 304), and one byte range (`Range`, within `If-Range`) as 206, or 416
/// past its end. Several ranges get the whole file, as §14.2 allows. Result files are written
/// once, by a rename; a file written again has another time, so another tag. Our own code,
/// not tower-http's `ServeFile`: in tower-http 0.6 that has no `ETag`, and answers errors as
/// plain text.
async fn serve_result(
    d: &Daemon,
    id: &str,
    folder: Option<MaterialFolder>,
    file: ResultFile,
    headers: &HeaderMap,
) -> ApiResult<Response> {
    let s = done(d, id)?;
    let shown = match folder {
        Some(f) => format!("{}/{}", f.name(), file.name()),
        None => file.name().to_string(),
    };
    let missing = || not_found(format!("session {id} has no {shown}"));
    let mut dir = s.dir.join("result");
    if let Some(f) = folder {
        dir = dir.join(f.name());
    }
    let mut opened = tokio::fs::File::open(dir.join(file.name()))
        .await
        .map_err(|_| missing())?;
    let meta = opened.metadata().await.map_err(|_| missing())?;
    let length = meta.len();
    let tag = entity_tag(length, meta.modified().ok());
    let tag_header = HeaderValue::from_str(&tag).expect("an entity tag is ASCII");
    let given = |name: header::HeaderName| headers.get(name).and_then(|v| v.to_str().ok());
    // A list may come in several field lines; each is part of it.
    let mut none_match = headers
        .get_all(header::IF_NONE_MATCH)
        .iter()
        .filter_map(|v| v.to_str().ok());
    if none_match.any(|list| none_match_fails(list, &tag)) {
        return Ok((StatusCode::NOT_MODIFIED, [(header::ETAG, tag_header)]).into_response());
    }
    // A range of another version of the file would splice two files: the whole file then.
    let same = given(header::IF_RANGE).is_none_or(|v| v.trim() == tag);
    let range = match given(header::RANGE) {
        Some(r) if same => byte_range(r, length),
        _ => Ranged::Whole,
    };
    let (status, first, last) = match range {
        Ranged::Whole => (StatusCode::OK, 0, length.checked_sub(1)),
        Ranged::Part(first, last) => (StatusCode::PARTIAL_CONTENT, first, Some(last)),
        Ranged::Unsatisfiable => {
            let mut response = ApiError(
                StatusCode::RANGE_NOT_SATISFIABLE,
                ErrorCode::RangeNotSatisfiable,
                format!("{shown} has {length} bytes; the range asked for starts past them"),
            )
            .into_response();
            response.headers_mut().insert(
                header::CONTENT_RANGE,
                HeaderValue::from_str(&format!("bytes */{length}")).expect("ASCII"),
            );
            return Ok(response);
        }
    };
    let count = last.map_or(0, |last| last + 1 - first);
    if first > 0 {
        use tokio::io::AsyncSeekExt as _;
        opened
            .seek(std::io::SeekFrom::Start(first))
            .await
            .map_err(|_| missing())?;
    }
    let chunks = futures_util::stream::try_unfold((opened, count), |(mut f, left)| async move {
        use tokio::io::AsyncReadExt as _;
        if left == 0 {
            return Ok(None);
        }
        let mut chunk = vec![0u8; FILE_CHUNK.min(usize::try_from(left).unwrap_or(FILE_CHUNK))];
        let n = f.read(&mut chunk).await?;
        if n == 0 {
            return Err(std::io::Error::new(
                std::io::ErrorKind::UnexpectedEof,
                "the file ended before its length",
            ));
        }
        chunk.truncate(n);
        Ok(Some((axum::body::Bytes::from(chunk), (f, left - n as u64))))
    });
    // The report is a page of inline images, SVG and CSS: nothing in it may run or load.
    let policy = "default-src 'none'; img-src data:; style-src 'unsafe-inline'";
    let mut response = (
        status,
        [
            (header::CONTENT_TYPE, file.media_type()),
            (header::CONTENT_SECURITY_POLICY, policy),
            (header::ACCEPT_RANGES, "bytes"),
        ],
        [(header::CONTENT_LENGTH, count.to_string())],
        axum::body::Body::from_stream(chunks),
    )
        .into_response();
    let headers = response.headers_mut();
    headers.insert(header::ETAG, tag_header);
    if let (StatusCode::PARTIAL_CONTENT, Some(last)) = (status, last) {
        headers.insert(
            header::CONTENT_RANGE,
            HeaderValue::from_str(&format!("bytes {first}-{last}/{length}")).expect("ASCII"),
        );
    }
    Ok(response)
}

/// A strong entity tag (RFC 9110 §8.8.3) from a file's length and modification time, to the
/// nanosecond: `"LENGTH-SECONDS.NANOS"` in hex.
fn entity_tag(length: u64, modified: Option<std::time::SystemTime>) -> String {
    let since = modified
        .and_then(|m| m.duration_since(std::time::UNIX_EPOCH).ok())
        .unwrap_or_default();
    format!(
        "\"{length:x}-{:x}.{:x}\"",
        since.as_secs(),
        since.subsec_nanos()
    )
}

/// Whether `If-None-Match: list` fails for the tag `tag`, so that a GET answers 304: `*`, or a
/// tag in the list that matches by the weak comparison (RFC 9110 §13.1.2).
fn none_match_fails(list: &str, tag: &str) -> bool {
    list.split(',')
        .map(str::trim)
        .any(|t| t == "*" || t.strip_prefix("W/").unwrap_or(t) == tag)
}

/// What a `Range` header asks of a file.
#[derive(Debug, PartialEq, Eq)]
enum Ranged {
    /// No range the server takes (none, several, or not `bytes=` in RFC 9110's syntax): the
    /// whole file, 200.
    Whole,
    /// Bytes `first..=last`, within the file: 206.
    Part(u64, u64),
    /// A range that starts past the end, or asks for the last 0 bytes: 416.
    Unsatisfiable,
}

/// The one byte range of `Range: value` (RFC 9110 §14.1.2) of a file of `length` bytes.
fn byte_range(value: &str, length: u64) -> Ranged {
    let digits = |s: &str| -> Option<u64> {
        if s.is_empty() || !s.bytes().all(|b| b.is_ascii_digit()) {
            return None;
        }
        // More digits than a u64 holds: past any file's end.
        Some(s.parse().unwrap_or(u64::MAX))
    };
    let Some((unit, spec)) = value.trim().split_once('=') else {
        return Ranged::Whole;
    };
    if !unit.trim().eq_ignore_ascii_case("bytes") || spec.contains(',') {
        return Ranged::Whole;
    }
    let Some((first, last)) = spec.trim().split_once('-') else {
        return Ranged::Whole;
    };
    let (first, last) = (first.trim(), last.trim());
    if first.is_empty() {
        // The last N bytes.
        return match digits(last) {
            None => Ranged::Whole,
            Some(0) => Ranged::Unsatisfiable,
            Some(_) if length == 0 => Ranged::Unsatisfiable,
            Some(n) => Ranged::Part(length - n.min(length), length - 1),
        };
    }
    let Some(first) = digits(first) else {
        return Ranged::Whole;
    };
    let last = match (last.is_empty(), digits(last)) {
        (true, _) => None,
        (false, Some(last)) => Some(last),
        (false, None) => return Ranged::Whole,
    };
    if last.is_some_and(|last| last < first) {
        // An invalid range: the header is ignored (§14.1.1).
        return Ranged::Whole;
    }
    if first >= length {
        return Ranged::Unsatisfiable;
    }
    Ranged::Part(first, last.map_or(length - 1, |last| last.min(length - 1)))
}

/// The session's events as Server-Sent Events, one JSON [`Event`] each, with its place as
/// `id`: from the first (after `Last-Event-ID`), ending after `finished`.
#[utoipa::path(
    get,
    path = "/sessions/{id}/events",
    params(
        ("id" = String, Path, description = "the session's id"),
        ("Last-Event-ID" = Option<String>, Header, description = "the last event a client saw: the stream resumes after it"),
    ),
    responses(
        (status = 200, description = "a stream of events, each `data` an Event", content_type = "text/event-stream", body = StreamEvent),
        (status = 404, description = "`not_found`: no such session", body = ErrorBody),
        (status = 503, description = "`too_many_streams`: as many event streams are open as the daemon serves at once (half its connection cap, at most 64), so that `/health` and a cancel always get a connection", body = ErrorBody),
    )
)]
async fn events(
    State(d): State<Shared>,
    Path(id): Path<String>,
    headers: axum::http::HeaderMap,
) -> ApiResult<Sse<impl Stream<Item = Result<SseEvent, Infallible>>>> {
    let log = match d.events(&id) {
        Some(log) => log,
        None => {
            // Not run by this daemon: a stored session's stream is its outcome alone.
            let s = open(&d, &id)?;
            let log = super::EventLog::new();
            let last = s.manifest().history.last();
            let reason = last.and_then(|t| t.reason.clone());
            let reason = reason.map(|r| d.relative(&r));
            let failed = s.manifest().state == brdfd_rig::session::State::Failed;
            // Sessions that failed before codes were recorded: a cancel is told by its words.
            let code = last.and_then(|t| t.code).filter(|_| failed).or_else(|| {
                (failed && reason.as_deref() == Some(brdfd_rig::flow::CANCELLED))
                    .then_some(brdfd_rig::error::FailureCode::Cancelled)
            });
            log.push(Event::Finished {
                session: id.clone(),
                state: s.manifest().state,
                result: (s.manifest().state == brdfd_rig::session::State::Done)
                    .then(|| brdfd_rig::stored_summary(&s.dir.join("result/coefficients.json")))
                    .flatten()
                    .map(Box::new),
                cancelled: code == Some(brdfd_rig::error::FailureCode::Cancelled),
                code,
                error: reason,
            });
            log
        }
    };
    // Counted while the stream lives (the guard moves into it), and refused beyond the cap.
    let guard = StreamSlot::take(&d).ok_or_else(|| {
        ApiError(
            StatusCode::SERVICE_UNAVAILABLE,
            ErrorCode::TooManyStreams,
            format!(
                "{} event streams are open, the most this daemon serves at once; close one, or \
                 poll GET /sessions/{id} instead",
                d.max_event_streams
            ),
        )
    })?;
    // A client that reconnects says the last event it saw; it gets the ones after it.
    let from = log.resume_from(headers.get("last-event-id").and_then(|v| v.to_str().ok()));
    let (history, live) = log.subscribe();
    let run = log.run();
    let sse = move |index: usize, e: &Event| {
        SseEvent::default()
            .id(format!("{run}-{index}"))
            .json_data(e)
            .unwrap_or_else(|_| SseEvent::default().data("{}"))
    };
    // The history first (after `Last-Event-ID`), then live events, until `finished`.
    let ended = history.iter().any(|e| matches!(e, Event::Finished { .. }));
    let first = stream::iter(
        history
            .into_iter()
            .enumerate()
            .skip(from)
            .map(move |(id, e)| Ok(sse(id, &e))),
    );
    let rest = stream::unfold(
        (live, ended, guard),
        move |(mut rx, ended, guard)| async move {
            if ended {
                return None;
            }
            loop {
                match rx.recv().await {
                    Ok((id, e)) => {
                        let last = matches!(e, Event::Finished { .. });
                        if id < from {
                            // Only when the client's id is ahead of this run's history: skip to it.
                            if last {
                                return None;
                            }
                            continue;
                        }
                        return Some((Ok(sse(id, &e)), (rx, last, guard)));
                    }
                    // A slow reader misses events rather than stalling the capture.
                    Err(tokio::sync::broadcast::error::RecvError::Lagged(_)) => continue,
                    Err(tokio::sync::broadcast::error::RecvError::Closed) => return None,
                }
            }
        },
    );
    use futures_util::StreamExt;
    Ok(Sse::new(first.chain(rest)).keep_alive(KeepAlive::default()))
}

/// One of the daemon's event-stream slots, given back when dropped (the stream ended, or its
/// client went away).
struct StreamSlot(std::sync::Arc<std::sync::atomic::AtomicUsize>);

impl StreamSlot {
    fn take(d: &Shared) -> Option<StreamSlot> {
        use std::sync::atomic::Ordering;
        let open = d.event_streams.clone();
        open.fetch_update(Ordering::AcqRel, Ordering::Acquire, |n| {
            (n < d.max_event_streams).then_some(n + 1)
        })
        .ok()?;
        Some(StreamSlot(open))
    }
}

impl Drop for StreamSlot {
    fn drop(&mut self) {
        self.0.fetch_sub(1, std::sync::atomic::Ordering::AcqRel);
    }
}

#[cfg(test)]
mod tests {
    use super::{byte_range, is_own_host, none_match_fails, Ranged};

    #[test]
    fn one_byte_range_is_taken_as_rfc_9110_writes_it() {
        let part = Ranged::Part;
        for (range, length, wanted) in [
            ("bytes=0-9", 100, part(0, 9)),
            ("bytes=90-", 100, part(90, 99)),
            ("bytes=-10", 100, part(90, 99)),
            ("bytes=-1000", 100, part(0, 99)),
            ("bytes=50-1000", 100, part(50, 99)),
            ("Bytes = 1-2", 100, part(1, 2)),
            ("bytes=100-", 100, Ranged::Unsatisfiable),
            ("bytes=100-200", 100, Ranged::Unsatisfiable),
            ("bytes=-0", 100, Ranged::Unsatisfiable),
            ("bytes=0-", 0, Ranged::Unsatisfiable),
            ("bytes=99999999999999999999999-", 100, Ranged::Unsatisfiable),
            // Ignored: the whole file.
            ("bytes=0-1,3-4", 100, Ranged::Whole),
            ("bytes=9-0", 100, Ranged::Whole),
            ("bytes=+1-2", 100, Ranged::Whole),
            ("bytes=1", 100, Ranged::Whole),
            ("bytes=-", 100, Ranged::Whole),
            ("items=0-9", 100, Ranged::Whole),
            ("", 100, Ranged::Whole),
        ] {
            assert_eq!(byte_range(range, length), wanted, "{range:?} of {length}");
        }
    }

    #[test]
    fn if_none_match_compares_tags_weakly() {
        let tag = "\"1f-2.3\"";
        for list in [tag, "*", "W/\"1f-2.3\"", "\"x\", \"1f-2.3\""] {
            assert!(none_match_fails(list, tag), "{list}");
        }
        for list in ["\"x\"", "1f-2.3", ""] {
            assert!(!none_match_fails(list, tag), "{list}");
        }
    }

    #[test]
    fn own_hosts_are_addresses_localhost_and_the_configured_names() {
        let hosts = vec!["bench-pc.lab".to_string()];
        for ok in [
            "127.0.0.1:7878",
            "127.0.0.1",
            "192.168.1.20:7878",
            "[::1]:7878",
            "localhost:7878",
            "LOCALHOST",
            "bench-pc.lab:7878",
            "Bench-PC.lab.",
        ] {
            assert!(is_own_host(ok, &hosts), "{ok}");
        }
        for refused in [
            "evil.example:7878",
            "evil.example",
            "localhost.evil.example",
            "127.0.0.1.evil.example",
            "[not-an-address]:80",
            "",
        ] {
            assert!(!is_own_host(refused, &hosts), "{refused}");
        }
    }
}
