//! `brdfd ptp`: talk to one PTP camera directly, over USB or PTP/IP. For checking a camera at
//! the bench before a session, and for scripted shots.

use std::path::PathBuf;

use brdfd::selector::Selector;
use brdfd_ptp::{Camera, CaptureOptions, Exposure, Target};

#[derive(clap::Subcommand)]
pub enum PtpCommand {
    /// Print what the camera reports: model, serial, storage, operations.
    Info(PortArg),
    /// Take one picture (or a bracket) and save the files exactly as the camera sent them.
    Capture(CaptureArgs),
}

#[derive(clap::Args)]
pub struct PortArg {
    /// `usb` (first PTP camera), `usb:VVVV[:PPPP]` (vendor[:product], hex), or `ptpip:HOST[:PORT]`.
    #[arg(long, default_value = "usb")]
    pub port: String,
}

#[derive(clap::Args)]
pub struct CaptureArgs {
    #[command(flatten)]
    pub port: PortArg,
    /// Shutter speeds in seconds; several make a bracket. The camera's current speed if absent.
    #[arg(long, value_delimiter = ',')]
    pub shutter: Vec<f64>,
    #[arg(long)]
    pub f_number: Option<f64>,
    #[arg(long)]
    pub iso: Option<u32>,
    /// Save to the card and keep the file there (Nikon: the default keeps it in RAM only).
    #[arg(long)]
    pub card: bool,
    /// Folder for the files.
    #[arg(long, default_value = ".")]
    pub out: PathBuf,
}

/// Opens the camera a port selector names (`usb`, `usb:VVVV[:PPPP]`, `ptpip:HOST[:PORT]`).
pub fn open(port: &str) -> anyhow::Result<Camera> {
    brdfd::rig::open::ptp_camera(&port.parse::<Selector>()?)
}

pub fn run(cmd: PtpCommand) -> anyhow::Result<()> {
    match cmd {
        PtpCommand::Info(p) => {
            let mut cam = open(&p.port)?;
            let i = cam.info.clone();
            println!(
                "{} {} (version {}, serial {})",
                i.manufacturer, i.model, i.device_version, i.serial_number
            );
            println!("link: {}", cam.describe());
            println!(
                "vendor extension: {:#x} ({})",
                i.vendor_extension_id, i.vendor_extension_desc
            );
            println!(
                "capture flow: {}",
                if cam.is_nikon() {
                    "Nikon (SDRAM or card, GetEvent polling)"
                } else {
                    "generic (InitiateCapture, events)"
                }
            );
            for id in cam.storage_ids()? {
                match cam.storage_info(id) {
                    Ok(s) => println!(
                        "storage {id:#010x}: {} MB free of {} MB",
                        s.free_space_bytes >> 20,
                        s.max_capacity >> 20
                    ),
                    Err(e) => println!("storage {id:#010x}: {e}"),
                }
            }
            let ops: Vec<String> = i.operations.iter().map(|o| format!("{o:04x}")).collect();
            println!("operations: {}", ops.join(" "));
            cam.close()?;
        }
        PtpCommand::Capture(a) => {
            let mut cam = open(&a.port.port)?;
            let applied = cam.set_exposure(&Exposure {
                shutter_s: None,
                f_number: a.f_number,
                iso: a.iso,
            })?;
            println!(
                "{}: f/{:?} ISO {:?} applied",
                cam.describe(),
                applied.f_number,
                applied.iso
            );
            let opts = CaptureOptions {
                target: if a.card { Target::Card } else { Target::Sdram },
                delete_after: false,
            };
            std::fs::create_dir_all(&a.out)?;
            let speeds: Vec<Option<f64>> = if a.shutter.is_empty() {
                vec![None]
            } else {
                a.shutter.iter().map(|&s| Some(s)).collect()
            };
            for s in speeds {
                if let Some(s) = s {
                    println!("shutter {s} s: camera applied {} s", cam.set_shutter(s)?);
                }
                let shot = cam.capture(&opts, &mut |phase, done, total| {
                    if phase == "download" && total > 0 && done == total {
                        eprintln!("  downloaded {total} bytes");
                    }
                })?;
                let path = super::write_new(&a.out, &shot.info.filename, &shot.data)?;
                println!("{}", path.display());
            }
            cam.close()?;
        }
    }
    Ok(())
}
