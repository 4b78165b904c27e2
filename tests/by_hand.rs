//! Views turned by hand, on a rig with no turntable: `brdfd capture --views N` asks at the
//! terminal between views, and the daemon waits for `POST /sessions/{id}/continue` after its
//! `waiting_for_operator` event. The simulated rig's `[simulation] turntable = "absent"` is
//! such a rig (its simulated object still turns, as a hand would turn it).

mod common;

use std::time::{Duration, Instant};

use common::{answering, Daemon};

/// The shipped simulated rig without its turntable, its object camera at 64².
fn rig() -> String {
    format!(
        "{}\n[simulation]\nturntable = \"absent\"\n",
        include_str!("../config/rigs/simulated.toml")
            .replace("width = 256", "width = 64")
            .replace("height = 256", "height = 64")
    )
}

fn capture_args() -> Vec<&'static str> {
    vec![
        "capture",
        "--rig",
        "rig.toml",
        "--material",
        "gold",
        "--size",
        "64",
        "--views",
        "3",
        "--turn",
        "45",
        "--state-dir",
        "state",
    ]
}

#[test]
fn the_cli_asks_for_each_turn_and_goes_on_after_enter() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("rig.toml"), rig()).unwrap();
    let (ok, text) = answering(dir.path(), &capture_args(), 2);
    assert!(ok, "{text}");
    assert!(
        text.contains("the rig has no turntable, so it is turned by hand"),
        "{text}"
    );
    for (view, deg) in [(2, "45.0"), (3, "90.0")] {
        assert!(
            text.contains(&format!(
                "view {view} of 3: turn the object by hand to {deg}°"
            )) && text.contains(&format!("view {view} of 3: turned by hand to {deg}°")),
            "{text}"
        );
    }
    // Every view went into the estimate.
    assert!(text.contains("re-renders the photos"), "{text}");
}

/// With no one at the terminal the capture stops after the first view; resumed with someone
/// there, it goes on from the second.
#[test]
fn with_no_one_at_the_terminal_the_capture_stops_and_resumes() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("rig.toml"), rig()).unwrap();
    let (ok, text) = answering(dir.path(), &capture_args(), 0);
    assert!(!ok, "{text}");
    assert!(text.contains("standard input is closed"), "{text}");
    assert!(text.contains("brdfd session resume"), "{text}");
    let (ok, text) = answering(
        dir.path(),
        &["session", "resume", "latest", "--state-dir", "state"],
        2,
    );
    assert!(ok, "{text}");
    assert!(
        text.contains("view1: 5 files already in the session"),
        "{text}"
    );
    assert!(text.contains("turned by hand to 90.0°"), "{text}");
}

/// Waits until the daemon's capture `id` waits for `view`'s turn.
fn wait_for_view(daemon: &Daemon, id: &str, view: u64) {
    let start = Instant::now();
    loop {
        let (_, s) = daemon.get(&format!("/sessions/{id}"));
        if s["waiting_for_view"] == view {
            return;
        }
        assert!(
            start.elapsed() < Duration::from_secs(120),
            "never waited for view {view}: {s}"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

fn daemon(dir: &std::path::Path) -> Daemon {
    std::fs::write(dir.join("rig.toml"), rig()).unwrap();
    let rig_path = dir.join("rig.toml");
    Daemon::start(&dir.join("state"), &["--rig", rig_path.to_str().unwrap()])
}

#[test]
fn the_daemon_waits_for_continue_for_the_view_it_asked() {
    let dir = tempfile::tempdir().unwrap();
    let daemon = daemon(dir.path());
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
    wait_for_view(&daemon, &id, 2);
    // An answer for another view is refused; the right one is taken at once.
    let path = format!("/sessions/{id}/continue");
    let (status, body) = daemon.post(&path, serde_json::json!({"view": 3}));
    assert_eq!(status, 409, "{body}");
    assert!(
        body["message"].as_str().unwrap().contains("view 3"),
        "{body}"
    );
    let (status, body) = daemon.post(&path, serde_json::json!({"view": 2}));
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

#[test]
fn a_capture_waiting_for_a_turn_can_be_cancelled() {
    let dir = tempfile::tempdir().unwrap();
    let daemon = daemon(dir.path());
    let (_, started) = daemon.post(
        "/sessions",
        serde_json::json!({"material": "gold", "views": 2}),
    );
    let id = started["id"].as_str().unwrap().to_string();
    wait_for_view(&daemon, &id, 2);
    let (status, body) = daemon.post(&format!("/sessions/{id}/cancel"), serde_json::json!({}));
    assert_eq!(status, 202, "{body}");
    let last = daemon.events(&id).last().cloned().unwrap();
    assert_eq!(last["state"], "failed", "{last}");
    assert!(
        last["error"].as_str().unwrap().contains("cancelled"),
        "{last}"
    );
}

/// `brdfd session follow` asks at its terminal for the wait that is on, and answers it.
#[test]
fn session_follow_answers_the_wait_that_is_on() {
    let dir = tempfile::tempdir().unwrap();
    let daemon = daemon(dir.path());
    let (_, started) = daemon.post(
        "/sessions",
        serde_json::json!({"material": "gold", "views": 2, "turn": 45.0}),
    );
    let id = started["id"].as_str().unwrap().to_string();
    wait_for_view(&daemon, &id, 2);
    let addr = format!("--daemon={}", daemon.addr);
    let (ok, text) = answering(
        dir.path(),
        &["session", "follow", &id, "--state-dir", "state", &addr],
        1,
    );
    assert!(ok, "{text}");
    assert!(text.contains("Ctrl-C stops following"), "{text}");
    assert!(text.contains("turned by hand to 45.0°"), "{text}");
}
