//! `brdfd calibrate target`: the board to print. `brdfd calibrate pose`: the object camera's
//! pose (and focal length) from a photo of it on the bench, written into the rig file; the
//! flow is the rig's (`brdfd_rig::calibrate_pose`), this reads the arguments into its request
//! and prints what it reports.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{bail, Context as _};
use brdfd_core::geometry::Camera;
use brdfd_pose::board::Board;
use brdfd_pose::silhouette::Refined;
use brdfd_pose::{angle_between_deg, pinhole, Calibrated, Focal};
use brdfd_rig::calibrate_pose::{Field, PhotosFrom, PoseCalibration, PoseReport, PoseRequest};
use brdfd_rig::config::Rig;
use brdfd_rig::error::RigError;
use brdfd_rig::flow::Context;
use brdfd_rig::{Devices, Progress, KEEP_ALIVE};

use super::progress::{Bars, Terminal};
use brdfd_rig::calibrate::{calibration_dir, Folder};

#[derive(clap::Args)]
pub struct TargetArgs {
    /// The folder the board's files go to: board.svg and board.png (300 dpi) to print, and
    /// board.toml, the board file `brdfd calibrate pose --board` reads.
    #[arg(short, long, default_value = "board")]
    pub out: PathBuf,
    /// Squares across the board.
    #[arg(long, default_value_t = Board::default().cols)]
    pub cols: u32,
    /// Squares down the board.
    #[arg(long, default_value_t = Board::default().rows)]
    pub rows: u32,
    /// A square's side, millimetres.
    #[arg(long, default_value_t = Board::default().square_mm)]
    pub square_mm: f64,
    /// A marker's side over its square's.
    #[arg(long, default_value_t = Board::default().marker)]
    pub marker: f64,
    /// The ArUco dictionary of the markers (OpenCV's names).
    #[arg(long, default_value_t = Board::default().dictionary)]
    pub dictionary: String,
    /// Write over a board file already in the folder (its measured square size is lost).
    #[arg(long)]
    pub force: bool,
}

pub fn target(a: TargetArgs) -> anyhow::Result<()> {
    let board = Board {
        rows: a.rows,
        cols: a.cols,
        square_mm: a.square_mm,
        marker: a.marker,
        dictionary: a.dictionary,
        ..Board::default()
    };
    let (svg, png) = board.printable()?;
    let file = a.out.join("board.toml");
    if file.exists() && !a.force {
        bail!(
            "{} is there already (it may hold a square size measured on its print): give another --out, or --force",
            file.display()
        );
    }
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    if file.exists() {
        // --force: the board file before (its measured square) is kept.
        let backup = a.out.join("board.toml.bak");
        std::fs::copy(&file, &backup).with_context(|| format!("keeping {}", backup.display()))?;
        println!("the board file before is {}", backup.display());
    }
    for (name, bytes) in [
        ("board.svg", svg.as_bytes()),
        ("board.png", &png[..]),
        ("board.toml", board.to_toml().as_bytes()),
    ] {
        brdfd_rig::session::write_atomic(&a.out.join(name), bytes)?;
    }
    let (w, h) = board.size_mm();
    println!(
        "wrote {dir}/board.svg and board.png: a ChArUco board of {c} × {r} squares of {s} mm ({w} × {h} mm), {d}",
        dir = a.out.display(),
        c = board.cols,
        r = board.rows,
        s = board.square_mm,
        d = board.dictionary
    );
    println!("  1. print it at 100% (no \"fit to page\") and glue it flat to stiff card;");
    println!(
        "  2. measure a square; if it is not {} mm, put its side into {}/board.toml (square_mm);",
        board.square_mm,
        a.out.display()
    );
    println!("  3. stand it where the object goes, facing the camera, its centre on the turntable's axis (or say where in the board file's [placement]);");
    println!(
        "  4. brdfd calibrate pose --rig RIG --board {}/board.toml",
        a.out.display()
    );
    Ok(())
}

#[derive(clap::Args)]
pub struct PoseArgs {
    /// The rig file: its object camera (a pinhole camera) is read, then written with the
    /// pose found, and its object's placement with --refine-object (the file before is kept
    /// beside it as FILE.bak).
    #[arg(short, long)]
    pub rig: PathBuf,
    /// The board file `brdfd calibrate target` wrote; else its default board, standing where
    /// the object goes.
    #[arg(long)]
    pub board: Option<PathBuf>,
    /// Photos of the board from the object camera (JPEG or PNG), taken already; else the
    /// rig's object camera photographs it now.
    #[arg(long, num_args = 1..)]
    pub photo: Vec<PathBuf>,
    /// Views of the board: photographed at 0°, then turned on the turntable by +--turn, −--turn,
    /// ... (views at a slant pin the focal length down); else 3 on a rig with a turntable and
    /// no --photo, 1 otherwise.
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=9))]
    pub views: Option<u32>,
    /// Turntable degrees between views of the board.
    #[arg(long, default_value_t = 30.0)]
    pub turn: f64,
    /// Keep the rig's focal length; else it is refined where the view pins it down (a board
    /// seen at a slant), starting from the photo's EXIF focal length if it has one.
    #[arg(long)]
    pub fix_focal: bool,
    /// The sensor's width, millimetres, for a photo whose EXIF gives the focal length but
    /// not the focal plane's resolution.
    #[arg(long)]
    pub sensor_width_mm: Option<f64>,
    /// Also refine where the object stands, from its silhouette: after the board, the empty
    /// bench and then the object are photographed at the board's views, and the rig's mesh
    /// aligned with the object's outline. The placement found is written into
    /// `[geometry.shape]` (a mesh). Lay white card under and behind a dark or grey object,
    /// black cloth under a white one.
    #[arg(long)]
    pub refine_object: bool,
    /// With --photo: photos of the object standing where the rig places it, from the camera
    /// as it stood for the board's; the bracket's frames, each with its --empty-photo.
    /// Refines the object's placement as --refine-object does.
    #[arg(long, num_args = 1.., requires = "empty_photo")]
    pub object_photo: Vec<PathBuf>,
    /// The empty bench's photos, one for each --object-photo, at its exposure.
    #[arg(long, num_args = 1.., requires = "object_photo")]
    pub empty_photo: Vec<PathBuf>,
    /// Print the pose only; leave the rig file as it is.
    #[arg(long)]
    pub dry_run: bool,
    /// Write the pose even when the corners fit it poorly (over 1 px RMS or 3 px at worst).
    #[arg(long)]
    pub force: bool,
    /// Where the board's photos go; else a new folder under the state directory's
    /// `calibrations/`.
    #[arg(short, long)]
    pub out: Option<PathBuf>,
    /// The state directory; else BRDFD_STATE_DIR, else the XDG data directory.
    #[arg(long)]
    pub state_dir: Option<PathBuf>,
}

pub fn pose(a: PoseArgs) -> anyhow::Result<()> {
    let rig = Rig::read(&a.rig)?;
    let board = match &a.board {
        Some(p) => brdfd_rig::config::read_board(p)?,
        None => Board::default(),
    };
    let photos = if a.photo.is_empty() && a.object_photo.is_empty() {
        PhotosFrom::Camera {
            views: a.views,
            turn_deg: a.turn,
        }
    } else {
        PhotosFrom::Files {
            board: a.photo,
            object: a.object_photo,
            empty: a.empty_photo,
            views: a.views,
        }
    };
    let request = PoseRequest {
        rig_file: a.rig.clone(),
        board,
        photos,
        focal: if a.fix_focal {
            Focal::Fixed
        } else {
            Focal::Refine
        },
        sensor_width_mm: a.sensor_width_mm,
        refine_object: a.refine_object,
        write: !a.dry_run,
        force: a.force,
    };
    let calibration = PoseCalibration::new(&rig, request).map_err(in_flags)?;
    let mut report = Printed;
    let (outcome, out) = if calibration.shoots() {
        let devices = Devices::start(&rig, KEEP_ALIVE)?;
        let out = calibration_dir(a.out.as_deref(), a.state_dir.as_deref(), "pose")?;
        println!("the photos go to {}", out.display());
        let cx = Context {
            rig: &rig,
            devices: &devices,
            progress: Arc::new(Bars::new()) as Arc<dyn Progress>,
            cancel: Default::default(),
            operator: Arc::new(Terminal),
        };
        let mut folder = Folder(out.clone());
        let outcome = calibration
            .run(Some((&cx, &mut folder)), Some(&out), &mut report)
            .map_err(in_flags)?;
        (outcome, Some(out))
    } else {
        // Made by the flow once there is a fit to write into it.
        let out = a.out.clone();
        let outcome = calibration
            .run(None, out.as_deref(), &mut report)
            .map_err(in_flags)?;
        (outcome, out)
    };
    if let Some(out) = &out {
        println!("the fit is in {}", out.join("pose.json").display());
    }
    match outcome.saved {
        Some(Err(e)) => return Err(e.into()),
        Some(Ok(saved)) => {
            println!(
                "wrote the {} into {} (the file before is {})",
                if matches!(outcome.placed, Some(Ok(_))) {
                    "pose and the object's placement"
                } else {
                    "pose"
                },
                a.rig.display(),
                saved.backup.display()
            );
            super::warn_not_ready(&saved);
        }
        None => println!("the rig file is left as it is"),
    }
    match outcome.placed {
        Some(Err(e)) => Err(anyhow::Error::from(e).context(
            "the object's placement was not found; the camera's pose is kept (run again with --refine-object, or place the object by hand in [geometry.shape])",
        )),
        _ => Ok(()),
    }
}

/// The calibration's report, printed for the person at the terminal.
struct Printed;

impl PoseReport for Printed {
    fn found(&mut self, before: &Camera, found: &Calibrated) {
        print_found(before, found);
    }

    fn refined(&mut self, refined: &Refined) {
        print_refined(refined);
    }

    fn warn(&mut self, warning: &str) {
        eprintln!("  warning: {warning}");
    }

    /// Waits for the operator to change what stands on the bench; a simulated bench changes
    /// it itself.
    fn change_bench(&mut self, what: &str, simulated: bool) -> Result<(), RigError> {
        if simulated {
            println!("simulated rig: {what}: done by the simulated bench");
            return Ok(());
        }
        Terminal::ask(
            &format!("{what}, then press Enter"),
            "no one can change what stands on the bench: standard input is closed. --refine-object needs someone at the terminal, or photos taken already (--photo with --object-photo and --empty-photo)",
            &|| Ok(true),
        )
        .map(|_| ())
    }
}

/// A silhouette that matches the mesh worse than this at the offset found has lost or gained
/// a part: with the blur of a sharp lens, a good match is above 0.98.
const MIN_IOU: f64 = 0.97;

fn print_refined(r: &Refined) {
    let o = &r.offset;
    println!(
        "object: its middle moved [{:.2}, {:.2}, {:.2}] mm and turned {:.2}° about the vertical through it, from where [geometry.shape] placed it",
        o.shift[0] * 1e3,
        o.shift[1] * 1e3,
        o.shift[2] * 1e3,
        o.turn_deg
    );
    let list = |v: &[f64]| {
        v.iter()
            .map(|x| format!("{x:.3}"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    println!(
        "  silhouette overlap (IoU) in each view: {} as placed, {} as refined",
        list(&r.iou_before),
        list(&r.iou_after)
    );
    if r.iou_after.iter().any(|i| *i < MIN_IOU) {
        eprintln!("  warning: the object's outline does not match its mesh's well (below {MIN_IOU}): a face as bright as the bench behind it is lost (lay white card under and behind a dark or grey object, black cloth under a white one), or the mesh is not the object's");
    }
}

fn print_found(before: &Camera, c: &Calibrated) {
    let f = &c.fit;
    for v in &c.views {
        println!(
            "board: {} corners in {}{}",
            v.corners.len(),
            v.name,
            if c.views.len() > 1 {
                format!(" (turned {:.1}°)", v.turn_deg)
            } else {
                String::new()
            }
        );
    }
    println!(
        "reprojection: {:.3} px RMS, {:.3} px at worst, over {} corners in {}×{} photos",
        f.rms_px, f.worst_px, f.corners, c.photo_size.0, c.photo_size.1
    );
    let (k, e) = pinhole(&c.camera).expect("a pinhole camera");
    let (k0, e0) = pinhole(before).expect("a pinhole camera");
    match &f.focal {
        Ok(sigma) => println!(
            "focal length: fx {:.1} px (from {:.1}, {}), refined to ±{:.2}%",
            k.fx,
            c.start_fx * k.fx / f.intrinsics.fx,
            c.start_from,
            sigma * 100.0
        ),
        Err(why) => {
            println!("focal length: fx {:.1} px ({}), {why}", k.fx, c.start_from);
            if c.start_from.starts_with("EXIF") {
                eprintln!("  warning: the camera's distance is only as good as the EXIF's focal length: turn the board between views (--views 3 on a rig with a turntable), or give --sensor-width-mm");
            }
        }
    }
    let p = e.centre();
    let [lx, ly, lz] = match &c.camera {
        Camera::Pinhole { pose, .. } => pose.look_at,
        Camera::Orthographic { pose, .. } => pose.look_at,
    };
    println!(
        "camera at [{:.4}, {:.4}, {:.4}] m, looking at [{lx:.4}, {ly:.4}, {lz:.4}]",
        p.x, p.y, p.z
    );
    println!(
        "  against the rig's: moved {:.1} mm, turned {:.2}°, fx {:+.2}%",
        (p - e0.centre()).norm() * 1000.0,
        angle_between_deg(&e.rotation, &e0.rotation),
        (k.fx / k0.fx - 1.0) * 100.0
    );
}

/// The flag that sets each field of the flow's request.
fn flag(field: Field) -> &'static str {
    match field {
        Field::SensorWidth => "--sensor-width-mm",
        Field::Turn => "--turn",
        Field::Views => "--views",
        Field::BoardPhotos => "--photo",
        Field::ObjectPhotos => "--object-photo",
        Field::EmptyPhotos => "--empty-photo",
        Field::RefineObject => "--refine-object",
        Field::Force => "--force",
    }
}

/// The flow's refusal said in this command's flags; any other error as it is.
fn in_flags(e: RigError) -> anyhow::Error {
    match e {
        RigError::Refused(refused) => anyhow::anyhow!(refused.said_with(flag)),
        e => e.into(),
    }
}
