//! `brdfd theta`: the 360° camera on its own, over HTTP (THETA Web API) or USB (PTP): what it
//! reports, and a light-measurement capture merged into an HDR environment map. Also the
//! panorama step that `brdfd capture` runs.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{bail, Context};
use brdfd::core::envmap::EnvMap;
use brdfd::panorama::merge_bracket;
use brdfd::selector::Selector;
use brdfd_theta::{BracketPlan, Credentials, Exposure, Frame, HttpTimeouts, Theta};

#[derive(clap::Subcommand)]
pub enum ThetaCommand {
    /// Print what the camera reports: model, serial, firmware, link.
    Info(ThetaPort),
    /// Shoot an exposure bracket for light measurement, save the frames unchanged and the
    /// merged linear map as `panorama.exr`.
    Capture(ThetaCaptureArgs),
}

#[derive(clap::Args)]
pub struct ThetaPort {
    /// `osc:http://HOST[:PORT]` or `http://HOST[:PORT]` (access-point mode:
    /// http://192.168.1.1), `usb` (the first RICOH camera), `usb:VVVV:PPPP`, or
    /// `ptpip:HOST[:PORT]`.
    #[arg(long, default_value = "http://192.168.1.1")]
    pub port: String,
    /// HTTP Digest user, for a THETA in client mode (THETAxx<serial>).
    #[arg(long)]
    pub user: Option<String>,
    /// HTTP Digest password (the serial number unless it was changed).
    #[arg(long)]
    pub password: Option<String>,
}

#[derive(clap::Args)]
pub struct ThetaCaptureArgs {
    #[command(flatten)]
    pub port: ThetaPort,
    /// Shutter speeds in seconds; the light-probe bracket (1/16000 s to 1 s) if absent; one
    /// value shoots a single frame.
    #[arg(long, value_delimiter = ',')]
    pub shutter: Vec<f64>,
    #[arg(long, default_value_t = 100)]
    pub iso: u32,
    /// Folder for the frames and `panorama.exr`.
    #[arg(long, default_value = ".")]
    pub out: PathBuf,
}

/// Opens the THETA a port selector names.
pub fn open(p: &ThetaPort, timeouts: HttpTimeouts) -> anyhow::Result<Theta> {
    match p.port.parse::<Selector>()? {
        Selector::Osc(url) => {
            let credentials = match (&p.user, &p.password) {
                (Some(user), Some(password)) => Some(Credentials {
                    user: user.clone(),
                    password: password.clone(),
                }),
                (None, None) => None,
                _ => bail!("give both --user and --password, or neither"),
            };
            Ok(Theta::connect_http(&url, credentials, timeouts)?)
        }
        // On USB, plain `usb` means the first RICOH camera rather than the first PTP camera
        // (the DSLR may be plugged in too).
        Selector::Usb { vendor: None, .. } => {
            let port = format!("usb:{:04x}", brdfd_theta::usb::RICOH_VENDOR);
            Ok(Theta::from_ptp(super::ptp_cmd::open(&port)?)?)
        }
        Selector::Usb { .. } | Selector::PtpIp(_) => {
            Ok(Theta::from_ptp(super::ptp_cmd::open(&p.port)?)?)
        }
        other => bail!("{other} is not a THETA; use osc:http://HOST, usb or usb:05ca:PPPP"),
    }
}

/// Prepares the camera and shoots the plan: the frames as the camera sent them.
pub fn shoot_panorama(theta: &mut Theta, plan: &BracketPlan) -> anyhow::Result<Vec<Frame>> {
    for line in theta.prepare().context("preparing the THETA")? {
        tracing::info!("THETA: {line}");
    }
    let t = std::time::Instant::now();
    let mut last_phase = String::new();
    let frames = theta
        .capture(plan, &mut |phase, _| {
            if phase != last_phase {
                eprintln!("  panorama: {phase}");
                last_phase = phase.to_string();
            }
        })
        .context("shooting the panorama bracket")?;
    for f in &frames {
        check_exposure(f);
    }
    tracing::info!(
        frames = frames.len(),
        seconds = t.elapsed().as_secs_f64(),
        "panorama captured"
    );
    Ok(frames)
}

/// Shoots the plan and merges it: the map (in radiance units given by `gain`) and the
/// frames.
pub fn capture_panorama(
    theta: &mut Theta,
    plan: &BracketPlan,
    gain: f64,
) -> anyhow::Result<(EnvMap, Vec<Frame>)> {
    let frames = shoot_panorama(theta, plan)?;
    let files: Vec<(String, Vec<u8>)> = frames
        .iter()
        .map(|f| (f.name.clone(), f.data.clone()))
        .collect();
    let merged = merge_bracket(&files, gain).context("merging the panorama bracket")?;
    if merged.clipped_pixels > 0 {
        eprintln!(
            "  warning: {} pixels clip even in the shortest frame; they carry at least {:.1}% of the light, which is underestimated",
            merged.clipped_pixels,
            merged.clipped_share * 100.0
        );
    }
    Ok((merged.map, frames))
}

/// How far a frame's EXIF exposure may be from what was asked before it is reported:
/// cameras round speeds (1/3200 s is stored as 0.0003125 or 1/3200), but a different stop
/// means the camera did not take the setting.
const EXPOSURE_MISMATCH: f64 = 0.05;

/// The merge uses each frame's EXIF; a frame whose EXIF disagrees with the request means the
/// camera overrode the setting (auto exposure left on, a model limit), which the operator
/// should know.
fn check_exposure(f: &Frame) {
    match brdfd::radiometry::exif_exposure(&f.data, &f.name) {
        Ok(e) => {
            let shutter_off = (e.shutter_s / f.asked.shutter_s - 1.0).abs();
            let iso_off = (e.iso / f.asked.iso as f64 - 1.0).abs();
            if shutter_off > EXPOSURE_MISMATCH || iso_off > EXPOSURE_MISMATCH {
                eprintln!(
                    "  warning: {}: EXIF says {} s ISO {}, but {} s ISO {} was asked; the merge uses the EXIF values",
                    f.name, e.shutter_s, e.iso, f.asked.shutter_s, f.asked.iso
                );
            }
        }
        // The merge reports a missing EXIF exposure as an error, naming the file.
        Err(e) => tracing::debug!("{e}"),
    }
}

pub fn plan_from(shutter: &[f64], iso: u32) -> BracketPlan {
    if shutter.is_empty() {
        return BracketPlan::light_probe();
    }
    BracketPlan {
        shots: shutter
            .iter()
            .map(|&shutter_s| Exposure { shutter_s, iso })
            .collect(),
    }
}

pub fn run(cmd: ThetaCommand) -> anyhow::Result<()> {
    match cmd {
        ThetaCommand::Info(p) => {
            let theta = open(&p, HttpTimeouts::default())?;
            println!("{}", theta.describe());
            theta.close()?;
        }
        ThetaCommand::Capture(a) => {
            let mut theta = open(&a.port, HttpTimeouts::default())?;
            println!("{}", theta.describe());
            std::fs::create_dir_all(&a.out)
                .with_context(|| format!("creating {}", a.out.display()))?;
            let plan = plan_from(&a.shutter, a.iso);
            // A real camera's gain is unknown until calibrated: the map is in relative
            // units (pixel value per unit exposure factor).
            let (map, frames) = capture_panorama(&mut theta, &plan, 1.0)?;
            for f in &frames {
                let path = super::write_new(&a.out, &f.name, &f.data)?;
                println!(
                    "{} ({} bytes, asked {} s ISO {})",
                    path.display(),
                    f.data.len(),
                    f.asked.shutter_s,
                    f.asked.iso
                );
            }
            let exr = a.out.join("panorama.exr");
            brdfd::core::envmap::write_exr(&exr, map.width, map.height, &map.pixels)?;
            println!(
                "{} ({}×{}, linear, relative units)",
                exr.display(),
                map.width,
                map.height
            );
            theta.close()?;
        }
    }
    Ok(())
}

/// Timeouts for a simulated THETA on loopback: the real defaults, with faster polling.
pub fn loopback_timeouts() -> HttpTimeouts {
    HttpTimeouts {
        poll: Duration::from_millis(20),
        ..HttpTimeouts::default()
    }
}
