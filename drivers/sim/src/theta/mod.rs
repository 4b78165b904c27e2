//! A simulated RICOH THETA (a V, Z1 or X: [`ThetaModel`]) on the THETA Web API (OSC v2.1): a
//! real HTTP server on loopback with the camera's state machine, as the recorded responses in
//! `shared/data/theta/osc-fixtures/` show it:
//!
//! - `/osc/info`, `/osc/state`, `/osc/checkForUpdates`, `/osc/commands/execute`,
//!   `/osc/commands/status`, and the files under `/files/`;
//! - commands takePicture, startCapture (`_mode: bracket`, from `_autoBracket`), setOptions,
//!   getOptions, listFiles, delete, reset, with the API's validation and error codes;
//! - shots take time: a capture is `inProgress` (with its completion) until its frames are
//!   exposed, and the camera answers `disabledCommand` to another capture meanwhile;
//! - optional HTTP Digest, as a THETA in client mode asks for.
//!
//! Each frame comes from an [`ImageSource`] at the exposure asked for (the virtual bench's
//! panorama: an 8-bit equirectangular JPEG with EXIF). [`ThetaFaults`] injects what goes wrong
//! on a bench: 503s, slow answers, a connection dropped mid-download, a camera asleep.

mod digest;
mod models;

pub use models::ThetaModel;

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use axum::body::{Body, Bytes};
use axum::extract::State;
use axum::http::{HeaderMap, Method, StatusCode, Uri};
use axum::response::{IntoResponse, Response};
use brdfd_theta::osc::{self, error_code as ec, Command, CommandState, Progress};
use serde_json::{json, Map, Value};

use crate::{ImageSource, Shot};

/// The THETA V's shutter speeds as rationals (seconds = num/den), 1/25000 s to 60 s, from
/// RICOH's THETA USB API reference. The USB profile offers the same list as 0xD00F values.
pub const THETA_V_SHUTTERS: [(u32, u32); 61] = [
    (1, 25000),
    (1, 20000),
    (1, 16000),
    (1, 12500),
    (1, 10000),
    (1, 8000),
    (1, 6400),
    (1, 5000),
    (1, 4000),
    (1, 3200),
    (1, 2500),
    (1, 2000),
    (1, 1600),
    (1, 1250),
    (1, 1000),
    (1, 800),
    (1, 640),
    (1, 500),
    (1, 400),
    (1, 320),
    (1, 250),
    (1, 200),
    (1, 160),
    (1, 125),
    (1, 100),
    (1, 80),
    (1, 60),
    (1, 50),
    (1, 40),
    (1, 30),
    (1, 25),
    (1, 20),
    (1, 15),
    (1, 13),
    (1, 10),
    (1, 8),
    (1, 6),
    (1, 5),
    (1, 4),
    (1, 3),
    (10, 25),
    (1, 2),
    (10, 16),
    (10, 13),
    (1, 1),
    (13, 10),
    (16, 10),
    (2, 1),
    (25, 10),
    (32, 10),
    (4, 1),
    (5, 1),
    (6, 1),
    (8, 1),
    (10, 1),
    (13, 1),
    (15, 1),
    (20, 1),
    (25, 1),
    (30, 1),
    (60, 1),
];
/// The THETA V's fixed aperture.
pub const THETA_V_F_NUMBER: f64 = 2.0;
const STORAGE: &str = "744a605553442020104b8a2304010a01";
/// Nonces the camera accepts at once (a new one per challenge).
const NONCES_KEPT: usize = 16;

/// Identity and timing of the simulated camera.
#[derive(Debug, Clone)]
pub struct ThetaConfig {
    pub model: ThetaModel,
    pub serial: String,
    pub firmware: String,
    /// (user, password) for HTTP Digest; None answers without authentication (access-point
    /// mode).
    pub credentials: Option<(String, String)>,
    /// Time to expose and stitch one frame (a THETA V takes about 1 s; tests use less).
    pub shot_time: Duration,
}

impl ThetaConfig {
    /// A `model` with its firmware.
    pub fn of(model: ThetaModel) -> ThetaConfig {
        ThetaConfig {
            model,
            serial: "00165759".into(),
            firmware: model.firmware().into(),
            credentials: None,
            shot_time: Duration::from_millis(150),
        }
    }
}

impl Default for ThetaConfig {
    /// A THETA V.
    fn default() -> Self {
        ThetaConfig::of(ThetaModel::V)
    }
}

/// Faults to inject; each is used up as it fires.
#[derive(Debug, Clone, Default)]
pub struct ThetaFaults {
    /// Answer the next N requests with 503 serviceUnavailable.
    pub unavailable: u32,
    /// Delay the next N responses by the duration.
    pub slow: Option<(u32, Duration)>,
    /// Drop the connection after this many bytes of the next file download.
    pub drop_download_after: Option<usize>,
    /// The camera is asleep: the next request wakes it, and for this long every request is
    /// answered 503 while it wakes.
    pub asleep_for: Option<Duration>,
    /// Report file URLs on another host (a confused or hostile network): clients must refuse.
    pub foreign_file_urls: bool,
}

struct Job {
    command: Command,
}

struct CameraState {
    options: Map<String, Value>,
    files: BTreeMap<u32, Vec<u8>>,
    next_file: u32,
    jobs: BTreeMap<String, Job>,
    next_job: u32,
    /// The capture job running, if any.
    busy: Option<String>,
    fingerprint: u32,
    shots: u32,
    nonces: Vec<String>,
    waking_until: Option<Instant>,
    started: Instant,
    faults: ThetaFaults,
    log: Vec<String>,
}

struct Shared {
    camera: Mutex<CameraState>,
    source: Arc<dyn ImageSource>,
    config: ThetaConfig,
    addr: SocketAddr,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, CameraState> {
        // A panic while holding the lock leaves consistent data (every update is one
        // assignment), so a poisoned lock is still usable.
        self.camera.lock().unwrap_or_else(|p| p.into_inner())
    }
}

/// The simulated THETA's HTTP server. It runs on its own thread and runtime, and stops when
/// dropped.
pub struct OscServer {
    pub addr: SocketAddr,
    shared: Arc<Shared>,
    shutdown: Option<tokio::sync::oneshot::Sender<()>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl OscServer {
    /// Listens on `addr` (port 0 picks one) and serves until stopped.
    pub fn start(
        addr: &str,
        source: Arc<dyn ImageSource>,
        config: ThetaConfig,
    ) -> std::io::Result<OscServer> {
        let listener = std::net::TcpListener::bind(addr)?;
        listener.set_nonblocking(true)?;
        let addr = listener.local_addr()?;
        let shared = Arc::new(Shared {
            camera: Mutex::new(CameraState::new(config.model)),
            source,
            config,
            addr,
        });
        let (tx, rx) = tokio::sync::oneshot::channel::<()>();
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()?;
        let app = axum::Router::new()
            .fallback(handle)
            .with_state(shared.clone());
        let thread = std::thread::Builder::new()
            .name("sim-theta-http".into())
            .spawn(move || {
                runtime.block_on(async move {
                    let listener = match tokio::net::TcpListener::from_std(listener) {
                        Ok(l) => l,
                        Err(e) => {
                            tracing::error!("simulated THETA: {e}");
                            return;
                        }
                    };
                    let serve = axum::serve(listener, app).with_graceful_shutdown(async {
                        let _ = rx.await;
                    });
                    if let Err(e) = serve.await {
                        tracing::error!("simulated THETA: {e}");
                    }
                })
            })?;
        Ok(OscServer {
            addr,
            shared,
            shutdown: Some(tx),
            thread: Some(thread),
        })
    }

    /// `http://ADDR`, the base a client connects to.
    pub fn url(&self) -> String {
        format!("http://{}", self.addr)
    }

    /// Sets faults for the next requests.
    pub fn inject(&self, faults: ThetaFaults) {
        self.shared.lock().faults = faults;
    }

    /// What the camera saw: a `METHOD /path` line per request, followed by an indented
    /// `  execute camera.x` line for each command and `  401 challenge` for each Digest
    /// challenge sent.
    pub fn log(&self) -> Vec<String> {
        self.shared.lock().log.clone()
    }

    /// Current value of an option, as a client would read it.
    pub fn option(&self, name: &str) -> Option<Value> {
        self.shared.lock().options.get(name).cloned()
    }

    /// Frames shot since the camera started.
    pub fn shots(&self) -> u32 {
        self.shared.lock().shots
    }

    /// Files on the camera.
    pub fn file_count(&self) -> usize {
        self.shared.lock().files.len()
    }

    pub fn stop(&mut self) {
        if let Some(tx) = self.shutdown.take() {
            let _ = tx.send(());
        }
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for OscServer {
    fn drop(&mut self) {
        self.stop();
    }
}

impl CameraState {
    fn new(model: ThetaModel) -> CameraState {
        let shutters: Vec<f64> = model
            .shutters()
            .iter()
            .map(|&(n, d)| n as f64 / d as f64)
            .collect();
        let formats = model.image_formats();
        let mut options = json!({
            "captureMode": "image",
            "captureModeSupport": ["image", "_video", "_liveStreaming"],
            "exposureProgram": 2,
            "exposureProgramSupport": [1, 2, 4, 9],
            "shutterSpeed": 0.0,
            "shutterSpeedSupport": shutters,
            "iso": 0,
            "isoSupport": model.isos(),
            "aperture": model.aperture(),
            "apertureSupport": model.apertures(),
            "whiteBalance": "auto",
            "_colorTemperature": 5000,
            "exposureCompensation": 0.0,
            "exposureDelay": 0,
            "offDelay": 600,
            "sleepDelay": 180,
            "_filter": "off",
            "_filterSupport": model.filters(),
            "_autoBracket": {
                "_bracketNumber": 3,
                "_bracketParameters": [
                    {"shutterSpeed": 0.004, "iso": 100, "exposureProgram": 1, "whiteBalance": "auto", "_colorTemperature": 5000},
                    {"shutterSpeed": 0.016, "iso": 100, "exposureProgram": 1, "whiteBalance": "auto", "_colorTemperature": 5000},
                    {"shutterSpeed": 0.0625, "iso": 100, "exposureProgram": 1, "whiteBalance": "auto", "_colorTemperature": 5000}
                ]
            },
            "remainingPictures": 4883,
            "fileFormat": formats[0],
            "fileFormatSupport": formats,
        });
        if let Some(functions) = model.functions() {
            options["_function"] = json!("normal");
            options["_functionSupport"] = json!(functions);
        }
        CameraState {
            options: options.as_object().cloned().unwrap_or_default(),
            files: BTreeMap::new(),
            next_file: 10001,
            jobs: BTreeMap::new(),
            next_job: 1,
            busy: None,
            fingerprint: 1,
            shots: 0,
            nonces: Vec::new(),
            waking_until: None,
            started: Instant::now(),
            faults: ThetaFaults::default(),
            log: Vec::new(),
        }
    }

    fn file_url(&self, addr: SocketAddr, n: u32) -> String {
        let host = if self.faults.foreign_file_urls {
            // TEST-NET-1 (RFC 5737): never routed; the client must refuse before connecting.
            "192.0.2.1".to_string()
        } else {
            addr.to_string()
        };
        format!("http://{host}/files/{STORAGE}/100RICOH/R{n:07}.JPG")
    }

    fn capture_status(&self) -> &'static str {
        match self.busy.as_ref().and_then(|id| self.jobs.get(id)) {
            Some(j) if j.command.name == "camera.startCapture" => "bracket shooting",
            Some(_) => "shooting",
            None => "idle",
        }
    }
}

fn error_response(name: &str, code: &str, message: &str) -> Response {
    let status =
        StatusCode::from_u16(osc::error_code::http_status(code)).unwrap_or(StatusCode::BAD_REQUEST);
    (status, axum::Json(Command::failed(name, code, message))).into_response()
}

fn json_response(v: impl serde::Serialize) -> Response {
    axum::Json(v).into_response()
}

async fn handle(
    State(sh): State<Arc<Shared>>,
    method: Method,
    uri: Uri,
    headers: HeaderMap,
    body: Bytes,
) -> Response {
    let path = uri.path().to_string();
    let delay = {
        let mut cam = sh.lock();
        cam.log.push(format!("{method} {path}"));
        match cam.faults.slow {
            Some((n, d)) if n > 0 => {
                cam.faults.slow = if n > 1 { Some((n - 1, d)) } else { None };
                Some(d)
            }
            _ => None,
        }
    };
    if let Some(d) = delay {
        tokio::time::sleep(d).await;
    }
    if let Some(r) = check_auth(&sh, &method, &uri, &headers) {
        return r;
    }
    {
        let mut cam = sh.lock();
        if let Some(d) = cam.faults.asleep_for.take() {
            tracing::info!("simulated THETA: waking from sleep ({d:?})");
            cam.waking_until = Some(Instant::now() + d);
        }
        let waking = cam.waking_until.is_some_and(|t| Instant::now() < t);
        if waking || cam.faults.unavailable > 0 {
            cam.faults.unavailable = cam.faults.unavailable.saturating_sub(1);
            let why = if waking {
                "the camera is waking from sleep"
            } else {
                "processing requests cannot be received temporarily"
            };
            return error_response("", ec::SERVICE_UNAVAILABLE, why);
        }
    }
    match (method.as_str(), path.as_str()) {
        ("GET", "/osc/info") => info(&sh),
        ("POST", "/osc/state") => state(&sh),
        ("POST", "/osc/checkForUpdates") => {
            let fp = sh.lock().fingerprint;
            json_response(osc::Updates {
                state_fingerprint: format!("FIG_{fp:04}"),
                throttle_timeout: 60,
            })
        }
        ("POST", "/osc/commands/execute") => execute(&sh, &body),
        ("POST", "/osc/commands/status") => status(&sh, &body),
        ("GET", p) if p.starts_with("/files/") => file(&sh, p),
        _ => error_response(
            "",
            "notFound",
            &format!("no {method} {path} on this camera"),
        ),
    }
}

fn check_auth(sh: &Shared, method: &Method, uri: &Uri, headers: &HeaderMap) -> Option<Response> {
    let (user, password) = sh.config.credentials.as_ref()?;
    let realm = sh.config.model.name();
    let mut cam = sh.lock();
    let given = headers
        .get("authorization")
        .and_then(|h| h.to_str().ok())
        .and_then(digest::parse_authorization);
    let target = uri
        .path_and_query()
        .map(|p| p.as_str().to_string())
        .unwrap_or_default();
    if let Some(f) = &given {
        let nonce = f.get("nonce").cloned().unwrap_or_default();
        if cam.nonces.contains(&nonce) {
            match digest::verify(f, method.as_str(), &target, realm, user, password, &nonce) {
                Ok(()) => return None,
                Err(why) => tracing::info!("simulated THETA: Digest refused: {why}"),
            }
        }
    }
    // A fresh challenge; the nonce is unguessable enough for a simulator, and unique.
    let nonce = format!(
        "{:016x}{:08x}",
        cam.started.elapsed().as_nanos() as u64 ^ 0x5deece66d,
        cam.nonces.len() as u32 + cam.fingerprint
    );
    cam.log.push("  401 challenge".into());
    cam.nonces.push(nonce.clone());
    if cam.nonces.len() > NONCES_KEPT {
        cam.nonces.remove(0);
    }
    let challenge =
        format!(r#"Digest realm="{realm}", nonce="{nonce}", qop="auth", algorithm=MD5"#);
    Some(
        (
            StatusCode::UNAUTHORIZED,
            [("WWW-Authenticate", challenge)],
            "401 Unauthorized",
        )
            .into_response(),
    )
}

fn info(sh: &Shared) -> Response {
    let uptime = sh.lock().started.elapsed().as_secs();
    let c = &sh.config;
    json_response(osc::Info {
        manufacturer: "RICOH".into(),
        model: c.model.name().into(),
        serial_number: c.serial.clone(),
        firmware_version: c.firmware.clone(),
        support_url: "https://theta360.com/en/support/".into(),
        api_level: vec![2],
        endpoints: osc::Endpoints {
            http_port: sh.addr.port(),
            http_updates_port: sh.addr.port(),
        },
        gps: c.model.gps(),
        gyro: true,
        uptime,
        api: [
            "/osc/info",
            "/osc/state",
            "/osc/checkForUpdates",
            "/osc/commands/execute",
            "/osc/commands/status",
        ]
        .map(String::from)
        .to_vec(),
    })
}

fn state(sh: &Shared) -> Response {
    let cam = sh.lock();
    let latest = cam
        .files
        .keys()
        .next_back()
        .map(|&n| cam.file_url(sh.addr, n));
    json_response(osc::StateResponse {
        fingerprint: format!("FIG_{:04}", cam.fingerprint),
        state: osc::CameraState {
            battery_level: 0.98,
            storage_uri: Some(format!("http://{}/files/{STORAGE}/", sh.addr)),
            capture_status: cam.capture_status().into(),
            latest_file_url: Some(latest.unwrap_or_default()),
            camera_error: Vec::new(),
            api_version: 2,
            battery_state: Some("charging".into()),
            extra: Map::new(),
        },
    })
}

fn execute(sh: &Arc<Shared>, body: &[u8]) -> Response {
    let Ok(req) = serde_json::from_slice::<Value>(body) else {
        return error_response("", ec::INVALID_PARAMETER_VALUE, "the body is not JSON");
    };
    let name = req
        .get("name")
        .and_then(Value::as_str)
        .unwrap_or("")
        .to_string();
    let params = req.get("parameters").cloned().unwrap_or(json!({}));
    sh.lock().log.push(format!("  execute {name}"));
    match name.as_str() {
        "camera.getOptions" => get_options(sh, &name, &params),
        "camera.setOptions" => set_options(sh, &name, &params),
        "camera.takePicture" => start_capture_job(sh, &name, 1),
        "camera.startCapture" => {
            if params.get("_mode").and_then(Value::as_str) != Some("bracket") {
                return error_response(
                    &name,
                    ec::INVALID_PARAMETER_VALUE,
                    "this simulator shoots only _mode bracket",
                );
            }
            let n = sh.lock().options["_autoBracket"]["_bracketNumber"]
                .as_u64()
                .unwrap_or(0);
            start_capture_job(sh, &name, n as usize)
        }
        "camera.listFiles" => list_files(sh, &name, &params),
        "camera.delete" => delete(sh, &name, &params),
        "camera.reset" => {
            let mut cam = sh.lock();
            if cam.busy.is_some() {
                return error_response(&name, ec::DISABLED_COMMAND, "shooting");
            }
            cam.options = CameraState::new(sh.config.model).options;
            cam.fingerprint += 1;
            json_response(Command::done(&name, None))
        }
        "" => error_response(&name, ec::MISSING_PARAMETER, "no command name"),
        _ => error_response(&name, ec::UNKNOWN_COMMAND, "command executed is unknown"),
    }
}

fn get_options(sh: &Shared, name: &str, params: &Value) -> Response {
    let Some(names) = params.get("optionNames").and_then(Value::as_array) else {
        return error_response(name, ec::MISSING_PARAMETER, "optionNames");
    };
    let cam = sh.lock();
    let mut out = Map::new();
    for n in names {
        let key = n.as_str().unwrap_or("");
        match cam.options.get(key) {
            Some(v) => out.insert(key.to_string(), v.clone()),
            None => {
                return error_response(name, ec::INVALID_PARAMETER_NAME, &format!("option {key}"))
            }
        };
    }
    json_response(Command::done(name, Some(json!({ "options": out }))))
}

/// Checks one option value the way the camera does; Err is the message of an
/// invalidParameterValue.
fn validate_option(
    model: ThetaModel,
    key: &str,
    v: &Value,
    options: &Map<String, Value>,
) -> Result<(), String> {
    let in_support = |support: &str, x: f64| {
        options[support].as_array().is_some_and(|a| {
            a.iter().any(|s| {
                s.as_f64()
                    .is_some_and(|s| (s - x).abs() <= 1e-9 * s.max(1.0))
            })
        })
    };
    match key {
        "captureMode" => matches!(v.as_str(), Some("image" | "_video" | "_liveStreaming"))
            .then_some(())
            .ok_or("captureMode".into()),
        "exposureProgram" => matches!(v.as_u64(), Some(1 | 2 | 4 | 9))
            .then_some(())
            .ok_or("exposureProgram".into()),
        "shutterSpeed" => match v.as_f64() {
            Some(s) if s == 0.0 || in_support("shutterSpeedSupport", s) => Ok(()),
            _ => Err(format!("shutterSpeed {v}")),
        },
        "iso" => match v.as_f64() {
            Some(i) if i == 0.0 || in_support("isoSupport", i) => Ok(()),
            _ => Err(format!("iso {v}")),
        },
        "offDelay" | "sleepDelay" => match v.as_u64() {
            Some(65535) | Some(60..=65534) => Ok(()),
            _ => Err(format!("{key} {v}")),
        },
        "_filter" | "_function" | "fileFormat" => options[&format!("{key}Support")]
            .as_array()
            .is_some_and(|a| a.contains(v))
            .then_some(())
            .ok_or(format!("{key} {v} (not on a {})", model.name())),
        "aperture" => match v.as_f64() {
            Some(a) if a == 0.0 || in_support("apertureSupport", a) => Ok(()),
            _ => Err(format!("aperture {v} (not on a {})", model.name())),
        },
        "exposureDelay" => match v.as_u64() {
            Some(0..=10) => Ok(()),
            _ => Err(format!("exposureDelay {v}")),
        },
        "_autoBracket" => {
            let b: osc::AutoBracket =
                serde_json::from_value(v.clone()).map_err(|e| format!("_autoBracket: {e}"))?;
            let most = model.max_bracket();
            if !(2..=most).contains(&(b.number as u64)) || b.parameters.len() != b.number as usize {
                return Err(format!(
                    "_autoBracket: {} shots with {} parameter sets (2 to {most} on a {})",
                    b.number,
                    b.parameters.len(),
                    model.name()
                ));
            }
            for p in &b.parameters {
                if !in_support("shutterSpeedSupport", p.shutter_speed)
                    || !in_support("isoSupport", p.iso as f64)
                {
                    return Err(format!(
                        "_autoBracket: shutterSpeed {} iso {} not supported",
                        p.shutter_speed, p.iso
                    ));
                }
                // The X's bracket shoots in manual exposure only.
                if model == ThetaModel::X && p.exposure_program.is_some_and(|e| e != 1) {
                    return Err("_autoBracket: exposureProgram other than 1 on a THETA X".into());
                }
                if p.aperture
                    .is_some_and(|a| !in_support("apertureSupport", a))
                {
                    return Err(format!("_autoBracket: aperture {:?}", p.aperture));
                }
            }
            Ok(())
        }
        _ => Ok(()),
    }
}

fn set_options(sh: &Shared, name: &str, params: &Value) -> Response {
    let Some(opts) = params.get("options").and_then(Value::as_object) else {
        return error_response(name, ec::MISSING_PARAMETER, "options");
    };
    let mut cam = sh.lock();
    if cam.busy.is_some() {
        return error_response(name, ec::DISABLED_COMMAND, "the camera is shooting");
    }
    // RICOH's reference: setting `_function` together with exposureDelay is an error.
    if opts.contains_key("_function") && opts.contains_key("exposureDelay") {
        return error_response(
            name,
            ec::INVALID_PARAMETER_VALUE,
            "_function and exposureDelay in one setOptions",
        );
    }
    for (key, v) in opts {
        if !cam.options.contains_key(key) || key.ends_with("Support") {
            return error_response(name, ec::INVALID_PARAMETER_NAME, &format!("option {key}"));
        }
        if let Err(m) = validate_option(sh.config.model, key, v, &cam.options) {
            return error_response(name, ec::INVALID_PARAMETER_VALUE, &m);
        }
    }
    for (key, v) in opts {
        cam.options.insert(key.clone(), v.clone());
    }
    cam.fingerprint += 1;
    json_response(Command::done(name, None))
}

/// The exposures of a capture: the bracket's parameters, or the single-shot options (auto
/// exposure shoots 1/100 s at ISO 100).
fn planned_shots(options: &Map<String, Value>, name: &str, n: usize) -> Vec<(f64, u32)> {
    if name == "camera.startCapture" {
        return options["_autoBracket"]["_bracketParameters"]
            .as_array()
            .map(|a| {
                a.iter()
                    .take(n)
                    .map(|p| {
                        (
                            p["shutterSpeed"].as_f64().unwrap_or(0.01),
                            p["iso"].as_u64().unwrap_or(100) as u32,
                        )
                    })
                    .collect()
            })
            .unwrap_or_default();
    }
    let manual = options["exposureProgram"].as_u64() == Some(1);
    let shutter = options["shutterSpeed"]
        .as_f64()
        .filter(|s| manual && *s > 0.0);
    let iso = options["iso"].as_u64().filter(|i| manual && *i > 0);
    vec![(shutter.unwrap_or(0.01), iso.unwrap_or(100) as u32)]
}

fn start_capture_job(sh: &Arc<Shared>, name: &str, n: usize) -> Response {
    let mut cam = sh.lock();
    if cam.busy.is_some() {
        return error_response(name, ec::DISABLED_COMMAND, "the camera is shooting");
    }
    if cam.options["captureMode"].as_str() != Some("image") {
        return error_response(name, ec::DISABLED_COMMAND, "not in still-image mode");
    }
    let shots = planned_shots(&cam.options, name, n);
    if shots.is_empty() {
        return error_response(name, ec::INVALID_PARAMETER_VALUE, "no bracket parameters");
    }
    let id = cam.next_job.to_string();
    cam.next_job += 1;
    let command = Command {
        name: name.into(),
        state: CommandState::InProgress,
        id: Some(id.clone()),
        results: None,
        error: None,
        progress: Some(Progress { completion: 0.0 }),
    };
    cam.jobs.insert(
        id.clone(),
        Job {
            command: command.clone(),
        },
    );
    cam.busy = Some(id.clone());
    cam.fingerprint += 1;
    drop(cam);
    let worker = sh.clone();
    let name = name.to_string();
    std::thread::spawn(move || run_capture(&worker, &id, &name, &shots));
    json_response(command)
}

/// Exposes the frames one after another in real time and stores them, updating the job's
/// progress; the job is done when the last frame is stored.
fn run_capture(sh: &Shared, id: &str, name: &str, shots: &[(f64, u32)]) {
    let mut urls = Vec::new();
    let f_number = sh.lock().options["aperture"]
        .as_f64()
        .filter(|a| *a > 0.0)
        .unwrap_or(sh.config.model.aperture());
    for (i, &(shutter_s, iso)) in shots.iter().enumerate() {
        std::thread::sleep(sh.config.shot_time);
        let sequence = sh.lock().shots + 1;
        let shot = Shot {
            shutter_s,
            f_number,
            iso,
            raw: false,
            sequence,
        };
        let photo = sh.source.photo(&shot);
        let mut cam = sh.lock();
        cam.shots += 1;
        let data = match photo {
            Ok(d) => d,
            Err(e) => {
                tracing::error!("simulated THETA: image source failed: {e}");
                if let Some(j) = cam.jobs.get_mut(id) {
                    j.command = Command::failed(name, ec::UNEXPECTED, &e);
                    j.command.id = Some(id.into());
                }
                cam.busy = None;
                return;
            }
        };
        let n = cam.next_file;
        cam.next_file += 1;
        cam.files.insert(n, data);
        urls.push(cam.file_url(sh.addr, n));
        if let Some(j) = cam.jobs.get_mut(id) {
            j.command.progress = Some(Progress {
                completion: (i + 1) as f64 / shots.len() as f64,
            });
        }
    }
    let mut cam = sh.lock();
    let results = if name == "camera.takePicture" {
        json!({ "fileUrl": urls.first() })
    } else {
        json!({ "fileUrls": urls })
    };
    if let Some(j) = cam.jobs.get_mut(id) {
        j.command = Command::done(name, Some(results));
        j.command.id = Some(id.into());
    }
    cam.busy = None;
    cam.fingerprint += 1;
}

fn status(sh: &Shared, body: &[u8]) -> Response {
    let id = serde_json::from_slice::<Value>(body)
        .ok()
        .and_then(|v| v.get("id").cloned())
        .map(|v| {
            v.as_str()
                .map(String::from)
                .unwrap_or_else(|| v.to_string())
        });
    let Some(id) = id else {
        return error_response("", ec::MISSING_PARAMETER, "id");
    };
    let cam = sh.lock();
    match cam.jobs.get(&id) {
        Some(j) => json_response(&j.command),
        None => error_response("", ec::INVALID_PARAMETER_VALUE, &format!("no command {id}")),
    }
}

fn list_files(sh: &Shared, name: &str, params: &Value) -> Response {
    let count = params.get("entryCount").and_then(Value::as_u64);
    let Some(count) = count else {
        return error_response(name, ec::MISSING_PARAMETER, "entryCount");
    };
    let start = params
        .get("startPosition")
        .and_then(Value::as_u64)
        .unwrap_or(0);
    let cam = sh.lock();
    let entries: Vec<osc::FileEntry> = cam
        .files
        .iter()
        .rev()
        .skip(start as usize)
        .take(count as usize)
        .map(|(&n, data)| osc::FileEntry {
            name: format!("R{n:07}.JPG"),
            file_url: cam.file_url(sh.addr, n),
            size: data.len() as u64,
            date_time_zone: "2026:11:22 12:00:00+00:00".into(),
            width: sh.source.dimensions().0,
            height: sh.source.dimensions().1,
            projection_type: Some("Equirectangular".into()),
        })
        .collect();
    json_response(Command::done(
        name,
        Some(json!({ "entries": entries, "totalEntries": cam.files.len() })),
    ))
}

fn file_number(path: &str) -> Option<u32> {
    let file = path.rsplit('/').next()?;
    file.strip_prefix('R')?.strip_suffix(".JPG")?.parse().ok()
}

fn delete(sh: &Shared, name: &str, params: &Value) -> Response {
    let Some(urls) = params.get("fileUrls").and_then(Value::as_array) else {
        return error_response(name, ec::MISSING_PARAMETER, "fileUrls");
    };
    let mut cam = sh.lock();
    let mut numbers = Vec::new();
    for u in urls {
        match u.as_str() {
            Some("all" | "image") => numbers.extend(cam.files.keys().copied()),
            Some(u) => match file_number(u).filter(|n| cam.files.contains_key(n)) {
                Some(n) => numbers.push(n),
                None => {
                    return error_response(
                        name,
                        ec::INVALID_PARAMETER_VALUE,
                        &format!("no file {u}"),
                    )
                }
            },
            None => return error_response(name, ec::INVALID_PARAMETER_VALUE, "fileUrls"),
        }
    }
    for n in numbers {
        cam.files.remove(&n);
    }
    cam.fingerprint += 1;
    json_response(Command::done(name, None))
}

fn file(sh: &Shared, path: &str) -> Response {
    let mut cam = sh.lock();
    let Some(data) = file_number(path).and_then(|n| cam.files.get(&n)).cloned() else {
        return error_response("", "notFound", &format!("no file {path}"));
    };
    let len = data.len();
    let body = match cam.faults.drop_download_after.take() {
        Some(cut) => {
            tracing::info!("simulated THETA: dropping the connection after {cut} of {len} bytes");
            let head = Bytes::from(data[..cut.min(len)].to_vec());
            let chunks: Vec<Result<Bytes, std::io::Error>> = vec![
                Ok(head),
                Err(std::io::Error::new(
                    std::io::ErrorKind::ConnectionReset,
                    "simulated drop",
                )),
            ];
            Body::from_stream(futures_util::stream::iter(chunks))
        }
        None => Body::from(data),
    };
    (
        [
            ("Content-Type", "image/jpeg".to_string()),
            ("Content-Length", len.to_string()),
        ],
        body,
    )
        .into_response()
}
