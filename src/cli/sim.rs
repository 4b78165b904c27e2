//! `brdfd sim`: run a simulated device on its own, for trying clients (ours, gphoto2, a THETA
//! app) without hardware. It serves until it is stopped.

use std::io::Write;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use anyhow::{anyhow, Context};
use brdfd_bench::cache::RenderCache;
use brdfd_bench::camera::BenchCamera;
use brdfd_bench::panorama::BenchPanorama;
use brdfd_bench::raw_file::RawFormat;
use brdfd_bench::VirtualBench;
use brdfd_sim::ptp::{ptpip::Server, Profile, Responder};
use brdfd_sim::theta::{OscServer, ThetaConfig, ThetaModel};
use brdfd_sim::{ImageSource, SizedPayload};

#[derive(clap::Subcommand)]
pub enum SimCommand {
    /// A PTP camera served over PTP/IP (TCP), rendering the virtual bench.
    Camera(CameraArgs),
    /// A RICOH THETA V on the THETA Web API (HTTP), photographing an environment map.
    Theta(ThetaArgs),
    /// A trigger box and turntable on a pseudo-terminal, speaking the brdfd rig protocol.
    Serial,
    /// A GRBL 1.1 G-code controller on a pseudo-terminal, a turntable on its A axis.
    Grbl {
        /// Homing enabled ($22=1): it starts locked in Alarm until homed.
        #[arg(long)]
        homing: bool,
        /// The axes' maximum rate, degrees per second.
        #[arg(long, default_value_t = 90.0)]
        rate: f64,
    },
}

#[derive(clap::Args)]
pub struct CameraArgs {
    /// Address to listen on (PTP/IP's port is 15740).
    #[arg(long, default_value = "127.0.0.1:15740")]
    pub ptpip: String,
    /// Camera profile: generic, nikon-d5100, theta-v or theta-z1 (the THETAs serve panoramas).
    #[arg(long, default_value = "nikon-d5100")]
    pub profile: String,
    /// Material on the virtual bench (name or alias).
    #[arg(short, long, default_value = "gold")]
    pub material: String,
    /// Image size of the simulated camera, in pixels.
    #[arg(long, default_value_t = 256, value_parser = super::image_size)]
    pub size: usize,
    /// Serve files of exactly this many bytes instead of rendered photos (transfer tests).
    #[arg(long)]
    pub payload_bytes: Option<usize>,
    /// Serve the camera as a real USB device instead of over PTP/IP: on the FunctionFS
    /// mounted at DIR, of a configfs gadget that is bound to a device controller once this
    /// prints `descriptors written` (Linux; docs/devices.md shows the steps).
    #[arg(long, value_name = "DIR")]
    pub functionfs: Option<PathBuf>,
    /// A fault to test a host against (with --functionfs): the first download halts
    /// (stalls) the bulk-in endpoint after this many bytes and abandons the transfer.
    #[arg(long, value_name = "BYTES", requires = "functionfs")]
    pub halt_in_download: Option<usize>,
    /// The RAW files it writes when set to RAW or RAW + JPEG (image quality NEF+Fine, say):
    /// nef (14-bit, uncompressed), dng (14-bit) or dng12 (12-bit).
    #[arg(long, value_enum, default_value = "nef")]
    pub raw: RawArg,
}

/// `--raw`: the simulated camera's RAW format.
#[derive(clap::ValueEnum, Clone, Copy)]
pub enum RawArg {
    Nef,
    Dng,
    Dng12,
}

impl From<RawArg> for RawFormat {
    fn from(a: RawArg) -> RawFormat {
        match a {
            RawArg::Nef => RawFormat::Nef,
            RawArg::Dng => RawFormat::Dng,
            RawArg::Dng12 => RawFormat::Dng12,
        }
    }
}

#[derive(clap::Args)]
pub struct ThetaArgs {
    /// Address to listen on (a real THETA answers on port 80 of 192.168.1.1).
    #[arg(long, default_value = "127.0.0.1:8080")]
    pub http: String,
    /// Environment map the camera photographs (.hdr, .exr); the procedural studio if absent.
    #[arg(long)]
    pub env: Option<PathBuf>,
    /// Width of the panoramas, in pixels (larger maps are downsampled to it).
    #[arg(long, default_value_t = 1024)]
    pub width: usize,
    /// Ask for HTTP Digest with this user (client mode); needs a password, from
    /// --password-file, BRDFD_THETA_PASSWORD or --password.
    #[arg(long)]
    pub user: Option<String>,
    // The password the simulated THETA asks for with --user.
    #[command(flatten)]
    pub password: super::theta_cmd::PasswordArgs,
    /// Time to expose and stitch one frame, in milliseconds.
    #[arg(long, default_value_t = 500)]
    pub shot_ms: u64,
    /// The model: v, z1 or x (their options, shutter speeds, ISOs, apertures, file formats
    /// and bracket limits differ; docs/devices.md).
    #[arg(long, default_value = "v", value_parser = parse_theta_model)]
    pub model: ThetaModel,
}

fn parse_theta_model(name: &str) -> Result<ThetaModel, String> {
    ThetaModel::parse(name).ok_or_else(|| format!("{name}: a THETA model is v, z1 or x"))
}

fn bench_env(env: &Option<PathBuf>) -> anyhow::Result<brdfd_core::envmap::EnvMap> {
    Ok(match env {
        Some(p) => brdfd_radiometry::panorama::load_envmap(p)
            .with_context(|| format!("reading {}", p.display()))?,
        None => brdfd_bench::studio_envmap(1024),
    })
}

/// `sim camera --functionfs DIR`: the camera on a USB gadget's FunctionFS, rendered first
/// (the host may ask for a photo as soon as the gadget is bound).
#[cfg(target_os = "linux")]
fn functionfs(
    dir: &std::path::Path,
    profile: &str,
    responder: brdfd_sim::ptp::SharedResponder,
    rendering: Option<Arc<BenchCamera>>,
) -> anyhow::Result<()> {
    if let Some(camera) = rendering {
        camera
            .prepare()
            .map_err(|e| anyhow!("rendering the virtual bench: {e}"))?;
    }
    let name = format!("brdfd simulated {profile}");
    // Written by `serve` before it waits for the host; a script binds the gadget after it.
    let announce = dir.join("ep0");
    std::thread::spawn({
        let (dir, profile) = (dir.to_path_buf(), profile.to_string());
        move || {
            // ep1 appears once the descriptors are in.
            while !dir.join("ep1").exists() {
                std::thread::sleep(std::time::Duration::from_millis(10));
            }
            println!(
                "simulated {profile} camera: descriptors written on {}",
                dir.display()
            );
        }
    });
    brdfd_sim::ptp::functionfs::serve(dir, &name, responder)
        .with_context(|| format!("serving on the FunctionFS at {}", announce.display()))
}

#[cfg(not(target_os = "linux"))]
fn functionfs(
    _: &std::path::Path,
    _: &str,
    _: brdfd_sim::ptp::SharedResponder,
    _: Option<Arc<BenchCamera>>,
) -> anyhow::Result<()> {
    anyhow::bail!("--functionfs needs Linux")
}

pub fn run(cmd: SimCommand) -> anyhow::Result<()> {
    match cmd {
        SimCommand::Camera(a) => {
            let profile = Profile::parse(&a.profile).ok_or_else(|| {
                anyhow!(
                    "unknown profile {:?}; one of {}",
                    a.profile,
                    Profile::NAMES.join(", ")
                )
            })?;
            let mut rendering: Option<Arc<BenchCamera>> = None;
            let source: Arc<dyn ImageSource> = match (a.payload_bytes, profile) {
                (Some(bytes), _) => Arc::new(SizedPayload { bytes }),
                (None, p) if p.is_theta() => Arc::new(BenchPanorama::new(
                    &bench_env(&None)?,
                    1024,
                    p.theta_model().unwrap_or_default(),
                )),
                (None, _) => {
                    let bench = VirtualBench::embedded(&a.material, a.size)?
                        .with_cache(RenderCache::user());
                    // The D5100 names itself as the real one does: RAW readers find the
                    // sensor's layout and levels by make and model.
                    let (make, model): (String, String) = match profile {
                        Profile::NikonD5100 => ("NIKON CORPORATION".into(), "NIKON D5100".into()),
                        Profile::CanonEosR6 => ("Canon".into(), "Canon EOS R6".into()),
                        Profile::SonyA7M4 => ("SONY".into(), "ILCE-7M4".into()),
                        _ => ("brdfd".into(), format!("simulated {}", a.profile)),
                    };
                    rendering = Some(Arc::new(
                        BenchCamera::new(bench, &make, &model).with_raw(a.raw.into()),
                    ));
                    rendering.clone().unwrap()
                }
            };
            let responder = Responder::new(profile, source).shared();
            responder.lock().unwrap().faults.halt_in_download = a.halt_in_download;
            if let Some(dir) = &a.functionfs {
                return functionfs(dir, &a.profile, responder, rendering);
            }
            let server = Server::start(&a.ptpip, responder)
                .with_context(|| format!("listening on {}", a.ptpip))?;
            // Scripts wait for this line before connecting.
            println!("simulated {} camera: PTP/IP on {}", a.profile, server.addr);
            // The scene renders while the camera already answers (captures get DeviceBusy
            // until it is done); scripts that want the first shot at once wait for this line.
            if let Some(camera) = rendering {
                camera
                    .prepare()
                    .map_err(|e| anyhow!("rendering the virtual bench: {e}"))?;
            }
            // A script that read only the first line may have closed its end: that is no
            // reason for the camera to stop.
            let _ = writeln!(std::io::stdout(), "simulated {} camera: ready", a.profile);
            loop {
                std::thread::park();
            }
        }
        SimCommand::Serial => {
            let (peer, client_end) = brdfd_sim::serial::SerialPeer::start(Default::default())?;
            // Scripts wait for this line, then open the path with `brdfd serial --port`.
            println!("simulated turntable: serial:{}", peer.path);
            // Holding our own handle on the terminal keeps it open between clients: when the
            // last one closes a pseudo-terminal, the peer would read a hang-up.
            let _keep = client_end;
            loop {
                std::thread::park();
            }
        }
        SimCommand::Grbl { homing, rate } => {
            if !(rate.is_finite() && rate > 0.0) {
                anyhow::bail!(
                    "--rate {rate}: the rate must be a positive number of degrees per second"
                );
            }
            let config = brdfd_sim::grbl::GrblConfig {
                homing,
                rate_per_s: rate,
                ..Default::default()
            };
            let (peer, client_end) = brdfd_sim::grbl::GrblPeer::start(config)?;
            // Scripts wait for this line, then open the path with `brdfd serial --port`.
            println!("simulated GRBL turntable: grbl:{}", peer.path);
            let _keep = client_end;
            loop {
                std::thread::park();
            }
        }
        SimCommand::Theta(a) => {
            let credentials = a.password.credentials(a.user.as_deref())?;
            let name = a.model.name();
            let source = BenchPanorama::new(&bench_env(&a.env)?, a.width, name);
            let config = ThetaConfig {
                credentials,
                shot_time: Duration::from_millis(a.shot_ms),
                ..ThetaConfig::of(a.model)
            };
            let server = OscServer::start(&a.http, Arc::new(source), config)
                .with_context(|| format!("listening on {}", a.http))?;
            // Scripts wait for this line before connecting.
            println!("simulated {name}: THETA Web API on {}", server.url());
            loop {
                std::thread::park();
            }
        }
    }
}
