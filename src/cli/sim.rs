//! `brdfd sim`: run a simulated device on its own, for trying clients (ours, gphoto2) without
//! hardware. It serves until it is stopped.

use std::sync::Arc;

use anyhow::{anyhow, Context};
use brdfd::bench::camera::BenchCamera;
use brdfd::bench::VirtualBench;
use brdfd_sim::ptp::{ptpip::Server, Profile, Responder};
use brdfd_sim::{ImageSource, SizedPayload};

#[derive(clap::Subcommand)]
pub enum SimCommand {
    /// A PTP camera served over PTP/IP (TCP), rendering the virtual bench.
    Camera(CameraArgs),
}

#[derive(clap::Args)]
pub struct CameraArgs {
    /// Address to listen on (PTP/IP's port is 15740).
    #[arg(long, default_value = "127.0.0.1:15740")]
    pub ptpip: String,
    /// Camera profile: generic, nikon-d5100, theta-v.
    #[arg(long, default_value = "nikon-d5100")]
    pub profile: String,
    /// Material on the virtual bench (name or alias).
    #[arg(long, default_value = "gold")]
    pub material: String,
    /// Image size of the simulated camera, in pixels.
    #[arg(long, default_value_t = 256)]
    pub size: usize,
    /// Serve files of exactly this many bytes instead of rendered photos (transfer tests).
    #[arg(long)]
    pub payload_bytes: Option<usize>,
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
            let source: Arc<dyn ImageSource> = match a.payload_bytes {
                Some(bytes) => Arc::new(SizedPayload { bytes }),
                None => {
                    let bench = VirtualBench::embedded(&a.material, a.size)?;
                    let camera =
                        BenchCamera::new(bench, "brdfd", &format!("simulated {}", a.profile));
                    camera
                        .prepare()
                        .map_err(|e| anyhow!("rendering the virtual bench: {e}"))?;
                    Arc::new(camera)
                }
            };
            let server = Server::start(&a.ptpip, Responder::new(profile, source).shared())
                .with_context(|| format!("listening on {}", a.ptpip))?;
            // Scripts wait for this line before connecting.
            println!("simulated {} camera: PTP/IP on {}", a.profile, server.addr);
            loop {
                std::thread::park();
            }
        }
    }
}
