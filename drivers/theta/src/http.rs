//! The THETA Web API client (OSC v2.1 over HTTP), async on `reqwest`.
//!
//! - Every request has a timeout ([`HttpTimeouts`]).
//! - Retries follow what the API allows. `serviceUnavailable` (HTTP 503) means the camera did
//!   not take the request, so any request is sent again after a pause. A timeout or a dropped
//!   connection is retried only for requests that change nothing (info, state, status,
//!   getOptions, setOptions, listFiles, downloads). A takePicture whose answer was lost may
//!   have fired, so it is never sent twice.
//! - HTTP Digest (RFC 7616, MD5, qop=auth) for client mode, where the THETA asks for it.
//!   The challenge is kept and reused with an increasing nonce count, as the RFC intends.
//! - File URLs are followed only when they point at the camera's own host and port.
//! - A connection that cannot be made before the camera has ever answered is not retried: the
//!   address, the camera's network mode or a firewall is wrong, and waiting out the retry
//!   budget would only keep the user waiting for the same answer.
//!
//! It does not own a runtime; [`crate::Theta`] wraps it for blocking callers.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use reqwest::{Method, StatusCode, Url};
use serde_json::{json, Value};

use crate::error::{Result, ThetaError};
use crate::osc::{error_code, Command, CommandState, ErrorBody, Info, StateResponse, Updates};

/// Timeouts and retry limits. The defaults suit a THETA V on its own access point.
#[derive(Debug, Clone, Copy)]
pub struct HttpTimeouts {
    /// Connecting, and each request that is not a download or a capture wait.
    pub request: Duration,
    /// Polling interval of `/osc/commands/status` while a command is in progress.
    pub poll: Duration,
    /// How long one command (a bracket of 13 shots at up to 1 s each, with stitching) may
    /// stay in progress.
    pub command: Duration,
    /// A whole file download, per attempt (a 5376 × 2688 JPEG is about 5 MB).
    pub download: Duration,
    /// How long to keep retrying a request the camera was not ready for.
    pub retry_budget: Duration,
}

impl Default for HttpTimeouts {
    fn default() -> Self {
        HttpTimeouts {
            request: Duration::from_secs(10),
            poll: Duration::from_millis(500),
            command: Duration::from_secs(180),
            download: Duration::from_secs(60),
            retry_budget: Duration::from_secs(30),
        }
    }
}

/// Longest wait for a TCP connection, whatever `request` is. A camera on the local network
/// accepts within milliseconds; Linux sends the SYN again after 1 s, so this covers one lost
/// SYN and still answers a dead address within 5 s.
pub const CONNECT_TIMEOUT: Duration = Duration::from_secs(3);

/// First pause before a retry; it doubles up to `RETRY_PAUSE_MAX`.
const RETRY_PAUSE: Duration = Duration::from_millis(100);
const RETRY_PAUSE_MAX: Duration = Duration::from_secs(2);
/// Attempts at one file download before giving up.
pub const DOWNLOAD_ATTEMPTS: u32 = 3;
/// The largest file a THETA download may be: its biggest pictures (a Z1's DNG, an X's 11K
/// JPEG) are under 100 MB. A camera announcing or sending more is refused, not believed.
pub const MAX_FILE_BYTES: u64 = 512 << 20;
/// The largest JSON answer: a long `camera.listFiles` is well under this.
pub const MAX_JSON_BYTES: u64 = 16 << 20;

/// Commands that change nothing on the camera, or set it to the same state when repeated.
const IDEMPOTENT_COMMANDS: [&str; 6] = [
    "camera.getOptions",
    "camera.setOptions",
    "camera.listFiles",
    "camera._getMetadata",
    "camera.getLivePreview",
    "camera.reset",
];

#[derive(Debug, Clone)]
pub struct Credentials {
    pub user: String,
    pub password: String,
}

/// Progress of a command or a download: a phase name and a fraction in [0, 1].
pub type Progress<'a> = &'a mut (dyn FnMut(&str, f64) + Send);

pub struct OscClient {
    http: reqwest::Client,
    base: Url,
    credentials: Option<Credentials>,
    /// The last Digest challenge, reused (with a rising nonce count) until the camera issues
    /// a new one.
    challenge: Mutex<Option<digest_auth::WwwAuthenticateHeader>>,
    /// Whether the camera has answered anything yet: until it has, a failed connection is
    /// a wrong address rather than a camera waking up.
    answered: AtomicBool,
    pub timeouts: HttpTimeouts,
}

impl OscClient {
    /// `base` is the camera's address: `http://192.168.1.1` in access-point mode.
    pub fn new(
        base: &str,
        credentials: Option<Credentials>,
        timeouts: HttpTimeouts,
    ) -> Result<OscClient> {
        let base = Url::parse(base)
            .ok()
            .filter(|u| u.scheme() == "http" && u.host_str().is_some())
            .ok_or_else(|| ThetaError::Unreachable {
                what: "THETA address".into(),
                camera: base.into(),
                reason: "not an http://HOST[:PORT] address".into(),
            })?;
        let http = reqwest::Client::builder()
            .connect_timeout(timeouts.request.min(CONNECT_TIMEOUT))
            // The camera is on the local network: a proxy from the environment would only
            // get in the way.
            .no_proxy()
            // A THETA never redirects; following one would fetch another host's bytes as if
            // they were the camera's (a downloaded frame, say).
            .redirect(reqwest::redirect::Policy::none())
            .build()
            .map_err(|e| ThetaError::Unreachable {
                what: "HTTP client".into(),
                camera: base.to_string(),
                reason: e.to_string(),
            })?;
        Ok(OscClient {
            http,
            base,
            credentials,
            challenge: Mutex::new(None),
            answered: AtomicBool::new(false),
            timeouts,
        })
    }

    pub fn base(&self) -> &Url {
        &self.base
    }

    /// `GET /osc/info`.
    pub async fn info(&self) -> Result<Info> {
        let v = self
            .json(Method::GET, "/osc/info", None, "info", true)
            .await?;
        parse(v, "info")
    }

    /// `POST /osc/state`.
    pub async fn state(&self) -> Result<StateResponse> {
        let v = self
            .json(Method::POST, "/osc/state", None, "state", true)
            .await?;
        parse(v, "state")
    }

    /// `POST /osc/checkForUpdates`: whether the state changed since `fingerprint`.
    pub async fn check_for_updates(&self, fingerprint: &str) -> Result<Updates> {
        let body = json!({ "stateFingerprint": fingerprint });
        let v = self
            .json(
                Method::POST,
                "/osc/checkForUpdates",
                Some(body),
                "checkForUpdates",
                true,
            )
            .await?;
        parse(v, "checkForUpdates")
    }

    /// `POST /osc/commands/execute`, returning the first answer (which may be inProgress).
    pub async fn execute(&self, name: &str, parameters: Value) -> Result<Command> {
        let body = json!({ "name": name, "parameters": parameters });
        let retry = IDEMPOTENT_COMMANDS.contains(&name);
        let v = self
            .json(
                Method::POST,
                "/osc/commands/execute",
                Some(body),
                name,
                retry,
            )
            .await?;
        command_result(parse(v, name)?, name)
    }

    /// `POST /osc/commands/status`.
    pub async fn status(&self, id: &str, what: &str) -> Result<Command> {
        let body = json!({ "id": id });
        let v = self
            .json(Method::POST, "/osc/commands/status", Some(body), what, true)
            .await?;
        command_result(parse(v, what)?, what)
    }

    /// Executes a command and polls its status until it is done; an error state is an error.
    #[tracing::instrument(skip(self, parameters, progress), fields(camera = %self.base))]
    pub async fn run(
        &self,
        name: &str,
        parameters: Value,
        progress: Progress<'_>,
    ) -> Result<Command> {
        let start = Instant::now();
        let mut c = self.execute(name, parameters).await?;
        while c.state == CommandState::InProgress {
            if let Some(p) = c.progress {
                progress(name, p.completion);
            }
            let id = c.id.clone().ok_or_else(|| ThetaError::Malformed {
                what: name.into(),
                reason: "inProgress without a command id".into(),
            })?;
            if start.elapsed() > self.timeouts.command {
                return Err(ThetaError::Timeout {
                    what: format!("{name} (still in progress)"),
                    camera: self.base.to_string(),
                    after: self.timeouts.command,
                });
            }
            tokio::time::sleep(self.timeouts.poll).await;
            c = self.status(&id, name).await?;
        }
        progress(name, 1.0);
        Ok(c)
    }

    /// Sets options (`camera.setOptions`).
    pub async fn set_options(&self, options: Value) -> Result<()> {
        self.execute("camera.setOptions", json!({ "options": options }))
            .await
            .map(|_| ())
    }

    /// Reads options (`camera.getOptions`).
    pub async fn get_options(&self, names: &[&str]) -> Result<serde_json::Map<String, Value>> {
        Ok(self
            .execute("camera.getOptions", json!({ "optionNames": names }))
            .await?
            .options())
    }

    /// Downloads a file the camera named, with retries; only from the camera itself.
    #[tracing::instrument(skip(self, progress), fields(camera = %self.base))]
    pub async fn download(&self, url: &str, progress: Progress<'_>) -> Result<Vec<u8>> {
        let parsed = Url::parse(url).ok().filter(|u| self.is_camera(u));
        let Some(parsed) = parsed else {
            return Err(ThetaError::ForeignUrl {
                url: url.into(),
                camera: self.base.to_string(),
            });
        };
        let mut last = String::new();
        for attempt in 1..=DOWNLOAD_ATTEMPTS {
            match self.download_once(&parsed, progress).await {
                Ok(bytes) => return Ok(bytes),
                Err(e) => {
                    tracing::warn!(attempt, "download of {url} failed: {e}");
                    last = e.to_string();
                    tokio::time::sleep(RETRY_PAUSE * attempt).await;
                }
            }
        }
        Err(ThetaError::Download {
            url: url.into(),
            attempts: DOWNLOAD_ATTEMPTS,
            reason: last,
        })
    }

    /// A body of `n` bytes, announced or received, is refused above `limit`.
    fn check_size(&self, what: &str, n: u64, limit: u64) -> Result<()> {
        if n <= limit {
            return Ok(());
        }
        Err(ThetaError::Malformed {
            what: what.into(),
            reason: format!(
                "the camera at {} sends {n} bytes or more, beyond the {limit} a THETA answer can be",
                self.base
            ),
        })
    }

    async fn download_once(&self, url: &Url, progress: Progress<'_>) -> Result<Vec<u8>> {
        let what = format!("download {}", url.path());
        let mut resp = self
            .send(Method::GET, url.clone(), None, &what, true)
            .await?;
        if resp.status() != StatusCode::OK {
            return Err(http_error(resp, &what).await);
        }
        let expected = resp.content_length();
        if let Some(n) = expected {
            self.check_size(&what, n, MAX_FILE_BYTES)?;
        }
        // Room for what was announced (checked above), in steps, not all at once on trust.
        let mut data = Vec::with_capacity(expected.unwrap_or(0).min(64 << 20) as usize);
        let deadline = Instant::now() + self.timeouts.download;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            let chunk = tokio::time::timeout(left, resp.chunk())
                .await
                .map_err(|_| self.timeout(&what, self.timeouts.download))?
                .map_err(|e| self.unreachable(&what, &e))?;
            let Some(chunk) = chunk else { break };
            data.extend_from_slice(&chunk);
            self.check_size(&what, data.len() as u64, MAX_FILE_BYTES)?;
            if let Some(n) = expected {
                progress("download", data.len() as f64 / n.max(1) as f64);
            }
        }
        if let Some(n) = expected {
            if data.len() as u64 != n {
                return Err(ThetaError::Unreachable {
                    what,
                    camera: self.base.to_string(),
                    reason: format!("connection closed after {} of {n} bytes", data.len()),
                });
            }
        }
        Ok(data)
    }

    fn is_camera(&self, u: &Url) -> bool {
        u.scheme() == self.base.scheme()
            && u.host_str() == self.base.host_str()
            && u.port_or_known_default() == self.base.port_or_known_default()
    }

    /// A JSON request with the retry policy, returning the body of a 2xx answer; API error
    /// objects become [`ThetaError::Command`].
    async fn json(
        &self,
        method: Method,
        path: &str,
        body: Option<Value>,
        what: &str,
        idempotent: bool,
    ) -> Result<Value> {
        let url = self.base.join(path).map_err(|e| ThetaError::Malformed {
            what: what.into(),
            reason: e.to_string(),
        })?;
        let mut resp = self.send(method, url, body, what, idempotent).await?;
        let status = resp.status();
        let mut bytes = Vec::new();
        while let Some(chunk) = resp.chunk().await.map_err(|e| self.unreachable(what, &e))? {
            bytes.extend_from_slice(&chunk);
            self.check_size(what, bytes.len() as u64, MAX_JSON_BYTES)?;
        }
        let v: Value = serde_json::from_slice(&bytes).map_err(|e| {
            if status.is_success() {
                ThetaError::Malformed {
                    what: what.into(),
                    reason: e.to_string(),
                }
            } else {
                ThetaError::Http {
                    what: what.into(),
                    status: status.as_u16(),
                    body: String::from_utf8_lossy(&bytes).chars().take(200).collect(),
                }
            }
        })?;
        if status.is_success() {
            return Ok(v);
        }
        Err(api_error(&v, what, status))
    }

    /// Sends one request, answering a Digest challenge and retrying as the API allows.
    async fn send(
        &self,
        method: Method,
        url: Url,
        body: Option<Value>,
        what: &str,
        idempotent: bool,
    ) -> Result<reqwest::Response> {
        let start = Instant::now();
        let mut pause = RETRY_PAUSE;
        let mut answered_challenge = false;
        loop {
            let outcome = self.send_once(&method, &url, body.as_ref(), what).await;
            if outcome.is_ok() {
                self.answered.store(true, Ordering::Relaxed);
            }
            let retryable = match &outcome {
                Ok(r) if r.status() == StatusCode::UNAUTHORIZED && !answered_challenge => {
                    self.take_challenge(r, what)?;
                    answered_challenge = true;
                    continue;
                }
                Ok(r) if r.status() == StatusCode::UNAUTHORIZED => {
                    return Err(ThetaError::Auth {
                        what: what.into(),
                        reason: "the THETA refused the credentials".into(),
                    })
                }
                Ok(r) => r.status() == StatusCode::SERVICE_UNAVAILABLE,
                Err(ThetaError::NoConnection { .. }) => {
                    idempotent && self.answered.load(Ordering::Relaxed)
                }
                Err(_) => idempotent,
            };
            if !retryable || start.elapsed() + pause > self.timeouts.retry_budget {
                return outcome;
            }
            tracing::debug!(what, ?pause, "camera not ready; retrying");
            tokio::time::sleep(pause).await;
            pause = (pause * 2).min(RETRY_PAUSE_MAX);
        }
    }

    async fn send_once(
        &self,
        method: &Method,
        url: &Url,
        body: Option<&Value>,
        what: &str,
    ) -> Result<reqwest::Response> {
        let bytes = body.map(|b| b.to_string().into_bytes());
        let mut req = self.http.request(method.clone(), url.clone());
        if let Some(b) = &bytes {
            req = req
                .header("Content-Type", "application/json;charset=utf-8")
                .body(b.clone());
        }
        if let Some(auth) = self.authorization(method, url, bytes.as_deref())? {
            req = req.header("Authorization", auth);
        }
        let timeout = if method == Method::GET && url.path().starts_with("/files/") {
            self.timeouts.download
        } else {
            self.timeouts.request
        };
        req.timeout(timeout).send().await.map_err(|e| {
            // Before the timeout test: a connect timeout is both, and it is the connection
            // that failed, within CONNECT_TIMEOUT rather than `timeout`.
            if e.is_connect() {
                self.no_connection(what, &e)
            } else if e.is_timeout() {
                self.timeout(what, timeout)
            } else {
                self.unreachable(what, &e)
            }
        })
    }

    fn take_challenge(&self, r: &reqwest::Response, what: &str) -> Result<()> {
        let auth_err = |reason: &str| ThetaError::Auth {
            what: what.into(),
            reason: reason.into(),
        };
        if self.credentials.is_none() {
            return Err(auth_err(
                "the THETA asks for a user and password (client mode)",
            ));
        }
        let header = r
            .headers()
            .get("WWW-Authenticate")
            .ok_or_else(|| auth_err("HTTP 401 without a WWW-Authenticate header"))?;
        let challenge = parse_challenge(header.as_bytes()).map_err(|e| auth_err(&e))?;
        *self.challenge.lock().unwrap_or_else(|p| p.into_inner()) = Some(challenge);
        Ok(())
    }

    fn authorization(
        &self,
        method: &Method,
        url: &Url,
        body: Option<&[u8]>,
    ) -> Result<Option<String>> {
        let mut guard = self.challenge.lock().unwrap_or_else(|p| p.into_inner());
        let (Some(c), Some(challenge)) = (&self.credentials, guard.as_mut()) else {
            return Ok(None);
        };
        let mut uri = url.path().to_string();
        if let Some(q) = url.query() {
            uri.push('?');
            uri.push_str(q);
        }
        let ctx = digest_auth::AuthContext::new_with_method(
            c.user.as_str(),
            c.password.as_str(),
            uri,
            body,
            method.as_str().into(),
        );
        challenge
            .respond(&ctx)
            .map(|h| Some(h.to_header_string()))
            .map_err(|e| ThetaError::Auth {
                what: url.path().into(),
                reason: format!("cannot answer the Digest challenge: {e}"),
            })
    }

    fn timeout(&self, what: &str, after: Duration) -> ThetaError {
        ThetaError::Timeout {
            what: what.into(),
            camera: self.base.to_string(),
            after,
        }
    }

    fn unreachable(&self, what: &str, e: &reqwest::Error) -> ThetaError {
        ThetaError::Unreachable {
            what: what.into(),
            camera: self.base.to_string(),
            reason: chain(e),
        }
    }

    fn no_connection(&self, what: &str, e: &reqwest::Error) -> ThetaError {
        // The innermost cause says it ("Connection refused (os error 111)"); reqwest's own
        // layers ("error sending request for url ...", "client error (Connect)") do not.
        let mut reason = causes(e).pop().unwrap_or_default();
        if reason.is_empty() || e.is_timeout() {
            let after = self.timeouts.request.min(CONNECT_TIMEOUT);
            reason = format!("no answer within {after:?}");
        }
        ThetaError::NoConnection {
            what: what.into(),
            camera: self.base.to_string(),
            reason,
        }
    }
}

/// reqwest's Display hides the cause (connection refused, reset, ...): the whole chain.
fn chain(e: &reqwest::Error) -> String {
    causes(e).join(": ")
}

/// `e`'s words, then each of its causes', outermost first.
fn causes(e: &reqwest::Error) -> Vec<String> {
    let mut all = vec![e.to_string()];
    let mut source = std::error::Error::source(e);
    while let Some(s) = source {
        all.push(s.to_string());
        source = s.source();
    }
    all
}

/// A `WWW-Authenticate` Digest challenge, as bytes off the network. digest_auth 0.3 panics on
/// a challenge that is not ASCII (the issue 20 fuzzer found it), so only visible ASCII (and
/// tabs) reaches it: a camera's challenge has no reason to hold anything else.
pub fn parse_challenge(
    header: &[u8],
) -> std::result::Result<digest_auth::WwwAuthenticateHeader, String> {
    let text = std::str::from_utf8(header)
        .ok()
        .filter(|h| h.bytes().all(|b| b == b'\t' || (b' '..=b'~').contains(&b)))
        .ok_or_else(|| {
            format!(
                "the Digest challenge is not ASCII text: {:?}",
                String::from_utf8_lossy(header)
            )
        })?;
    digest_auth::parse(text).map_err(|e| format!("cannot read the Digest challenge {text:?}: {e}"))
}

fn parse<T: serde::de::DeserializeOwned>(v: Value, what: &str) -> Result<T> {
    serde_json::from_value(v).map_err(|e| ThetaError::Malformed {
        what: what.into(),
        reason: e.to_string(),
    })
}

/// A command in state `error` (with HTTP 200, as `status` reports it) is an error too.
fn command_result(c: Command, what: &str) -> Result<Command> {
    if c.state != CommandState::Error {
        return Ok(c);
    }
    let e = c.error.unwrap_or(ErrorBody {
        code: error_code::UNEXPECTED.into(),
        message: "state error without an error object".into(),
    });
    Err(ThetaError::Command {
        what: what.into(),
        status: error_code::http_status(&e.code),
        code: e.code,
        message: e.message,
    })
}

fn api_error(v: &Value, what: &str, status: StatusCode) -> ThetaError {
    match v
        .get("error")
        .cloned()
        .map(serde_json::from_value::<ErrorBody>)
    {
        Some(Ok(e)) => ThetaError::Command {
            what: what.into(),
            code: e.code,
            message: e.message,
            status: status.as_u16(),
        },
        _ => ThetaError::Http {
            what: what.into(),
            status: status.as_u16(),
            body: v.to_string().chars().take(200).collect(),
        },
    }
}

async fn http_error(mut resp: reqwest::Response, what: &str) -> ThetaError {
    let status = resp.status();
    // Enough of the body to say what went wrong; an endless one is not read to its end.
    let mut body = Vec::new();
    while let Ok(Some(chunk)) = resp.chunk().await {
        body.extend_from_slice(&chunk);
        if body.len() > 64 << 10 {
            break;
        }
    }
    match serde_json::from_slice::<Value>(&body) {
        Ok(v) => api_error(&v, what, status),
        Err(_) => ThetaError::Http {
            what: what.into(),
            status: status.as_u16(),
            body: String::from_utf8_lossy(&body).chars().take(200).collect(),
        },
    }
}
