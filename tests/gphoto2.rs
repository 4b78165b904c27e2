//! Debian's gphoto2 as an outside check of the simulated camera: it must recognise the
//! simulated D5100 over PTP/IP, capture and download from it, and get the same file our own
//! client gets. CI installs gphoto2 and sets BRDFD_REQUIRE_GPHOTO2=1, so there the test
//! cannot skip.

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use brdfd_ptp::transport::ptpip::{Initiator, PtpIpTransport};
use brdfd_ptp::{Camera, CaptureOptions, Timeouts};

struct Sim(Child);

impl Drop for Sim {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn gphoto2_present() -> bool {
    let present = Command::new("gphoto2").arg("--version").output().is_ok();
    if !present {
        assert!(
            std::env::var_os("BRDFD_REQUIRE_GPHOTO2").is_none(),
            "gphoto2 is required here but not installed"
        );
        eprintln!("skipping: gphoto2 is not installed (apt-get install gphoto2)");
    }
    present
}

#[test]
fn gphoto2_captures_from_the_simulated_d5100_over_ptpip() {
    if !gphoto2_present() {
        return;
    }
    // gphoto2 always uses port 15740; an address of our own on loopback avoids clashes.
    let host = format!(
        "127.0.{}.{}",
        std::process::id() % 200 + 20,
        std::process::id() % 250 + 3
    );
    let mut child = Command::new(env!("CARGO_BIN_EXE_brdfd"))
        .args([
            "sim",
            "camera",
            "--profile",
            "nikon-d5100",
            "--size",
            "48",
            "--ptpip",
        ])
        .arg(format!("{host}:15740"))
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let mut ready = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut ready)
        .unwrap();
    let _sim = Sim(child);
    assert!(ready.contains("PTP/IP on"), "{ready}");

    let dir = tempfile::tempdir().unwrap();
    let port = format!("ptpip:{host}");
    let summary = Command::new("gphoto2")
        .args(["--port", &port, "--summary"])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&summary.stdout);
    assert!(
        summary.status.success(),
        "{text}\n{}",
        String::from_utf8_lossy(&summary.stderr)
    );
    assert!(
        text.contains("Model: D5100") && text.contains("Vendor Extension ID: 0xa"),
        "{text}"
    );
    assert!(text.contains("Exposure Time(0x500d):(readwrite)"), "{text}");

    let file = dir.path().join("gphoto2.jpg");
    let cap = Command::new("gphoto2")
        .args([
            "--port",
            &port,
            "--capture-image-and-download",
            "--filename",
        ])
        .arg(&file)
        .output()
        .unwrap();
    assert!(
        cap.status.success(),
        "{}",
        String::from_utf8_lossy(&cap.stderr)
    );
    let theirs = std::fs::read(&file).unwrap();
    assert_eq!(
        &theirs[..4],
        [0xFF, 0xD8, 0xFF, 0xE1],
        "JPEG with an Exif segment first"
    );

    let link = PtpIpTransport::connect(
        format!("{host}:15740"),
        Initiator::default(),
        Duration::from_secs(5),
    )
    .unwrap();
    let mut cam = Camera::open(Box::new(link), Timeouts::default()).unwrap();
    let ours = cam
        .capture(&CaptureOptions::default(), &mut |_, _, _| {})
        .unwrap();
    assert_eq!(
        ours.data, theirs,
        "same scene, same exposure: the same file"
    );
}
