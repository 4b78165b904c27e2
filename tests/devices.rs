//! The device layer as an operator uses it: `brdfd devices`, `brdfd serial` against
//! `brdfd sim serial` on a real pseudo-terminal, and `brdfd v4l` on the simulated camera;
//! and frame averaging, which is why the V4L2 path grabs several frames.

use std::sync::Arc;

use brdfd_bench::camera::BenchCamera;
use brdfd_bench::VirtualBench;
use brdfd_radiometry::{average_frames, Exposure};
use brdfd_sim::v4l::SimV4l;
use brdfd_v4l::{FrameSource, PixelFormat, Settings};

mod common;

use common::{brdfd, out, Simulator};

#[test]
fn serial_commands_drive_a_simulated_turntable_on_a_pseudo_terminal() {
    let dir = tempfile::tempdir().unwrap();
    let sim = Simulator::start(&["sim", "serial"]);
    let port = sim.addr.clone();
    assert!(port.starts_with("serial:/dev/"), "{port}");
    let info = brdfd(&["serial", "info", "--port", &port], dir.path());
    let rot = brdfd(
        &["serial", "rotate", "--port", &port, "--deg", "-30"],
        dir.path(),
    );
    let fire = brdfd(
        &["serial", "fire", "--port", &port, "--ms", "50"],
        dir.path(),
    );
    let again = brdfd(&["serial", "info", "--port", &port], dir.path());
    let json = brdfd(&["serial", "info", "--port", &port, "--json"], dir.path());
    let cable_port = port.replace("serial:", "cable:dtr:");
    let cable = brdfd(&["serial", "fire", "--port", &cable_port], dir.path());
    drop(sim);
    assert!(info.status.success(), "{}", out(&info));
    assert!(
        out(&info).contains("brdfd-sim-turntable version 1; shutter output: yes; turntable: yes")
    );
    assert!(out(&rot).contains("at 330.00°"), "{}", out(&rot));
    let parsed: serde_json::Value = serde_json::from_str(&out(&json)).expect("JSON");
    assert_eq!(parsed["name"], "brdfd-sim-turntable", "{}", out(&json));
    assert_eq!(parsed["can_rotate"], true);
    assert_eq!(
        parsed["position_deg"].as_f64(),
        Some(330.0),
        "{}",
        out(&json)
    );
    assert!(out(&fire).contains("fired 50 ms"), "{}", out(&fire));
    // A second process sees the position the first left.
    assert!(out(&again).contains("position 330.00°"), "{}", out(&again));
    // A pseudo-terminal has no modem lines: the cable says so instead of pretending.
    assert!(!cable.status.success());
    assert!(out(&cable).contains("cannot drive Dtr"), "{}", out(&cable));

    let missing = brdfd(
        &["serial", "info", "--port", "serial:/dev/ttyUSB-none"],
        dir.path(),
    );
    assert!(!missing.status.success());
    assert!(
        out(&missing).contains("does not exist"),
        "{}",
        out(&missing)
    );
}

#[test]
fn serial_commands_drive_a_simulated_grbl_turntable() {
    let dir = tempfile::tempdir().unwrap();
    let sim = Simulator::start(&["sim", "grbl", "--homing", "--rate", "180"]);
    let port = sim.addr.clone();
    assert!(port.starts_with("grbl:/dev/"), "{port}");
    // Locked in Alarm at start (homing enabled): `info` says so without homing it, a turn
    // is refused with what to do, and `home` homes it.
    let info = brdfd(&["serial", "info", "--port", &port], dir.path());
    let locked = brdfd(
        &["serial", "rotate", "--port", &port, "--deg", "10"],
        dir.path(),
    );
    let homed = brdfd(&["serial", "home", "--port", &port], dir.path());
    let rot = brdfd(
        &["serial", "rotate", "--port", &port, "--deg", "-30"],
        dir.path(),
    );
    let json = brdfd(&["serial", "info", "--port", &port, "--json"], dir.path());
    let home = brdfd(&["serial", "home", "--port", &port], dir.path());
    let fire = brdfd(&["serial", "fire", "--port", &port], dir.path());
    drop(sim);
    assert!(info.status.success(), "{}", out(&info));
    assert!(
        out(&info).contains("Grbl 1.1h, turntable on the A axis; state Alarm; position 0.00°"),
        "{}",
        out(&info)
    );
    assert!(!locked.status.success());
    assert!(
        out(&locked).contains("state Alarm") && out(&locked).contains("brdfd serial home"),
        "{}",
        out(&locked)
    );
    assert!(out(&homed).contains("at 0.00°"), "{}", out(&homed));
    assert!(out(&rot).contains("at 330.00°"), "{}", out(&rot));
    let parsed: serde_json::Value = serde_json::from_str(&out(&json)).expect("JSON");
    assert_eq!(
        parsed["position_deg"].as_f64(),
        Some(330.0),
        "{}",
        out(&json)
    );
    assert_eq!(parsed["axis"], "A");
    assert!(out(&home).contains("at 0.00°"), "{}", out(&home));
    assert!(!fire.status.success());
    assert!(
        out(&fire).contains("a GRBL controller turns the table only"),
        "{}",
        out(&fire)
    );
}

#[test]
fn devices_lists_every_kind_and_finds_a_theta_on_the_network() {
    let dir = tempfile::tempdir().unwrap();
    let sim = Simulator::start(&["sim", "theta", "--http", "127.0.0.1:0", "--width", "64"]);
    let url = sim.addr.clone();
    // Only ever loopback here: the default address is a real camera's.
    let o = brdfd(
        &["devices", "--theta", &url, "--timeout-ms", "300"],
        dir.path(),
    );
    let gone = brdfd(
        &[
            "devices",
            "--theta",
            "http://127.0.0.1:9",
            "--timeout-ms",
            "300",
        ],
        dir.path(),
    );
    let json = brdfd(
        &["devices", "--json", "--theta", &url, "--timeout-ms", "300"],
        dir.path(),
    );
    drop(sim);
    let rows: serde_json::Value = serde_json::from_slice(&json.stdout).unwrap();
    let theta = rows
        .as_array()
        .unwrap()
        .iter()
        .find(|r| r["selector"] == format!("osc:{url}"))
        .unwrap_or_else(|| panic!("no THETA row: {rows}"));
    assert_eq!(theta["ok"], true, "{theta}");
    assert_eq!(theta["section"], "THETA over Wi-Fi", "{theta}");
    let text = out(&o);
    assert!(o.status.success(), "{text}");
    for section in [
        "PTP cameras on USB",
        "THETA over Wi-Fi",
        "V4L2 cameras:",
        "Serial ports:",
    ] {
        assert!(text.contains(section), "{section} missing:\n{text}");
    }
    assert!(
        text.contains(&format!("osc:{url}  RICOH THETA V (serial 00165759")),
        "{text}"
    );
    assert!(
        out(&gone).contains("none answered within 300ms"),
        "{}",
        out(&gone)
    );
}

#[test]
fn v4l_capture_on_the_simulated_camera_writes_the_averaged_frame() {
    let dir = tempfile::tempdir().unwrap();
    let o = brdfd(
        &[
            "v4l",
            "capture",
            "--device",
            "sim",
            "--frames",
            "3",
            "--exposure",
            "0.01",
            "--out",
            "f.exr",
        ],
        dir.path(),
    );
    let text = out(&o);
    assert!(o.status.success(), "{text}");
    assert!(text.contains("applied: exposure 0.01 s"), "{text}");
    assert!(text.contains("3 frames of 128×128 averaged"), "{text}");
    let r = brdfd_core::raster::Raster::read(&dir.path().join("f.exr")).unwrap();
    assert_eq!((r.width, r.height), (128, 128));
    let bad = brdfd(
        &["v4l", "capture", "--device", "serial:/dev/ttyS0"],
        dir.path(),
    );
    assert!(out(&bad).contains("is not a V4L2 camera"), "{}", out(&bad));
}

/// Averaging N frames divides the sensor noise by about √N.
#[test]
fn averaging_frames_reduces_noise_by_the_square_root_of_their_number() {
    use brdfd_core::raster::srgb_to_linear;
    let bench = VirtualBench::embedded("paint", 48).unwrap();
    let source = Arc::new(BenchCamera::new(bench, "brdfd", "sim"));
    let exposure_s = 0.004;
    let grab = |noise: f32, n: usize| {
        let mut cam = SimV4l::new(source.clone(), "sim");
        cam.noise_levels = noise;
        cam.frame_interval = std::time::Duration::ZERO;
        cam.start(PixelFormat::Yuyv, 48, 48).unwrap();
        cam.apply(&Settings {
            exposure_s: Some(exposure_s),
            ..Settings::default()
        })
        .unwrap();
        let frames: Vec<_> = (0..n)
            .map(|_| {
                brdfd_v4l::decode(&cam.next_frame(std::time::Duration::from_secs(1)).unwrap())
                    .unwrap()
            })
            .collect();
        let e = Exposure {
            shutter_s: exposure_s,
            f_number: 2.0,
            iso: 100.0,
        };
        average_frames(&frames, e, "sim").unwrap().values
    };
    let clean = grab(0.0, 1);
    // Noise of 4 levels can clip within 12 levels of black or white, which biases the mean
    // there (averaging cannot remove a bias): those pixels are left out, and the exposure
    // is chosen so that the object itself is well inside the range.
    let (lo, hi) = (srgb_to_linear(12.0 / 255.0), srgb_to_linear(243.0 / 255.0));
    let inside: Vec<usize> = (0..clean.pixels.len())
        .filter(|&i| clean.pixels[i].iter().all(|&v| v > lo && v < hi))
        .collect();
    assert!(
        inside.len() > 500,
        "only {} usable pixels: exposure wrong for the scene",
        inside.len()
    );
    let truth = &clean.pixels;
    let rms = |r: &brdfd_core::raster::Raster| {
        let s: f64 = inside
            .iter()
            .flat_map(|&i| (0..3).map(move |c| ((r.pixels[i][c] - truth[i][c]) as f64).powi(2)))
            .sum();
        (s / (3 * inside.len()) as f64).sqrt()
    };
    let (one, sixteen) = (rms(&grab(4.0, 1)), rms(&grab(4.0, 16)));
    eprintln!(
        "noise over {} pixels: 1 frame {one:.5}, 16 frames {sixteen:.5}",
        inside.len()
    );
    // √16 = 4, so 0.25 for independent noise; each frame's 8-bit rounding adds a small floor:
    // allow up to 0.35.
    assert!(sixteen / one < 0.35, "noise {one:.5} → {sixteen:.5}");
}

/// `capture --simulate --views 2`: the simulated turntable on a pseudo-terminal turns the
/// object between two DSLR brackets, and one estimate uses both views.
#[test]
fn capture_with_the_simulated_turntable_uses_every_view() {
    let dir = tempfile::tempdir().unwrap();
    let o = brdfd(
        &[
            "capture",
            "--simulate",
            "--material",
            "gold",
            "--size",
            "48",
            "--views",
            "2",
            "--turn",
            "45",
            // The basis model, whose selection records which view each pixel came from.
            "--model",
            "basis",
            "--out",
            "r",
        ],
        dir.path(),
    );
    let text = out(&o);
    assert!(o.status.success(), "{text}");
    assert!(
        text.contains("turntable: brdfd-sim-turntable 1 on serial:/dev/"),
        "{text}"
    );
    assert!(text.contains("view 2 of 2: turntable at 45.00°"), "{text}");
    let json: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.path().join("r/coefficients.json")).unwrap(),
    )
    .unwrap();
    let views = json["chosen_views"].as_array().unwrap();
    assert_eq!(views.len(), 20);
    assert!(views.iter().all(|v| v.as_u64().unwrap() < 2));
    let raw: Vec<String> = std::fs::read_dir(dir.path().join("r/raw"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(
        raw.iter().filter(|n| n.starts_with("view2-dslr-")).count(),
        5,
        "{raw:?}"
    );
    let zero = brdfd(
        &[
            "capture",
            "--simulate",
            "--material",
            "gold",
            "--views",
            "0",
        ],
        dir.path(),
    );
    assert!(
        out(&zero).contains("--views must be at least 1"),
        "{}",
        out(&zero)
    );
}

/// A loopback port where a connection is never accepted: its queue (of one) is held full, so
/// a connect waits until it gives up, as at an address where nothing answers. Held while the
/// values live.
fn silent_port() -> (std::net::TcpListener, std::net::TcpStream, u16) {
    use std::os::fd::AsRawFd;
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    // SAFETY: a listening socket of ours; listen() again only shortens its queue.
    assert_eq!(unsafe { libc::listen(listener.as_raw_fd(), 0) }, 0);
    let port = listener.local_addr().unwrap().port();
    let filler = std::net::TcpStream::connect(("127.0.0.1", port)).unwrap();
    (listener, filler, port)
}

/// Issue 42: `theta info` at an address where nothing listens was silent for 29 s, retrying;
/// `theta info` and `ptp info` answer within 5 s, saying what to check. Over USB, `ptp info`
/// says why USB cannot be used as `brdfd devices` does, not only "libusb: Other error".
#[test]
fn a_dead_address_is_answered_within_five_seconds_with_what_to_check() {
    let dir = tempfile::tempdir().unwrap();
    let (_listener, _filler, silent) = silent_port();
    let within = |args: &[&str]| {
        let start = std::time::Instant::now();
        let o = brdfd(args, dir.path());
        let took = start.elapsed();
        assert!(!o.status.success(), "{args:?}: {}", out(&o));
        assert!(
            took < std::time::Duration::from_secs(5),
            "{args:?} took {took:?}"
        );
        out(&o)
    };
    for port in ["9".to_string(), silent.to_string()] {
        let said = within(&[
            "theta",
            "info",
            "--port",
            &format!("http://127.0.0.1:{port}"),
        ]);
        assert!(
            said.contains(&format!(
                "cannot connect to the THETA at http://127.0.0.1:{port}/"
            )) && said.contains("Check the address")
                && said.contains("access-point mode")
                && said.contains("firewall"),
            "{said}"
        );
        let said = within(&["ptp", "info", "--port", &format!("ptpip:127.0.0.1:{port}")]);
        assert!(
            said.contains(&format!(
                "cannot connect to a PTP/IP camera at 127.0.0.1:{port}"
            )) && said.contains("Check the address")
                && said.contains("PTP/IP (PC connection) mode")
                && said.contains("firewall"),
            "{said}"
        );
    }
    // Something that answers, but not as a camera.
    let http = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = http.local_addr().unwrap().port();
    std::thread::spawn(move || {
        use std::io::Write;
        if let Ok((mut s, _)) = http.accept() {
            let _ = s.write_all(b"HTTP/1.1 400 Bad Request\r\n\r\n");
        }
    });
    let said = within(&["ptp", "info", "--port", &format!("ptpip:127.0.0.1:{port}")]);
    assert!(
        said.contains("answered, but not as a PTP/IP camera"),
        "{said}"
    );
    // USB: without USB access (a container), the reason and what to do, as `devices` says.
    let said = out(&brdfd(&["ptp", "info"], dir.path()));
    if said.contains("libusb") {
        assert!(said.contains("no USB access here?"), "{said}");
        let listed = out(&brdfd(&["devices", "--no-theta-http"], dir.path()));
        assert!(listed.contains("no USB access here?"), "{listed}");
    }
}

/// A pseudo-terminal: its controlling side, and the path of the side a child writes to.
fn pty() -> (std::fs::File, std::path::PathBuf) {
    use std::os::fd::FromRawFd;
    // SAFETY: plain libc calls on a descriptor they return, checked before use; ptsname_r
    // writes a NUL-terminated path into the buffer given.
    unsafe {
        let fd = libc::posix_openpt(libc::O_RDWR | libc::O_NOCTTY);
        assert!(fd >= 0, "no pseudo-terminal");
        assert_eq!(libc::grantpt(fd), 0);
        assert_eq!(libc::unlockpt(fd), 0);
        let mut name = [0 as libc::c_char; 128];
        assert_eq!(libc::ptsname_r(fd, name.as_mut_ptr(), name.len()), 0);
        let path = std::ffi::CStr::from_ptr(name.as_ptr())
            .to_string_lossy()
            .into_owned();
        (std::fs::File::from_raw_fd(fd), path.into())
    }
}

/// Issue 42: the logs are coloured at a terminal, and not when NO_COLOR is set
/// (https://no-color.org), nor when they go to a file or pipe.
#[test]
fn logs_honour_no_color() {
    use std::io::Read;
    let dir = tempfile::tempdir().unwrap();
    // What `brdfd` writes to a terminal, with NO_COLOR as given.
    let logged = |no_color: Option<&str>| {
        let (mut terminal, path) = pty();
        let tty = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .open(&path)
            .unwrap();
        let mut c = common::command();
        c.args(["theta", "info", "--port", "http://127.0.0.1:9"])
            .current_dir(dir.path())
            // Debug level: the HTTP client logs its connection attempt.
            .env("BRDFD_LOG", "debug")
            .env_remove("NO_COLOR")
            .stdout(std::process::Stdio::null())
            .stderr(tty);
        if let Some(v) = no_color {
            c.env("NO_COLOR", v);
        }
        let status = c.status().unwrap();
        assert!(!status.success());
        // Drop the child's side first: with no writer left, a read past the end fails (EIO)
        // instead of waiting.
        drop(c);
        let mut bytes = Vec::new();
        let mut buf = [0u8; 4096];
        while let Ok(n) = terminal.read(&mut buf) {
            if n == 0 {
                break;
            }
            bytes.extend_from_slice(&buf[..n]);
        }
        let text = String::from_utf8_lossy(&bytes).into_owned();
        assert!(text.contains("DEBUG"), "{text}");
        text
    };
    assert!(logged(None).contains("\x1b["), "a terminal gets colour");
    assert!(!logged(Some("1")).contains("\x1b["), "NO_COLOR=1");
    // The standard: set and not empty. Empty is as if unset.
    assert!(logged(Some("")).contains("\x1b["), "NO_COLOR empty");
    let piped = common::command()
        .args(["theta", "info", "--port", "http://127.0.0.1:9"])
        .env("BRDFD_LOG", "debug")
        .env_remove("NO_COLOR")
        .output()
        .unwrap();
    assert!(out(&piped).contains("DEBUG"), "{}", out(&piped));
    assert!(!out(&piped).contains("\x1b["), "a pipe gets none");
}
