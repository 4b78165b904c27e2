//! Helpers for the integration tests that run the real binary, as a user would.

// Each test file uses some of these, and Rust builds this module into each one.
#![allow(dead_code)]

use std::io::{BufRead, BufReader, Read, Write};
use std::path::Path;
use std::process::{Child, Command, Output, Stdio};

/// A loopback address where no daemon listens: `capture` and `session resume` look for a
/// daemon first, and tests that mean the in-process path must not find one a developer left
/// running on the default port.
pub const NO_DAEMON: &str = "127.0.0.1:9";

/// `brdfd` as a command, with no daemon to find unless the test gives one.
pub fn command() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_brdfd"));
    isolated(&mut c);
    c
}

/// A command that runs brdfd, kept apart from the developer's own brdfd: no daemon to find,
/// no settings from ~/.config/brdfd, no state directory of theirs, and simulated scenes
/// rendered once for the whole test run rather than into their cache.
pub fn isolated(c: &mut Command) -> &mut Command {
    let tmp = Path::new(env!("CARGO_TARGET_TMPDIR"));
    c.env("BRDFD_DAEMON", NO_DAEMON)
        .env("BRDFD_RENDER_CACHE", tmp.join("render-cache"))
        .env("XDG_CONFIG_HOME", tmp.join("no-config"))
        .env_remove("BRDFD_CONFIG")
        .env_remove("BRDFD_STATE_DIR")
}

/// Runs `brdfd ARGS` in `dir` and waits for it.
pub fn brdfd(args: &[&str], dir: &Path) -> Output {
    command()
        .args(args)
        .current_dir(dir)
        .output()
        .expect("brdfd runs")
}

/// `brdfd render --gltf GLTF --env MAP` on its built-in sphere at `size`² with `lights`, into
/// `out` (all in `dir`): the glTF material as brdfd renders it.
pub fn render_gltf(
    dir: &Path,
    gltf: &str,
    map: &str,
    size: usize,
    lights: usize,
    out: &str,
) -> Output {
    let (size, lights) = (size.to_string(), lights.to_string());
    brdfd(
        &[
            "render", "--gltf", gltf, "--env", map, "--size", &size, "--lights", &lights, "--out",
            out,
        ],
        dir,
    )
}

/// Runs `brdfd ARGS` in `dir`, which must succeed: what it said, on both streams.
/// Runs brdfd, which must fail: what it said.
pub fn fails(args: &[&str], dir: &Path) -> String {
    let run = brdfd(args, dir);
    let said = out(&run);
    assert!(
        !run.status.success(),
        "brdfd {} succeeded:\n{said}",
        args.join(" ")
    );
    said
}

pub fn succeeds(args: &[&str], dir: &Path) -> String {
    let run = brdfd(args, dir);
    let said = out(&run);
    assert!(run.status.success(), "brdfd {}:\n{said}", args.join(" "));
    said
}

/// Standard output and standard error.
pub fn text(o: &Output) -> (String, String) {
    (
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

/// Both streams in one string, for matching messages wherever they went.
pub fn out(o: &Output) -> String {
    let (a, b) = text(o);
    a + &b
}

/// A `brdfd sim ...` process, stopped when dropped.
pub struct Simulator {
    child: Child,
    /// The last word of the simulator's first line: the address or path to connect to.
    pub addr: String,
}

impl Simulator {
    /// Starts `brdfd ARGS` and waits for the line it prints when it is ready.
    pub fn start(args: &[&str]) -> Simulator {
        let mut child = command()
            .args(args)
            .stdout(Stdio::piped())
            .spawn()
            .expect("brdfd sim starts");
        let mut line = String::new();
        BufReader::new(child.stdout.take().expect("piped stdout"))
            .read_line(&mut line)
            .expect("the simulator prints its address");
        let addr = line.trim().rsplit(' ').next().unwrap_or("").to_string();
        Simulator { child, addr }
    }
}

impl Drop for Simulator {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// `brdfd serve --simulate` on a free loopback port, killed when dropped.
pub struct Daemon {
    pub child: Child,
    /// IP:PORT of the API.
    pub addr: String,
    stdout: BufReader<std::process::ChildStdout>,
    http: reqwest::blocking::Client,
}

impl Daemon {
    pub fn start(state: &Path, extra: &[&str]) -> Daemon {
        Daemon::spawn(command(), state, extra)
    }

    /// [`Daemon::start`] with at most `files` open file descriptors (soft and hard limit).
    pub fn start_with_open_files(state: &Path, extra: &[&str], files: u32) -> Daemon {
        let mut sh = Command::new("sh");
        isolated(&mut sh).args([
            "-c",
            &format!("ulimit -n {files} && exec \"$0\" \"$@\""),
            env!("CARGO_BIN_EXE_brdfd"),
        ]);
        Daemon::spawn(sh, state, extra)
    }

    fn spawn(mut brdfd: Command, state: &Path, extra: &[&str]) -> Daemon {
        let mut child = brdfd
            .args(["serve", "--api", "127.0.0.1:0", "--state-dir"])
            .arg(state)
            .args(extra)
            .stdout(Stdio::piped())
            .spawn()
            .expect("brdfd serve starts");
        let mut stdout = BufReader::new(child.stdout.take().expect("piped stdout"));
        let mut line = String::new();
        stdout
            .read_line(&mut line)
            .expect("the daemon prints its address");
        let addr = line
            .split("http://")
            .nth(1)
            .and_then(|r| r.split_whitespace().next())
            .unwrap_or_else(|| panic!("no address in {line:?}"))
            .to_string();
        Daemon {
            child,
            addr,
            stdout,
            http: reqwest::blocking::Client::new(),
        }
    }

    pub fn simulated(state: &Path) -> Daemon {
        Daemon::start(state, &["--simulate"])
    }

    fn url(&self, path: &str) -> String {
        format!("http://{}/api/v1{path}", self.addr)
    }

    fn answer(r: reqwest::blocking::Response) -> (u16, serde_json::Value) {
        let status = r.status().as_u16();
        (status, r.json().unwrap_or(serde_json::Value::Null))
    }

    pub fn get(&self, path: &str) -> (u16, serde_json::Value) {
        Daemon::answer(self.http.get(self.url(path)).send().expect("GET"))
    }

    pub fn get_bytes(&self, path: &str) -> (u16, Vec<u8>) {
        let r = self.http.get(self.url(path)).send().expect("GET");
        (r.status().as_u16(), r.bytes().expect("body").to_vec())
    }

    /// The session `id` as `GET /sessions` lists it.
    pub fn listed(&self, id: &str) -> serde_json::Value {
        let (_, list) = self.get("/sessions");
        list.as_array()
            .and_then(|all| all.iter().find(|s| s["id"] == id))
            .cloned()
            .unwrap_or_else(|| panic!("{id} is not listed: {list}"))
    }

    pub fn post(&self, path: &str, body: serde_json::Value) -> (u16, serde_json::Value) {
        Daemon::answer(
            self.http
                .post(self.url(path))
                .json(&body)
                .send()
                .expect("POST"),
        )
    }

    /// Reads a session's event stream to its end; the events, as JSON.
    pub fn events(&self, id: &str) -> Vec<serde_json::Value> {
        let r = self
            .http
            .get(self.url(&format!("/sessions/{id}/events")))
            .send()
            .expect("GET events");
        assert_eq!(r.status().as_u16(), 200);
        BufReader::new(r)
            .lines()
            .map_while(Result::ok)
            .filter_map(|l| {
                l.strip_prefix("data:")
                    .map(|d| serde_json::from_str(d.trim()).expect("an event is JSON"))
            })
            .collect()
    }

    /// A session's event stream, resumed after the event `last` if given (`Last-Event-ID`),
    /// to its end: each event's id and JSON.
    pub fn events_after(&self, id: &str, last: Option<&str>) -> Vec<(String, serde_json::Value)> {
        let mut r = self.http.get(self.url(&format!("/sessions/{id}/events")));
        if let Some(last) = last {
            r = r.header("Last-Event-ID", last);
        }
        let r = r.send().expect("GET events");
        assert_eq!(r.status().as_u16(), 200);
        let mut out = Vec::new();
        let mut current = None;
        for line in BufReader::new(r).lines().map_while(Result::ok) {
            if let Some(i) = line.strip_prefix("id:") {
                current = Some(i.trim().to_string());
            } else if let Some(d) = line.strip_prefix("data:") {
                let id = current.take().expect("every event has an id");
                out.push((
                    id,
                    serde_json::from_str(d.trim()).expect("an event is JSON"),
                ));
            }
        }
        out
    }

    /// Follows the session's event stream until `phase` starts.
    pub fn wait_for_phase(&self, id: &str, phase: &str) {
        // No overall timeout: the stream stays open for as long as the capture takes to get
        // there.
        let http = reqwest::blocking::Client::builder()
            .timeout(None)
            .build()
            .expect("a client");
        let r = http
            .get(self.url(&format!("/sessions/{id}/events")))
            .send()
            .expect("GET events");
        for line in BufReader::new(r).lines().map_while(Result::ok) {
            if let Some(d) = line.strip_prefix("data:") {
                let e: serde_json::Value = serde_json::from_str(d.trim()).expect("JSON");
                if e["type"] == "phase_started" && e["phase"] == phase {
                    return;
                }
                assert!(e["type"] != "finished", "{phase} never started: {e}");
            }
        }
        panic!("the event stream ended before {phase} started");
    }

    /// Waits until the session's manifest says `step` is complete.
    pub fn wait_for_step(&self, id: &str, step: &str) {
        let start = std::time::Instant::now();
        loop {
            let (_, s) = self.get(&format!("/sessions/{id}"));
            let done = s["manifest"]["steps"]
                .as_array()
                .is_some_and(|v| v.iter().any(|x| x["name"] == step && x["complete"] == true));
            if done {
                return;
            }
            assert!(
                start.elapsed() < std::time::Duration::from_secs(120),
                "{step} never completed"
            );
            std::thread::sleep(std::time::Duration::from_millis(10));
        }
    }

    /// The rest of what the daemon printed, after it exits.
    /// Waits for the daemon to exit, failing the test after `limit` (a hang, not a speed
    /// check); its exit status and how long it took.
    pub fn wait_for_exit(
        &mut self,
        limit: std::time::Duration,
    ) -> (std::process::ExitStatus, std::time::Duration) {
        let start = std::time::Instant::now();
        loop {
            if let Some(s) = self.child.try_wait().unwrap() {
                return (s, start.elapsed());
            }
            assert!(start.elapsed() < limit, "the daemon did not stop");
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
    }

    pub fn rest_of_stdout(&mut self) -> String {
        let mut s = String::new();
        let _ = std::io::Read::read_to_string(&mut self.stdout, &mut s);
        s
    }

    pub fn signal(&self, sig: &str) {
        // The shell's own `kill`: no procps needed on a bare CI machine.
        let ok = Command::new("sh")
            .args(["-c", &format!("kill {sig} {}", self.child.id())])
            .status()
            .expect("kill runs")
            .success();
        assert!(ok, "kill {sig} failed");
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Whether every program in `tools` is on PATH. If not, the test skips with how to install
/// them, unless the environment variable `required` is set (CI sets it where it installs them).
pub fn tools_present(tools: &[&str], required: &str, install: &str) -> bool {
    let present = tools.iter().all(|t| {
        Command::new("sh")
            .args(["-c", &format!("command -v {t}")])
            .output()
            .is_ok_and(|o| o.status.success())
    });
    if !present {
        assert!(
            std::env::var_os(required).is_none(),
            "{} required here ({required}) but not installed",
            tools.join(", ")
        );
        eprintln!("skipping: {install}");
    }
    present
}

/// The coefficients printed under `title:` (`  name = +value` lines).
pub fn printed_coefficients(out: &str, title: &str) -> Vec<f64> {
    out.lines()
        .skip_while(|l| l.trim_end() != format!("{title}:"))
        .skip(1)
        .map_while(|l| l.split_once(" = ").and_then(|(_, v)| v.trim().parse().ok()))
        .collect()
}

/// ‖a − b‖ / ‖b‖.
pub fn relative_error(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    let d: f64 = a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum();
    let n: f64 = b.iter().map(|y| y * y).sum();
    (d / n).sqrt()
}

/// `brdfd session show` verifies every raw file of the session: `files` of them.
pub fn assert_verifies(dir: &Path, state: &str, id: &str, files: usize) {
    let show = brdfd(&["session", "show", id, "--state-dir", state], dir);
    assert!(
        out(&show).contains(&format!("{files} raw files verified")),
        "{}",
        out(&show)
    );
}

/// Checks a `report.html` as a reader would need it: one HTML document whose elements all
/// close, every inline image a PNG that decodes, the three BRDF-slice plots with their axis
/// labels, and `figures` figures. Returns the page.
pub fn check_report(path: &Path, figures: usize) -> String {
    use base64::Engine as _;
    let html = std::fs::read_to_string(path).expect("report.html is written");
    assert!(html.starts_with("<!DOCTYPE html>"), "not an HTML document");
    // Elements close in order (void elements and self-closed SVG ones aside).
    const VOID: [&str; 4] = ["meta", "img", "br", "hr"];
    let mut open: Vec<String> = Vec::new();
    let mut rest = html.as_str();
    while let Some(i) = rest.find('<') {
        rest = &rest[i + 1..];
        let end = rest.find('>').expect("a tag that ends");
        let tag = &rest[..end];
        rest = &rest[end + 1..];
        if tag.starts_with('!') || tag.ends_with('/') {
            continue;
        }
        let name: String = tag
            .trim_start_matches('/')
            .chars()
            .take_while(|c| c.is_ascii_alphanumeric())
            .collect();
        if VOID.contains(&name.as_str()) {
            continue;
        }
        if tag.starts_with('/') {
            assert_eq!(
                open.pop().as_deref(),
                Some(name.as_str()),
                "</{name}> closes nothing open"
            );
        } else {
            open.push(name);
        }
    }
    assert!(open.is_empty(), "left open: {open:?}");
    let images: Vec<&str> = html.split("data:image/png;base64,").skip(1).collect();
    assert!(images.len() >= figures, "{} images", images.len());
    for data in images {
        let data = &data[..data.find('"').expect("a quoted data URI")];
        let png = base64::engine::general_purpose::STANDARD
            .decode(data)
            .expect("base64");
        image::load_from_memory_with_format(&png, image::ImageFormat::Png).expect("a PNG");
    }
    assert_eq!(html.matches("<svg").count(), 3, "three BRDF slices");
    // Against √θh, MERL's own axis, so that a sharp peak is not squeezed into a few degrees.
    assert_eq!(
        html.matches("θh (degrees, square-root scale)").count(),
        3,
        "x axis labels"
    );
    assert_eq!(html.matches("BRDF (1/sr)").count(), 3, "y axis labels");
    assert_eq!(html.matches("<figure>").count(), figures, "figures");
    html
}

/// The reference data folder beside the repository (`../shared/data`), or `None`, said, for
/// the tests that need it to skip where it is missing (CI has it).
pub fn shared_data() -> Option<std::path::PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data");
    if dir.is_dir() {
        Some(dir)
    } else {
        eprintln!("SKIPPED: ../shared/data is missing (CI has it)");
        None
    }
}

/// Runs `brdfd` in `dir` with `args`, pressing Enter each time it asks for a turn, at most
/// `presses` times; then standard input is closed. Its exit and everything it printed.
pub fn answering(dir: &std::path::Path, args: &[&str], presses: usize) -> (bool, String) {
    let mut child = command()
        .args(args)
        .current_dir(dir)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdin = Some(child.stdin.take().unwrap());
    let mut stdout = child.stdout.take().unwrap();
    let printed = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = stdout.read_to_string(&mut s);
        s
    });
    // The prompt goes to standard error: Enter is pressed only once it has been asked, so a
    // capture that did not wait would not have been answered.
    let mut said = String::new();
    let mut pressed = 0;
    if presses == 0 {
        stdin.take();
    }
    for line in BufReader::new(child.stderr.take().unwrap()).lines() {
        let line = line.unwrap();
        if line.contains("press Enter once it is turned") {
            if let Some(s) = stdin.as_mut() {
                s.write_all(b"\n").unwrap();
                pressed += 1;
                if pressed == presses {
                    stdin.take();
                }
            }
        }
        said.push_str(&line);
        said.push('\n');
    }
    let status = child.wait().unwrap();
    (status.success(), printed.join().unwrap() + &said)
}

/// The relit error the capture printed.
pub fn relit(text: &str) -> f64 {
    text.split("the estimate is ")
        .nth(1)
        .and_then(|s| s.split_whitespace().next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no relit error in\n{text}"))
}
