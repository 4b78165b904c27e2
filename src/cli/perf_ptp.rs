//! PTP/IP benchmark: capture and download a 25 MB file from the simulated camera on
//! loopback, with our client and with gphoto2 in the same run.

use std::process::Command;
use std::sync::Arc;
use std::time::{Duration, Instant};

use brdfd_ptp::transport::ptpip::{Initiator, PtpIpTransport};
use brdfd_ptp::{Camera, CaptureOptions, Target, Timeouts};
use brdfd_sim::ptp::{ptpip::Server, Profile, Responder};
use brdfd_sim::SizedPayload;

pub const FILE_BYTES: usize = 25_000_000;

fn median(mut t: Vec<f64>) -> f64 {
    t.sort_by(f64::total_cmp);
    t[t.len() / 2]
}

pub fn run(runs: usize) -> anyhow::Result<()> {
    let responder = Responder::new(
        Profile::Generic,
        Arc::new(SizedPayload { bytes: FILE_BYTES }),
    )
    .shared();
    let server = Server::start("127.0.0.1:0", responder)?;
    let host = server.addr.to_string();
    // gphoto2's port syntax is HOST:COMMANDPORT:EVENTPORT; the simulator takes both on one.
    let gphoto_port = format!("ptpip:{host}:{}", server.addr.port());
    let opts = CaptureOptions {
        target: Target::Card,
        delete_after: true,
    };
    println!(
        "\nPTP/IP capture + download of a {} MB file on loopback ({host}):",
        FILE_BYTES / 1_000_000
    );
    let mut ours = Vec::new();
    for _ in 0..runs.max(1) {
        let s = Instant::now();
        let t = PtpIpTransport::connect(server.addr, Initiator::default(), Duration::from_secs(5))?;
        let mut cam = Camera::open(Box::new(t), Timeouts::default())?;
        let shot = cam.capture(&opts, &mut |_, _, _| {})?;
        anyhow::ensure!(shot.data.len() == FILE_BYTES, "short download");
        cam.close()?;
        ours.push(s.elapsed().as_secs_f64());
    }
    let ours = median(ours);
    println!(
        "  brdfd (connect, session, capture, download, delete): {:.3} s median",
        ours
    );

    let dir = tempfile::tempdir()?;
    let mut theirs = Vec::new();
    for i in 0..runs.max(1) {
        let file = dir.path().join(format!("g{i}.jpg"));
        let s = Instant::now();
        let out = Command::new("gphoto2")
            .args([
                "--port",
                &gphoto_port,
                "--capture-image-and-download",
                "--force-overwrite",
            ])
            .arg("--filename")
            .arg(&file)
            .output();
        let out = match out {
            Ok(o) => o,
            Err(_) => {
                println!("  gphoto2: not installed (apt-get install gphoto2), no comparison");
                return Ok(());
            }
        };
        let t = s.elapsed().as_secs_f64();
        anyhow::ensure!(
            out.status.success(),
            "gphoto2 failed: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        anyhow::ensure!(
            std::fs::metadata(&file)?.len() as usize == FILE_BYTES,
            "gphoto2 got a short file"
        );
        theirs.push(t);
    }
    let theirs = median(theirs);
    println!(
        "  gphoto2 (the same, as a process):                   {:.3} s median",
        theirs
    );
    println!(
        "  ratio brdfd / gphoto2: {:.2} (below 1 means less overhead than gphoto2)",
        ours / theirs
    );
    Ok(())
}
