//! brdfd-daemon, `brdfd serve`: the long-running daemon. It sits above the rig
//! (`brdfd-rig`) and below the binary (docs/architecture.md). It owns the rig's devices (one worker thread
//! each, kept alive and re-opened; see [`brdfd_rig::worker`]), runs one capture at a time
//! on them, and serves the HTTP API of [`api`] on tokio, and a web page ([`web`]).
//!
//! A capture runs on a thread of its own, because the flow and the devices block; the async
//! side only starts it, relays its events and answers questions.

pub mod api;
pub mod openapi;
pub mod server;
pub mod throttle;
pub mod web;

use std::collections::VecDeque;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

use brdfd_rig::error::said;
use brdfd_rig::error::{RigError, StepExt};
use tokio::sync::broadcast;

use brdfd_rig::config::Rig;
use brdfd_rig::flow::{self, Context};
use brdfd_rig::session::{Session, State};
use brdfd_rig::settings::CaptureSettings;
use brdfd_rig::{Cancel, Devices, Event, GoAhead, Plan};

/// Events of one session: everything so far, and a channel for what comes next. A client
/// that connects late gets the history first, so no event is missed. An event's id is
/// `RUN-N`: this log's run and the event's place in it (0 for the first). The event stream
/// sends it, so that a client that reconnects with `Last-Event-ID` resumes after the last
/// event it saw; an id of another run (the session resumed since, or a daemon restarted)
/// resumes nothing, and the client gets this run's events from the first.
pub struct EventLog {
    /// Unique among the logs this daemon makes, and unlike any earlier daemon's.
    run: u64,
    history: Mutex<Vec<Event>>,
    live: broadcast::Sender<(usize, Event)>,
}

impl EventLog {
    fn new() -> Arc<EventLog> {
        use std::sync::atomic::{AtomicU64, Ordering};
        static NEXT: AtomicU64 = AtomicU64::new(0);
        let started = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_micros() as u64);
        Arc::new(EventLog {
            run: started.wrapping_add(NEXT.fetch_add(1, Ordering::Relaxed)),
            history: Mutex::new(Vec::new()),
            live: broadcast::channel(1024).0,
        })
    }

    /// This log's run: the event stream's ids are `RUN-N`.
    pub fn run(&self) -> u64 {
        self.run
    }

    /// Where a stream resumes for a client's `Last-Event-ID`: after it if it is this run's,
    /// else from the first event.
    pub fn resume_from(&self, last_event_id: Option<&str>) -> usize {
        last_event_id
            .and_then(|id| id.trim().split_once('-'))
            .filter(|(run, _)| run.parse::<u64>().ok() == Some(self.run))
            .and_then(|(_, n)| n.parse::<usize>().ok())
            .map_or(0, |n| n.saturating_add(1))
    }

    fn push(&self, e: Event) {
        // Pushed and sent under one lock, so that `subscribe` sees each event exactly once.
        let mut h = self.history.lock().expect("event log");
        let id = h.len();
        h.push(e.clone());
        let _ = self.live.send((id, e));
    }

    /// Whether the session has sent its last event, `Finished`.
    fn finished(&self) -> bool {
        let h = self.history.lock().expect("event log");
        matches!(h.last(), Some(Event::Finished { .. }))
    }

    /// The phases under way ([`Event::under_way`]).
    fn under_way(&self) -> Vec<String> {
        Event::under_way(&self.history.lock().expect("event log"))
    }

    /// The history so far and a receiver for every later event, with its id.
    pub fn subscribe(&self) -> (Vec<Event>, broadcast::Receiver<(usize, Event)>) {
        let h = self.history.lock().expect("event log");
        (h.clone(), self.live.subscribe())
    }
}

/// The capture running now.
struct Running {
    id: String,
    cancel: Cancel,
    /// The operator's go-ahead, for a capture that waits for the object to be turned by hand.
    go_ahead: GoAhead,
    thread: JoinHandle<()>,
    log: Arc<EventLog>,
}

impl Running {
    /// Over once its session has sent `Finished`, the flow's last act, and not only once the
    /// thread has ended a moment later: a client that saw `Finished` must find the daemon
    /// idle (a cancel then is `not_running`, a new capture is not `busy`).
    fn over(&self) -> bool {
        self.thread.is_finished() || self.log.finished()
    }
}

pub struct Daemon {
    pub rig: Rig,
    rig_text: String,
    devices: Arc<Devices>,
    pub state_dir: PathBuf,
    /// The state directory's paths, as the API's words leave them out.
    hidden: Hidden,
    pub token: Option<String>,
    /// Host names the API answers to besides IP addresses and `localhost` (brdfd.toml's
    /// `hosts`).
    pub hosts: Vec<String>,
    running: Mutex<Option<Running>>,
    /// Failures the manifest could not record yet (issue 20, D10), by session id: retried
    /// until written, and shown by the API meanwhile.
    unrecorded: Unrecorded,
    /// Set when the daemon stops: ends the retries of [`Daemon::unrecorded`].
    stopping: Cancel,
    /// Event logs of the latest captures, oldest first (a stored session older than these
    /// streams its outcome alone).
    events: Mutex<VecDeque<(String, Arc<EventLog>)>>,
    /// Event streams open now, and how many may be ([`Daemon::max_event_streams`]).
    pub(crate) event_streams: Arc<std::sync::atomic::AtomicUsize>,
    /// Event streams at most, below the server's connection cap (`serve` sets it to half of
    /// that, at most [`MAX_EVENT_STREAMS`]): streams stay open for a whole capture, and must
    /// leave connections for `/health` and a cancel.
    pub max_event_streams: usize,
    /// Wrong tokens per address, and the lockouts they earn.
    pub(crate) throttle: throttle::Throttle,
}

/// Event streams at most, whatever the connection cap: a bench has a few clients.
pub const MAX_EVENT_STREAMS: usize = 64;

/// The state directory's folder of scene files (environment maps, NBRDF files) that a
/// simulated capture through the daemon may name.
pub const SCENES_DIR: &str = "scenes";

/// The scene file `name` of the plan's field `what`: a bare file name, found as a regular
/// file in `state`'s [`SCENES_DIR`].
fn scene_file(
    state: &std::path::Path,
    what: &str,
    name: &std::path::Path,
) -> Result<PathBuf, RigError> {
    use std::path::Component;
    let dir = state.join(SCENES_DIR);
    let mut parts = name.components();
    // The messages reach API clients: they name the folder as the state directory's, never by
    // its absolute path on this machine.
    if !matches!(
        (parts.next(), parts.next()),
        (Some(Component::Normal(_)), None)
    ) {
        return Err(RigError::invalid(format!(
            "`{what}` must name a file in the daemon's {SCENES_DIR} folder, not give a path: {:?}",
            name.display().to_string()
        )));
    }
    let path = dir.join(name);
    let meta = std::fs::metadata(&path).map_err(|e| {
        RigError::invalid(format!(
            "`{what}`: no file {:?} in the daemon's {SCENES_DIR} folder ({})",
            name.display().to_string(),
            e.kind()
        ))
    })?;
    if !meta.is_file() {
        return Err(RigError::invalid(format!(
            "`{what}`: {:?} in the daemon's {SCENES_DIR} folder is not a regular file",
            name.display().to_string()
        )));
    }
    Ok(path)
}

/// A plan's scene files are named, never given as paths: a name has no `/` (the pattern the
/// API's description gives `env` and `nbrdf`). A name of that shape that is no file in the
/// folder (`..`, say) is refused when it is looked up ([`scene_file`]).
fn scene_names(plan: &Plan) -> Result<(), String> {
    for (what, file) in [("env", &plan.env), ("nbrdf", &plan.nbrdf)] {
        if let Some(name) = file {
            let name = name.to_string_lossy();
            if name.is_empty() || name.contains('/') {
                return Err(format!(
                    "`{what}` must name a file in the daemon's {SCENES_DIR} folder, not give a path: {name:?}"
                ));
            }
        }
    }
    Ok(())
}

/// The state directory's path as given and as resolved, which what the API says leaves out:
/// no answer tells a client where this machine keeps its files. Resolved once, when the daemon
/// starts.
#[derive(Clone, Debug)]
struct Hidden {
    given: String,
    resolved: String,
}

impl Hidden {
    fn of(state_dir: &std::path::Path) -> Hidden {
        let given = state_dir.display().to_string();
        let resolved = std::fs::canonicalize(state_dir)
            .map(|p| p.display().to_string())
            .unwrap_or_else(|_| given.clone());
        Hidden { given, resolved }
    }

    /// `text` with the paths in the state directory relative to it.
    fn strip(&self, text: &str) -> String {
        let mut text = text.to_string();
        for dir in [&self.resolved, &self.given] {
            if !dir.is_empty() && dir != "/" {
                text = text
                    .replace(&format!("{dir}/"), "")
                    .replace(dir.as_str(), "the state directory");
            }
        }
        text
    }
}

/// `e` as a client may see it: a failure's words name no folder of the server's.
fn private_event(hidden: &Hidden, e: Event) -> Event {
    match e {
        Event::Finished {
            session,
            state,
            result,
            error,
            cancelled,
            code,
        } => Event::Finished {
            session,
            state,
            result,
            error: error.map(|x| hidden.strip(&x)),
            cancelled,
            code,
        },
        e => e,
    }
}

type Unrecorded = Arc<Mutex<std::collections::BTreeMap<String, flow::Unrecorded>>>;

/// How often a failure the manifest could not record is tried again.
const RECORD_RETRY: std::time::Duration = std::time::Duration::from_secs(1);

/// How often a retry looks whether the daemon is stopping: SIGTERM must end it within 2 s.
const STOP_CHECK: std::time::Duration = std::time::Duration::from_millis(50);

/// Tries to record `id`'s failure every [`RECORD_RETRY`] until it is written, the session is
/// resumed (its entry in `pending` is gone: its run records its own state), or the daemon
/// stops (`stopping`; the next daemon's start marks the session interrupted). Why: a capture
/// that failed for want of disk space or file descriptors could not write its failure either,
/// and its manifest said `capturing` for as long as the daemon ran, idle.
fn record_when_possible(
    state: &std::path::Path,
    id: &str,
    pending: &Unrecorded,
    stopping: &Cancel,
) {
    let mut waited = std::time::Duration::ZERO;
    loop {
        if stopping.is_cancelled() {
            return;
        }
        std::thread::sleep(STOP_CHECK);
        waited += STOP_CHECK;
        if waited < RECORD_RETRY {
            continue;
        }
        waited = std::time::Duration::ZERO;
        // Held while writing, so that a resume, which takes the entry out under this lock
        // first, never meets a retry half done.
        let mut pending = pending.lock().expect("unrecorded");
        let Some(u) = pending.get(id).cloned() else {
            return;
        };
        match flow::record_failure(state, id, &u) {
            Ok(true) => {
                tracing::info!(session = %id, "the failure is recorded in the manifest now");
                pending.remove(id);
                return;
            }
            Ok(false) => {}
            Err(e) => {
                tracing::debug!(session = %id, "the failure still cannot be recorded: {}", said(&e))
            }
        }
    }
}

/// Captures whose events the daemon keeps.
const EVENT_LOGS_KEPT: usize = 32;

/// Why a capture could not start or resume. The API answers each with its own status
/// (`api::start_error`). The causes are said as API clients may read them
/// ([`Daemon::private`]): in words, without this machine's paths.
#[derive(Debug, thiserror::Error)]
pub enum StartError {
    #[error("busy: session {0} is capturing on this rig; wait for it, or cancel it")]
    Busy(String),
    /// The plan breaks a rule its schema states (a name, a range, a count): fix the plan.
    #[error("{0}")]
    Invalid(String),
    /// A well-formed plan this daemon cannot carry out: a material its simulator lacks, a scene
    /// file not in its folder, a rig that cannot run it.
    #[error("{0}")]
    Unusable(String),
    #[error("no session {0:?}; GET /api/v1/sessions lists them")]
    NotFound(String),
    #[error("session {0} is already done; its result is at /api/v1/sessions/{0}/result")]
    Done(String),
    /// A stored session that cannot go on as it is (its files changed, or the rig no longer
    /// fits its plan).
    #[error("session {0} cannot be resumed: {1}")]
    NotResumable(String, String),
    /// The state directory could not hold the session, or the capture's thread not start.
    #[error("{0}")]
    Storage(String),
}

impl Daemon {
    /// Starts the rig's devices and marks sessions that a previous daemon left running as
    /// interrupted.
    pub fn start(
        rig: Rig,
        rig_text: String,
        state_dir: PathBuf,
        token: Option<String>,
        keep_alive: std::time::Duration,
    ) -> Result<Daemon, RigError> {
        // Made now, so that its resolved path is known from the start (and a folder that
        // cannot be made fails the daemon here, not the first capture).
        std::fs::create_dir_all(&state_dir)
            .with_step(|| format!("creating the state directory {}", state_dir.display()))?;
        for m in Session::list(&state_dir)? {
            let mut s = Session::open(&state_dir, &m.id)?;
            if s.mark_if_interrupted()? {
                tracing::warn!(session = %m.id, "interrupted by the last daemon's end; marked failed, resumable");
            }
        }
        let devices = Arc::new(Devices::start(&rig, keep_alive)?);
        Ok(Daemon {
            rig,
            rig_text,
            devices,
            hidden: Hidden::of(&state_dir),
            state_dir,
            token,
            hosts: Vec::new(),
            running: Mutex::new(None),
            unrecorded: Unrecorded::default(),
            stopping: Cancel::default(),
            events: Mutex::new(VecDeque::new()),
            event_streams: Arc::default(),
            max_event_streams: MAX_EVENT_STREAMS,
            throttle: throttle::Throttle::default(),
        })
    }

    /// `e` as API clients may read it: paths in the state directory relative to it, so that no
    /// answer tells a client where this machine keeps its files.
    pub fn private(&self, e: &(dyn std::error::Error + 'static)) -> String {
        self.relative(&said(e))
    }

    /// `text` with the state directory's path (as given, and resolved) left out of the paths
    /// in it.
    pub fn relative(&self, text: &str) -> String {
        self.hidden.strip(text)
    }

    pub fn devices(&self) -> Vec<brdfd_rig::DeviceStatus> {
        self.devices.status()
    }

    /// The id of the capture running now.
    pub fn busy(&self) -> Option<String> {
        let mut r = self.running.lock().expect("running");
        if r.as_ref().is_some_and(Running::over) {
            *r = None;
        }
        r.as_ref().map(|r| r.id.clone())
    }

    pub fn events(&self, id: &str) -> Option<Arc<EventLog>> {
        let logs = self.events.lock().expect("events");
        logs.iter()
            .rev()
            .find(|(i, _)| i == id)
            .map(|(_, l)| l.clone())
    }

    /// The manifest as the API shows it: with a failure it could not record yet.
    pub fn shown(&self, mut m: brdfd_rig::session::Manifest) -> brdfd_rig::session::Manifest {
        // The reasons recorded are the flow's words, which may name a file by its full path.
        for t in &mut m.history {
            t.reason = t.reason.take().map(|r| self.relative(&r));
        }
        if let Some(u) = self.unrecorded.lock().expect("unrecorded").get(&m.id) {
            m.state = State::Failed;
            m.history.push(brdfd_rig::session::Transition {
                state: State::Failed,
                at: m.history.last().map(|t| t.at.clone()).unwrap_or_default(),
                reason: Some(format!("{} ({}; retried every second)", u.reason, u)),
                code: Some(u.code),
            });
        }
        m
    }

    /// Creates a session for the plan and starts capturing it.
    pub fn start_capture(&self, plan: Plan) -> Result<Session, StartError> {
        // A malformed plan is refused as such whether or not a capture runs: the caller
        // learns what to fix, not only that it must wait.
        plan.validate()
            .map_err(|e| StartError::Invalid(e.to_string()))?;
        scene_names(&plan).map_err(StartError::Invalid)?;
        // The scene files by name first: every later step reads the files they resolve to,
        // never a path the client sent.
        let plan = self
            .scene_files(plan)
            .map_err(|e| StartError::Unusable(said(&e)))?;
        let settings = CaptureSettings::resolve(&plan, &self.rig)
            .map_err(|e| StartError::Unusable(self.private(&e)))?;
        // One lock from the busy check to the launch: two plans sent at once must not both
        // pass the check and leave a session behind for the one that loses.
        let mut running = self.lock_idle()?;
        let session = settings
            .new_session(&self.state_dir, &self.rig_text)
            .map_err(|e| StartError::Storage(self.private(&e)))?;
        self.launch(&mut running, session, settings)
    }

    /// The plan with its scene files (`env`, `nbrdf`) looked up by name in the state
    /// directory's [`SCENES_DIR`]. A client names them and never hands the daemon a path:
    /// a path would let any client make the daemon read any file on its machine, or
    /// `/dev/zero` without end.
    fn scene_files(&self, mut plan: Plan) -> Result<Plan, RigError> {
        for (what, file) in [("env", &mut plan.env), ("nbrdf", &mut plan.nbrdf)] {
            if let Some(name) = file.as_ref() {
                *file = Some(scene_file(&self.state_dir, what, name)?);
            }
        }
        Ok(plan)
    }

    /// Continues a stored session from its last complete step.
    pub fn resume(&self, id: &str) -> Result<Session, StartError> {
        self.check_idle()?;
        // A failure not yet recorded is no longer retried: the resumed run records its own
        // state, and no retry may write the manifest while `resumable` does.
        self.unrecorded.lock().expect("unrecorded").remove(id);
        let mut s = Session::open(&self.state_dir, id).map_err(|e| match e {
            e if e.names_no_session(id) => StartError::NotFound(id.to_string()),
            e => StartError::Storage(self.private(&e)),
        })?;
        if s.manifest().state == State::Done {
            return Err(StartError::Done(id.to_string()));
        }
        let unresumable = |e: RigError| StartError::NotResumable(id.to_string(), self.private(&e));
        let plan = resumable(&mut s).map_err(unresumable)?;
        let settings = CaptureSettings::resolve(&plan, &self.rig).map_err(unresumable)?;
        // Checked again under the lock: another capture may have started meanwhile.
        let mut running = self.lock_idle()?;
        self.launch(&mut running, s, settings)
    }

    fn check_idle(&self) -> Result<(), StartError> {
        match self.busy() {
            Some(id) => Err(StartError::Busy(id)),
            None => Ok(()),
        }
    }

    /// The lock on the running capture, if none runs; [`StartError::Busy`] otherwise.
    fn lock_idle(&self) -> Result<std::sync::MutexGuard<'_, Option<Running>>, StartError> {
        let running = self.running.lock().expect("running");
        match running.as_ref().filter(|r| !r.over()) {
            Some(r) => Err(StartError::Busy(r.id.clone())),
            None => Ok(running),
        }
    }

    /// Starts capturing `session` on its thread; `running` is the lock [`Daemon::lock_idle`]
    /// gave.
    fn launch(
        &self,
        running: &mut Option<Running>,
        session: Session,
        settings: CaptureSettings,
    ) -> Result<Session, StartError> {
        let id = session.manifest().id.clone();
        let log = EventLog::new();
        {
            let mut logs = self.events.lock().expect("events");
            if logs.len() >= EVENT_LOGS_KEPT {
                logs.pop_front();
            }
            logs.push_back((id.clone(), log.clone()));
        }
        let cancel = Cancel::default();
        let go_ahead = GoAhead::default();
        let operator: Arc<dyn brdfd_rig::Operator> = Arc::new(go_ahead.clone());
        let reply = session.clone();
        let thread_log = log.clone();
        let (devices, rig, c) = (self.devices.clone(), self.rig.clone(), cancel.clone());
        let (state_dir, pending) = (self.state_dir.clone(), self.unrecorded.clone());
        let hidden = self.hidden.clone();
        let stopping = self.stopping.clone();
        // A resumed session records its own state.
        pending.lock().expect("unrecorded").remove(&id);
        let thread = std::thread::Builder::new()
            .name(format!("capture-{id}"))
            .spawn(move || {
                let mut session = session;
                let progress = thread_log.clone();
                let cx = Context {
                    rig: &rig,
                    devices: &devices,
                    progress: Arc::new(move |e: Event| progress.push(private_event(&hidden, e))),
                    cancel: c,
                    operator,
                };
                let id = session.manifest().id.clone();
                match flow::execute(&mut session, &settings, &cx) {
                    Ok(_) => tracing::info!(session = %id, "capture done"),
                    Err(e) => {
                        tracing::warn!(session = %id, "capture failed: {}", said(&e));
                        if let Some(u) = e.unrecorded() {
                            pending
                                .lock()
                                .expect("unrecorded")
                                .insert(id.clone(), u.clone());
                            // The capture is over (its `finished` event is sent), so the
                            // daemon is idle while this thread waits to record it.
                            record_when_possible(&state_dir, &id, &pending, &stopping);
                        }
                    }
                }
            })
            .map_err(|e| StartError::Storage(e.to_string()))?;
        *running = Some(Running {
            id,
            cancel,
            go_ahead,
            thread,
            log,
        });
        Ok(reply)
    }

    /// Asks the running capture to stop at its next frame; false when `id` is not running.
    pub fn cancel(&self, id: &str) -> bool {
        let r = self.running.lock().expect("running");
        match r.as_ref() {
            Some(r) if r.id == id && !r.over() => {
                r.cancel.cancel();
                true
            }
            _ => false,
        }
    }

    /// Tells the running capture `id` that the operator has turned the object (for view
    /// `view`, if given); false if it is not running, or not waiting for that turn.
    pub fn proceed(&self, id: &str, view: Option<usize>) -> bool {
        let r = self.running.lock().expect("running");
        match r.as_ref() {
            Some(r) if r.id == id && !r.over() => r.go_ahead.give(view),
            _ => false,
        }
    }

    /// The view whose hand turn the running capture `id` waits for, if it waits.
    pub fn waiting_for(&self, id: &str) -> Option<usize> {
        let r = self.running.lock().expect("running");
        r.as_ref()
            .filter(|r| r.id == id && !r.over())
            .and_then(|r| r.go_ahead.waiting())
    }

    /// Cancels the running capture, if any, and waits for it to record its state.
    pub fn shut_down(&self) {
        self.stopping.cancel();
        let r = self.running.lock().expect("running").take();
        if let Some(r) = r {
            // A capture that finished earlier has nothing to cancel: say so only when one runs.
            if !r.over() {
                let waiting = match r.log.under_way().join(", ") {
                    w if w.is_empty() => "its current step".to_string(),
                    w => w,
                };
                tracing::info!(
                    session = %r.id,
                    "shutting down: cancelling the running capture, and waiting for {waiting} to stop (a few seconds at most; what was captured is kept)"
                );
            }
            r.cancel.cancel();
            let _ = r.thread.join();
        }
    }
}

/// The plan of a stored session, after adopting files stored but not yet listed and checking
/// every checksum: what a resume needs before it continues.
pub fn resumable(s: &mut Session) -> Result<Plan, RigError> {
    if s.manifest().state == State::Done {
        return Err(RigError::invalid(format!(
            "session {} is already done",
            s.manifest().id
        )));
    }
    // Left capturing or estimating by a process that is gone: recorded as what it is, so
    // that the resumed run starts from a failed session, as every resume does.
    s.mark_if_interrupted()?;
    let adopted = s.adopt_orphans()?;
    if adopted > 0 {
        tracing::info!("{adopted} raw files were stored but not yet listed; listed now");
    }
    s.verify().step("checking what the session already holds")?;
    serde_json::from_value(s.manifest().options.clone()).step("the manifest's capture options")
}
