//! Views turned by hand, on a rig with no turntable: `brdfd capture --views N` asks at the
//! terminal between views, and the daemon waits for `POST /sessions/{id}/continue` after its
//! `waiting_for_operator` event. The simulated rig's `[simulation] turntable = "absent"` is
//! such a rig (its simulated object still turns, as a hand would turn it).

mod common;

use std::io::Write;
use std::process::Stdio;

use common::{command, out, Daemon};

/// The shipped simulated rig without its turntable, its object camera at 64².
fn rig() -> String {
    format!(
        "{}\n[simulation]\nturntable = \"absent\"\n",
        include_str!("../config/rigs/simulated.toml")
            .replace("width = 256", "width = 64")
            .replace("height = 256", "height = 64")
    )
}

/// `brdfd capture` of two views with `answer` on its standard input (None: closed).
fn capture(dir: &std::path::Path, answer: Option<&str>) -> (bool, String) {
    std::fs::write(dir.join("rig.toml"), rig()).unwrap();
    let mut child = command()
        .args([
            "capture",
            "--rig",
            "rig.toml",
            "--material",
            "gold",
            "--size",
            "64",
            "--views",
            "2",
            "--turn",
            "45",
            "--state-dir",
            "state",
        ])
        .current_dir(dir)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdin = child.stdin.take().unwrap();
    if let Some(a) = answer {
        stdin.write_all(a.as_bytes()).unwrap();
    } else {
        drop(stdin);
        let o = child.wait_with_output().unwrap();
        return (o.status.success(), out(&o));
    }
    let o = child.wait_with_output().unwrap();
    (o.status.success(), out(&o))
}

#[test]
fn the_cli_asks_for_each_turn_and_goes_on_after_enter() {
    let dir = tempfile::tempdir().unwrap();
    let (ok, text) = capture(dir.path(), Some("\n"));
    assert!(ok, "{text}");
    assert!(
        text.contains("the rig has no turntable, so it is turned by hand"),
        "{text}"
    );
    assert!(
        text.contains("view 2 of 2: turn the object by hand to 45.0°")
            && text.contains("press Enter once it is turned"),
        "{text}"
    );
    assert!(text.contains("turned by hand to 45.0°"), "{text}");
    // Both views went into the estimate.
    assert!(text.contains("re-renders the photos"), "{text}");
}

#[test]
fn with_no_one_at_the_terminal_the_capture_stops_and_can_be_resumed() {
    let dir = tempfile::tempdir().unwrap();
    let (ok, text) = capture(dir.path(), None);
    assert!(!ok, "{text}");
    assert!(text.contains("standard input is closed"), "{text}");
    assert!(text.contains("brdfd session resume"), "{text}");
}

#[test]
fn the_daemon_waits_for_continue() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("rig.toml"), rig()).unwrap();
    let rig_path = dir.path().join("rig.toml");
    let daemon = Daemon::start(
        &dir.path().join("state"),
        &["--rig", rig_path.to_str().unwrap()],
    );
    // Nothing waits yet.
    let (status, body) = daemon.post("/sessions/nothing/continue", serde_json::json!({}));
    assert_eq!(status, 409, "{body}");
    assert_eq!(body["error"], "not_waiting");
    let (status, started) = daemon.post(
        "/sessions",
        serde_json::json!({"material": "gold", "views": 2, "turn": 45.0}),
    );
    assert_eq!(status, 202, "{started}");
    let id = started["id"].as_str().unwrap().to_string();
    // The capture asks, and waits until told.
    let start = std::time::Instant::now();
    loop {
        let (_, s) = daemon.get(&format!("/sessions/{id}"));
        let views = s["manifest"]["steps"].as_array().map_or(0, |steps| {
            steps.iter().filter(|s| s["complete"] == true).count()
        });
        if views >= 2 {
            break; // the panorama and view 1
        }
        assert!(
            start.elapsed().as_secs() < 120,
            "view 1 never finished: {s}"
        );
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
    let (status, body) = loop {
        let (status, body) =
            daemon.post(&format!("/sessions/{id}/continue"), serde_json::json!({}));
        if status == 202 || start.elapsed().as_secs() > 120 {
            break (status, body);
        }
        std::thread::sleep(std::time::Duration::from_millis(100));
    };
    assert_eq!(status, 202, "{body}");
    assert_eq!(body["continuing"], true);
    let events = daemon.events(&id);
    let waiting = events
        .iter()
        .find(|e| e["type"] == "waiting_for_operator")
        .expect("a waiting_for_operator event");
    assert_eq!(waiting["view"], 2);
    assert_eq!(waiting["degrees"], 45.0);
    let last = events.last().unwrap();
    assert_eq!(last["type"], "finished", "{last}");
    assert_eq!(last["state"], "done", "{last}");
}
