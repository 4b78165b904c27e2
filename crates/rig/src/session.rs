//! Sessions on disk: one folder per capture under the state directory,
//! `sessions/<YYYYMMDD-HHMMSS>-<material>-<id>/`, holding
//!
//! - `manifest.json`: the state machine (created → capturing → captured → estimating → done,
//!   or failed with a reason), its history, the rig and material files as used, the devices,
//!   brdfd's version, and the capture steps with every raw file's sha256;
//! - `raw/`: every file exactly as a device sent it, written the moment it arrives;
//! - `derived/`: HDR maps and other intermediate results;
//! - `result/`: what the estimate wrote (coefficients, BRDF files, preview).
//!
//! Every write is atomic: a temporary file in the same folder, fsync, rename, fsync of the
//! folder. A killed process leaves either the old file or the new one, never half of one.
//!
//! Capture happens in steps (the panorama bracket, each DSLR view). A step counts once all
//! its files are on disk. A step caught half-done keeps its files (an incomplete attempt, in
//! the manifest) and `resume` shoots it again as a new attempt: nothing captured is lost, and
//! nothing is captured twice under one name.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::SystemTime;

use sha2::{Digest, Sha256};

use crate::config::validate_name;
pub use brdfd_api::event::FailureCode;
pub use brdfd_api::session::{Manifest, PhaseTime, RawFile, State, Step, Transition};

#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    #[error("{path}: {reason}")]
    Io { path: String, reason: String },
    #[error("no session {id:?} under {dir}; `brdfd session list` shows them")]
    NotFound { id: String, dir: String },
    #[error("{0}")]
    Invalid(String),
    #[error("{path}: checksum mismatch (sha256 {found}, manifest says {expected}): the file changed after capture")]
    Checksum {
        path: String,
        expected: String,
        found: String,
    },
    /// A change of state the session's life does not have (see [`State::may_become`]).
    #[error("session {id} is {from}, and cannot become {to}")]
    Transition { id: String, from: State, to: State },
}

impl SessionError {
    /// Whether this error, from opening session `id`, means there is no such session: none
    /// stored under it, or `id` has a shape no session's id has. A session whose manifest is
    /// wrong is there, and is no such case.
    pub fn names_no_session(&self, id: &str) -> bool {
        match self {
            SessionError::NotFound { .. } => true,
            SessionError::Invalid(_) => validate_name("session id", id).is_err(),
            _ => false,
        }
    }
}

pub type Result<T> = std::result::Result<T, SessionError>;

fn io(path: &Path, e: std::io::Error) -> SessionError {
    let reason = if e.raw_os_error() == Some(28) {
        format!("{e}: the disk is full; free space and run `brdfd session resume` (what was captured is kept)")
    } else {
        e.to_string()
    };
    SessionError::Io {
        path: path.display().to_string(),
        reason,
    }
}

/// Writes `bytes` to `path` atomically: temporary file beside it, fsync, rename, fsync of the
/// folder.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    // A bare file name's parent is "", which names no folder to sync.
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = dir.join(format!(".{name}.tmp"));
    let result = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)?;
        std::fs::File::open(dir)?.sync_all()
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result.map_err(|e| io(path, e))
}

/// Writes a camera file into `dir` under its own name (made safe: it may come from a device),
/// or `N-name` if that exists: an earlier capture is never overwritten. Returns the path
/// written.
pub fn write_new(dir: &Path, name: &str, bytes: &[u8]) -> Result<PathBuf> {
    let name = &safe_file_name(name);
    for i in 0.. {
        let path = if i == 0 {
            dir.join(name)
        } else {
            dir.join(format!("{i}-{name}"))
        };
        // create_new: the existence check and the creation are one step.
        match std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&path)
        {
            Ok(mut f) => {
                f.write_all(bytes)
                    .and_then(|_| f.sync_all())
                    .map_err(|e| failed("writing", &path, e))?;
                return Ok(path);
            }
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(failed("creating", &path, e)),
        }
    }
    unreachable!("an unbounded range ends only by returning")
}

/// A camera file that could not be made: not a session's, so without [`io`]'s advice to
/// resume one.
fn failed(doing: &str, path: &Path, e: std::io::Error) -> SessionError {
    SessionError::Io {
        path: format!("{doing} {}", path.display()),
        reason: e.to_string(),
    }
}

/// A file name a device chose, made safe to create in a folder of ours: letters, digits,
/// `.`, `-` and `_` only (so no separator, `..` component or absolute path survives), not
/// hidden, not empty. A camera's ObjectInfo name is whatever the camera says.
pub fn safe_file_name(device_name: &str) -> String {
    let safe: String = device_name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '.' || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect();
    match safe.strip_prefix('.') {
        _ if safe.is_empty() => "unnamed".into(),
        Some(_) => format!("_{safe}"),
        None => safe,
    }
}

pub(crate) fn sha256_hex(bytes: &[u8]) -> String {
    Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

fn now() -> String {
    humantime::format_rfc3339_seconds(SystemTime::now()).to_string()
}

/// What `Session::fail_unless_running` found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Marked {
    /// Done or failed already: nothing written.
    Ended,
    /// A process holds the session: nothing written.
    Running,
    /// Recorded as failed now.
    Failed,
}

/// A running capture's hold on its session (see [`Session::claim`]).
#[derive(Debug)]
pub struct SessionLock(#[allow(dead_code)] std::fs::File);

#[derive(Debug, Clone)]
pub struct Session {
    pub dir: PathBuf,
    /// Private: its state changes only through [`Session::set_state`], which checks the move
    /// and saves it.
    manifest: Manifest,
}

/// The state directory: `--state-dir`, else `BRDFD_STATE_DIR`, else the daemon config's,
/// else `$XDG_DATA_HOME/brdfd`, else `~/.local/share/brdfd`.
pub fn state_dir(flag: Option<&Path>, configured: Option<&Path>) -> Result<PathBuf> {
    if let Some(p) = flag {
        return Ok(p.to_path_buf());
    }
    if let Some(p) = std::env::var_os("BRDFD_STATE_DIR").filter(|v| !v.is_empty()) {
        return Ok(PathBuf::from(p));
    }
    if let Some(p) = configured {
        return Ok(p.to_path_buf());
    }
    if let Some(p) = std::env::var_os("XDG_DATA_HOME").filter(|v| !v.is_empty()) {
        return Ok(PathBuf::from(p).join("brdfd"));
    }
    std::env::var_os("HOME")
        .filter(|v| !v.is_empty())
        .map(|h| PathBuf::from(h).join(".local/share/brdfd"))
        .ok_or_else(|| {
            SessionError::Invalid(
                "no state directory: give --state-dir or set BRDFD_STATE_DIR".into(),
            )
        })
}

fn sessions_dir(state: &Path) -> PathBuf {
    state.join("sessions")
}

/// The folder of session `id` under the state directory (not checked: see [`Session::open`]).
pub fn session_dir(state: &Path, id: &str) -> PathBuf {
    sessions_dir(state).join(id)
}

impl Session {
    /// A new session folder for `material`, in state `created`.
    pub fn create(
        state: &Path,
        material: &str,
        rig: &str,
        preset: Option<&str>,
        options: serde_json::Value,
    ) -> Result<Session> {
        validate_name("material", material).map_err(SessionError::Invalid)?;
        let created = now();
        // 20261122T233000 from 2026-11-22T23:30:00Z, and 24 random bits.
        let stamp: String = created
            .chars()
            .filter(|c| c.is_ascii_digit())
            .take(14)
            .collect();
        let id = format!(
            "{}-{}-{material}-{:06x}",
            &stamp[..8],
            &stamp[8..],
            rand::random::<u32>() & 0xFF_FFFF
        );
        let dir = sessions_dir(state).join(&id);
        for sub in ["raw", "derived", "result"] {
            std::fs::create_dir_all(dir.join(sub)).map_err(|e| io(&dir, e))?;
        }
        let s = Session {
            dir,
            manifest: Manifest {
                id,
                material: material.into(),
                created: created.clone(),
                software: format!("brdfd {}", env!("CARGO_PKG_VERSION")),
                state: State::Created,
                history: vec![Transition {
                    state: State::Created,
                    at: created,
                    reason: None,
                    code: None,
                }],
                rig: rig.into(),
                preset: preset.map(String::from),
                options,
                devices: Vec::new(),
                steps: Vec::new(),
                phases: Vec::new(),
            },
        };
        s.save()?;
        Ok(s)
    }

    /// Opens a session by id (validated: an id names a folder under `sessions/`, no more).
    pub fn open(state: &Path, id: &str) -> Result<Session> {
        validate_name("session id", id).map_err(SessionError::Invalid)?;
        let dir = session_dir(state, id);
        let path = dir.join("manifest.json");
        let text = std::fs::read_to_string(&path).map_err(|e| {
            if e.kind() == std::io::ErrorKind::NotFound {
                SessionError::NotFound {
                    id: id.into(),
                    dir: sessions_dir(state).display().to_string(),
                }
            } else {
                io(&path, e)
            }
        })?;
        let manifest: Manifest = serde_json::from_str(&text).map_err(|e| SessionError::Io {
            path: path.display().to_string(),
            reason: format!("not a brdfd manifest: {e}"),
        })?;
        // Raw names are joined to raw/ when files are read back: an edited manifest must not
        // lead outside the session. brdfd only ever writes names safe_file_name keeps as they
        // are.
        for f in manifest.steps.iter().flat_map(|s| &s.files) {
            if safe_file_name(&f.name) != f.name {
                return Err(SessionError::Invalid(format!(
                    "{}: raw file {:?} is not a plain file name (was the manifest edited?)",
                    path.display(),
                    f.name
                )));
            }
        }
        Ok(Session { dir, manifest })
    }

    /// Claims the session for one running capture: an exclusive lock on `.lock` in its
    /// folder, held while the returned guard lives and released by the kernel if the process
    /// dies. A second claim, from this process or another, fails.
    pub fn claim(&self) -> Result<SessionLock> {
        let path = self.dir.join(".lock");
        let file = std::fs::OpenOptions::new()
            .create(true)
            .truncate(false)
            .write(true)
            .open(&path)
            .map_err(|e| io(&path, e))?;
        match file.try_lock() {
            Ok(()) => Ok(SessionLock(file)),
            Err(std::fs::TryLockError::WouldBlock) => Err(SessionError::Invalid(format!(
                "session {} is being captured right now (by the daemon or another brdfd)",
                self.manifest.id
            ))),
            Err(std::fs::TryLockError::Error(e)) => Err(io(&path, e)),
        }
    }

    /// A session left in a running state (created, capturing, captured, estimating) that no
    /// process is running: the process running it died. Marked failed, so that it reads as
    /// what it is and `resume` continues it. Returns whether it was interrupted.
    pub fn mark_if_interrupted(&mut self) -> Result<bool> {
        let id = self.manifest.id.clone();
        let marked = self.fail_unless_running(
            |was| {
                format!(
                    "interrupted while {was}: the process running it stopped; `brdfd session resume {id}` continues it"
                )
            },
            Some(FailureCode::Failed),
        )?;
        Ok(marked == Marked::Failed)
    }

    /// Records the session as failed, with the reason `why` gives for the state it was left
    /// in and its code if known, unless it already ended or a process runs it (holds its
    /// claim).
    pub(crate) fn fail_unless_running(
        &mut self,
        why: impl FnOnce(State) -> String,
        code: Option<FailureCode>,
    ) -> Result<Marked> {
        if matches!(self.manifest.state, State::Done | State::Failed) {
            return Ok(Marked::Ended);
        }
        let Ok(_lock) = self.claim() else {
            return Ok(Marked::Running);
        };
        let reason = why(self.manifest.state);
        self.record(State::Failed, Some(reason), code)?;
        Ok(Marked::Failed)
    }

    /// Every session's manifest, oldest first.
    pub fn list(state: &Path) -> Result<Vec<Manifest>> {
        let dir = sessions_dir(state);
        let entries = match std::fs::read_dir(&dir) {
            Ok(e) => e,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
            Err(e) => return Err(io(&dir, e)),
        };
        let mut out = Vec::new();
        for e in entries.flatten() {
            let id = e.file_name().to_string_lossy().into_owned();
            if let Ok(s) = Session::open(state, &id) {
                out.push(s.manifest);
            }
        }
        out.sort_by(|a, b| a.id.cmp(&b.id));
        Ok(out)
    }
    /// The session's manifest as it stands.
    pub fn manifest(&self) -> &Manifest {
        &self.manifest
    }

    /// The manifest, without the session.
    pub fn into_manifest(self) -> Manifest {
        self.manifest
    }

    /// Records how long each phase of the run took; saved with the next save.
    pub(crate) fn set_phases(&mut self, phases: Vec<PhaseTime>) {
        self.manifest.phases = phases;
    }

    /// Records a device the session used, by its identity, once; saved with the next save.
    pub(crate) fn note_device(&mut self, identity: String) {
        if !self.manifest.devices.contains(&identity) {
            self.manifest.devices.push(identity);
        }
    }

    pub fn save(&self) -> Result<()> {
        let json = serde_json::to_vec_pretty(&self.manifest)
            .map_err(|e| SessionError::Invalid(format!("manifest: {e}")))?;
        write_atomic(&self.dir.join("manifest.json"), &json)
    }

    /// Moves the session to `state` and records why, if the move is one a session's life has
    /// ([`State::may_become`]); otherwise nothing changes. If the manifest cannot be written,
    /// the session keeps its state in memory too, so that what it says stays what is stored.
    pub fn set_state(&mut self, state: State, reason: Option<String>) -> Result<()> {
        self.record(state, reason, None)
    }

    /// Records the session as failed, with the reason for people and its code for programs
    /// (the code reaches API clients in the stream's `finished` event).
    pub fn fail(&mut self, reason: String, code: FailureCode) -> Result<()> {
        self.record(State::Failed, Some(reason), Some(code))
    }

    fn record(
        &mut self,
        state: State,
        reason: Option<String>,
        code: Option<FailureCode>,
    ) -> Result<()> {
        let from = self.manifest.state;
        if !from.may_become(state) {
            return Err(SessionError::Transition {
                id: self.manifest.id.clone(),
                from,
                to: state,
            });
        }
        self.manifest.state = state;
        self.manifest.history.push(Transition {
            state,
            at: now(),
            reason,
            code,
        });
        self.save().inspect_err(|_| {
            self.manifest.history.pop();
            self.manifest.state = from;
        })
    }

    /// The complete attempt of a step, if there is one.
    pub(crate) fn complete_step(&self, name: &str) -> Option<&Step> {
        self.manifest
            .steps
            .iter()
            .find(|s| s.name == name && s.complete)
    }

    /// Starts a new attempt of a step (earlier incomplete attempts keep their files).
    pub(crate) fn begin_step(&mut self, name: &str, meta: serde_json::Value) -> Result<u32> {
        let attempt = self
            .manifest
            .steps
            .iter()
            .filter(|s| s.name == name)
            .count() as u32
            + 1;
        self.manifest.steps.push(Step {
            name: name.into(),
            attempt,
            complete: false,
            files: Vec::new(),
            meta,
        });
        self.save()?;
        Ok(attempt)
    }

    fn current_step(&mut self, name: &str) -> Result<&mut Step> {
        self.manifest
            .steps
            .iter_mut()
            .rev()
            .find(|s| s.name == name)
            .ok_or_else(|| SessionError::Invalid(format!("step {name} was not begun")))
    }

    /// Stores a device's file as it arrived, under `raw/<step>-a<attempt>-<frame>-<name>`
    /// (the frame counts the attempt's files from 01, so a name the device reuses is stored
    /// apart), and records it in the manifest.
    pub(crate) fn add_raw(
        &mut self,
        step: &str,
        device_name: &str,
        bytes: &[u8],
    ) -> Result<PathBuf> {
        let current = self.current_step(step)?;
        let (attempt, stored) = (current.attempt, current.files.len());
        let raw = self.dir.join("raw");
        // A file stored before a crash, and not yet adopted, keeps its frame: never
        // overwritten, the next free one is taken.
        let (name, path) = (stored + 1..)
            .map(|frame| {
                let name = format!(
                    "{step}-a{attempt}-{frame:02}-{}",
                    safe_file_name(device_name)
                );
                let path = raw.join(&name);
                (name, path)
            })
            .find(|(_, path)| !path.exists())
            .expect("an unbounded range has a free frame");
        write_atomic(&path, bytes)?;
        let file = RawFile {
            name,
            sha256: sha256_hex(bytes),
            bytes: bytes.len() as u64,
            device_name: Some(device_name.to_string()),
        };
        self.current_step(step)?.files.push(file);
        self.save()?;
        Ok(path)
    }

    pub(crate) fn finish_step(&mut self, step: &str) -> Result<()> {
        self.current_step(step)?.complete = true;
        self.save()
    }

    /// Raw files on disk that the manifest does not list: a process killed between storing a
    /// file and saving the manifest leaves one. They are added to the attempt their name
    /// says, so nothing captured is lost. Returns how many were adopted.
    pub fn adopt_orphans(&mut self) -> Result<usize> {
        let raw = self.dir.join("raw");
        let listed: std::collections::HashSet<String> = self
            .manifest
            .steps
            .iter()
            .flat_map(|s| s.files.iter().map(|f| f.name.clone()))
            .collect();
        let mut adopted = 0;
        for e in std::fs::read_dir(&raw).map_err(|e| io(&raw, e))?.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            if name.starts_with('.') || listed.contains(&name) {
                continue;
            }
            let Some((step, rest)) = self.manifest.steps.iter_mut().find_map(|s| {
                let prefix = format!("{}-a{}-", s.name, s.attempt);
                let rest = name.strip_prefix(&prefix)?.to_string();
                Some((s, rest))
            }) else {
                continue;
            };
            // `<frame>-<device name>`, or the device's name alone in an older session.
            let device_name = match rest.split_once('-') {
                Some((frame, n))
                    if frame.len() >= 2 && frame.bytes().all(|b| b.is_ascii_digit()) =>
                {
                    n
                }
                _ => &rest,
            };
            let bytes = std::fs::read(e.path()).map_err(|err| io(&e.path(), err))?;
            tracing::warn!("adopting {name}: stored before the manifest was saved");
            step.files.push(RawFile {
                device_name: Some(device_name.to_string()),
                name,
                sha256: sha256_hex(&bytes),
                bytes: bytes.len() as u64,
            });
            adopted += 1;
        }
        if adopted > 0 {
            self.save()?;
        }
        Ok(adopted)
    }

    /// A raw file's bytes, checked against the manifest's sha256.
    pub fn read_raw(&self, file: &RawFile) -> Result<Vec<u8>> {
        let path = self.dir.join("raw").join(&file.name);
        let bytes = std::fs::read(&path).map_err(|e| io(&path, e))?;
        let found = sha256_hex(&bytes);
        if found != file.sha256 {
            return Err(SessionError::Checksum {
                path: path.display().to_string(),
                expected: file.sha256.clone(),
                found,
            });
        }
        Ok(bytes)
    }

    /// Checks every raw file of every step; returns how many were checked.
    pub fn verify(&self) -> Result<usize> {
        let mut n = 0;
        for s in &self.manifest.steps {
            for f in &s.files {
                self.read_raw(f)?;
                n += 1;
            }
        }
        Ok(n)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_manifest_naming_a_file_outside_the_session_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let mut s = Session::create(dir.path(), "gold", "", None, serde_json::json!({})).unwrap();
        s.begin_step("view1", serde_json::json!({})).unwrap();
        s.add_raw("view1", "DSC_0001.JPG", b"jpeg").unwrap();
        let id = s.manifest.id.clone();
        assert!(Session::open(dir.path(), &id).is_ok());
        // Tampered: the raw name climbs out of raw/.
        let path = s.dir.join("manifest.json");
        let text = std::fs::read_to_string(&path).unwrap();
        let name = &s.manifest.steps[0].files[0].name;
        std::fs::write(&path, text.replace(name.as_str(), "../../../../etc/passwd")).unwrap();
        let e = Session::open(dir.path(), &id).unwrap_err().to_string();
        assert!(
            e.contains("\"../../../../etc/passwd\" is not a plain file name"),
            "{e}"
        );
    }

    /// A session's life: created, capturing, captured, estimating, done; any step before done
    /// may fail, and a failed one captures again. Any other move is refused with both states
    /// named, and leaves the manifest, on disk and in memory, as it was.
    #[test]
    fn a_session_moves_only_along_its_life() {
        let dir = tempfile::tempdir().unwrap();
        let mut s = Session::create(dir.path(), "gold", "", None, serde_json::json!({})).unwrap();
        let id = s.manifest.id.clone();
        let refused = |s: &mut Session, to: State| {
            let (from, entries) = (s.manifest.state, s.manifest.history.len());
            let e = s.set_state(to, None).unwrap_err().to_string();
            assert_eq!(e, format!("session {id} is {from}, and cannot become {to}"));
            let stored = Session::open(dir.path(), &id).unwrap().manifest;
            for m in [&s.manifest, &stored] {
                assert_eq!((m.state, m.history.len()), (from, entries));
            }
        };
        refused(&mut s, State::Done);
        refused(&mut s, State::Captured);
        s.set_state(State::Capturing, None).unwrap();
        refused(&mut s, State::Capturing);
        refused(&mut s, State::Estimating);
        s.set_state(State::Captured, None).unwrap();
        refused(&mut s, State::Capturing);
        s.set_state(State::Failed, Some("the camera vanished".into()))
            .unwrap();
        // Resumed: failed, then capturing again; a resume that fails at once fails again.
        s.set_state(State::Failed, Some("still gone".into()))
            .unwrap();
        refused(&mut s, State::Estimating);
        s.set_state(State::Capturing, None).unwrap();
        s.set_state(State::Captured, None).unwrap();
        s.set_state(State::Estimating, None).unwrap();
        s.set_state(State::Done, None).unwrap();
        for to in [State::Failed, State::Capturing, State::Done] {
            refused(&mut s, to);
        }
        let states: Vec<State> = s.manifest.history.iter().map(|t| t.state).collect();
        use State::*;
        assert_eq!(
            states,
            [Created, Capturing, Captured, Failed, Failed, Capturing, Captured, Estimating, Done]
        );
    }

    #[test]
    fn a_device_cannot_name_a_file_outside_our_folder() {
        for (given, safe) in [
            ("DSC_0001.JPG", "DSC_0001.JPG"),
            ("../../x.JPG", "_.._.._x.JPG"),
            ("/etc/passwd", "_etc_passwd"),
            ("..", "_.."),
            (".hidden", "_.hidden"),
            ("", "unnamed"),
            ("R0010001 (1).JPG", "R0010001__1_.JPG"),
        ] {
            assert_eq!(safe_file_name(given), safe, "{given:?}");
        }
    }

    #[test]
    fn steps_attempts_and_checksums() {
        let dir = tempfile::tempdir().unwrap();
        let mut s = Session::create(
            dir.path(),
            "gold",
            "simulated = true",
            None,
            serde_json::json!({}),
        )
        .unwrap();
        assert!(s.manifest.id.contains("-gold-"));
        s.begin_step("panorama", serde_json::json!({})).unwrap();
        s.add_raw("panorama", "R0010001.JPG", b"first").unwrap();
        // Killed here: the next attempt keeps the first one's file and names its own apart.
        let mut s = Session::open(dir.path(), &s.manifest.id).unwrap();
        assert!(s.complete_step("panorama").is_none());
        assert_eq!(s.begin_step("panorama", serde_json::json!({})).unwrap(), 2);
        s.add_raw("panorama", "R0010001.JPG", b"second").unwrap();
        s.finish_step("panorama").unwrap();
        let step = s.complete_step("panorama").unwrap();
        assert_eq!(step.files[0].name, "panorama-a2-01-R0010001.JPG");
        assert_eq!(step.files[0].device_name(step), "R0010001.JPG");
        assert_eq!(s.read_raw(&step.files[0]).unwrap(), b"second");
        assert_eq!(s.verify().unwrap(), 2);
        std::fs::write(s.dir.join("raw/panorama-a1-01-R0010001.JPG"), b"tampered").unwrap();
        assert!(s
            .verify()
            .unwrap_err()
            .to_string()
            .contains("checksum mismatch"));
        assert!(Session::open(dir.path(), "../../etc").is_err());
        assert!(Session::open(dir.path(), "20260101-000000-gold-000000")
            .unwrap_err()
            .to_string()
            .contains("no session"));
    }

    #[test]
    fn a_name_the_camera_reuses_keeps_every_file() {
        let dir = tempfile::tempdir().unwrap();
        let mut s = Session::create(dir.path(), "gold", "", None, serde_json::json!({})).unwrap();
        s.begin_step("view1", serde_json::json!({})).unwrap();
        for bytes in [b"one", b"two"] {
            s.add_raw("view1", "DSC_0001.NEF", bytes).unwrap();
        }
        // Stored by a process killed before it saved the manifest: adopted with its name.
        std::fs::write(s.dir.join("raw/view1-a1-03-DSC_0001.NEF"), b"three").unwrap();
        let mut s = Session::open(dir.path(), &s.manifest.id).unwrap();
        assert_eq!(s.adopt_orphans().unwrap(), 1);
        // The next frame number is taken by the adopted file.
        s.add_raw("view1", "DSC_0001.NEF", b"four").unwrap();
        s.finish_step("view1").unwrap();
        let step = s.complete_step("view1").unwrap();
        let names: Vec<_> = step.files.iter().map(|f| f.name.as_str()).collect();
        assert_eq!(
            names,
            [
                "view1-a1-01-DSC_0001.NEF",
                "view1-a1-02-DSC_0001.NEF",
                "view1-a1-03-DSC_0001.NEF",
                "view1-a1-04-DSC_0001.NEF"
            ]
        );
        assert!(step
            .files
            .iter()
            .all(|f| f.device_name(step) == "DSC_0001.NEF"));
        let read: Vec<_> = step.files.iter().map(|f| s.read_raw(f).unwrap()).collect();
        assert_eq!(read, [&b"one"[..], b"two", b"three", b"four"]);
    }
}
