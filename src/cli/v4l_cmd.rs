//! `brdfd v4l`: a V4L2 camera on its own (the fallback object camera, or a THETA in UVC
//! mode): manual settings, N frames averaged in linear light, written as EXR.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{anyhow, bail, Context};
use brdfd_bench::cache::RenderCache;
use brdfd_bench::camera::BenchCamera;
use brdfd_bench::VirtualBench;
use brdfd_radiometry::{average_frames, Exposure};
use brdfd_rig::selector::Selector;
use brdfd_v4l::{FrameSource, Settings};

#[derive(clap::Subcommand)]
pub enum V4lCommand {
    /// Set exposure, gain and white balance by hand, grab frames and average them.
    Capture(V4lCaptureArgs),
}

#[derive(clap::Args)]
pub struct V4lCaptureArgs {
    /// `v4l:/dev/videoN`, or `sim` for a simulated camera on the virtual bench.
    #[arg(long, default_value = "v4l:/dev/video0")]
    pub device: String,
    /// Frames to average.
    #[arg(long, default_value_t = 8)]
    pub frames: usize,
    /// Exposure time, seconds (auto exposure is switched off).
    #[arg(long, default_value_t = 1.0 / 60.0)]
    pub exposure: f64,
    /// Sensor gain, in the device's own units (auto gain is switched off).
    #[arg(long)]
    pub gain: Option<i64>,
    /// White balance, kelvin (auto white balance is switched off).
    #[arg(long, default_value_t = 5000)]
    pub white_balance: i64,
    /// Material on the simulated bench (with `--device sim`).
    #[arg(short, long, default_value = "gold")]
    pub material: String,
    /// The averaged frame, linear, as EXR.
    #[arg(short, long, default_value = "frame.exr")]
    pub out: PathBuf,
}

pub fn run(cmd: V4lCommand) -> anyhow::Result<()> {
    let V4lCommand::Capture(a) = cmd;
    if a.frames == 0 {
        bail!("--frames must be at least 1");
    }
    let mut source: Box<dyn FrameSource> = if a.device == "sim" {
        let bench = VirtualBench::embedded(&a.material, 128)?.with_cache(RenderCache::user());
        let camera = BenchCamera::new(bench, "brdfd", "simulated webcam");
        camera
            .prepare()
            .map_err(|e| anyhow!("rendering the virtual bench: {e}"))?;
        Box::new(brdfd_sim::v4l::SimV4l::new(
            Arc::new(camera),
            "simulated webcam",
        ))
    } else {
        match a.device.parse::<Selector>()? {
            Selector::V4l(path) => Box::new(brdfd_v4l::device::V4lCamera::open(&path)?),
            other => bail!("{other} is not a V4L2 camera; use v4l:/dev/videoN or sim"),
        }
    };
    println!("{}", source.describe());
    let settings = Settings {
        exposure_s: Some(a.exposure),
        gain: a.gain,
        white_balance_k: Some(a.white_balance),
    };
    let (applied, frames) = brdfd_v4l::capture(source.as_mut(), &settings, a.frames)?;
    println!(
        "applied: exposure {} s, gain {}, white balance {} K ({})",
        applied
            .exposure_s
            .map_or("unknown".into(), |e| e.to_string()),
        applied.gain.map_or("unchanged".into(), |g| g.to_string()),
        applied
            .white_balance_k
            .map_or("unknown".into(), |k| k.to_string()),
        applied.notes.join(", ")
    );
    // The V4L2 API reports no aperture or ISO: the exposure is the time alone, and the map's
    // units are relative until the rig is calibrated.
    let exposure = Exposure {
        shutter_s: applied.exposure_s.unwrap_or(a.exposure),
        f_number: 1.0,
        iso: 100.0,
    };
    let frame = average_frames(&frames, exposure, &source.describe())?;
    frame
        .values
        .write_exr(&a.out)
        .with_context(|| format!("writing {}", a.out.display()))?;
    println!(
        "{} frames of {}×{} averaged in linear light: {}",
        frames.len(),
        frame.values.width,
        frame.values.height,
        a.out.display()
    );
    Ok(())
}
