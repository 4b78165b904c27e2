//! `brdfd calibrate target`: the board to print. `brdfd calibrate pose`: the object camera's
//! pose (and focal length) from a photo of it on the bench, written into the rig file.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{bail, Context as _};
use brdfd::config::Rig;
use brdfd::core::geometry::Camera;
use brdfd::pose::board::Board;
use brdfd::pose::{angle_between_deg, pinhole, Calibrated, Focal};
use brdfd::rig::flow::{Context, Keep};
use brdfd::rig::pose::{self, BoardPhoto};
use brdfd::rig::{Devices, Progress, KEEP_ALIVE};
use toml_edit::{value, Array, Item};

use super::progress::{Bars, Terminal};
use super::rig_file::RigFile;

#[derive(clap::Args)]
pub struct TargetArgs {
    /// The folder the board's files go to: board.svg and board.png (300 dpi) to print, and
    /// board.toml, the board file `brdfd calibrate pose --board` reads.
    #[arg(long, default_value = "board")]
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
    for (name, bytes) in [
        ("board.svg", svg.as_bytes()),
        ("board.png", &png[..]),
        ("board.toml", board.to_toml().as_bytes()),
    ] {
        brdfd::session::write_atomic(&a.out.join(name), bytes)?;
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
    /// pose found (the file before is kept beside it as FILE.bak).
    #[arg(long)]
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
    /// Print the pose only; leave the rig file as it is.
    #[arg(long)]
    pub dry_run: bool,
    /// Where the board's photos go; else a new folder under the state directory's
    /// `calibrations/`.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// The state directory; else BRDFD_STATE_DIR, else the XDG data directory.
    #[arg(long)]
    pub state_dir: Option<PathBuf>,
}

pub fn pose(a: PoseArgs) -> anyhow::Result<()> {
    let rig = Rig::read(&a.rig)?;
    let board = match &a.board {
        Some(p) => Board::read(p)?,
        None => Board::default(),
    };
    if pinhole(&rig.geometry.camera).is_none() {
        bail!(
            "{}: the object camera is orthographic: a pose from a board needs a pinhole camera ([geometry.camera] type = \"pinhole\", with fx, fy, cx, cy)",
            a.rig.display()
        );
    }
    if let Some(s) = a.sensor_width_mm {
        if !(s.is_finite() && s > 0.0) {
            bail!("--sensor-width-mm must be a positive number of millimetres, not {s}");
        }
    }
    // Opened first: a file the pose cannot go into is said before anything is shot.
    let rig_file = if a.dry_run {
        None
    } else {
        Some(RigFile::open(&a.rig)?)
    };
    let focal = if a.fix_focal {
        Focal::Fixed
    } else {
        Focal::Refine
    };
    let mut warn = |w: String| eprintln!("  warning: {w}");
    let views = if a.photo.is_empty() {
        let roles = brdfd::rig::plan::devices(&rig)?;
        let n = a.views.unwrap_or(if roles.turntable { 3 } else { 1 }) as usize;
        if !(a.turn.is_finite() && a.turn.abs() > 0.0 && a.turn.abs() < 80.0) {
            bail!(
                "--turn must be a number of degrees between 0 and 80, not {}",
                a.turn
            );
        }
        let devices = Devices::start(&rig, KEEP_ALIVE)?;
        let out = out_dir(&a)?;
        println!("the board's photos go to {}", out.display());
        let cx = Context {
            rig: &rig,
            devices: &devices,
            progress: Arc::new(Bars::new()) as Arc<dyn Progress>,
            cancel: Default::default(),
            operator: Arc::new(Terminal),
        };
        let shot = pose::shoot(&cx, &mut Folder(out), &board, &pose::view_angles(n, a.turn))?;
        pose::solve_views(
            &mut warn,
            &rig.geometry.camera,
            &board,
            &shot,
            focal,
            a.sensor_width_mm,
        )?
    } else {
        if a.views.is_some_and(|v| v > 1) {
            bail!("--views photographs the board on the turntable; with --photo, each photo is one view of the board as placed");
        }
        let photos = a
            .photo
            .iter()
            .map(|p| {
                let bytes = std::fs::read(p).with_context(|| format!("reading {}", p.display()))?;
                BoardPhoto::decode(&p.display().to_string(), &bytes)
            })
            .collect::<anyhow::Result<Vec<_>>>()?;
        let view = [pose::BoardView {
            turn_deg: 0.0,
            photos,
        }];
        pose::solve_views(
            &mut warn,
            &rig.geometry.camera,
            &board,
            &view,
            focal,
            a.sensor_width_mm,
        )?
    };
    let found = views;
    print_found(&rig.geometry.camera, &found);
    match rig_file {
        Some(f) => {
            let note = format!(
                "by `brdfd calibrate pose` on {}: {:.3} px RMS over {} board corners",
                humantime::format_rfc3339_seconds(std::time::SystemTime::now()),
                found.fit.rms_px,
                found.fit.corners
            );
            let backup = write_camera(f, &found.camera, &note)?;
            println!(
                "wrote the pose into {} (the file before is {})",
                a.rig.display(),
                backup.display()
            );
        }
        None => println!("the rig file is left as it is"),
    }
    Ok(())
}

fn out_dir(a: &PoseArgs) -> anyhow::Result<PathBuf> {
    let out = match &a.out {
        Some(o) => o.clone(),
        None => {
            let state = brdfd::session::state_dir(a.state_dir.as_deref(), None)?;
            let stamp = humantime::format_rfc3339_seconds(std::time::SystemTime::now())
                .to_string()
                .replace(':', "");
            state.join("calibrations").join(format!("{stamp}-pose"))
        }
    };
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    Ok(out)
}

/// The board's photos, each under its own name in the calibration's folder.
struct Folder(PathBuf);

impl Keep for Folder {
    fn keep(&mut self, name: &str, bytes: &[u8]) -> anyhow::Result<()> {
        super::write_new(&self.0, name, bytes)?;
        Ok(())
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
        Err(why) => println!("focal length: fx {:.1} px ({}), {why}", k.fx, c.start_from),
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

/// Writes the camera's pose and focal lengths into `[geometry.camera]`, with a comment that
/// says where they came from; the rest of the file as it was.
fn write_camera(mut file: RigFile, camera: &Camera, note: &str) -> anyhow::Result<PathBuf> {
    let Camera::Pinhole { fx, fy, pose, .. } = camera else {
        bail!("a pose is written for a pinhole camera");
    };
    let path = file.path.display().to_string();
    let table = file
        .doc
        .get_mut("geometry")
        .and_then(|g| g.get_mut("camera"))
        .and_then(Item::as_table_like_mut)
        .with_context(|| format!("{path} has no [geometry.camera] table to write the pose into"))?;
    let triple = |v: [f64; 3]| {
        let mut a = Array::new();
        for x in v {
            a.push(x);
        }
        value(a)
    };
    let round = |x: f64| (x * 100.0).round() / 100.0;
    table.insert("fx", value(round(*fx)));
    table.insert("fy", value(round(*fy)));
    table.insert("position", triple(pose.position));
    table.insert("look_at", triple(pose.look_at));
    table.insert("up", triple(pose.up));
    if let Some(mut key) = table.key_mut("position") {
        key.leaf_decor_mut()
            .set_prefix(format!("# The pose and focal length {note}.\n"));
    }
    file.save()
}
