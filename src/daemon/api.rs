//! The daemon's HTTP API, version 1. Every body is JSON; errors are
//! `{"error": "<code>", "message": "<what was wrong>"}` with a matching HTTP status.
//!
//! | method and path | answer |
//! |---|---|
//! | `GET /api/v1/openapi.json` | this API's OpenAPI 3.1 description ([`openapi`]); needs no token |
//! | `GET /api/v1/health` | `{"software", "rig": {"simulated"}, "busy": id or null}` |
//! | `GET /api/v1/materials` | `{"presets": [...]}`: the material presets a capture can name |
//! | `GET /api/v1/devices` | `[{"role", "selector", "state": "closed"/"open"/"lost", "identity", "last_error", "opened"}]` |
//! | `GET /api/v1/sessions` | `[{"id", "state", "material", "created", "running"}]`, oldest first |
//! | `POST /api/v1/sessions` | body: a plan (`{"material": "gold", "pixels": "20", "views": 1, ...}`); 202 `{"id", "dir", "events"}`; 409 `busy`; 400 `bad_request` |
//! | `GET /api/v1/sessions/{id}` | `{"id", "dir", "manifest", "waiting_for_view"}`: where it is stored, its manifest, and the view whose hand turn it waits for |
//! | `GET /api/v1/sessions/{id}/events` | Server-Sent Events, one JSON [`Event`] each with its place as `id`, from the session's first (after `Last-Event-ID` if given); ends after `finished` |
//! | `GET /api/v1/sessions/{id}/result` | `coefficients.json`; 409 `not_done` until the session is done |
//! | `GET /api/v1/sessions/{id}/result/{file}` | `report.html`, `coefficients.json`, `preview.png`, `preview.json`, `compare.png`, `preview.exr`, `brdf-bivariate.exr`, `brdf-sigma.exr`, `brdf.binary`, `material.gltf`, `material.mtlx`, `light.hdr` |
//! | `POST /api/v1/sessions/{id}/cancel` | 202; 409 `not_running` |
//! | `POST /api/v1/sessions/{id}/continue` | the object is turned by hand, as the `waiting_for_operator` event asked: 202; 409 `not_waiting` |
//! | `POST /api/v1/sessions/{id}/resume` | 202 as for a new capture; 409 `busy` |
//!
//! With a token configured, every request needs `Authorization: Bearer <token>`, or the
//! cookie the web page's sign-in sets ([`web`]) (401 `unauthorized` otherwise). Every POST needs `Content-Type: application/json`, its body or
//! not (415 `unsupported_media_type` otherwise).

use std::convert::Infallible;
use std::sync::Arc;

use axum::extract::{DefaultBodyLimit, Path, Request, State};
use axum::http::{header, StatusCode};
use axum::middleware::Next;
use axum::response::sse::{Event as SseEvent, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use futures_util::stream::{self, Stream};
use utoipa::{Modify as _, OpenApi as _};
use utoipa_axum::{router::OpenApiRouter, routes};

use super::openapi::{
    ApiDoc, Cancelling, ContinueRequest, Continuing, ErrorBody, FileBytes, Guards, Health,
    Materials, RigSummary, SessionDetail, SessionItem, Started, StreamEvent,
};
use super::{web, Daemon, StartError};
use crate::rig::{Event, Plan};
use crate::session::{Session, State as SessionState};

pub type Shared = Arc<Daemon>;

/// An error answer.
struct ApiError(StatusCode, &'static str, String);

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let body = ErrorBody {
            error: self.1.into(),
            message: self.2,
        };
        (self.0, Json(body)).into_response()
    }
}

type ApiResult<T> = Result<T, ApiError>;

fn not_found(e: impl std::fmt::Display) -> ApiError {
    ApiError(StatusCode::NOT_FOUND, "not_found", e.to_string())
}

fn bad_request(e: impl std::fmt::Display) -> ApiError {
    ApiError(StatusCode::BAD_REQUEST, "bad_request", e.to_string())
}

/// The API's routes, each registered with its OpenAPI description ([`openapi`]).
fn api() -> OpenApiRouter<Shared> {
    OpenApiRouter::with_openapi(ApiDoc::openapi())
        .routes(routes!(health))
        .routes(routes!(devices))
        .routes(routes!(materials))
        .routes(routes!(list, start))
        .routes(routes!(show))
        .routes(routes!(events))
        .routes(routes!(result))
        .routes(routes!(result_file))
        .routes(routes!(cancel))
        .routes(routes!(continue_capture))
        .routes(routes!(resume))
}

/// The OpenAPI description of everything under `/api/v1`, as `GET /api/v1/openapi.json`
/// serves it.
pub fn openapi() -> utoipa::openapi::OpenApi {
    let mut description = OpenApiRouter::<Shared>::new()
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
        .layer(axum::middleware::from_fn(require_json_posts))
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
            get(move || async move {
                (
                    [(header::CONTENT_TYPE, "application/json")],
                    description.to_string(),
                )
            }),
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
        "too_many_attempts",
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
            return ApiError(
                StatusCode::UNAUTHORIZED,
                "unauthorized",
                "this daemon requires `Authorization: Bearer <token>` (the token in its brdfd.toml), or, in a browser, signing in on its page at /"
                    .into(),
            )
            .into_response();
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
                "unknown_host",
                format!(
                    "this daemon does not answer to the host {host:?}: reach it by IP address or localhost, or add the name to `hosts` in its brdfd.toml"
                ),
            )
            .into_response();
        }
    }
    next.run(req).await
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
                "unsupported_media_type",
                "every POST needs `Content-Type: application/json` (with a JSON body, `{}` if there is nothing to say), so that a web page cannot send one across sites".into(),
            )
            .into_response();
        }
    }
    next.run(req).await
}

/// The daemon's software, its rig, and the capture running now.
#[utoipa::path(get, path = "/health", responses((status = 200, body = Health)))]
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
#[utoipa::path(get, path = "/devices", responses((status = 200, body = Vec<crate::rig::DeviceStatus>)))]
async fn devices(State(d): State<Shared>) -> Json<Vec<crate::rig::DeviceStatus>> {
    Json(d.devices())
}

/// The material presets a capture can name.
#[utoipa::path(get, path = "/materials", responses((status = 200, body = Materials)))]
async fn materials() -> Json<Materials> {
    Json(Materials {
        presets: crate::config::preset_names(),
    })
}

/// The stored sessions, oldest first.
#[utoipa::path(
    get,
    path = "/sessions",
    responses(
        (status = 200, body = Vec<SessionItem>),
        (status = 500, description = "`storage`: the state directory cannot be read", body = ErrorBody),
    )
)]
async fn list(State(d): State<Shared>) -> ApiResult<Json<Vec<SessionItem>>> {
    let all = Session::list(&d.state_dir)
        .map_err(|e| ApiError(StatusCode::INTERNAL_SERVER_ERROR, "storage", e.to_string()))?;
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

fn started(s: Session) -> Response {
    let id = s.manifest.id;
    let events = format!("{API}/sessions/{id}/events");
    let dir = s.dir.display().to_string();
    (StatusCode::ACCEPTED, Json(Started { id, dir, events })).into_response()
}

fn start_error(e: StartError) -> ApiError {
    match e {
        StartError::Busy(_) => ApiError(StatusCode::CONFLICT, "busy", e.to_string()),
        StartError::Invalid(_) => bad_request(e),
    }
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
    request_body = crate::rig::Plan,
    responses(
        (status = 202, description = "started; follow `events`", body = Started),
        (status = 400, description = "`bad_request`: the plan is not valid JSON, or names what does not exist", body = ErrorBody),
        (status = 408, description = "`request_timeout`: the plan did not arrive in time", body = ErrorBody),
        (status = 409, description = "`busy`: a capture is running", body = ErrorBody),
        (status = 500, description = "`internal`: the daemon could not start the capture's thread", body = ErrorBody),
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
        .map_err(|e| ApiError(StatusCode::INTERNAL_SERVER_ERROR, "internal", e.to_string()))?
        .map_err(start_error)?;
    Ok(started(s))
}

/// Resumes a session that stopped: from its last complete step.
#[utoipa::path(
    post,
    path = "/sessions/{id}/resume",
    params(("id" = String, Path, description = "the session's id")),
    request_body(content = Object, description = "`{}`", content_type = "application/json"),
    responses(
        (status = 202, description = "resumed; follow `events`", body = Started),
        (status = 400, description = "`bad_request`: the session cannot be resumed", body = ErrorBody),
        (status = 409, description = "`busy`: a capture is running", body = ErrorBody),
        (status = 500, description = "`internal`: the daemon could not start the capture's thread", body = ErrorBody),
    )
)]
async fn resume(State(d): State<Shared>, Path(id): Path<String>) -> ApiResult<Response> {
    on_capture_thread(move || d.resume(&id)).await
}

fn open(d: &Daemon, id: &str) -> ApiResult<Session> {
    Session::open(&d.state_dir, id).map_err(not_found)
}

/// A session: where it is stored, and its manifest.
#[utoipa::path(
    get,
    path = "/sessions/{id}",
    params(("id" = String, Path, description = "the session's id")),
    responses(
        (status = 200, body = SessionDetail),
        (status = 404, description = "`not_found`: no such session", body = ErrorBody),
    )
)]
async fn show(State(d): State<Shared>, Path(id): Path<String>) -> ApiResult<Json<SessionDetail>> {
    let s = open(&d, &id)?;
    let waiting_for_view = d.waiting_for(&id);
    Ok(Json(SessionDetail {
        id,
        dir: s.dir.display().to_string(),
        manifest: d.shown(s.manifest),
        waiting_for_view,
    }))
}

/// A request's JSON body, read within [`PLAN_READ_TIMEOUT`] and [`MAX_PLAN_BYTES`] (an empty
/// body is `{}`). Parsed here rather than by the Json extractor, so that the error names the
/// field in our own error shape.
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
            "request_timeout",
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
    serde_json::from_slice(body).map_err(|e| bad_request(format!("{what}: {e}")))
}

/// Tells the running capture that the operator has turned the object by hand, as its
/// `waiting_for_operator` event asked (a rig with no turntable, several views).
#[utoipa::path(
    post,
    path = "/sessions/{id}/continue",
    params(("id" = String, Path, description = "the session's id")),
    request_body(content = ContinueRequest, content_type = "application/json"),
    responses(
        (status = 202, body = Continuing),
        (status = 400, description = "`bad_request`: the body is not `{}` or `{\"view\": N}`", body = ErrorBody),
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
            "not_waiting",
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
    request_body(content = Object, description = "`{}`", content_type = "application/json"),
    responses(
        (status = 202, body = Cancelling),
        (status = 409, description = "`not_running`: the session is not capturing now", body = ErrorBody),
    )
)]
async fn cancel(State(d): State<Shared>, Path(id): Path<String>) -> ApiResult<Response> {
    if d.cancel(&id) {
        let body = Cancelling {
            id,
            cancelling: true,
        };
        Ok((StatusCode::ACCEPTED, Json(body)).into_response())
    } else {
        Err(ApiError(
            StatusCode::CONFLICT,
            "not_running",
            format!("session {id} is not capturing now"),
        ))
    }
}

fn done(d: &Daemon, id: &str) -> ApiResult<Session> {
    let s = open(d, id)?;
    if s.manifest.state != SessionState::Done {
        return Err(ApiError(
            StatusCode::CONFLICT,
            "not_done",
            format!("session {id} is {:?}, not done", s.manifest.state),
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
        (status = 200, body = Object, content_type = "application/json"),
        (status = 404, description = "`not_found`: no such session, or no result file", body = ErrorBody),
        (status = 409, description = "`not_done`: the session is not done", body = ErrorBody),
    )
)]
async fn result(State(d): State<Shared>, Path(id): Path<String>) -> ApiResult<Response> {
    let s = done(&d, &id)?;
    let bytes = tokio::fs::read(s.dir.join("result/coefficients.json"))
        .await
        .map_err(not_found)?;
    Ok(([(header::CONTENT_TYPE, "application/json")], bytes).into_response())
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
}

impl ResultFile {
    pub const ALL: [ResultFile; 14] = [
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
        }
    }

    fn media_type(self) -> &'static str {
        match self {
            ResultFile::PreviewPng | ResultFile::Compare | ResultFile::Visibility => "image/png",
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

/// One of a finished session's result files (docs/formats.md).
#[utoipa::path(
    get,
    path = "/sessions/{id}/result/{file}",
    params(
        ("id" = String, Path, description = "the session's id"),
        ("file" = ResultFile, Path, description = "the file"),
    ),
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
        )),
        (status = 404, description = "`not_found`: no such session, or no such file in its result (`brdf-sigma.exr` with an uncertainty band, `compare.png` with a photo, `light.hdr` with a capture's map, `object.gltf` on a mesh)", body = ErrorBody),
        (status = 409, description = "`not_done`: the session is not done", body = ErrorBody),
    )
)]
async fn result_file(
    State(d): State<Shared>,
    Path((id, file)): Path<(String, String)>,
) -> ApiResult<Response> {
    let file =
        ResultFile::named(&file).ok_or_else(|| not_found(format!("no result file {file:?}")))?;
    let s = done(&d, &id)?;
    let path = s.dir.join("result").join(file.name());
    let opened = tokio::fs::File::open(&path).await.map_err(not_found)?;
    let length = opened.metadata().await.map_err(not_found)?.len();
    // Streamed from disk a chunk at a time: 40 clients that ask for the 35 MB BRDF table and
    // never read it hold a chunk each, not the file (the server's write timeout drops them).
    let chunks = futures_util::stream::try_unfold(opened, |mut f| async move {
        use tokio::io::AsyncReadExt as _;
        let mut chunk = vec![0u8; 64 * 1024];
        let n = f.read(&mut chunk).await?;
        chunk.truncate(n);
        Ok::<_, std::io::Error>((n > 0).then_some((axum::body::Bytes::from(chunk), f)))
    });
    // The report is a page of inline images, SVG and CSS: nothing in it may run or load.
    let policy = "default-src 'none'; img-src data:; style-src 'unsafe-inline'";
    Ok((
        [
            (header::CONTENT_TYPE, file.media_type()),
            (header::CONTENT_SECURITY_POLICY, policy),
        ],
        [(header::CONTENT_LENGTH, length.to_string())],
        axum::body::Body::from_stream(chunks),
    )
        .into_response())
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
            let reason = s.manifest.history.last().and_then(|t| t.reason.clone());
            log.push(Event::Finished {
                session: id.clone(),
                state: s.manifest.state,
                result: (s.manifest.state == crate::session::State::Done)
                    .then(|| crate::rig::Summary::read(&s.dir.join("result/coefficients.json")))
                    .flatten()
                    .map(Box::new),
                cancelled: s.manifest.state == crate::session::State::Failed
                    && reason.as_deref() == Some(crate::rig::flow::CANCELLED),
                error: reason,
            });
            log
        }
    };
    // Counted while the stream lives (the guard moves into it), and refused beyond the cap.
    let guard = StreamSlot::take(&d).ok_or_else(|| {
        ApiError(
            StatusCode::SERVICE_UNAVAILABLE,
            "too_many_streams",
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
    use super::is_own_host;

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
