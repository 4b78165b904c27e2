//! PTP/IP benchmark: capture and download a 25 MB file from each simulated body on loopback,
//! with our client and with gphoto2 in the same run.

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

/// The simulated bodies measured, each with the capture flow it speaks: the standard
/// InitiateCapture, Nikon's capture to SDRAM with GetEvent polling, Canon's EOS remote release
/// with its event records, Sony's SDIO control with the shot read from memory, and the THETAs'
/// RICOH properties over the standard flow.
const BODIES: [Profile; 6] = [
    Profile::Generic,
    Profile::NikonD5100,
    Profile::CanonEosR6,
    Profile::SonyA7M4,
    Profile::ThetaV,
    Profile::ThetaZ1,
];

pub fn run(runs: usize) -> anyhow::Result<()> {
    println!(
        "\nPTP/IP capture + download of a {} MB file on loopback, per simulated body (medians of {} runs):",
        FILE_BYTES / 1_000_000,
        runs.max(1)
    );
    println!("  body          brdfd    gphoto2   ratio (below 1: less overhead than gphoto2)");
    for profile in BODIES {
        let name = Profile::NAMES
            .into_iter()
            .find(|n| Profile::parse(n) == Some(profile))
            .unwrap_or("?");
        let (ours, theirs) = body(profile, runs)?;
        match theirs {
            Some(t) => println!("  {name:12}  {ours:.3} s  {t:.3} s   {:.2}", ours / t),
            None => {
                println!(
                    "  {name:12}  {ours:.3} s  gphoto2 not installed (apt-get install gphoto2)"
                )
            }
        }
    }
    println!(
        "  brdfd: connect, session, capture, download, delete; gphoto2: the same, as a process"
    );
    Ok(())
}

/// brdfd's and gphoto2's median seconds for one body; `None` for gphoto2 when it is not
/// installed.
fn body(profile: Profile, runs: usize) -> anyhow::Result<(f64, Option<f64>)> {
    let responder = Responder::new(profile, Arc::new(SizedPayload { bytes: FILE_BYTES })).shared();
    let server = Server::start("127.0.0.1:0", responder)?;
    let host = server.addr.to_string();
    // gphoto2's port syntax is HOST:COMMANDPORT:EVENTPORT; the simulator takes both on one.
    let gphoto_port = format!("ptpip:{host}:{}", server.addr.port());
    let opts = CaptureOptions {
        target: Target::Card,
        delete_after: true,
    };
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
        let Ok(out) = out else {
            return Ok((ours, None));
        };
        let t = s.elapsed().as_secs_f64();
        anyhow::ensure!(
            out.status.success(),
            "gphoto2 failed on the simulated {profile:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        anyhow::ensure!(
            std::fs::metadata(&file)?.len() as usize == FILE_BYTES,
            "gphoto2 got a short file from the simulated {profile:?}"
        );
        theirs.push(t);
    }
    Ok((ours, Some(median(theirs))))
}
