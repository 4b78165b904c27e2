//! The daemon's HTTP API, version 1. Every body is JSON; errors are
//! `{"error": "<code>", "message": "<what was wrong>"}` with a matching HTTP status.
//!
//! | method and path | answer |
//! |---|---|
//! | `GET /api/v1/health` | `{"software", "rig": {"simulated", "file"}, "busy": id or null}` |
//! | `GET /api/v1/materials` | `{"presets": [...]}`: the material presets a capture can name |
//! | `GET /api/v1/devices` | `[{"role", "selector", "state": "closed"/"open"/"lost", "identity", "last_error", "opened"}]` |
//! | `GET /api/v1/sessions` | `[{"id", "state", "material", "created"}]`, oldest first |
//! | `POST /api/v1/sessions` | body: a plan (`{"material": "gold", "pixels": "20", "views": 1, ...}`); 202 `{"id", "dir", "events"}`; 409 `busy`; 400 `bad_request` |
//! | `GET /api/v1/sessions/{id}` | `{"id", "dir", "manifest"}`: where it is stored, and its manifest |
//! | `GET /api/v1/sessions/{id}/events` | Server-Sent Events, one JSON [`Event`] each with its place as `id`, from the session's first (after `Last-Event-ID` if given); ends after `finished` |
//! | `GET /api/v1/sessions/{id}/result` | `coefficients.json`; 409 `not_done` until the session is done |
//! | `GET /api/v1/sessions/{id}/result/{file}` | `report.html`, `preview.png`, `preview.json`, `compare.png`, `preview.exr`, `brdf-bivariate.exr`, `brdf-sigma.exr`, `brdf.binary`; for a hybrid or analytic estimate also `material.gltf`, `material.mtlx` |
//! | `POST /api/v1/sessions/{id}/cancel` | 202; 409 `not_running` |
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
use serde_json::{json, Value};

use super::{web, Daemon, StartError};
use crate::rig::{Event, Plan};
use crate::session::{Session, State as SessionState};

pub type Shared = Arc<Daemon>;

/// An error answer.
struct ApiError(StatusCode, &'static str, String);

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        (self.0, Json(json!({ "error": self.1, "message": self.2 }))).into_response()
    }
}

type ApiResult<T> = Result<T, ApiError>;

fn not_found(e: impl std::fmt::Display) -> ApiError {
    ApiError(StatusCode::NOT_FOUND, "not_found", e.to_string())
}

fn bad_request(e: impl std::fmt::Display) -> ApiError {
    ApiError(StatusCode::BAD_REQUEST, "bad_request", e.to_string())
}

pub fn router(daemon: Shared) -> Router {
    let api = Router::new()
        .route("/health", get(health))
        .route("/devices", get(devices))
        .route("/materials", get(materials))
        .route("/sessions", get(list).post(start))
        .route("/sessions/{id}", get(show))
        .route("/sessions/{id}/events", get(events))
        .route("/sessions/{id}/result", get(result))
        .route("/sessions/{id}/result/{file}", get(result_file))
        .route("/sessions/{id}/cancel", post(cancel))
        .route("/sessions/{id}/resume", post(resume))
        .layer(axum::middleware::from_fn(require_json_posts))
        .layer(axum::middleware::from_fn_with_state(
            daemon.clone(),
            require_token,
        ))
        .layer(axum::middleware::from_fn_with_state(
            daemon.clone(),
            require_own_host,
        ));
    // The web page: its files need no token (they hold no data), but the host check, as
    // every answer does.
    let page = Router::new()
        .route("/", get(web::index))
        .route("/app.js", get(web::script))
        .route("/app.css", get(web::style))
        .route(
            "/login",
            post(web::login).layer(DefaultBodyLimit::max(web::MAX_LOGIN_BYTES)),
        )
        .layer(axum::middleware::from_fn_with_state(
            daemon.clone(),
            require_own_host,
        ));
    Router::new()
        .nest("/api/v1", api)
        .merge(page)
        .fallback(|| async {
            not_found("no such endpoint; the API is under /api/v1 (docs/api.md)")
        })
        .with_state(daemon)
}

async fn require_token(State(d): State<Shared>, req: Request, next: Next) -> Response {
    if let Some(token) = &d.token {
        let given = req
            .headers()
            .get(header::AUTHORIZATION)
            .and_then(|v| v.to_str().ok())
            .and_then(|v| v.strip_prefix("Bearer "))
            .map(|g| g.as_bytes().to_vec())
            // The web page's sign-in cookie (see [`web`]).
            .or_else(|| web::token_from_cookie(req.headers()));
        let ok = given.is_some_and(|g| web::same_secret(&g, token.as_bytes()));
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

async fn health(State(d): State<Shared>) -> Json<Value> {
    Json(json!({
        "software": format!("brdfd {}", env!("CARGO_PKG_VERSION")),
        "rig": { "simulated": d.rig.simulated },
        "busy": d.busy(),
    }))
}

async fn devices(State(d): State<Shared>) -> Json<Value> {
    Json(json!(d.devices()))
}

async fn materials() -> Json<Value> {
    Json(json!({ "presets": crate::config::preset_names() }))
}

async fn list(State(d): State<Shared>) -> ApiResult<Json<Value>> {
    let all = Session::list(&d.state_dir)
        .map_err(|e| ApiError(StatusCode::INTERNAL_SERVER_ERROR, "storage", e.to_string()))?;
    Ok(Json(Value::Array(
        all.into_iter()
            .map(|m| json!({ "id": m.id, "state": m.state, "material": m.material, "created": m.created }))
            .collect(),
    )))
}

fn started(s: Session) -> Response {
    let id = s.manifest.id;
    (
        StatusCode::ACCEPTED,
        Json(json!({
            "id": id,
            "dir": s.dir,
            "events": format!("/api/v1/sessions/{id}/events"),
        })),
    )
        .into_response()
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

async fn start(State(d): State<Shared>, body: axum::body::Body) -> ApiResult<Response> {
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
                "the plan did not arrive within {} s",
                PLAN_READ_TIMEOUT.as_secs()
            ),
        )
    })?
    .map_err(|e| bad_request(format!("the plan (at most {MAX_PLAN_BYTES} bytes): {e}")))?;
    // Parsed here rather than by the Json extractor, so that the error names the field in
    // our own error shape.
    let plan: Plan =
        serde_json::from_slice(&body).map_err(|e| bad_request(format!("the plan: {e}")))?;
    let s = tokio::task::spawn_blocking(move || d.start_capture(plan))
        .await
        .map_err(|e| ApiError(StatusCode::INTERNAL_SERVER_ERROR, "internal", e.to_string()))?
        .map_err(start_error)?;
    Ok(started(s))
}

async fn resume(State(d): State<Shared>, Path(id): Path<String>) -> ApiResult<Response> {
    let s = tokio::task::spawn_blocking(move || d.resume(&id))
        .await
        .map_err(|e| ApiError(StatusCode::INTERNAL_SERVER_ERROR, "internal", e.to_string()))?
        .map_err(start_error)?;
    Ok(started(s))
}

fn open(d: &Daemon, id: &str) -> ApiResult<Session> {
    Session::open(&d.state_dir, id).map_err(not_found)
}

async fn show(State(d): State<Shared>, Path(id): Path<String>) -> ApiResult<Json<Value>> {
    let s = open(&d, &id)?;
    Ok(Json(
        json!({ "id": id, "dir": s.dir, "manifest": s.manifest }),
    ))
}

async fn cancel(State(d): State<Shared>, Path(id): Path<String>) -> ApiResult<Response> {
    if d.cancel(&id) {
        Ok((
            StatusCode::ACCEPTED,
            Json(json!({ "id": id, "cancelling": true })),
        )
            .into_response())
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

async fn result(State(d): State<Shared>, Path(id): Path<String>) -> ApiResult<Response> {
    let s = done(&d, &id)?;
    let bytes = tokio::fs::read(s.dir.join("result/coefficients.json"))
        .await
        .map_err(not_found)?;
    Ok(([(header::CONTENT_TYPE, "application/json")], bytes).into_response())
}

async fn result_file(
    State(d): State<Shared>,
    Path((id, file)): Path<(String, String)>,
) -> ApiResult<Response> {
    // A fixed list: a file name from the request never reaches the file system unchecked.
    let kind = match file.as_str() {
        "preview.png" | "compare.png" => "image/png",
        "preview.exr" | "brdf-bivariate.exr" | "brdf-sigma.exr" => "image/x-exr",
        "brdf.binary" => "application/octet-stream",
        "coefficients.json" | "preview.json" => "application/json",
        "report.html" => "text/html; charset=utf-8",
        // glTF's registered media type; MaterialX has none, and is XML.
        "material.gltf" => "model/gltf+json",
        "material.mtlx" => "application/xml",
        _ => return Err(not_found(format!("no result file {file:?}"))),
    };
    let s = done(&d, &id)?;
    let bytes = tokio::fs::read(s.dir.join("result").join(&file))
        .await
        .map_err(not_found)?;
    // The report is a page of inline images, SVG and CSS: nothing in it may run or load.
    let policy = "default-src 'none'; img-src data:; style-src 'unsafe-inline'";
    Ok((
        [
            (header::CONTENT_TYPE, kind),
            (header::CONTENT_SECURITY_POLICY, policy),
        ],
        bytes,
    )
        .into_response())
}

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
            log.push(Event::Finished {
                session: id.clone(),
                state: s.manifest.state,
                result: (s.manifest.state == crate::session::State::Done)
                    .then(|| crate::rig::Summary::read(&s.dir.join("result/coefficients.json")))
                    .flatten(),
                error: s.manifest.history.last().and_then(|t| t.reason.clone()),
            });
            log
        }
    };
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
    let rest = stream::unfold((live, ended), move |(mut rx, ended)| async move {
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
                    return Some((Ok(sse(id, &e)), (rx, last)));
                }
                // A slow reader misses events rather than stalling the capture.
                Err(tokio::sync::broadcast::error::RecvError::Lagged(_)) => continue,
                Err(tokio::sync::broadcast::error::RecvError::Closed) => return None,
            }
        }
    });
    use futures_util::StreamExt;
    Ok(Sse::new(first.chain(rest)).keep_alive(KeepAlive::default()))
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
