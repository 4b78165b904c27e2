//! The daemon as an operator and a lab's scripts meet it: `brdfd serve --simulate` as a
//! process, driven through its HTTP API and through `brdfd capture`.

mod common;

use std::time::{Duration, Instant};

use common::{brdfd, command, out, printed_coefficients, relative_error, text, Daemon};
use serde_json::json;

/// With the material's projection on the bench (`--in-span`), the coefficients are known.
/// Every pixel recovers them within 6% (relative L2 over the six coefficients; measured
/// 5.0% at 96 × 96, 4.2% before the renderers read the map inside a sharp lobe): what is left
/// is the capture chain itself (8-bit JPEG brackets, the THETA map's HDR merge and
/// downsampling, the lights' compression, and the bench's photo and the estimate's rows
/// integrating the lobe's peak at their own light counts). The paper's 20 pixels
/// recover them within 15% (measured 7.5%). The paper's joint colour model, not the gold
/// preset's per-channel one: the projection is a joint-colour BRDF, and six unknowns measure
/// the chain more sharply than eighteen (per channel: 11% and 18%).
#[test]
fn captures_in_the_daemon_and_in_process_recover_the_known_coefficients() {
    let dir = tempfile::tempdir().unwrap();
    let daemon = Daemon::simulated(&dir.path().join("daemon-state"));
    let args = [
        "capture",
        "--simulate",
        "--in-span",
        "--material",
        "gold",
        "--size",
        "96",
        "--model",
        "basis",
        "--pixels",
        "all",
        "--colour",
        "joint",
        "--verbose",
    ];

    let mut with_daemon = args.to_vec();
    with_daemon.extend(["--daemon", daemon.addr.as_str()]);
    let o = brdfd(&with_daemon, dir.path());
    let (stdout, stderr) = text(&o);
    assert!(o.status.success(), "{stdout}\n{stderr}");
    assert!(
        stdout.contains(&format!("running in the daemon at http://{}", daemon.addr)),
        "{stdout}"
    );
    let estimated = printed_coefficients(&stdout, "coefficients");
    let truth = printed_coefficients(&stdout, "ground truth projected on the basis");
    assert_eq!((estimated.len(), truth.len()), (6, 6), "{stdout}");
    let e = relative_error(&estimated, &truth);
    assert!(e < 0.06, "all pixels, in the daemon: {e:.4}\n{stdout}");

    let mut here = args.to_vec();
    here.extend(["--in-process", "--state-dir", "local"]);
    let o = brdfd(&here, dir.path());
    let local = out(&o);
    assert!(o.status.success(), "{local}");
    assert!(local.contains("running in this process"), "{local}");
    // One flow, two ways of running it: the same numbers.
    assert_eq!(printed_coefficients(&local, "coefficients"), estimated);

    // A second capture on the same daemon, with the preset's 20 pixels, reuses the open
    // devices rather than opening them again.
    let mut twenty = with_daemon.clone();
    let at = twenty.iter().position(|a| *a == "all").unwrap();
    twenty[at] = "20";
    let o = brdfd(&twenty, dir.path());
    let stdout = out(&o);
    assert!(o.status.success(), "{stdout}");
    let e = relative_error(
        &printed_coefficients(&stdout, "coefficients"),
        &printed_coefficients(&stdout, "ground truth projected on the basis"),
    );
    assert!(e < 0.15, "20 pixels: {e:.4}\n{stdout}");
    let (status, devices) = daemon.get("/devices");
    assert_eq!(status, 200);
    let devices = devices.as_array().unwrap();
    // The DSLR, its fallback webcam, the THETA and the turntable.
    assert_eq!(devices.len(), 4, "{devices:?}");
    for d in devices {
        assert_eq!(d["state"], "open", "{d}");
        assert_eq!(d["opened"], 1, "{d}");
    }
}

/// Starts a slow capture (four turntable views) through the API; returns its id.
fn start_slow(daemon: &Daemon) -> String {
    let (status, body) = daemon.post(
        "/sessions",
        json!({ "material": "gold", "size": 96, "views": 4 }),
    );
    assert_eq!(status, 202, "{body}");
    body["id"].as_str().unwrap().to_string()
}

#[test]
fn a_second_capture_is_refused_and_a_cancelled_one_resumes() {
    let dir = tempfile::tempdir().unwrap();
    let daemon = Daemon::simulated(&dir.path().join("state"));
    let id = start_slow(&daemon);

    let (status, body) = daemon.post("/sessions", json!({ "material": "chrome" }));
    assert_eq!(status, 409, "{body}");
    assert_eq!(body["error"], "busy");
    assert!(body["message"].as_str().unwrap().contains(&id), "{body}");
    // A bad plan is a bad request even while a capture runs: the caller learns what to fix.
    let (status, body) = daemon.post("/sessions", json!({ "material": "../x" }));
    assert_eq!((status, body["error"].as_str()), (400, Some("bad_request")));
    // Issue 20, D4: what a web page may send across sites without asking first (a text/plain
    // body, or a POST with no body) is refused, so no page can cancel or start a capture.
    let http = reqwest::blocking::Client::new();
    let url = |path: &str| format!("http://{}/api/v1{path}", daemon.addr);
    let page = http
        .post(url(&format!("/sessions/{id}/cancel")))
        .header("Content-Type", "text/plain")
        .body("{}")
        .send()
        .unwrap();
    assert_eq!(page.status().as_u16(), 415);
    let body: serde_json::Value = page.json().unwrap();
    assert_eq!(body["error"], "unsupported_media_type", "{body}");
    let bare = http.post(url("/sessions")).send().unwrap();
    assert_eq!(bare.status().as_u16(), 415);
    // The capture was not cancelled by either.
    let (status, _) = daemon.post("/sessions", json!({ "material": "chrome" }));
    assert_eq!(status, 409);
    let o = brdfd(
        &[
            "capture",
            "--simulate",
            "--material",
            "paint",
            "--daemon",
            &daemon.addr,
        ],
        dir.path(),
    );
    assert!(!o.status.success());
    assert!(
        out(&o).contains(&format!("busy: session {id} is capturing")),
        "{}",
        out(&o)
    );
    assert_eq!(daemon.get("/health").1["busy"], id.as_str());
    // The list says which session is running, and that it is capturing, never "created".
    let listed = daemon.listed(&id);
    assert_eq!(
        (&listed["running"], &listed["state"]),
        (&json!(true), &json!("capturing")),
        "{listed}"
    );

    daemon.wait_for_step(&id, "view1");
    let (status, body) = daemon.post(&format!("/sessions/{id}/cancel"), json!({}));
    assert_eq!(status, 202, "{body}");
    let events = daemon.events(&id);
    let last = events.last().unwrap();
    assert_eq!(last["type"], "finished", "{last}");
    assert_eq!(last["state"], "failed");
    assert!(
        last["error"].as_str().unwrap().contains("cancelled"),
        "{last}"
    );
    assert_eq!(last["cancelled"], true, "{last}");
    assert_eq!(last["code"], "cancelled", "{last}");
    // The stream showed the phases as they ran.
    assert!(events
        .iter()
        .any(|e| e["type"] == "phase_done" && e["phase"] == "panorama bracket"));
    assert!(events
        .iter()
        .any(|e| e["type"] == "progress" && e["phase"] == "view1: object bracket"));
    let (status, body) = daemon.post(&format!("/sessions/{id}/cancel"), json!({}));
    assert_eq!((status, body["error"].as_str()), (409, Some("not_running")));
    // No such session: not found, as for a resume.
    let (status, body) = daemon.post("/sessions/20000101-000000-gold-abcdef/cancel", json!({}));
    assert_eq!((status, body["error"].as_str()), (404, Some("not_found")));
    let (status, body) = daemon.get(&format!("/sessions/{id}/result"));
    assert_eq!((status, body["error"].as_str()), (409, Some("not_done")));
    // The manifest keeps the cancel's code beside its words.
    let (status, detail) = daemon.get(&format!("/sessions/{id}"));
    assert_eq!(status, 200, "{detail}");
    let failed = detail["manifest"]["history"]
        .as_array()
        .unwrap()
        .last()
        .unwrap();
    assert_eq!(
        (&failed["state"], &failed["code"]),
        (&json!("failed"), &json!("cancelled")),
        "{failed}"
    );

    let (status, body) = daemon.post(&format!("/sessions/{id}/resume"), json!({}));
    assert_eq!(status, 202, "{body}");
    let events = daemon.events(&id);
    let texts: Vec<&str> = events.iter().filter_map(|e| e["text"].as_str()).collect();
    assert!(
        texts.contains(&"panorama: 8 frames already in the session"),
        "{texts:?}"
    );
    let finished = events.last().unwrap();
    assert_eq!(finished["state"], "done");
    // A capture that did not fail has no failure code.
    assert!(finished.get("code").is_none(), "{finished}");
    // Every event has an id; a client that reconnects with Last-Event-ID gets only what came
    // after it, and one with an id of another run (say, before the session was resumed, or
    // from another daemon) gets this run's events from the first.
    let all = daemon.events_after(&id, None);
    let n = all.len();
    assert_eq!(n, events.len());
    let resumed = daemon.events_after(&id, Some(&all[n - 3].0));
    assert_eq!(resumed, all[n - 2..].to_vec());
    assert_eq!(&resumed[1].1, finished);
    let run = all[0].0.split_once('-').unwrap().0;
    let other_run = format!("{}-{}", run.parse::<u64>().unwrap() + 1, n - 3);
    assert_eq!(daemon.events_after(&id, Some(&other_run)), all);
    // The finished event carries the result itself, not prose: model, columns, coefficients
    // and the fit, as coefficients.json has them.
    let summary = &finished["result"];
    assert_eq!(summary["model"], "hybrid", "{finished}");
    assert_eq!(
        summary["columns"].as_array().unwrap().len(),
        summary["coefficients"].as_array().unwrap().len()
    );
    assert!(summary["fit_error"].as_f64().unwrap() < 0.1, "{finished}");
    assert!(summary["fit_verdict"].as_str().unwrap().starts_with("good"));
    assert!(
        summary["relight_error"].as_f64().is_some(),
        "a simulator knows the truth"
    );
    let (_, stored) = daemon.get(&format!("/sessions/{id}"));
    let steps = stored["manifest"]["steps"].as_array().unwrap();
    for step in ["panorama", "view1"] {
        let n = steps.iter().filter(|s| s["name"] == step).count();
        assert_eq!(n, 1, "{step} was shot again");
    }

    let (status, result) = daemon.get(&format!("/sessions/{id}/result"));
    assert_eq!(status, 200);
    assert_eq!(result["coefficients"], summary["coefficients"]);
    // The default model: two lobes' weights and roughnesses, and the mix's weights.
    assert_eq!(result["model"], "hybrid");
    let mixed = result["mixture"].as_array().unwrap().len();
    assert_eq!(
        result["coefficients"].as_array().unwrap().len(),
        17 + 3 * mixed
    );
    let (status, png) = daemon.get_bytes(&format!("/sessions/{id}/result/preview.png"));
    assert_eq!(status, 200);
    assert!(png.starts_with(b"\x89PNG"));
    let (status, html) = daemon.get_bytes(&format!("/sessions/{id}/result/report.html"));
    assert_eq!(status, 200);
    assert!(html.starts_with(b"<!DOCTYPE html>"));
    let (status, png) = daemon.get_bytes(&format!("/sessions/{id}/result/compare.png"));
    assert_eq!(status, 200);
    assert!(png.starts_with(b"\x89PNG"));
    // The capture's light, for the 3D view: Radiance RGBE, as the daemon's media type says.
    let (status, hdr) = daemon.get_bytes(&format!("/sessions/{id}/result/light.hdr"));
    assert_eq!(status, 200);
    assert!(
        hdr.starts_with(b"#?RADIANCE"),
        "{:?}",
        &hdr[..16.min(hdr.len())]
    );
    // Done, so no longer running.
    let listed = daemon.listed(&id);
    assert_eq!(listed["running"], false, "{listed}");
    let (status, _) = daemon.get_bytes(&format!("/sessions/{id}/result/manifest.json"));
    assert_eq!(status, 404);
    let (status, body) = daemon.get("/sessions/..%2F..%2Fetc");
    assert_eq!(status, 404, "{body}");
    // A misspelt field and an unknown value are refused, naming what was wrong.
    let (status, body) = daemon.post(
        "/sessions",
        json!({ "material": "gold", "color": "per-channel" }),
    );
    assert_eq!(status, 400);
    assert!(
        body["message"]
            .as_str()
            .unwrap()
            .contains("unknown field `color`"),
        "{body}"
    );
    let (status, body) = daemon.post("/sessions", json!({ "material": "gold", "colour": "rgb" }));
    assert_eq!(status, 400);
    let message = body["message"].as_str().unwrap();
    assert!(
        message.contains("`rgb`") && message.contains("per-channel"),
        "{body}"
    );

    // Another daemon on the same sessions, which did not run this one, ends its stream with
    // the same result, read back from the stored coefficients.json.
    drop(daemon);
    let later = Daemon::simulated(&dir.path().join("state"));
    let replayed = later.events(&id);
    assert_eq!(
        replayed.len(),
        1,
        "a stored session's stream is its outcome"
    );
    assert_eq!(&replayed[0]["result"], summary, "{}", replayed[0]);
    // A browser that reconnects with the earlier daemon's last id still gets the outcome.
    let last_seen = all.last().unwrap().0.clone();
    let again = later.events_after(&id, Some(&last_seen));
    assert_eq!(again.len(), 1, "{again:?}");
    assert_eq!(again[0].1["type"], "finished");
}

#[test]
fn a_daemon_killed_mid_capture_is_restarted_and_the_session_resumed() {
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("state");
    let state_arg = state.to_str().unwrap();
    let mut first = Daemon::simulated(&state);
    let id = start_slow(&first);
    first.wait_for_step(&id, "view1");
    let (_, before) = first.get(&format!("/sessions/{id}"));
    first.signal("-KILL");
    first.child.wait().unwrap();

    let second = Daemon::simulated(&state);
    let (_, after) = second.get(&format!("/sessions/{id}"));
    assert_eq!(after["manifest"]["state"], "failed");
    let reason = after["manifest"]["history"]
        .as_array()
        .unwrap()
        .last()
        .unwrap()["reason"]
        .as_str()
        .unwrap()
        .to_string();
    assert!(reason.contains("interrupted"), "{reason}");

    let o = brdfd(
        &[
            "session",
            "resume",
            &id,
            "--daemon",
            &second.addr,
            "--state-dir",
            state_arg,
        ],
        dir.path(),
    );
    let text = out(&o);
    assert!(o.status.success(), "{text}");
    assert!(text.contains("running in the daemon"), "{text}");
    assert!(
        text.contains("view1: 5 files already in the session"),
        "{text}"
    );

    let (_, done) = second.get(&format!("/sessions/{id}"));
    assert_eq!(done["manifest"]["state"], "done");
    let files = |m: &serde_json::Value| -> Vec<(String, String)> {
        m["manifest"]["steps"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|s| s["complete"] == true)
            .flat_map(|s| s["files"].as_array().unwrap().clone())
            .map(|f| {
                (
                    f["name"].as_str().unwrap().to_string(),
                    f["sha256"].as_str().unwrap().to_string(),
                )
            })
            .collect()
    };
    let (was, now) = (files(&before), files(&done));
    for f in &was {
        assert!(now.contains(f), "{f:?} lost or changed");
    }
    let mut names: Vec<&String> = now.iter().map(|(n, _)| n).collect();
    names.sort();
    names.dedup();
    assert_eq!(names.len(), now.len(), "a raw file is listed twice");
    // 8 panorama frames and 5 per view.
    assert_eq!(now.len(), 8 + 4 * 5);
    common::assert_verifies(dir.path(), state_arg, &id, now.len());
}

#[test]
fn sigterm_cancels_the_capture_and_stops_the_daemon() {
    let dir = tempfile::tempdir().unwrap();
    let mut daemon = Daemon::simulated(&dir.path().join("state"));
    let id = start_slow(&daemon);
    daemon.wait_for_step(&id, "panorama");
    daemon.signal("-TERM");
    let (status, _) = daemon.wait_for_exit(Duration::from_secs(60));
    assert!(status.success(), "{status}");
    let said = daemon.rest_of_stdout();
    assert!(
        said.contains("shutting down") && said.contains("stopped"),
        "{said}"
    );
    let show = brdfd(
        &[
            "session",
            "show",
            &id,
            "--state-dir",
            dir.path().join("state").to_str().unwrap(),
        ],
        dir.path(),
    );
    let text = out(&show);
    assert!(text.contains("\"state\": \"failed\""), "{text}");
    assert!(
        text.contains("cancelled; what was captured is kept"),
        "{text}"
    );
}

/// Issue 40: SIGTERM ends the daemon within 5 s in every long phase of a capture: while the
/// simulated camera's scene renders and it shoots, in the estimate, and in writing the
/// results. A phase that can still finish in time (the results) is let finish.
#[test]
fn sigterm_stops_the_daemon_within_5_s_in_every_phase() {
    for phase in ["view1: object bracket", "estimate", "write results"] {
        let dir = tempfile::tempdir().unwrap();
        let mut daemon = Daemon::simulated(&dir.path().join("state"));
        let (status, body) = daemon.post(
            "/sessions",
            json!({ "material": "gold", "size": 128, "views": 2 }),
        );
        assert_eq!(status, 202, "{body}");
        let id = body["id"].as_str().unwrap().to_string();
        daemon.wait_for_phase(&id, phase);
        daemon.signal("-TERM");
        let (status, took) = daemon.wait_for_exit(Duration::from_secs(60));
        eprintln!("SIGTERM in {phase}: stopped {took:.2?} after it");
        assert!(status.success(), "{status}");
        assert!(took < Duration::from_secs(5), "{phase}: {took:?}");
        let said = daemon.rest_of_stdout();
        assert!(said.contains("stopped"), "{said}");
        let manifest: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(
                dir.path()
                    .join("state/sessions")
                    .join(&id)
                    .join("manifest.json"),
            )
            .unwrap(),
        )
        .unwrap();
        let cancelled = manifest["state"] == "failed"
            && manifest["history"]
                .to_string()
                .contains("cancelled; what was captured is kept");
        assert!(
            cancelled || (phase == "write results" && manifest["state"] == "done"),
            "{phase}: {manifest}"
        );
    }
}

/// A simulated daemon whose brdfd.toml (in `dir`) sets the token "correct horse".
fn with_token(dir: &std::path::Path) -> Daemon {
    std::fs::write(
        dir.join("brdfd.toml"),
        "api = \"127.0.0.1:7878\"\ntoken = \"correct horse\"\n",
    )
    .unwrap();
    Daemon::start(
        &dir.join("state"),
        &[
            "--simulate",
            "--config",
            dir.join("brdfd.toml").to_str().unwrap(),
        ],
    )
}

#[test]
fn a_configured_token_is_required_and_other_machines_need_one() {
    let dir = tempfile::tempdir().unwrap();
    let daemon = with_token(dir.path());
    let (status, body) = daemon.get("/health");
    assert_eq!(
        (status, body["error"].as_str()),
        (401, Some("unauthorized"))
    );
    let client = reqwest::blocking::Client::new();
    let url = format!("http://{}/api/v1/health", daemon.addr);
    let wrong = client
        .get(&url)
        .bearer_auth("correct horsf")
        .send()
        .unwrap();
    assert_eq!(wrong.status().as_u16(), 401);
    let right = client
        .get(&url)
        .bearer_auth("correct horse")
        .send()
        .unwrap();
    assert_eq!(right.status().as_u16(), 200);

    // The web page's sign-in: a form, a cookie the API accepts, and nothing else.
    let page = format!("http://{}", daemon.addr);
    let no_redirects = reqwest::blocking::Client::builder()
        .redirect(reqwest::redirect::Policy::none())
        .build()
        .unwrap();
    let login = |body: String, host: Option<&str>| {
        let mut r = no_redirects
            .post(format!("{page}/login"))
            .header("Content-Type", "application/x-www-form-urlencoded")
            .body(body);
        if let Some(h) = host {
            r = r.header("Host", h);
        }
        r.send().unwrap()
    };
    assert_eq!(
        login("token=correct+horsf".into(), None).status().as_u16(),
        401
    );
    let signed_in = login("token=correct+horse".into(), None);
    assert_eq!(signed_in.status().as_u16(), 303);
    let cookie = signed_in.headers()["set-cookie"]
        .to_str()
        .unwrap()
        .to_string();
    assert!(
        cookie.contains("HttpOnly") && cookie.contains("SameSite=Strict"),
        "{cookie}"
    );
    let pair = cookie.split(';').next().unwrap().to_string();
    assert!(!pair.contains("correct"), "the token in clear: {pair}");
    let with_cookie = |path: &str| {
        no_redirects
            .get(format!("{page}{path}"))
            .header("Cookie", &pair)
            .send()
            .unwrap()
    };
    assert_eq!(with_cookie("/api/v1/health").status().as_u16(), 200);
    // A wrong Authorization header is not rescued by the cookie's absence, nor the reverse.
    let forged = no_redirects
        .get(format!("{page}/api/v1/health"))
        .header("Cookie", "brdfd_token=636f7272656374")
        .send()
        .unwrap();
    assert_eq!(forged.status().as_u16(), 401);
    // With the cookie, a form-encoded POST (what another page could send) is still refused.
    let form_post = no_redirects
        .post(format!("{page}/api/v1/sessions"))
        .header("Cookie", &pair)
        .header("Content-Type", "application/x-www-form-urlencoded")
        .body("material=gold")
        .send()
        .unwrap();
    assert_eq!(form_post.status().as_u16(), 415);
    // The page and the sign-in answer only to this daemon's own names, and read little.
    assert_eq!(
        login("token=correct+horse".into(), Some("evil.example"))
            .status()
            .as_u16(),
        421
    );
    assert_eq!(
        login("token=".to_string() + &"x".repeat(10_000), None)
            .status()
            .as_u16(),
        413
    );
    let index = with_cookie("/");
    assert_eq!(index.status().as_u16(), 200);
    let policy = index.headers()["content-security-policy"].to_str().unwrap();
    assert!(policy.contains("default-src 'none'"), "{policy}");

    // The CLI without the token is told what is missing.
    let o = brdfd(
        &[
            "capture",
            "--simulate",
            "--material",
            "gold",
            "--daemon",
            &daemon.addr,
        ],
        dir.path(),
    );
    assert!(!o.status.success());
    assert!(out(&o).contains("Authorization: Bearer"), "{}", out(&o));

    let o = command()
        .args([
            "serve",
            "--simulate",
            "--api",
            "0.0.0.0:0",
            "--state-dir",
            "s",
        ])
        .current_dir(dir.path())
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(
        out(&o).contains("reachable from other machines: set `token` too"),
        "{}",
        out(&o)
    );
}

/// Issue 20, D3: sockets that send nothing, or half a request, cannot lock the daemon up, and
/// they are what an attacker gets before authentication. With the cap at 64 connections, 300
/// held sockets later `/health` still answers (the oldest idle connections are closed to make
/// room); a socket that sends nothing is closed after the header timeout; and SIGTERM stops
/// the daemon while clients still hold half-sent requests.
#[test]
fn idle_and_half_sent_connections_cannot_lock_the_daemon_up() {
    use std::io::{Read, Write};
    use std::net::TcpStream;
    let dir = tempfile::tempdir().unwrap();
    let mut daemon = Daemon::start(
        &dir.path().join("state"),
        &[
            "--simulate",
            "--max-connections",
            "64",
            "--header-timeout",
            "2",
        ],
    );
    let mut held = Vec::new();
    for i in 0..300 {
        let mut s = TcpStream::connect(&daemon.addr).unwrap();
        if i % 10 == 0 {
            s.write_all(b"GET /api/v1/health HTTP/1.1\r\nHost: brdfd\r\n")
                .unwrap();
        }
        held.push(s);
    }
    let t = Instant::now();
    let (status, body) = daemon.get("/health");
    eprintln!("/health with 300 sockets held: {:?}", t.elapsed());
    assert_eq!(status, 200, "{body}");

    // A socket that sends nothing is closed by the daemon (a read returns end of stream or a
    // reset), long before the client's own 60 s read timeout.
    let mut quiet = TcpStream::connect(&daemon.addr).unwrap();
    quiet
        .set_read_timeout(Some(Duration::from_secs(60)))
        .unwrap();
    let t = Instant::now();
    let mut buf = [0u8; 64];
    match quiet.read(&mut buf) {
        Ok(0) => {}
        Ok(n) => panic!("the daemon answered {n} bytes to nothing"),
        Err(e) => assert!(
            !matches!(
                e.kind(),
                std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
            ),
            "the daemon kept a silent socket open: {e}"
        ),
    }
    eprintln!("a silent socket was closed after {:?}", t.elapsed());

    // A plan whose body does not arrive is answered 408 (after 10 s), so a body trickled a
    // byte at a time cannot hold a connection busy for good.
    let mut slow = TcpStream::connect(&daemon.addr).unwrap();
    slow.write_all(
        b"POST /api/v1/sessions HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\nContent-Length: 100\r\n\r\n{",
    )
    .unwrap();
    slow.set_read_timeout(Some(Duration::from_secs(60)))
        .unwrap();
    let mut answer = String::new();
    let _ = slow.read_to_string(&mut answer);
    assert!(answer.starts_with("HTTP/1.1 408"), "{answer}");

    // Half-sent requests held open do not keep SIGTERM from ending the daemon.
    let mut half = TcpStream::connect(&daemon.addr).unwrap();
    half.write_all(
        b"POST /api/v1/sessions HTTP/1.1\r\nHost: brdfd\r\nContent-Length: 100\r\n\r\n{",
    )
    .unwrap();
    daemon.signal("-TERM");
    let (status, took) = daemon.wait_for_exit(Duration::from_secs(30));
    eprintln!("stopped {took:?} after SIGTERM");
    assert!(status.success(), "{status}");
    drop((held, half));
}

/// Issue 20, D4: a page after DNS rebinding names its own host, and is refused whatever it
/// asks; a plan names scene files from the daemon's `scenes/` folder and never gives a path
/// (`/dev/zero` would be read without end), and `brdfd capture` says so before sending.
#[test]
fn other_hosts_and_server_paths_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("state");
    let mut daemon = Daemon::simulated(&state);
    let http = reqwest::blocking::Client::new();
    let url = format!("http://{}/api/v1/sessions", daemon.addr);
    let r = http
        .get(&url)
        .header("Host", "evil.example:7878")
        .send()
        .unwrap();
    assert_eq!(r.status().as_u16(), 421);
    let body: serde_json::Value = r.json().unwrap();
    assert_eq!(body["error"], "unknown_host", "{body}");
    let r = http
        .get(&url)
        .header("Host", "localhost:7878")
        .send()
        .unwrap();
    assert_eq!(r.status().as_u16(), 200);

    // A plan that breaks its schema's rules is a bad request; one of the right shape that names
    // no file there cannot be carried out (422, issue 42).
    for (plan, status_wanted, says) in [
        (
            json!({ "material": "gold", "env": "/dev/zero" }),
            400,
            "not give a path",
        ),
        (
            json!({ "material": "gold", "nbrdf": "../../etc/passwd" }),
            400,
            "not give a path",
        ),
        (
            json!({ "material": "gold", "nbrdf": ".." }),
            422,
            "not give a path",
        ),
        (
            json!({ "material": "gold", "env": "missing.hdr" }),
            422,
            "no file \"missing.hdr\"",
        ),
        // Issue 40: a 9,000-exposure bracket was accepted.
        (
            json!({ "material": "gold", "bracket": vec![0.01; 9000] }),
            400,
            "bracket has 9000 shutter speeds; at most 32",
        ),
    ] {
        let (status, body) = daemon.post("/sessions", plan.clone());
        assert_eq!(status, status_wanted, "{plan}: {body}");
        assert!(body["message"].as_str().unwrap().contains(says), "{body}");
    }
    // Nothing was started, and no session was created for the refused plans.
    let (_, list) = daemon.get("/sessions");
    assert_eq!(list.as_array().expect("a list").len(), 0, "{list}");

    // The CLI refuses a path for the daemon before sending it, and says what to do.
    let o = brdfd(
        &[
            "capture",
            "--simulate",
            "--material",
            "gold",
            "--env",
            "/dev/zero",
            "--daemon",
            &daemon.addr,
        ],
        dir.path(),
    );
    let (stdout, stderr) = text(&o);
    assert!(!o.status.success(), "{stdout}");
    assert!(stderr.contains("copy the file there"), "{stderr}");
    daemon.signal("-TERM");
    let _ = daemon.child.wait();
}

/// Issue 20, D9: plans sent at once start one capture, and the ones refused as busy leave no
/// session behind (before, 10 rounds of 6 left 43 sessions stuck in `created`).
#[test]
fn plans_sent_at_once_leave_no_orphan_sessions() {
    let dir = tempfile::tempdir().unwrap();
    let daemon = Daemon::simulated(&dir.path().join("state"));
    let mut started = Vec::new();
    for _round in 0..3 {
        let answers: Vec<(u16, serde_json::Value)> = std::thread::scope(|s| {
            let posts: Vec<_> = (0..6)
                .map(|_| {
                    s.spawn(|| daemon.post("/sessions", json!({ "material": "gold", "size": 32 })))
                })
                .collect();
            posts.into_iter().map(|p| p.join().unwrap()).collect()
        });
        let ok: Vec<&serde_json::Value> = answers
            .iter()
            .filter(|(status, _)| *status == 202)
            .map(|(_, body)| body)
            .collect();
        assert!(
            answers
                .iter()
                .all(|(status, _)| [202, 409].contains(status)),
            "{answers:?}"
        );
        assert_eq!(ok.len(), 1, "{answers:?}");
        let id = ok[0]["id"].as_str().unwrap().to_string();
        // Wait for it to end (cancelled, so that the round is short).
        let (status, _) = daemon.post(&format!("/sessions/{id}/cancel"), json!({}));
        assert!([202, 409].contains(&status));
        let t = Instant::now();
        while daemon.get("/health").1["busy"] != serde_json::Value::Null {
            assert!(
                t.elapsed() < Duration::from_secs(120),
                "the capture never ended"
            );
            std::thread::sleep(Duration::from_millis(20));
        }
        started.push(id);
    }
    let (_, list) = daemon.get("/sessions");
    let mut listed: Vec<String> = list
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["id"].as_str().unwrap().to_string())
        .collect();
    listed.sort();
    started.sort();
    assert_eq!(listed, started, "{list}");
}

/// Issue 20, D10: a capture that fails for want of file descriptors cannot write its failure
/// either. The daemon goes idle all the same, and records the failure once it can; before,
/// the manifest said `capturing` for as long as the daemon ran.
#[test]
fn a_failure_that_could_not_be_written_is_recorded_once_it_can() {
    use std::net::TcpStream;
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("state");
    // Few descriptors, and a connection cap above them: held connections can take them all.
    let daemon = Daemon::start_with_open_files(
        &state,
        &[
            "--simulate",
            "--max-connections",
            "1000",
            "--header-timeout",
            "60",
        ],
        128,
    );
    let id = start_slow(&daemon);
    let manifest = state.join("sessions").join(&id).join("manifest.json");
    let on_disk = || -> serde_json::Value {
        serde_json::from_slice(&std::fs::read(&manifest).unwrap()).unwrap()
    };
    std::thread::scope(|s| {
        let stream = s.spawn(|| daemon.events(&id));
        daemon.wait_for_step(&id, "view1");
        // Every descriptor the daemon has left goes to a connection that says nothing.
        let flood: Vec<TcpStream> = (0..200)
            .filter_map(|_| TcpStream::connect(&daemon.addr).ok())
            .collect();
        let events = stream.join().unwrap();
        let last = events.last().unwrap();
        assert_eq!(last["state"], "failed", "{last}");
        let unwritten = on_disk();
        assert_eq!(
            unwritten["state"], "capturing",
            "the failure was written at once: the flood did not take every descriptor, so \
             this test did not reach what it checks ({last})"
        );
        drop(flood);
    });
    // Once descriptors are free, the failure is recorded, the daemon is idle, and the
    // session can be resumed.
    let start = Instant::now();
    while on_disk()["state"] != "failed" {
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "the failure was never recorded: {}",
            on_disk()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let written = on_disk();
    let reason = &written["history"].as_array().unwrap().last().unwrap()["reason"];
    assert!(reason.as_str().is_some_and(|r| !r.is_empty()), "{written}");
    let (status, health) = daemon.get("/health");
    assert_eq!(status, 200);
    assert_eq!(health["busy"], serde_json::Value::Null, "{health}");
    let (status, shown) = daemon.get(&format!("/sessions/{id}"));
    assert_eq!(status, 200);
    assert_eq!(shown["manifest"]["state"], "failed", "{shown}");
}

/// The daemon's resident memory, bytes (Linux).
fn resident(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    let kb: u64 = status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .unwrap();
    kb * 1024
}

/// Issue 40: result files were read whole into memory per request, and a response nobody
/// read was never timed out: 40 clients asking for `brdf.binary` (35 MB) and reading nothing
/// took the daemon from 138 MB to 1.5 GB. Streamed from disk with a write timeout, memory
/// stays flat, the stalled connections are dropped, and a reader gets the whole file.
#[test]
fn clients_that_never_read_a_large_result_hold_neither_memory_nor_their_slot() {
    use std::io::{Read as _, Write as _};
    use std::net::TcpStream;
    let dir = tempfile::tempdir().unwrap();
    let daemon = Daemon::start(
        &dir.path().join("state"),
        &["--simulate", "--write-timeout", "2"],
    );
    let (status, started) = daemon.post("/sessions", json!({ "material": "gold", "size": 64 }));
    assert_eq!(status, 202, "{started}");
    let id = started["id"].as_str().unwrap().to_string();
    assert_eq!(daemon.events(&id).last().unwrap()["state"], "done");
    let path = format!("/api/v1/sessions/{id}/result/brdf.binary");
    let (status, whole) = daemon.get_bytes(&format!("/sessions/{id}/result/brdf.binary"));
    assert_eq!(status, 200);
    assert!(whole.len() > 30_000_000, "{}", whole.len());

    let pid = daemon.child.id();
    let before = resident(pid);
    let stalled: Vec<TcpStream> = (0..40)
        .map(|_| {
            let mut s = TcpStream::connect(&daemon.addr).unwrap();
            write!(s, "GET {path} HTTP/1.1\r\nHost: {}\r\n\r\n", daemon.addr).unwrap();
            s
        })
        .collect();
    std::thread::sleep(Duration::from_millis(1500));
    let during = resident(pid);
    println!(
        "resident memory: {} MB before, {} MB with 40 stalled readers of {} MB",
        before >> 20,
        during >> 20,
        whole.len() >> 20
    );
    assert!(during < before + (100 << 20), "{before} → {during}");
    // The daemon answers meanwhile.
    assert_eq!(daemon.get("/health").0, 200);
    // Past the write timeout, each stalled connection is dropped: what a late reader gets
    // ends, short of the file.
    std::thread::sleep(Duration::from_secs(3));
    for mut s in stalled {
        s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
        let mut got = Vec::new();
        let _ = s.read_to_end(&mut got);
        assert!(
            got.len() < whole.len(),
            "a stalled reader got the whole file"
        );
    }
    let after = resident(pid);
    assert!(after < before + (100 << 20), "{before} → {after}");
    // And a reader that reads gets every byte.
    let (status, again) = daemon.get_bytes(&format!("/sessions/{id}/result/brdf.binary"));
    assert_eq!((status, again == whole), (200, true));
}

/// Issue 40: event streams could fill the connection cap, and then a cancel was refused too.
/// Streams have a cap of their own, half the connections: beyond it a stream is refused with
/// 503, and `/health` and a cancel still get through.
#[test]
fn event_streams_leave_connections_for_health_and_cancel() {
    use std::io::{Read as _, Write as _};
    use std::net::TcpStream;
    let dir = tempfile::tempdir().unwrap();
    let daemon = Daemon::start(
        &dir.path().join("state"),
        &["--simulate", "--max-connections", "8"],
    );
    let id = start_slow(&daemon);
    let open_stream = || {
        let mut s = TcpStream::connect(&daemon.addr).unwrap();
        write!(
            s,
            "GET /api/v1/sessions/{id}/events HTTP/1.1\r\nHost: {}\r\n\r\n",
            daemon.addr
        )
        .unwrap();
        let mut head = [0u8; 12];
        s.read_exact(&mut head).unwrap();
        (String::from_utf8_lossy(&head).into_owned(), s)
    };
    let streams: Vec<_> = (0..4).map(|_| open_stream()).collect();
    for (head, _) in &streams {
        assert_eq!(head, "HTTP/1.1 200", "{head}");
    }
    let (head, _) = open_stream();
    assert_eq!(head, "HTTP/1.1 503", "a fifth stream of 8 connections");
    assert_eq!(daemon.get("/health").0, 200);
    // Clients that go away give their slots back (the daemon sees the connection close).
    drop(streams);
    let start = Instant::now();
    let again: Vec<_> = (0..4)
        .map(|_| loop {
            let (head, s) = open_stream();
            if head == "HTTP/1.1 200" {
                break s;
            }
            assert!(
                start.elapsed() < Duration::from_secs(10),
                "the slots were not given back: {head}"
            );
            std::thread::sleep(Duration::from_millis(50));
        })
        .collect();
    let (status, body) = daemon.post(&format!("/sessions/{id}/cancel"), json!({}));
    assert_eq!(status, 202, "{body}");
    drop(again);
}

/// Issue 40: 1,900 token guesses a second went unhindered. Five wrong tokens from an address
/// are free (a person mistyping); then each locks the address out for a delay that doubles,
/// answered 429 with `Retry-After` even for the right token, through the API and the sign-in
/// form alike; once it has passed, the right token works and clears the address.
#[test]
fn wrong_tokens_lock_their_address_out_for_a_growing_delay() {
    let dir = tempfile::tempdir().unwrap();
    let daemon = with_token(dir.path());
    let client = reqwest::blocking::Client::new();
    let url = format!("http://{}/api/v1/health", daemon.addr);
    let with = |token: &str| client.get(&url).bearer_auth(token).send().unwrap();
    // Asking without a token guesses nothing.
    for _ in 0..10 {
        assert_eq!(client.get(&url).send().unwrap().status().as_u16(), 401);
    }
    for guess in 0..6 {
        assert_eq!(
            with(&format!("guess {guess}")).status().as_u16(),
            401,
            "{guess}"
        );
    }
    let locked = with("correct horse");
    assert_eq!(locked.status().as_u16(), 429);
    let wait: u64 = locked.headers()["retry-after"]
        .to_str()
        .unwrap()
        .parse()
        .unwrap();
    assert!((1..=60).contains(&wait), "{wait}");
    // The sign-in form is locked out too.
    let form = client
        .post(format!("http://{}/login", daemon.addr))
        .header("content-type", "application/x-www-form-urlencoded")
        .body("token=correct+horse")
        .send()
        .unwrap();
    assert_eq!(form.status().as_u16(), 429);
    std::thread::sleep(Duration::from_secs(wait));
    assert_eq!(with("correct horse").status().as_u16(), 200);
    // Cleared: the next mistake is free again.
    assert_eq!(with("guess again").status().as_u16(), 401);
    assert_eq!(with("correct horse").status().as_u16(), 200);
}

/// A relay to the daemon that cuts the first event stream it carries once `cut_after` events
/// have passed, as a proxy's timeout or a dropped Wi-Fi link would, and keeps what every client
/// sent (the request heads).
struct CuttingRelay {
    addr: String,
    sent: std::sync::Arc<std::sync::Mutex<Vec<u8>>>,
}

impl CuttingRelay {
    fn start(daemon: &str, cut_after: usize) -> CuttingRelay {
        use std::io::{Read, Write};
        use std::net::{Shutdown, TcpListener, TcpStream};
        use std::sync::atomic::{AtomicBool, Ordering};
        use std::sync::{Arc, Mutex};
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = listener.local_addr().unwrap().to_string();
        let sent: Arc<Mutex<Vec<u8>>> = Arc::default();
        let cut = Arc::new(AtomicBool::new(false));
        let (daemon, log) = (daemon.to_string(), sent.clone());
        std::thread::spawn(move || {
            for client in listener.incoming().map_while(Result::ok) {
                let Ok(server) = TcpStream::connect(&daemon) else {
                    continue;
                };
                let streaming = Arc::new(AtomicBool::new(false));
                // Client to daemon: kept, and marked once it asks for an event stream.
                let (mut from, mut to) = (client.try_clone().unwrap(), server.try_clone().unwrap());
                let (log, asked) = (log.clone(), streaming.clone());
                std::thread::spawn(move || {
                    let mut buf = [0u8; 4096];
                    while let Ok(n @ 1..) = from.read(&mut buf) {
                        log.lock().unwrap().extend_from_slice(&buf[..n]);
                        if String::from_utf8_lossy(&buf[..n]).contains("/events HTTP/1.1") {
                            asked.store(true, Ordering::SeqCst);
                        }
                        if to.write_all(&buf[..n]).is_err() {
                            break;
                        }
                    }
                    let _ = to.shutdown(Shutdown::Write);
                });
                // Daemon to client: the first event stream ends after `cut_after` events.
                let (mut from, mut to, cut) = (server, client, cut.clone());
                std::thread::spawn(move || {
                    let mut buf = [0u8; 4096];
                    let mut events = 0;
                    while let Ok(n @ 1..) = from.read(&mut buf) {
                        let mut end = n;
                        if streaming.load(Ordering::SeqCst) && !cut.load(Ordering::SeqCst) {
                            // Up to the end of the event that makes `cut_after` (its blank line).
                            let text = &buf[..n];
                            let mut at = 0;
                            while let Some(i) = find(&text[at..], b"data:") {
                                events += 1;
                                at += i + 5;
                                if events == cut_after {
                                    end = find(&text[at..], b"\n\n").map_or(n, |j| at + j + 2);
                                    break;
                                }
                            }
                        }
                        if to.write_all(&buf[..end]).is_err() {
                            break;
                        }
                        if events >= cut_after && !cut.swap(true, Ordering::SeqCst) {
                            let _ = to.shutdown(Shutdown::Both);
                            let _ = from.shutdown(Shutdown::Both);
                            return;
                        }
                    }
                    let _ = to.shutdown(Shutdown::Write);
                });
            }
        });
        CuttingRelay { addr, sent }
    }

    /// The `Last-Event-ID` of each event-stream request sent through the relay, in order
    /// (`None` for a request without one).
    fn stream_requests(&self) -> Vec<Option<String>> {
        let sent = String::from_utf8_lossy(&self.sent.lock().unwrap()).to_string();
        sent.split("GET ")
            .filter(|r| r.contains("/events HTTP/1.1"))
            .map(|r| {
                let head = r.split("\r\n\r\n").next().unwrap();
                head.lines()
                    .filter_map(|l| l.split_once(':'))
                    .find(|(name, _)| name.trim().eq_ignore_ascii_case("last-event-id"))
                    .map(|(_, v)| v.trim().to_string())
            })
            .collect()
    }
}

/// Where `needle` first starts in `haystack`.
fn find(haystack: &[u8], needle: &[u8]) -> Option<usize> {
    haystack.windows(needle.len()).position(|w| w == needle)
}

/// Issue 42: `brdfd capture` through the daemon follows the event stream; when it drops before
/// the capture finishes, the CLI opens it again with the last event's id as `Last-Event-ID`,
/// and goes on after that event, rather than failing ("the event stream ended").
#[test]
fn the_cli_follows_a_dropped_event_stream_from_its_last_event() {
    let dir = tempfile::tempdir().unwrap();
    let daemon = Daemon::simulated(&dir.path().join("state"));
    let relay = CuttingRelay::start(&daemon.addr, 3);
    let o = brdfd(
        &[
            "capture",
            "--simulate",
            "--material",
            "gold",
            "--size",
            "64",
            "--daemon",
            &relay.addr,
        ],
        dir.path(),
    );
    let (stdout, stderr) = text(&o);
    assert!(o.status.success(), "{stdout}\n{stderr}");
    assert!(stdout.contains(" done: "), "{stdout}");
    let requests = relay.stream_requests();
    assert_eq!(requests.len(), 2, "{requests:?}");
    assert_eq!(requests[0], None);
    // The third event's id, `RUN-2`: the stream goes on after it.
    let resumed = requests[1]
        .as_deref()
        .expect("the second asks with Last-Event-ID");
    assert!(resumed.ends_with("-2"), "{resumed}");
}

/// The server in this test's own process, on port 0, as mini-redis tests its server: beside
/// the tests of the binary, this one sees both sides at once. Through a session's whole life
/// the API says what the session's files say, the state moves along its life and no other
/// way, and the server stops when its shutdown future resolves, with nothing left running.
#[test]
fn the_server_in_process_agrees_with_the_stored_session_and_stops_cleanly() {
    use brdfd_daemon::{api, server, Daemon as Core};
    use brdfd_rig::config::Rig;
    use brdfd_rig::session::{Session, State};
    use serde_json::Value;
    use std::sync::Arc;

    // What the binary's main does: the daemon's rig is the simulated one.
    brdfd_simrig::provide();
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("state");
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let (started, bound) = std::sync::mpsc::channel();
    let state_dir = state.clone();
    let server = std::thread::spawn(move || {
        runtime.block_on(async move {
            let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
            let daemon = tokio::task::block_in_place(|| {
                Core::start(
                    Rig::simulated(),
                    include_str!("../config/rigs/simulated.toml").into(),
                    state_dir,
                    None,
                    Duration::from_secs(30),
                )
            })
            .map_err(std::io::Error::other)?;
            let daemon = Arc::new(daemon);
            started
                .send((listener.local_addr()?, daemon.clone()))
                .unwrap();
            let shutting = daemon.clone();
            let app = api::router(daemon);
            server::serve(listener, app, server::Limits::default(), async move {
                let _ = stopped.await;
                let _ = tokio::task::spawn_blocking(move || shutting.shut_down()).await;
            })
            .await
        })
    });
    let (addr, daemon) = bound.recv_timeout(Duration::from_secs(60)).unwrap();
    let api = format!("http://{addr}/api/v1");
    let http = reqwest::blocking::Client::new();
    let get = |path: &str| -> (u16, Value) {
        let r = http.get(format!("{api}{path}")).send().unwrap();
        (r.status().as_u16(), r.json().unwrap())
    };
    let post = |path: &str, body: Value| -> (u16, Value) {
        let r = http
            .post(format!("{api}{path}"))
            .json(&body)
            .send()
            .unwrap();
        (r.status().as_u16(), r.json().unwrap())
    };

    assert_eq!(get("/health").0, 200);
    let (status, body) = post("/sessions", json!({ "material": "gold", "size": 64 }));
    assert_eq!(status, 202, "{body}");
    let id = body["id"].as_str().unwrap().to_string();
    // Polled, not followed: each answer is compared with the files as they are then.
    let deadline = Instant::now() + Duration::from_secs(600);
    let shown = loop {
        let (status, body) = get(&format!("/sessions/{id}"));
        assert_eq!(status, 200, "{body}");
        let stored = Session::open(&state, &id).unwrap().into_manifest();
        let said: State = serde_json::from_value(body["manifest"]["state"].clone()).unwrap();
        // The answer was read first; the capture may have moved on since, never back.
        let order = |s: State| {
            [
                State::Created,
                State::Capturing,
                State::Captured,
                State::Estimating,
                State::Done,
            ]
            .iter()
            .position(|x| *x == s)
            .unwrap_or_else(|| panic!("{id} went {s}: {body}"))
        };
        assert!(
            order(said) <= order(stored.state),
            "API {said}, files {}",
            stored.state
        );
        if said == State::Done && daemon.busy().is_none() {
            break body;
        }
        assert!(Instant::now() < deadline, "not done in time: {body}");
        std::thread::sleep(Duration::from_millis(200));
    };
    let stored = Session::open(&state, &id).unwrap().into_manifest();
    let life: Vec<State> = stored.history.iter().map(|t| t.state).collect();
    assert_eq!(
        life,
        [
            State::Created,
            State::Capturing,
            State::Captured,
            State::Estimating,
            State::Done
        ]
    );
    assert_eq!(
        shown["manifest"]["history"].as_array().unwrap().len(),
        life.len()
    );
    // Done is final: the API refuses to resume it, and the files do not change.
    let (status, body) = post(&format!("/sessions/{id}/resume"), json!({}));
    assert_eq!(
        (status, body["error"].as_str()),
        (409, Some("already_done")),
        "{body}"
    );
    assert_eq!(
        Session::open(&state, &id)
            .unwrap()
            .into_manifest()
            .history
            .len(),
        life.len()
    );

    stop.send(()).unwrap();
    let deadline = Instant::now() + Duration::from_secs(60);
    while !server.is_finished() {
        assert!(Instant::now() < deadline, "the server did not stop");
        std::thread::sleep(Duration::from_millis(50));
    }
    server.join().unwrap().unwrap();
    assert!(http.get(format!("{api}/health")).send().is_err());
    // The daemon's last holder is this test: nothing inside it still runs.
    assert_eq!(Arc::strong_count(&daemon), 1);
}
