//! `brdfd ptp`: talk to one PTP camera directly, over USB or PTP/IP. For checking a camera at
//! the bench before a session, and for scripted shots.

use std::path::PathBuf;

use brdfd_ptp::{Camera, CaptureOptions, Exposure, ImageFormat, Target};
use brdfd_rig::selector::Selector;

#[derive(clap::Subcommand)]
pub enum PtpCommand {
    /// Print what the camera reports: model, serial, storage, operations.
    Info {
        #[command(flatten)]
        port: PortArg,
        /// Print it as JSON.
        #[arg(long)]
        json: bool,
    },
    /// Take one picture (or a bracket) and save the files exactly as the camera sent them.
    Capture(CaptureArgs),
}

#[derive(clap::Args)]
pub struct PortArg {
    /// `usb` (first PTP camera), `usb:VVVV[:PPPP]` (vendor[:product], hex), or `ptpip:HOST[:PORT]`.
    #[arg(short, long, default_value = "usb")]
    pub port: String,
}

#[derive(clap::Args)]
pub struct CaptureArgs {
    #[command(flatten)]
    pub port: PortArg,
    /// Shutter speeds in seconds; several make a bracket. The camera's current speed if absent.
    #[arg(long, value_delimiter = ',')]
    pub shutter: Vec<f64>,
    /// Aperture as an f-number (8 for f/8); the camera's current one if absent. The camera
    /// may round it: what it applied is printed.
    #[arg(long)]
    pub f_number: Option<f64>,
    /// ISO sensitivity; the camera's current one if absent.
    #[arg(long)]
    pub iso: Option<u32>,
    /// Save to the card and keep the file there (Nikon and Canon EOS: the default keeps it in
    /// the camera's RAM only, for the computer).
    #[arg(long)]
    pub card: bool,
    /// The files each shot makes: jpeg, raw, or raw+jpeg; as the camera is set if not given.
    #[arg(long, value_parser = ["jpeg", "raw", "raw+jpeg"])]
    pub files: Option<String>,
    /// Folder for the files.
    #[arg(short, long, default_value = ".")]
    pub out: PathBuf,
}

/// Opens the camera a port selector names (`usb`, `usb:VVVV[:PPPP]`, `ptpip:HOST[:PORT]`).
pub fn open(port: &str) -> anyhow::Result<Camera> {
    Ok(brdfd_rig::open::ptp_camera(&port.parse::<Selector>()?)?)
}

pub fn run(cmd: PtpCommand) -> anyhow::Result<()> {
    match cmd {
        PtpCommand::Info { port, json } => {
            let mut cam = open(&port.port)?;
            let info = camera_info(&mut cam)?;
            cam.close()?;
            if json {
                println!("{}", serde_json::to_string_pretty(&info)?);
            } else {
                print_info(&info);
            }
        }
        PtpCommand::Capture(a) => {
            let mut cam = open(&a.port.port)?;
            let applied = cam.set_exposure(&Exposure {
                shutter_s: None,
                f_number: a.f_number,
                iso: a.iso,
            })?;
            // What the camera applied, or "as set" for what was not asked (it was left alone).
            let shown = |v: Option<String>| v.unwrap_or_else(|| "as set".into());
            println!(
                "{}: aperture {}, ISO {}",
                cam.describe(),
                shown(applied.f_number.map(|f| format!("f/{f}"))),
                shown(applied.iso.map(|i| i.to_string()))
            );
            if let Some(files) = &a.files {
                let want = match files.as_str() {
                    "raw" => ImageFormat::Raw,
                    "raw+jpeg" => ImageFormat::RawJpeg,
                    _ => ImageFormat::Jpeg,
                };
                println!("files: {:?}", cam.set_format(want)?);
            }
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
                for file in cam.capture_all(&opts, &mut |_, _, _| {})? {
                    eprintln!("  downloaded {} bytes", file.data.len());
                    let path =
                        brdfd_rig::session::write_new(&a.out, &file.info.filename, &file.data)?;
                    println!("{}", path.display());
                }
            }
            cam.close()?;
        }
    }
    Ok(())
}

/// What `ptp info` reports, as `--json` prints it.
#[derive(serde::Serialize)]
struct CameraInfo {
    manufacturer: String,
    model: String,
    device_version: String,
    serial_number: String,
    link: String,
    vendor_extension_id: u32,
    vendor_extension_desc: String,
    capture_flow: CaptureFlow,
    storage: Vec<StorageRow>,
    /// Operation codes, as hex.
    operations: Vec<String>,
}

#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum CaptureFlow {
    /// SDRAM or card, GetEvent polling.
    Nikon,
    /// Remote release, GetEvent records, to the host or the card.
    CanonEos,
    /// SDIO connection, shutter buttons, the shot in the camera's memory.
    Sony,
    /// InitiateCapture, events.
    Generic,
    /// No remote capture brdfd speaks yet (a Canon PowerShot's, an older Sony's).
    None,
}

impl CaptureFlow {
    /// The flow brdfd's PTP driver shoots `cam` with.
    pub fn of(cam: &Camera) -> CaptureFlow {
        if cam.is_nikon() {
            CaptureFlow::Nikon
        } else if cam.is_canon_eos() {
            CaptureFlow::CanonEos
        } else if cam.is_sony() {
            CaptureFlow::Sony
        } else if cam.info.supports(brdfd_ptp::codes::op::INITIATE_CAPTURE) {
            CaptureFlow::Generic
        } else {
            CaptureFlow::None
        }
    }

    /// Its name, as `ptp info` writes it.
    pub fn name(self) -> &'static str {
        match self {
            CaptureFlow::Nikon => "nikon",
            CaptureFlow::CanonEos => "canon-eos",
            CaptureFlow::Sony => "sony",
            CaptureFlow::Generic => "generic",
            CaptureFlow::None => "none",
        }
    }
}

#[derive(serde::Serialize)]
struct StorageRow {
    id: String,
    free_bytes: Option<u64>,
    capacity_bytes: Option<u64>,
    /// Why the storage could not be read, if it could not.
    error: Option<String>,
}

fn camera_info(cam: &mut Camera) -> anyhow::Result<CameraInfo> {
    let i = cam.info.clone();
    let storage = cam
        .storage_ids()?
        .into_iter()
        .map(|id| match cam.storage_info(id) {
            Ok(s) => StorageRow {
                id: format!("{id:#010x}"),
                free_bytes: Some(s.free_space_bytes),
                capacity_bytes: Some(s.max_capacity),
                error: None,
            },
            Err(e) => StorageRow {
                id: format!("{id:#010x}"),
                free_bytes: None,
                capacity_bytes: None,
                error: Some(e.to_string()),
            },
        })
        .collect();
    Ok(CameraInfo {
        link: cam.describe(),
        capture_flow: CaptureFlow::of(cam),
        operations: i.operations.iter().map(|o| format!("{o:04x}")).collect(),
        manufacturer: i.manufacturer,
        model: i.model,
        device_version: i.device_version,
        serial_number: i.serial_number,
        vendor_extension_id: i.vendor_extension_id,
        vendor_extension_desc: i.vendor_extension_desc,
        storage,
    })
}

fn print_info(i: &CameraInfo) {
    println!(
        "{} {} (version {}, serial {})",
        i.manufacturer, i.model, i.device_version, i.serial_number
    );
    println!("link: {}", i.link);
    println!(
        "vendor extension: {:#x} ({})",
        i.vendor_extension_id, i.vendor_extension_desc
    );
    println!(
        "capture flow: {}",
        match i.capture_flow {
            CaptureFlow::Nikon => "Nikon (SDRAM or card, GetEvent polling)",
            CaptureFlow::CanonEos => "Canon EOS (remote release, GetEvent records)",
            CaptureFlow::Sony => "Sony (SDIO control, shutter buttons, the shot in memory)",
            CaptureFlow::Generic => "generic (InitiateCapture, events)",
            CaptureFlow::None => "none that brdfd speaks yet",
        }
    );
    for s in &i.storage {
        match (&s.error, s.free_bytes, s.capacity_bytes) {
            (Some(e), _, _) => println!("storage {}: {e}", s.id),
            (None, Some(free), Some(cap)) => {
                println!(
                    "storage {}: {} MB free of {} MB",
                    s.id,
                    free >> 20,
                    cap >> 20
                )
            }
            _ => {}
        }
    }
    println!("operations: {}", i.operations.join(" "));
}
