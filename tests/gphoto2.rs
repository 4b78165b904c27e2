//! Debian's gphoto2 as an outside check of the simulated camera: it must recognise the
//! simulated cameras (generic, D5100, THETA Z1, Canon EOS R6 and Sony a7 IV) over PTP/IP, capture and download from
//! them, and get byte for byte the file our own client gets. CI installs gphoto2 and sets
//! BRDFD_REQUIRE_GPHOTO2=1, so there the test cannot skip.

mod common;

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

fn gphoto2(home: &std::path::Path, args: &[&str]) -> std::process::Output {
    // A throwaway HOME: gphoto2 keeps settings (and a PTP/IP GUID) in ~/.gphoto.
    Command::new("gphoto2")
        .env("HOME", home)
        .args(args)
        .output()
        .unwrap()
}

/// `brdfd sim camera --profile PROFILE` on a free loopback port: the process (stopped when
/// dropped), the rest of its output, and its PTP/IP address.
fn start_sim(profile: &str) -> (Sim, BufReader<std::process::ChildStdout>, String) {
    let mut child = common::isolated(&mut Command::new(env!("CARGO_BIN_EXE_brdfd")))
        .args([
            "sim",
            "camera",
            "--profile",
            profile,
            "--size",
            "48",
            "--ptpip",
            "127.0.0.1:0",
        ])
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(child.stdout.take().unwrap());
    let mut first = String::new();
    lines.read_line(&mut first).unwrap();
    let sim = Sim(child);
    assert!(first.contains("PTP/IP on"), "{first}");
    let addr = first.trim().rsplit(' ').next().unwrap().to_string();
    (sim, lines, addr)
}

#[test]
fn gphoto2_captures_from_the_simulated_cameras_over_ptpip() {
    if !gphoto2_present() {
        return;
    }
    for profile in [
        "generic",
        "nikon-d5100",
        "theta-z1",
        "canon-eos-r6",
        "sony-a7m4",
    ] {
        let (_sim, mut lines, addr) = start_sim(profile);

        let home = tempfile::tempdir().unwrap();
        // HOST:CMDPORT:EVENTPORT; with one port given, gphoto2 takes port + 1 for events.
        let tcp_port = addr.rsplit(':').next().unwrap();
        let port = format!("ptpip:127.0.0.1:{tcp_port}:{tcp_port}");
        let summary = gphoto2(home.path(), &["--port", &port, "--summary"]);
        let text = String::from_utf8_lossy(&summary.stdout);
        let want = match profile {
            "generic" => "Model: Simulated still camera",
            "nikon-d5100" => "Model: D5100",
            "canon-eos-r6" => "Model: Canon EOS R6",
            "sony-a7m4" => "Model: ILCE-7M4",
            _ => "Model: RICOH THETA Z1",
        };
        assert!(
            text.contains(want),
            "{profile}: {text}\n{}",
            String::from_utf8_lossy(&summary.stderr)
        );
        match profile {
            // The Z1's formats as its own dump lists them, and RICOH's F-Number.
            "theta-z1" => {
                assert!(
                    text.contains(
                        "Display Formats: Association/Directory, JPEG, MP4, DNG, Firmware"
                    ),
                    "{text}"
                );
                assert!(text.contains("F-Number(0x5007):(readwrite)"), "{text}");
            }
            // gphoto2 reads the R6 as its dump does: Canon's extension, no standard capture,
            // the EOS one.
            "canon-eos-r6" => {
                assert!(text.contains("Vendor Extension ID: 0xb"), "{text}");
                assert!(
                    text.contains("No Image Capture, No Open Capture, Canon EOS Capture"),
                    "{text}"
                );
            }
            // And the a7 IV as its dump: Sony's extension and capture, its properties read
            // through Sony's list, its buttons not readable.
            "sony-a7m4" => {
                assert!(text.contains("Vendor Extension ID: 0x11"), "{text}");
                assert!(
                    text.contains("No Image Capture, No Open Capture, Sony Capture"),
                    "{text}"
                );
                assert!(
                    text.contains("Shutter speed(0xd20d):(readwrite) (type=0x6) Range [73536 - 1966081, step 1]"),
                    "{text}"
                );
                assert!(
                    text.contains("Capture(0xd2c2): error 2002 on query."),
                    "{text}"
                );
            }
            _ => assert!(text.contains("Exposure Time(0x500d):(readwrite)"), "{text}"),
        }
        if profile == "nikon-d5100" {
            assert!(text.contains("Vendor Extension ID: 0xa"), "{text}");
        }

        // The summary above came while the simulator was still rendering its scene; the
        // capture waits until it has one, as a script would.
        let mut rendered = String::new();
        lines.read_line(&mut rendered).unwrap();
        assert!(rendered.contains("camera: ready"), "{rendered}");

        // gphoto2 exits 0 even when a capture fails: only the file counts.
        let file = home.path().join("gphoto2.jpg");
        let file_arg = file.to_str().unwrap();
        let cap = gphoto2(
            home.path(),
            &[
                "--port",
                &port,
                "--capture-image-and-download",
                "--filename",
                file_arg,
            ],
        );
        let theirs = std::fs::read(&file).unwrap_or_else(|_| {
            panic!(
                "{profile}: gphoto2 saved nothing: {}",
                String::from_utf8_lossy(&cap.stderr)
            )
        });
        assert_eq!(
            &theirs[..4],
            [0xFF, 0xD8, 0xFF, 0xE1],
            "JPEG with an Exif segment first"
        );

        let link =
            PtpIpTransport::connect(addr.as_str(), Initiator::default(), Duration::from_secs(5))
                .unwrap();
        let mut cam = Camera::open(Box::new(link), Timeouts::default()).unwrap();
        let opts = CaptureOptions {
            target: brdfd_ptp::Target::Card,
            delete_after: true,
        };
        let ours = cam.capture(&opts, &mut |_, _, _| {}).unwrap();
        assert_eq!(
            ours.data, theirs,
            "{profile}: same scene, same exposure: byte-identical files"
        );
    }
}

/// gphoto2 set to NEF + Fine gets both files of a shot from the simulated D5100's SDRAM
/// (the NEF, then the JPEG on the same handle), and brdfd decodes the NEF it saved.
#[test]
fn gphoto2_downloads_the_nef_and_the_jpeg_of_one_shot() {
    if !gphoto2_present() {
        return;
    }
    let (_sim, mut lines, address) = start_sim("nikon-d5100");
    // gphoto2 gives up on a camera that is busy rendering its scene: wait until it is ready.
    let mut rendered = String::new();
    lines.read_line(&mut rendered).unwrap();
    assert!(rendered.contains("camera: ready"), "{rendered}");
    let home = tempfile::tempdir().unwrap();
    let tcp_port = address.rsplit(':').next().unwrap();
    let port = format!("ptpip:127.0.0.1:{tcp_port}:{tcp_port}");
    let pattern = home.path().join("%f.%C");
    let cap = gphoto2(
        home.path(),
        &[
            "--port",
            &port,
            "--set-config-index",
            "/main/capturesettings/imagequality=6",
            "--capture-image-and-download",
            "--filename",
            pattern.to_str().unwrap(),
        ],
    );
    let log = String::from_utf8_lossy(&cap.stdout).into_owned();
    let mut saved: Vec<_> = std::fs::read_dir(home.path())
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| !n.starts_with('.'))
        .collect();
    saved.sort();
    // gphoto2 names a file of format "undefined" (as Nikon reports NEF) capt0000.nef.
    assert_eq!(saved, ["DSC_0001.JPG", "capt0000.nef"], "{log}");
    let nef = std::fs::read(home.path().join("capt0000.nef")).unwrap();
    let frame = brdfd_radiometry::raw::decode_raw(
        &nef,
        "capt0000.nef",
        brdfd_radiometry::raw::WhiteBalance::AsShot,
    )
    .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!((frame.values.width, frame.values.height), (48, 48));
}
