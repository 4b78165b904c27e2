//! `brdfd calibrate target`: the board to print. `brdfd calibrate pose`: the object camera's
//! pose (and focal length) from a photo of it on the bench, written into the rig file.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{bail, Context as _};
use brdfd_core::geometry::{Camera, Shape};
use brdfd_pose::board::Board;
use brdfd_pose::silhouette::Refined;
use brdfd_pose::{angle_between_deg, pinhole, Calibrated, Focal};
use brdfd_rig::config::Rig;
use brdfd_rig::flow::Context;
use brdfd_rig::pose::{self, OnBench, Photo};
use brdfd_rig::{Devices, Progress, KEEP_ALIVE};
use toml_edit::{value, Array, Item};

use super::calibrate_cmd::{calibration_dir, Folder};
use super::progress::{Bars, Terminal};
use super::rig_file::RigFile;

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
    let refine_object = a.refine_object || !a.object_photo.is_empty();
    if !a.object_photo.is_empty() && a.photo.is_empty() {
        bail!("--object-photo goes with --photo (the board's photos from the camera as it stood for the object's); without them, --refine-object photographs both");
    }
    if a.refine_object && !a.photo.is_empty() && a.object_photo.is_empty() {
        bail!("with --photo, --refine-object needs the object's photos and the empty bench's: --object-photo and --empty-photo");
    }
    if a.object_photo.len() != a.empty_photo.len() {
        bail!(
            "{} --object-photo and {} --empty-photo: each photo of the object needs one of the empty bench at its exposure",
            a.object_photo.len(),
            a.empty_photo.len()
        );
    }
    if refine_object && !matches!(rig.geometry.shape, Some(Shape::Mesh { .. })) {
        bail!(
            "{}: --refine-object aligns the object's mesh with its silhouette, and [geometry.shape] is no mesh",
            a.rig.display()
        );
    }
    // Opened first: a file the pose cannot go into is said before anything is shot.
    let rig_file = if a.dry_run {
        None
    } else {
        Some(open_for_pose(&a.rig, refine_object)?)
    };
    let focal = if a.fix_focal {
        Focal::Fixed
    } else {
        Focal::Refine
    };
    let settle = |found: &Calibrated, out: Option<&Path>| {
        print_found(&rig.geometry.camera, found);
        let note = note(found);
        if let Some(out) = out {
            write_json(out, &json(found, None, &note))?;
        }
        check_fit(found, a.force || rig_file.is_none())
    };
    let mut warn = |w: String| eprintln!("  warning: {w}");
    let (found, object, out) = if a.photo.is_empty() {
        let roles = brdfd_rig::plan::devices(&rig)?;
        let n = a.views.unwrap_or(if roles.turntable { 3 } else { 1 }) as usize;
        if !(a.turn.is_finite() && a.turn.abs() > 0.0 && a.turn.abs() < 80.0) {
            bail!(
                "--turn must be a number of degrees between 0 and 80, not {}",
                a.turn
            );
        }
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
        let angles = pose::view_angles(n, a.turn);
        let mut folder = Folder(out.clone());
        let mut shooting = pose::Shooting::default();
        let mut shoot = |on_bench, prefix| {
            pose::shoot(&cx, &mut folder, &mut shooting, on_bench, &angles, prefix)
        };
        let views = shoot(OnBench::Board(&board), "")?;
        let found = pose::solve(
            &mut warn,
            &rig.geometry.camera,
            &board,
            &views,
            focal,
            a.sensor_width_mm,
        )?;
        settle(&found, Some(&out))?;
        // An error from here on leaves the board's pose good: it is written all the same.
        let simulated = devices.sim.is_some();
        let object = refine_object.then(|| {
            ready(
                simulated,
                "take the board away, leaving the bench as it was",
            )?;
            let empty = shoot(OnBench::Nothing, "empty-")?;
            ready(
                simulated,
                "stand the object where [geometry.shape] places it, as nearly as you can",
            )?;
            Ok((empty, shoot(OnBench::Object, "object-")?))
        });
        (found, object, Some(out))
    } else {
        if a.views.is_some_and(|v| v > 1) {
            bail!("--views turns the board on the turntable; --photo takes photos of the board as it stands, and solves from the one that shows the most of it");
        }
        let view = |files: &[PathBuf]| {
            Ok::<_, anyhow::Error>(vec![pose::PhotoView {
                turn_deg: 0.0,
                photos: files
                    .iter()
                    .map(|p| {
                        let bytes =
                            std::fs::read(p).with_context(|| format!("reading {}", p.display()))?;
                        Photo::decode(&p.display().to_string(), &bytes)
                    })
                    .collect::<anyhow::Result<Vec<_>>>()?,
            }])
        };
        let found = pose::solve(
            &mut warn,
            &rig.geometry.camera,
            &board,
            &view(&a.photo)?,
            focal,
            a.sensor_width_mm,
        )?;
        let out = match &a.out {
            Some(o) => Some(calibration_dir(Some(o), None, "pose")?),
            None => None,
        };
        settle(&found, out.as_deref())?;
        let object = if refine_object {
            eprintln!("  warning: one view pins the object's distance from the camera only by its outline's size; photographed by `--refine-object` on a rig with a turntable, the slanted views pin it as well as the rest");
            Some(view(&a.empty_photo).and_then(|e| Ok((e, view(&a.object_photo)?))))
        } else {
            None
        };
        (found, object, out)
    };
    let note = note(&found);
    let placed = object.map(|photos| {
        let (empty, object) = photos?;
        let shape = rig.geometry.shape.as_ref().expect("checked to be a mesh");
        let refined = pose::refine_object(&found.camera, shape, &empty, &object)?;
        print_refined(&refined);
        let placed = refined.offset.placed(shape);
        if let Some(out) = &out {
            write_json(out, &json(&found, Some((&refined, &placed)), &note))?;
        }
        Ok::<_, anyhow::Error>(placed)
    });
    if let Some(out) = &out {
        println!("the fit is in {}", out.join("pose.json").display());
    }
    let shape = placed.as_ref().and_then(|p| p.as_ref().ok());
    match rig_file {
        Some(mut f) => {
            set_camera(&mut f, &found.camera, &note)?;
            if let Some(shape) = shape {
                set_shape(&mut f, shape)?;
            }
            let backup = f.save()?;
            println!(
                "wrote the {} into {} (the file before is {})",
                if shape.is_some() {
                    "pose and the object's placement"
                } else {
                    "pose"
                },
                a.rig.display(),
                backup.display()
            );
        }
        None => println!("the rig file is left as it is"),
    }
    match placed {
        Some(Err(e)) => Err(e.context(
            "the object's placement was not found; the camera's pose is kept (run again with --refine-object, or place the object by hand in [geometry.shape])",
        )),
        _ => Ok(()),
    }
}

/// Where the pose came from, for the rig file's comment and pose.json.
fn note(found: &Calibrated) -> String {
    format!(
        "by `brdfd calibrate pose` on {}: {:.3} px RMS over {} board corners",
        humantime::format_rfc3339_seconds(std::time::SystemTime::now()),
        found.fit.rms_px,
        found.fit.corners
    )
}

fn write_json(out: &Path, v: &serde_json::Value) -> anyhow::Result<()> {
    let text = serde_json::to_string_pretty(v)?;
    brdfd_rig::session::write_atomic(&out.join("pose.json"), text.as_bytes())?;
    Ok(())
}

/// A poor fit is an error, unless it is only printed (`warn_only`: --force, --dry-run).
fn check_fit(found: &Calibrated, warn_only: bool) -> anyhow::Result<()> {
    if found.fit.rms_px > MAX_RMS_PX || found.fit.worst_px > MAX_WORST_PX {
        let why = format!(
            "the board's corners do not fit one camera well ({:.2} px RMS, {:.2} px at worst; a good fit is under {MAX_RMS_PX} and {MAX_WORST_PX}): check the board's square_mm and [placement], that it is flat, and that it turned with the turntable",
            found.fit.rms_px, found.fit.worst_px
        );
        if !warn_only {
            bail!("{why}; the rig file is left as it is (--force writes it anyway)");
        }
        eprintln!("  warning: {why}");
    }
    Ok(())
}

/// Waits for the operator to change what stands on the bench; a simulated bench changes it
/// itself.
fn ready(simulated: bool, what: &str) -> anyhow::Result<()> {
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

/// A fit worse than these is not written without --force: the board's corners are found to
/// a tenth of a pixel, so a pixel means the model (the board's size or place, its flatness,
/// the lens's distortion) is wrong.
const MAX_RMS_PX: f64 = 1.0;
const MAX_WORST_PX: f64 = 3.0;

/// The rig file, opened for the pose before anything is shot: its `[geometry.camera]` must be
/// there to be written, and its `[geometry.shape]` for the object's placement.
fn open_for_pose(path: &Path, object: bool) -> anyhow::Result<RigFile> {
    let file = RigFile::open(path)?;
    let tables: &[(&str, &str)] = if object {
        &[("camera", "pose"), ("shape", "object's placement")]
    } else {
        &[("camera", "pose")]
    };
    for (table, what) in tables {
        let found = file
            .doc
            .get("geometry")
            .and_then(|g| g.get(table))
            .and_then(Item::as_table_like);
        if found.is_none() {
            bail!(
                "{} has no [geometry.{table}] table to write the {what} into",
                path.display()
            );
        }
    }
    Ok(file)
}

/// What `pose.json` holds: the fit, the camera written, and each view's corners; and the
/// object's placement refined from its silhouette, where it was.
fn json(c: &Calibrated, object: Option<(&Refined, &Shape)>, note: &str) -> serde_json::Value {
    let (k, _) = pinhole(&c.camera).expect("a pinhole camera");
    let pose = match &c.camera {
        Camera::Pinhole { pose, .. } | Camera::Orthographic { pose, .. } => pose,
    };
    let object = object.map(|(r, placed)| {
        let (rotation_deg, position) = match placed {
            Shape::Mesh {
                rotation_deg,
                position,
                ..
            } => (Some(rotation_deg), Some(position)),
            _ => (None, None),
        };
        serde_json::json!({
            "shift_m": r.offset.shift,
            "turn_deg": r.offset.turn_deg,
            "turned_about": r.offset.pivot,
            "iou_before": r.iou_before,
            "iou_after": r.iou_after,
            "rotation_deg": rotation_deg,
            "position": position,
        })
    });
    serde_json::json!({
        "measured": note,
        "object": object,
        "rms_px": c.fit.rms_px,
        "worst_px": c.fit.worst_px,
        "corners": c.fit.corners,
        "photo_size": [c.photo_size.0, c.photo_size.1],
        "focal": {
            "start_fx_px": c.start_fx,
            "start_from": c.start_from,
            "refined_sigma": c.fit.focal.as_ref().ok(),
            "held_because": c.fit.focal.as_ref().err(),
        },
        "camera": {
            "fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy,
            "position": pose.position, "look_at": pose.look_at, "up": pose.up,
        },
        "views": c.views.iter().map(|v| serde_json::json!({
            "photo": v.name,
            "turn_deg": v.turn_deg,
            "corners": v.corners.iter()
                .map(|p| serde_json::json!({ "world": p.world, "pixel": p.pixel }))
                .collect::<Vec<_>>(),
        })).collect::<Vec<_>>(),
    })
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

/// Sets the camera's pose and focal lengths in `[geometry.camera]`, with a comment that
/// says where they came from; the rest of the file as it was.
fn set_camera(file: &mut RigFile, camera: &Camera, note: &str) -> anyhow::Result<()> {
    let Camera::Pinhole { fx, fy, pose, .. } = camera else {
        bail!("a pose is written for a pinhole camera");
    };
    let path = file.path.display().to_string();
    let item = file
        .doc
        .get_mut("geometry")
        .and_then(|g| g.get_mut("camera"))
        .with_context(|| format!("{path} has no [geometry.camera] table to write the pose into"))?;
    // A comment above `fx` says where the numbers came from; an inline table holds none.
    let is_table = item.is_table();
    let table = item
        .as_table_like_mut()
        .with_context(|| format!("{path}: geometry.camera is not a table"))?;
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
    if let (true, Some(mut key)) = (is_table, table.key_mut("fx")) {
        key.leaf_decor_mut()
            .set_prefix(format!("# fx, fy, position, look_at and up {note}.\n"));
    }
    Ok(())
}

/// Sets the mesh's `position` and `rotation_deg` in `[geometry.shape]` to where its
/// silhouette placed it, with a comment that says so.
fn set_shape(file: &mut RigFile, placed: &Shape) -> anyhow::Result<()> {
    let Shape::Mesh {
        rotation_deg,
        position,
        ..
    } = placed
    else {
        bail!("an object's placement is written for a mesh");
    };
    let path = file.path.display().to_string();
    let item = file
        .doc
        .get_mut("geometry")
        .and_then(|g| g.get_mut("shape"))
        .with_context(|| {
            format!("{path} has no [geometry.shape] table to write the placement into")
        })?;
    let is_table = item.is_table();
    let table = item
        .as_table_like_mut()
        .with_context(|| format!("{path}: geometry.shape is not a table"))?;
    // Hundredths of a degree and hundredths of a millimetre: finer than a silhouette pins.
    let triple = |v: [f64; 3], decimals: usize| {
        let mut a = Array::new();
        for x in v {
            let x: f64 = format!("{x:.decimals$}").parse().expect("a number");
            a.push(x + 0.0);
        }
        value(a)
    };
    table.insert("rotation_deg", triple(*rotation_deg, 2));
    table.insert("position", triple(*position, 5));
    if let (true, Some(mut key)) = (is_table, table.key_mut("rotation_deg")) {
        key.leaf_decor_mut().set_prefix(format!(
            "# rotation_deg and position from the object's silhouette, by `brdfd calibrate pose --refine-object` on {}.\n",
            humantime::format_rfc3339_seconds(std::time::SystemTime::now())
        ));
    }
    Ok(())
}
