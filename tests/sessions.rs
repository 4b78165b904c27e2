//! Sessions on disk as an operator meets them: a capture killed with SIGKILL part-way and
//! resumed (issue 6's check, on the in-process path), listing and exporting.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

mod common;

use common::{brdfd, out};

/// The one session under `state`, and its manifest, once it exists.
fn manifest(state: &Path) -> Option<(PathBuf, serde_json::Value)> {
    let dir = std::fs::read_dir(state.join("sessions"))
        .ok()?
        .flatten()
        .next()?
        .path();
    let text = std::fs::read_to_string(dir.join("manifest.json")).ok()?;
    Some((dir, serde_json::from_str(&text).ok()?))
}

fn step_complete(m: &serde_json::Value, step: &str) -> bool {
    m["steps"]
        .as_array()
        .is_some_and(|s| s.iter().any(|x| x["name"] == step && x["complete"] == true))
}

/// Every raw file the manifest lists, name → sha256.
fn listed(m: &serde_json::Value) -> BTreeMap<String, String> {
    m["steps"]
        .as_array()
        .unwrap()
        .iter()
        .flat_map(|s| s["files"].as_array().unwrap().iter())
        .map(|f| {
            (
                f["name"].as_str().unwrap().to_string(),
                f["sha256"].as_str().unwrap().to_string(),
            )
        })
        .collect()
}

#[test]
fn a_capture_killed_mid_session_resumes_without_losing_or_repeating_anything() {
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("state");
    let state_arg = state.to_str().unwrap();
    let mut child = common::command()
        .args([
            "capture",
            "--simulate",
            "--material",
            "gold",
            "--size",
            "96",
            "--views",
            "4",
            "--state-dir",
            state_arg,
        ])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    // Kill it (SIGKILL) as soon as the first view is complete: the panorama and one view
    // are on disk, three views are not.
    let start = Instant::now();
    let before = loop {
        if let Some((_, m)) = manifest(&state) {
            if step_complete(&m, "view1") {
                break Some(m);
            }
        }
        if start.elapsed() > Duration::from_secs(120) {
            break None;
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    child.kill().unwrap();
    child.wait().unwrap();
    let before = before.expect("view 1 never completed");
    let (session_dir, killed) = manifest(&state).unwrap();
    assert_ne!(
        killed["state"], "done",
        "the capture finished before it could be killed"
    );
    assert!(!step_complete(&killed, "view4"));
    let id = killed["id"].as_str().unwrap().to_string();

    let list = brdfd(&["session", "list", "--state-dir", state_arg], dir.path());
    assert!(out(&list).contains(&id), "{}", out(&list));

    let resumed = brdfd(
        &["session", "resume", &id, "--state-dir", state_arg],
        dir.path(),
    );
    let text = out(&resumed);
    assert!(resumed.status.success(), "{text}");
    assert!(
        text.contains("panorama: 8 frames already in the session"),
        "{text}"
    );
    assert!(
        text.contains("view1: 5 files already in the session"),
        "{text}"
    );
    assert!(text.contains("view 4 of 4: turntable at 90.00°"), "{text}");

    let (_, done) = manifest(&state).unwrap();
    assert_eq!(done["state"], "done");
    // Nothing lost: every file listed at the kill is still listed, with the same checksum.
    let (was, now) = (listed(&before), listed(&done));
    for (name, sha) in &was {
        assert_eq!(now.get(name), Some(sha), "{name} lost or changed");
    }
    // Nothing repeated: the panorama and view 1 were not shot again.
    for step in ["panorama", "view1"] {
        let attempts = done["steps"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|s| s["name"] == step)
            .count();
        assert_eq!(attempts, 1, "{step} shot again");
    }
    // Every file on disk is listed, and every listed file is on disk and verifies.
    let on_disk: Vec<String> = std::fs::read_dir(session_dir.join("raw"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| !n.starts_with('.'))
        .collect();
    assert_eq!(on_disk.len(), now.len(), "{on_disk:?}");
    common::assert_verifies(dir.path(), state_arg, &id, now.len());
    assert!(session_dir.join("result/coefficients.json").is_file());

    let export = brdfd(
        &[
            "session",
            "export",
            &id,
            "--to",
            "exported",
            "--state-dir",
            state_arg,
        ],
        dir.path(),
    );
    assert!(export.status.success(), "{}", out(&export));
    assert!(dir
        .path()
        .join("exported")
        .join(&id)
        .join("manifest.json")
        .is_file());
}

#[test]
fn bad_session_ids_and_material_names_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().to_str().unwrap();
    let o = brdfd(
        &["session", "show", "../../etc", "--state-dir", state],
        dir.path(),
    );
    assert!(
        out(&o).contains("session id \"../../etc\" is not a valid name"),
        "{}",
        out(&o)
    );
    // A capture of `material` on the simulated rig, which must be refused: what it said.
    let refused = |material: &str| {
        let o = brdfd(
            &[
                "capture",
                "--simulate",
                "--material",
                material,
                "--state-dir",
                state,
            ],
            dir.path(),
        );
        assert!(!o.status.success());
        out(&o)
    };
    let text = refused("Gold/../x");
    assert!(
        text.contains("material \"Gold/../x\" is not a valid name"),
        "{text}"
    );
    assert!(!dir.path().join("sessions").exists(), "nothing was created");
    // A well-formed name the simulator does not have is refused before a session exists too.
    let text = refused("unobtainium");
    assert!(
        text.contains("no material \"unobtainium\"") && text.contains("gold-metallic-paint"),
        "{text}"
    );
    assert!(!text.contains("resume"), "{text}");
    assert!(!dir.path().join("sessions").exists(), "nothing was created");
    // A capital is taken as its lower-case letter, and a slip of the keyboard is answered
    // with the name it is nearest: `GLOD` is `glod`, which is not `gold`.
    let text = refused("GLOD");
    assert!(
        text.contains("no material \"glod\". Did you mean \"gold\"?"),
        "{text}"
    );
    assert!(!dir.path().join("sessions").exists(), "nothing was created");
    // A surface the presets are not named for is pointed to the preset whose notes name it.
    let text = refused("paper");
    assert!(
        text.contains("no material \"paper\". The preset \"paint\" covers it: Matte"),
        "{text}"
    );
    assert!(!dir.path().join("sessions").exists(), "nothing was created");
}

/// Issue 42: a session is named by any start of its id that only it has, as git names a
/// commit, or by the start of its random last part; more than one or none is said clearly.
#[test]
fn a_unique_prefix_names_a_session() {
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("state");
    let ids: Vec<String> = ["gold", "gold", "chrome"]
        .iter()
        .map(|m| {
            brdfd_rig::session::Session::create(&state, m, "simulated", None, serde_json::json!({}))
                .unwrap()
                .manifest()
                .id
                .clone()
        })
        .collect();
    let state = state.to_str().unwrap();
    let show = |id: &str| brdfd(&["session", "show", id, "--state-dir", state], dir.path());
    // The last part is random: a start of it that only one session has.
    let last = |id: &str| id.rsplit('-').next().unwrap().to_string();
    let unique = (1..=6)
        .map(|n| last(&ids[2])[..n].to_string())
        .find(|p| {
            ids[..2]
                .iter()
                .all(|i| !last(i).starts_with(p.as_str()) && !i.starts_with(p.as_str()))
        })
        .expect("three random parts differ within six digits");
    let o = show(&unique);
    assert!(o.status.success(), "{}", out(&o));
    assert!(
        out(&o).contains(&format!("session {}: created", ids[2])),
        "{}",
        out(&o)
    );
    // The id's own start: the chrome session's id is the only one with `chrome` in it.
    let start = ids[2].split("-chrome-").next().unwrap().to_string() + "-c";
    let o = show(&start);
    assert!(
        out(&o).contains(&format!("session {}:", ids[2])),
        "{}",
        out(&o)
    );
    // The century begins all three.
    let o = show("2");
    assert!(!o.status.success());
    let said = out(&o);
    assert!(
        said.contains("begins 3 session ids") && said.contains("give more of the id"),
        "{said}"
    );
    let o = show("ffffffff");
    assert!(!o.status.success());
    assert!(
        out(&o).contains("no session id starts with \"ffffffff\""),
        "{}",
        out(&o)
    );
}

/// A full disk, for real: the state directory is a 3 MB tmpfs, mounted in a user and mount
/// namespace of the test's own (`unshare -rm`), so no privilege is needed beyond what a CI
/// container gives. The raw files fit; the 35 MB MERL table of the results does not.
#[test]
fn a_full_disk_fails_the_session_clearly_and_it_resumes_once_there_is_room() {
    let dir = tempfile::tempdir().unwrap();
    let (state, kept) = (dir.path().join("state"), dir.path().join("kept"));
    std::fs::create_dir_all(&state).unwrap();
    std::fs::create_dir_all(&kept).unwrap();
    let usable = Command::new("unshare")
        .args(["-rm", "true"])
        .status()
        .is_ok_and(|s| s.success());
    assert!(
        usable,
        "this test needs user and mount namespaces (`unshare -rm`, util-linux)"
    );
    // Inside the namespace: fill the small disk, keep a copy of what the failure left, then
    // make room and resume. The tmpfs goes away with the namespace, so the script copies out.
    let script = r#"
        set -u
        mount -t tmpfs -o size=3m tmpfs "$STATE" || exit 90
        "$BRDFD" capture --simulate --material gold --size 96 --state-dir "$STATE" > "$KEPT/capture.log" 2>&1
        echo $? > "$KEPT/capture.rc"
        "$BRDFD" session show "$(ls "$STATE/sessions")" --state-dir "$STATE" > "$KEPT/show.log" 2>&1
        mkdir "$KEPT/full" && cp -a "$STATE/." "$KEPT/full/"
        mount -o remount,size=200m "$STATE" || exit 91
        "$BRDFD" session resume "$(ls "$STATE/sessions")" --state-dir "$STATE" > "$KEPT/resume.log" 2>&1
        echo $? > "$KEPT/resume.rc"
        "$BRDFD" session show "$(ls "$STATE/sessions")" --state-dir "$STATE" > "$KEPT/show-after.log" 2>&1
    "#;
    let ran = common::isolated(&mut Command::new("unshare"))
        .args(["-rm", "sh", "-c", script])
        .env("STATE", &state)
        .env("KEPT", &kept)
        .env("BRDFD", env!("CARGO_BIN_EXE_brdfd"))
        .status()
        .unwrap();
    assert!(ran.success(), "the namespace script failed: {ran}");
    let read = |f: &str| std::fs::read_to_string(kept.join(f)).unwrap();

    // The capture failed, saying where and why, and how to continue.
    assert_eq!(read("capture.rc").trim(), "1");
    let log = read("capture.log");
    assert!(log.contains("No space left on device"), "{log}");
    assert!(log.contains("brdfd session resume"), "{log}");
    // What was captured is on disk, listed and whole; the session says it failed and why.
    let show = read("show.log");
    assert!(show.contains("13 raw files verified"), "{show}");
    assert!(show.contains("\"state\": \"failed\""), "{show}");
    assert!(show.contains("No space left on device"), "{show}");
    // ...and what to do: the failure the core wrote (the results' table) says the disk is full.
    assert!(show.contains("the disk is full; free space"), "{show}");
    // ...and its code, for programs.
    assert!(show.contains("\"code\": \"disk_full\""), "{show}");
    let sessions: Vec<_> = std::fs::read_dir(kept.join("full/sessions"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    assert_eq!(sessions.len(), 1);
    // The half-written results were removed: that is what made room to record the failure.
    assert!(!sessions[0].join("result.partial").exists());

    // With room again, resume finishes it without shooting anything again.
    let resume = read("resume.log");
    assert_eq!(read("resume.rc").trim(), "0", "{resume}");
    assert!(
        resume.contains("panorama: 8 frames already in the session"),
        "{resume}"
    );
    assert!(
        resume.contains("view1: 5 files already in the session"),
        "{resume}"
    );
    let after = read("show-after.log");
    assert!(after.contains("\"state\": \"done\""), "{after}");
    assert!(after.contains("13 raw files verified"), "{after}");
}

/// A session that a vanished process left capturing: `session cancel latest` records it as
/// interrupted, and says how to resume it; a session being captured right now is left alone.
#[test]
fn cancel_records_a_session_left_capturing_as_interrupted() {
    use brdfd_rig::session::{Session, State};
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("state");
    let mut s = Session::create(&state, "gold", "", None, serde_json::json!({})).unwrap();
    s.set_state(State::Capturing, None).unwrap();
    let id = s.manifest().id.clone();
    let state_arg = state.to_str().unwrap();
    let cancel = ["session", "cancel", "latest", "--state-dir", state_arg];

    // Claimed, as by a running capture: refused, and nothing changes.
    let claim = s.claim().unwrap();
    let o = brdfd(&cancel, dir.path());
    assert!(!o.status.success());
    assert!(out(&o).contains("press Ctrl-C there"), "{}", out(&o));
    drop(claim);

    let o = brdfd(&cancel, dir.path());
    assert!(o.status.success(), "{}", out(&o));
    assert!(
        out(&o).contains(&format!("`brdfd session resume {id}` continues it")),
        "{}",
        out(&o)
    );
    let after = Session::open(&state, &id).unwrap();
    assert_eq!(after.manifest().state, State::Failed);
    let o = brdfd(&cancel, dir.path());
    assert!(out(&o).contains("is already failed"), "{}", out(&o));
}

/// Issue 40: Ctrl-C and SIGTERM stop an in-process capture within 5 s, in the estimate as
/// while shooting, and say what they wait for; the session is recorded as interrupted, with
/// what was captured kept.
#[test]
fn ctrl_c_and_sigterm_stop_a_capture_within_5_s() {
    // (signal, the manifest state it is sent in)
    for (signal, when) in [
        ("-INT", "estimating"),
        ("-TERM", "estimating"),
        ("-TERM", "capturing"),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let state = dir.path().join("state");
        let mut child = common::command()
            .current_dir(dir.path())
            .args([
                "capture",
                "--simulate",
                "--in-process",
                "--material",
                "gold",
            ])
            .args(["--size", "96", "--views", "2", "--state-dir"])
            .arg(&state)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let start = Instant::now();
        let session = loop {
            if let Some((dir, m)) = manifest(&state) {
                if m["state"] == when {
                    break dir;
                }
            }
            assert!(
                start.elapsed() < Duration::from_secs(120),
                "the capture never got to {when}"
            );
            assert!(child.try_wait().unwrap().is_none(), "the capture ended");
            std::thread::sleep(Duration::from_millis(5));
        };
        let sent = Instant::now();
        let killed = Command::new("sh")
            .args(["-c", &format!("kill {signal} {}", child.id())])
            .status()
            .unwrap();
        assert!(killed.success());
        let o = loop {
            if child.try_wait().unwrap().is_some() {
                break child.wait_with_output().unwrap();
            }
            assert!(sent.elapsed() < Duration::from_secs(60), "it never stopped");
            std::thread::sleep(Duration::from_millis(10));
        };
        let took = sent.elapsed();
        let said = format!(
            "{}{}",
            String::from_utf8_lossy(&o.stdout),
            String::from_utf8_lossy(&o.stderr)
        );
        eprintln!("{signal} while {when}: stopped {took:.2?} after it");
        assert!(
            took < Duration::from_secs(5),
            "{signal} while {when}: {took:?}\n{said}"
        );
        assert_eq!(o.status.code(), Some(1), "{said}");
        assert!(said.contains("stopping: waiting for"), "{said}");
        assert!(
            said.contains("interrupted; what was captured is kept"),
            "{said}"
        );
        let m: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(session.join("manifest.json")).unwrap())
                .unwrap();
        assert_eq!(m["state"], "failed", "{m}");
        let reason = m["history"].to_string();
        assert!(
            reason.contains("cancelled; what was captured is kept"),
            "{reason}"
        );
    }
}
