//! The daemon's web page in a real browser: Debian's headless Chromium, driven through
//! chromedriver over the W3C WebDriver protocol (a few JSON requests, spoken here directly).
//! It signs in with the token, starts a capture from the form, sees progress arrive, opens
//! the finished session's report and checks its images and plots, and saves screenshots. On a
//! rig turned by hand it checks the states a user watches: an error under the form, a running
//! session's state, the wait's spinner and elapsed time, and a cancel acknowledged at once.
//! The 3D viewer (three.js, WebGL through SwiftShader) renders a session's `material.gltf`,
//! and its picture is compared with `brdfd render --gltf` of the same file under the same map.
//! CI installs chromium and chromium-driver and sets BRDFD_REQUIRE_BROWSER=1, so there the
//! test cannot skip.

mod common;

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::{json, Value};

use common::Daemon;

/// Debian's Chromium, unless `BRDFD_CHROMIUM` names another.
fn chromium() -> String {
    std::env::var("BRDFD_CHROMIUM").unwrap_or_else(|_| "/usr/bin/chromium".into())
}

fn browser_present() -> bool {
    let present = Command::new("chromedriver")
        .arg("--version")
        .output()
        .is_ok()
        && std::path::Path::new(&chromium()).exists();
    if !present {
        assert!(
            std::env::var_os("BRDFD_REQUIRE_BROWSER").is_none(),
            "chromium and chromedriver are required here but not installed"
        );
        eprintln!("skipping: apt-get install chromium chromium-driver");
    }
    present
}

/// A chromedriver process with one headless Chromium session.
struct Browser {
    driver: Child,
    base: String,
    http: reqwest::blocking::Client,
    _profile: tempfile::TempDir,
}

impl Browser {
    fn start() -> Browser {
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let driver = Command::new("chromedriver")
            .arg(format!("--port={port}"))
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("chromedriver starts");
        let http = reqwest::blocking::Client::builder()
            .timeout(Duration::from_secs(60))
            .build()
            .unwrap();
        let root = format!("http://127.0.0.1:{port}");
        let start = Instant::now();
        while http
            .get(format!("{root}/status"))
            .send()
            .ok()
            .and_then(|r| r.json::<Value>().ok())
            .is_none_or(|v| v["value"]["ready"] != true)
        {
            assert!(
                start.elapsed() < Duration::from_secs(20),
                "chromedriver never ready"
            );
            std::thread::sleep(Duration::from_millis(50));
        }
        let profile = tempfile::tempdir().unwrap();
        // The flags Chromium needs as root in a closed sandbox: no background connections.
        let args = [
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            // WebGL on the CPU (SwiftShader): Chromium 137 and later no longer fall back to it
            // without this flag, and the viewer's tests need WebGL. The pages are our own.
            "--enable-unsafe-swiftshader",
            "--window-size=1200,1600",
            &format!("--user-data-dir={}", profile.path().display()),
        ];
        let caps = json!({"capabilities": {"alwaysMatch": {
            "browserName": "chrome",
            "goog:chromeOptions": {"binary": chromium(), "args": args},
        }}});
        let created: Value = http
            .post(format!("{root}/session"))
            .json(&caps)
            .send()
            .unwrap()
            .json()
            .unwrap();
        let session = created["value"]["sessionId"]
            .as_str()
            .unwrap_or_else(|| panic!("no browser session: {created}"))
            .to_string();
        Browser {
            driver,
            base: format!("{root}/session/{session}"),
            http,
            _profile: profile,
        }
    }

    fn call(&self, method: reqwest::Method, path: &str, body: Option<Value>) -> Value {
        let mut r = self.http.request(method, format!("{}{path}", self.base));
        if let Some(b) = body {
            r = r.json(&b);
        }
        let v: Value = r.send().unwrap().json().unwrap();
        assert!(v["value"]["error"].is_null(), "WebDriver {path}: {v}");
        v["value"].clone()
    }

    fn go(&self, url: &str) {
        self.call(reqwest::Method::POST, "/url", Some(json!({ "url": url })));
    }

    /// Runs `script` in the page (its `arguments`: `args`); what it returns.
    fn run(&self, script: &str, args: Value) -> Value {
        self.call(
            reqwest::Method::POST,
            "/execute/sync",
            Some(json!({ "script": script, "args": args })),
        )
    }

    fn element(&self, css: &str) -> String {
        let v = self.call(
            reqwest::Method::POST,
            "/element",
            Some(json!({"using": "css selector", "value": css})),
        );
        v.as_object()
            .and_then(|o| o.values().next())
            .and_then(Value::as_str)
            .unwrap_or_else(|| panic!("no element {css}: {v}"))
            .to_string()
    }

    fn click(&self, css: &str) {
        let e = self.element(css);
        self.call(
            reqwest::Method::POST,
            &format!("/element/{e}/click"),
            Some(json!({})),
        );
    }

    fn type_into(&self, css: &str, text: &str) {
        let e = self.element(css);
        self.call(
            reqwest::Method::POST,
            &format!("/element/{e}/value"),
            Some(json!({ "text": text })),
        );
    }

    /// Waits until `script` returns something truthy; that value.
    fn wait_for(&self, what: &str, script: &str, limit: Duration) -> Value {
        let start = Instant::now();
        loop {
            let v = self.run(script, json!([]));
            if !(v.is_null() || v == false || v == "") {
                return v;
            }
            assert!(start.elapsed() < limit, "{what}: not seen within {limit:?}");
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// Saves a screenshot where CI keeps test artefacts.
    fn screenshot(&self, name: &str) {
        use base64::Engine as _;
        let png = self.call(reqwest::Method::GET, "/screenshot", None);
        let png = base64::engine::general_purpose::STANDARD
            .decode(png.as_str().unwrap())
            .unwrap();
        let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("browser");
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join(name), png).unwrap();
    }
}

impl Drop for Browser {
    fn drop(&mut self) {
        let _ = self.http.delete(&self.base).send();
        let _ = self.driver.kill();
        let _ = self.driver.wait();
    }
}

#[test]
fn the_page_signs_in_captures_follows_progress_and_opens_the_report() {
    if !browser_present() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("brdfd.toml");
    std::fs::write(&config, "token = \"bench-token\"\n").unwrap();
    let config = config.to_str().unwrap();
    let daemon = Daemon::start(
        &dir.path().join("state"),
        &["--simulate", "--config", config],
    );
    let page = format!("http://{}/", daemon.addr);
    let browser = Browser::start();

    // Without the token the page asks for it, and a wrong one is refused.
    browser.go(&page);
    browser.wait_for(
        "the sign-in form",
        "return !document.getElementById('login').hidden",
        Duration::from_secs(10),
    );
    browser.type_into("#login input[name=token]", "wrong");
    browser.click("#login button");
    // The form's answer replaces the page once it arrives.
    browser.wait_for(
        "the refusal",
        "return document.body.textContent.includes(\"That is not this daemon's token\")",
        Duration::from_secs(10),
    );
    browser.go(&page);
    browser.wait_for(
        "the sign-in form again",
        "return !document.getElementById('login').hidden",
        Duration::from_secs(10),
    );
    browser.type_into("#login input[name=token]", "bench-token");
    browser.click("#login button");
    // Signed in: the token is in no address, and the devices are listed.
    let url = browser.call(reqwest::Method::GET, "/url", None);
    assert!(!url.as_str().unwrap().contains("bench-token"), "{url}");
    // No script sees the cookie (HttpOnly).
    let cookies = browser.run("return document.cookie", json!([]));
    assert!(
        !cookies.as_str().unwrap().contains("brdfd_token"),
        "{cookies}"
    );
    browser.wait_for(
        "the devices",
        "return document.querySelectorAll('#devices tbody tr').length >= 3",
        Duration::from_secs(10),
    );
    // For the record (not a check: speed is measured, not tested): how long the page took
    // to load, from the browser's own navigation timing.
    let load = browser.run(
        "const n = performance.getEntriesByType('navigation')[0]; return n.loadEventEnd - n.startTime",
        json!([]),
    );
    eprintln!("page load after sign-in: {load} ms");

    // A capture from the form, at a small size; progress arrives while it runs.
    browser.run(
        "document.querySelector('#capture input[name=size]').value = '64';
         document.getElementById('material').value = 'gold';",
        json!([]),
    );
    browser.click("#start");
    browser.wait_for(
        "a phase's progress bar",
        "return document.querySelectorAll('#phases .phase').length > 0",
        Duration::from_secs(30),
    );
    browser.screenshot("capture-running.png");
    let outcome = browser.wait_for(
        "the capture's outcome",
        "return document.getElementById('outcome').textContent",
        Duration::from_secs(300),
    );
    // The verdict first, then what it weighed.
    let outcome = outcome.as_str().unwrap();
    assert!(
        ["good", "fair", "poor"]
            .iter()
            .any(|v| outcome.starts_with(&format!("Verdict: {v} estimate (hybrid model)")))
            && outcome.contains("Done: model hybrid"),
        "{outcome}"
    );
    let phases = browser.run(
        "return document.querySelectorAll('#phases .phase.done').length",
        json!([]),
    );
    assert!(phases.as_u64().unwrap() >= 5, "phases done: {phases}");
    // No bar is left unfinished (a bracket's download bar went with its bracket's).
    let open = browser.run(
        "return [...document.querySelectorAll('#phases .phase:not(.done)')].map(p => p.textContent)",
        json!([]),
    );
    assert_eq!(open, json!([]), "phases left open");
    browser.screenshot("capture-done.png");

    // The session list links its report; the report's images decode and its plots have axes.
    let report = browser.wait_for(
        "the report link",
        "const a = [...document.querySelectorAll('#sessions a')].find(a => a.textContent === 'report');
         return a && a.href",
        Duration::from_secs(10),
    );
    browser.go(report.as_str().unwrap());
    let checked = browser.wait_for(
        "the report's images",
        "const imgs = [...document.images];
         if (imgs.length < 3 || !imgs.every(i => i.complete)) return null;
         return {
           images: imgs.length,
           decoded: imgs.filter(i => i.naturalWidth > 0).length,
           plots: document.querySelectorAll('svg').length,
           axes: [...document.querySelectorAll('svg text')]
             .filter(t => t.textContent.includes('θh (degrees, square-root scale)')).length,
         };",
        Duration::from_secs(20),
    );
    assert_eq!(checked["decoded"], checked["images"], "{checked}");
    assert_eq!(checked["plots"], 3, "{checked}");
    assert_eq!(checked["axes"], 3, "{checked}");
    browser.screenshot("report.png");
}

/// The simulated rig without its turntable, two views by default: a capture that waits for
/// the operator's turn, so the page's running states can be looked at without a race.
fn rig_turned_by_hand() -> String {
    format!(
        "{}\n[turntable]\nviews = 2\nstep_deg = 45.0\n\n[simulation]\nturntable = \"absent\"\n",
        include_str!("../config/rigs/simulated.toml")
    )
}

#[test]
fn the_page_shows_errors_a_running_capture_its_wait_and_a_cancel_at_once() {
    if !browser_present() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let rig = dir.path().join("rig.toml");
    std::fs::write(&rig, rig_turned_by_hand()).unwrap();
    let daemon = Daemon::start(&dir.path().join("state"), &["--rig", rig.to_str().unwrap()]);
    let browser = Browser::start();
    browser.go(&format!("http://{}/", daemon.addr));
    browser.wait_for(
        "the material presets",
        "return document.querySelectorAll('#material option').length > 0 && !document.getElementById('size-field').hidden",
        Duration::from_secs(10),
    );

    // A plan the daemon refuses: its error shows right under the form, in view.
    browser.run(
        "const size = document.querySelector('#capture input[name=size]');
         size.removeAttribute('min');
         size.value = '4';
         document.getElementById('material').value = 'gold';",
        json!([]),
    );
    browser.click("#start");
    let error = browser.wait_for(
        "the refusal under the form",
        "const e = document.getElementById('error');
         if (e.hidden || !e.textContent) return null;
         const r = e.getBoundingClientRect();
         return {
           text: e.textContent,
           after_form: document.getElementById('capture').nextElementSibling === e,
           in_view: r.top >= 0 && r.bottom <= window.innerHeight,
         };",
        Duration::from_secs(10),
    );
    assert!(
        error["text"]
            .as_str()
            .unwrap()
            .contains("size 4 is outside"),
        "{error}"
    );
    assert_eq!(error["after_form"], true, "{error}");
    assert_eq!(error["in_view"], true, "{error}");

    // A capture that runs until the object is turned: the error goes, the list says the
    // session is capturing (not "created"), with a spinner and no Resume.
    browser.run(
        "document.querySelector('#capture input[name=size]').value = '64';",
        json!([]),
    );
    browser.click("#start");
    let id = browser.wait_for(
        "the run's title",
        "const t = document.getElementById('run-title').textContent;
         return t.startsWith('session ') ? t.slice(8) : null",
        Duration::from_secs(10),
    );
    let id = id.as_str().unwrap().to_string();
    assert_eq!(
        browser.run("return document.getElementById('error').hidden", json!([])),
        true
    );
    let row = format!(
        "const row = [...document.querySelectorAll('#sessions tbody tr')]
           .find(r => r.cells[0].textContent === {});",
        json!(id)
    );
    // The daemon counts the capture as running from the moment its thread starts, and the
    // thread's first step records "capturing": a list fetched in between (a few milliseconds,
    // longer on a loaded machine) shows "created…", running and without buttons, until the
    // page's next refresh. The state the list settles on is what is checked.
    let listed = browser.wait_for(
        "the running session in the list, past its first step",
        &format!(
            "{row}
             if (!row || !row.querySelector('.state-running')) return null;
             const buttons = row.querySelectorAll('button').length;
             if (row.cells[1].textContent === 'created…' && buttons === 0) return null;
             return {{ state: row.cells[1].textContent, buttons }};"
        ),
        Duration::from_secs(30),
    );
    assert_eq!(listed["buttons"], 0, "{listed}");
    let state = listed["state"].as_str().unwrap();
    assert!(
        state == "capturing…" || state == "captured…",
        "a running capture is listed as {state:?}"
    );

    // The wait for the turn is a phase of its own, with a turning spinner and its elapsed
    // time counting up.
    let waiting = browser.wait_for(
        "the wait for the turn, a second in",
        "const p = [...document.querySelectorAll('#phases .phase.running')]
           .find(p => p.textContent.includes('view 2: waiting for the turn'));
         if (!p) return null;
         const seconds = parseInt(p.querySelector('.time').textContent, 10);
         if (!(seconds >= 1)) return null;
         const spinner = getComputedStyle(p.querySelector('.spinner'));
         return { seconds, visibility: spinner.visibility, animation: spinner.animationName,
                  continue_shown: !document.getElementById('continue').hidden };",
        Duration::from_secs(60),
    );
    assert_eq!(waiting["visibility"], "visible", "{waiting}");
    assert_eq!(waiting["animation"], "spin", "{waiting}");
    assert_eq!(waiting["continue_shown"], true, "{waiting}");
    browser.screenshot("capture-waiting.png");

    // Cancel is acknowledged in the same moment as the click, before the daemon answers.
    let ack = browser.run(
        "const b = document.getElementById('cancel');
         b.click();
         const m = document.querySelectorAll('#messages li');
         return { disabled: b.disabled, text: b.textContent, said: m[m.length - 1].textContent };",
        json!([]),
    );
    assert_eq!(ack["disabled"], true, "{ack}");
    assert_eq!(ack["text"], "Cancelling…", "{ack}");
    assert!(
        ack["said"].as_str().unwrap().starts_with("Cancel asked"),
        "{ack}"
    );
    let outcome = browser.wait_for(
        "the cancelled outcome",
        "const o = document.getElementById('outcome').textContent;
         return o.startsWith('Cancelled') ? o : null",
        Duration::from_secs(30),
    );
    assert!(outcome.as_str().unwrap().contains("Resume"), "{outcome}");
    // The wait stopped where it was, its spinner gone; the list offers to resume.
    let after = browser.wait_for(
        "the stopped capture in the list",
        &format!(
            "{row}
             if (!row || row.cells[1].textContent !== 'failed') return null;
             const wait = [...document.querySelectorAll('#phases .phase')]
               .find(p => p.textContent.includes('waiting for the turn'));
             return {{ resume: row.querySelectorAll('button').length,
                      stopped: wait.classList.contains('stopped'),
                      spinner: getComputedStyle(wait.querySelector('.spinner')).visibility }};"
        ),
        Duration::from_secs(10),
    );
    assert_eq!(after["resume"], 1, "{after}");
    assert_eq!(after["stopped"], true, "{after}");
    assert_eq!(after["spinner"], "hidden", "{after}");
    browser.screenshot("capture-cancelled.png");
}

/// sRGB (0–255) to linear.
fn linear(v: u8) -> f64 {
    let c = v as f64 / 255.0;
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// The 3D view's first frame, once drawn (or the page's error, as a failure).
fn viewer_frame(browser: &Browser) -> image::RgbImage {
    let png = browser.wait_for(
        "the viewer's first frame",
        "const e = document.getElementById('error');
         if (!e.hidden) return 'error: ' + e.textContent;
         if (document.body.dataset.rendered !== '1') return null;
         return document.getElementById('view').toDataURL('image/png');",
        Duration::from_secs(60),
    );
    let png = png.as_str().unwrap();
    assert!(!png.starts_with("error"), "{png}");
    use base64::Engine as _;
    let bytes = base64::engine::general_purpose::STANDARD
        .decode(png.trim_start_matches("data:image/png;base64,"))
        .unwrap();
    image::load_from_memory(&bytes).unwrap().into_rgb8()
}

#[test]
fn the_viewer_shows_the_export_as_brdfd_renders_it() {
    if !browser_present() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let daemon = Daemon::simulated(&dir.path().join("state"));
    let (status, started) = daemon.post("/sessions", json!({ "material": "gold", "size": 64 }));
    assert_eq!(status, 202, "{started}");
    let id = started["id"].as_str().unwrap().to_string();
    let last = daemon.events(&id).last().cloned().unwrap();
    assert_eq!(last["state"], "done", "{last}");

    let map = reqwest::blocking::get(format!("http://{}/maps/courtyard.hdr", daemon.addr)).unwrap();
    assert_eq!(map.status().as_u16(), 200);
    std::fs::write(dir.path().join("courtyard.hdr"), map.bytes().unwrap()).unwrap();
    let browser = Browser::start();

    // The export, fetched as the viewer fetches it. At 0° the viewer's map is where brdfd's
    // is; ±90° are the wrong quarter turns, which the figure must tell apart.
    let (status, gltf) = daemon.get_bytes(&format!("/sessions/{id}/result/material.gltf"));
    assert_eq!(status, 200);
    let errors = viewer_against_render(&browser, &daemon, &id, dir.path(), &gltf, &[0, 90, -90]);
    // Issue 38 asks for 0.10. The viewer integrates the map for glTF's BRDF itself (GGX
    // samples with filtered lookups, the map's peaks as lights, exact irradiance). Measured:
    // 0.023 for gold (brightness 1.01), 0.017 paint, 0.045 fabric; 0.93–1.07 a quarter turn
    // off. three.js's own image-based lighting was 0.35, 0.23 and 0.50.
    assert!(
        errors[0] <= 0.05,
        "the viewer is {:.4} from brdfd's render",
        errors[0]
    );
    assert!(
        errors[1..].iter().all(|e| *e > 10.0 * errors[0]),
        "a quarter turn of the light matches as well: {errors:?}"
    );

    // A clear coat, which a capture's fit takes only for some materials: the same session's
    // export replaced by a varnished metal, so that the viewer's coat is checked whatever gold
    // came to.
    let coated = brdfd_report::export::GltfMaterial {
        base_color: [0.9, 0.6, 0.2],
        metallic: 1.0,
        roughness: 0.6,
        specular: 1.0,
        specular_color: [1.0; 3],
        ior: 1.5,
        clearcoat: 1.0,
        clearcoat_roughness: 0.15,
        anisotropy: None,
    }
    .document("coated");
    let stored = dir
        .path()
        .join(format!("state/sessions/{id}/result/material.gltf"));
    assert!(stored.exists(), "{}", stored.display());
    std::fs::write(&stored, &coated).unwrap();
    let errors = viewer_against_render(&browser, &daemon, &id, dir.path(), coated.as_bytes(), &[0]);
    assert!(
        errors[0] <= 0.05,
        "the viewer is {:.4} from brdfd's render of a coated metal",
        errors[0]
    );

    // Brushed aluminium, as an estimate that chose an anisotropic lobe exports it: the
    // viewer stretches the lobe along the file's tangents (KHR_materials_anisotropy), and
    // brdfd renders it with the tangents laid from the axis the file names. The viewer's
    // picture is also compared with brdfd's render of the same material without its stretch,
    // which it must be far from.
    let brushed = brdfd_report::export::GltfMaterial {
        base_color: [0.91, 0.92, 0.92],
        metallic: 1.0,
        roughness: 0.25,
        specular: 1.0,
        specular_color: [1.0; 3],
        ior: 1.5,
        clearcoat: 0.0,
        clearcoat_roughness: 0.0,
        anisotropy: Some(brdfd_report::export::gltf::GltfAnisotropy {
            strength: 0.45,
            axis: brdfd_core::brdf::normalize([0.3, 0.8, 0.5]),
            rough_along_axis: true,
        }),
    };
    let isotropic = brdfd_report::export::GltfMaterial {
        anisotropy: None,
        ..brushed
    };
    let text = brushed.document("brushed");
    std::fs::write(&stored, &text).unwrap();
    let own = viewer_against_render(&browser, &daemon, &id, dir.path(), text.as_bytes(), &[0])[0];
    let unstretched = isotropic.document("brushed");
    let against_isotropic = viewer_against_render(
        &browser,
        &daemon,
        &id,
        dir.path(),
        unstretched.as_bytes(),
        &[0],
    )[0];
    assert!(
        own <= 0.05,
        "the viewer is {own:.4} from brdfd's render of brushed aluminium"
    );
    assert!(
        against_isotropic > 3.0 * own,
        "the viewer's brushed aluminium is {against_isotropic:.4} from the same metal unstretched, {own:.4} from itself"
    );
}

/// The viewer's picture of `gltf` (the session's `material.gltf`) under the courtyard map,
/// turned by each of `turns` degrees, against brdfd's render of the same file under the map
/// unturned, with the viewer's orthographic view: the relative RMSE of each.
fn viewer_against_render(
    browser: &Browser,
    daemon: &Daemon,
    id: &str,
    dir: &std::path::Path,
    gltf: &[u8],
    turns: &[i32],
) -> Vec<f64> {
    std::fs::write(dir.join("material.gltf"), gltf).unwrap();
    const SIZE: usize = 256;
    // 4,096 lights: within 0.04–0.07 of Mitsuba (tests/mitsuba.rs), 4 times faster than
    // the default.
    let o = common::render_gltf(
        dir,
        "material.gltf",
        "courtyard.hdr",
        SIZE,
        4096,
        "ours.exr",
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let ours = brdfd_core::raster::Raster::read(&dir.join("ours.exr")).unwrap();
    // The sphere's inside, away from its silhouette, where a mesh's facets and antialiasing
    // differ from a ray-cast sphere.
    let inside = |x: usize, y: usize| {
        let (u, v) = (
            (x as f64 + 0.5) / SIZE as f64 * 2.0 - 1.0,
            (y as f64 + 0.5) / SIZE as f64 * 2.0 - 1.0,
        );
        u * u + v * v < 0.95 * 0.95
    };
    let peak = (0..SIZE * SIZE)
        .filter(|i| inside(i % SIZE, i / SIZE))
        .flat_map(|i| ours.get(i % SIZE, i / SIZE))
        .fold(0f32, f32::max) as f64;
    // White a little above the brightest pixel: nothing clips, and 8 bits keep the detail.
    let exposure = 0.9 / peak;
    let mut errors = Vec::new();
    for turn in turns {
        browser.go(&format!(
            "http://{}/viewer.html?session={id}&map=courtyard&camera=orthographic&background=off&size={SIZE}&exposure={exposure}&turn={turn}",
            daemon.addr
        ));
        let theirs = viewer_frame(browser);
        assert_eq!(theirs.dimensions(), (SIZE as u32, SIZE as u32));
        let (mut diff, mut norm, mut ab) = (0.0, 0.0, 0.0);
        for y in 0..SIZE {
            for x in 0..SIZE {
                if !inside(x, y) {
                    continue;
                }
                let a = ours.get(x, y);
                let b = theirs.get_pixel(x as u32, y as u32).0;
                for c in 0..3 {
                    let (a, b) = (a[c] as f64 * exposure, linear(b[c]));
                    diff += (a - b).powi(2);
                    norm += a * a;
                    ab += a * b;
                }
            }
        }
        let error = (diff / norm).sqrt();
        // The brightness ratio tells a wrong exposure (or units) from a wrong shape.
        eprintln!(
            "viewer against brdfd render, light turned {turn}°: relative RMSE {error:.4}, \
             brightness {:.3}",
            ab / norm
        );
        errors.push(error);
        if *turn == 0 && errors.len() == 1 {
            browser.screenshot("viewer.png");
        }
    }
    errors
}

/// On a mesh, the viewer offers the export on the object (`object.gltf`) and draws it: the
/// grooved block's picture is not the sphere's.
#[test]
fn the_viewer_shows_the_export_on_the_sessions_mesh() {
    if !browser_present() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let rig =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("config/rigs/simulated-grooved-block.toml");
    let daemon = Daemon::start(&dir.path().join("state"), &["--rig", rig.to_str().unwrap()]);
    let (status, started) = daemon.post("/sessions", json!({ "material": "gold", "size": 64 }));
    assert_eq!(status, 202, "{started}");
    let id = started["id"].as_str().unwrap().to_string();
    let last = daemon.events(&id).last().cloned().unwrap();
    assert_eq!(last["state"], "done", "{last}");

    let browser = Browser::start();
    let mut shown = Vec::new();
    for shape in ["sphere", "object"] {
        browser.go(&format!(
            "http://{}/viewer.html?session={id}&shape={shape}&map=courtyard&background=off&size=128",
            daemon.addr
        ));
        let image = viewer_frame(&browser);
        let hidden = browser.run(
            "return document.getElementById('shape-label').hidden;",
            json!([]),
        );
        assert_eq!(hidden, false, "{shape}: the shape chooser is hidden");
        // Pixels the shape covers (the background is off: black).
        let covered = image
            .pixels()
            .filter(|p| p.0.iter().any(|c| *c > 8))
            .count();
        shown.push(covered);
        if shape == "object" {
            browser.screenshot("viewer-object.png");
        }
    }
    // Both drawn, and differently: a block is not a sphere.
    assert!(shown.iter().all(|c| *c > 500), "{shown:?}");
    assert!(
        (shown[0] as f64 - shown[1] as f64).abs() > 0.05 * shown[0] as f64,
        "the object's picture covers as much as the sphere's: {shown:?}"
    );
}
