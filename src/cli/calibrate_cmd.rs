//! `brdfd calibrate radiometry`: measure each camera's gain from a grey card (or another
//! target of known albedo) where the object goes, and write the gains into the rig file with
//! their spread. The target's photos are kept in a folder of their own.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{bail, Context as _};
use brdfd_rig::calibrate::{self, calibration_dir, Folder, Radiometry, Target};
use brdfd_rig::config::Rig;
use brdfd_rig::flow::Context;
use brdfd_rig::{Devices, Progress, KEEP_ALIVE};
use toml_edit::{value, Array, Item, Table};

use brdfd_rig::rig_file::{RigFile, Saved};

use super::progress::{Bars, Terminal};

#[derive(clap::Subcommand)]
pub enum CalibrateCommand {
    /// Measure each camera's gain from a target of known albedo (a grey card) put where the
    /// object goes, and write them into the rig file. The THETA's gain is the bench's unit and
    /// is kept; the DSLR's (RAW and JPEG) and the fallback camera's are measured against it.
    Radiometry(RadiometryArgs),
    /// Write a ChArUco board to print (SVG and PNG) and its board file, for `pose`.
    Target(super::pose_cmd::TargetArgs),
    /// Find the object camera's pose (and focal length) from a photo of the printed board
    /// standing where the object goes, and write it into the rig file.
    Pose(super::pose_cmd::PoseArgs),
}

#[derive(clap::Args)]
pub struct RadiometryArgs {
    /// The rig file: read, then written with the gains (the file before is kept beside it
    /// as FILE.bak).
    #[arg(short, long, conflicts_with = "simulate")]
    pub rig: Option<PathBuf>,
    /// The shipped simulated rig, whose target is a grey sphere on the simulated bench: the
    /// gains are printed, not written.
    #[arg(long)]
    pub simulate: bool,
    /// A target file: `albedo` and a `[shape]` table placing the target where the object goes
    /// (config/targets/ has one for the bench rig); else the rig's own object, as a target.
    #[arg(long)]
    pub target: Option<PathBuf>,
    /// The target's albedo: one number, or red,green,blue; else the target file's, else 0.18
    /// (a grey card).
    #[arg(long, value_delimiter = ',')]
    pub albedo: Vec<f64>,
    /// Print the gains only; leave the rig file as it is.
    #[arg(long)]
    pub dry_run: bool,
    /// Where the target's photos go; else a new folder under the state directory's
    /// `calibrations/`.
    #[arg(short, long)]
    pub out: Option<PathBuf>,
    /// The state directory; else BRDFD_STATE_DIR, else the XDG data directory.
    #[arg(long)]
    pub state_dir: Option<PathBuf>,
}

pub fn run(cmd: CalibrateCommand) -> anyhow::Result<()> {
    let a = match cmd {
        CalibrateCommand::Radiometry(a) => a,
        CalibrateCommand::Target(a) => return super::pose_cmd::target(a),
        CalibrateCommand::Pose(a) => return super::pose_cmd::pose(a),
    };
    let (rig, path) = match (&a.rig, a.simulate) {
        (Some(p), _) => (Rig::read(p)?, Some(p.clone())),
        (None, true) => (Rig::simulated(), None),
        (None, false) => {
            bail!("give --rig FILE (the rig to calibrate), or --simulate for the simulated rig")
        }
    };
    let mut target = match &a.target {
        Some(p) => Target::read(p)?,
        None => {
            if !rig.simulated {
                eprintln!("  warning: no --target: the rig's own object is taken as the target; a flat grey card needs its target file (config/targets/ has an example)");
            }
            Target::default()
        }
    };
    match a.albedo[..] {
        [] => {}
        [one] => target.albedo.0 = [one; 3],
        [r, g, b] => target.albedo.0 = [r, g, b],
        _ => bail!("--albedo takes one number or three (red,green,blue)"),
    }
    target.check("--albedo")?;
    // Opened first: a file the gains cannot go into is said before anything is shot.
    let rig_file = match &path {
        Some(p) if !a.dry_run => Some(open_for_gains(p)?),
        _ => None,
    };
    let out = calibration_dir(a.out.as_deref(), a.state_dir.as_deref(), "radiometry")?;
    println!(
        "target: albedo {:?} ({}); its photos go to {}",
        target.albedo.0,
        if target.shape.is_some() {
            "the target file's shape"
        } else {
            "on the rig's object"
        },
        out.display()
    );
    let devices = Devices::start(&rig, KEEP_ALIVE)?;
    let bars: Arc<dyn Progress> = Arc::new(Bars::new());
    let cx = Context {
        rig: &rig,
        devices: &devices,
        progress: bars,
        cancel: Default::default(),
        operator: Arc::new(Terminal),
    };
    let mut folder = Folder(out.clone());
    let result = calibrate::radiometry(&cx, &mut folder, &target)?;
    print_result(&result);
    let note = format!(
        "by `brdfd calibrate radiometry` on {}, a target of albedo {:?}",
        humantime::format_rfc3339_seconds(std::time::SystemTime::now()),
        result.albedo
    );
    std::fs::write(
        out.join("calibration.json"),
        serde_json::to_string_pretty(&json(&result, &note))?,
    )?;
    if !result.skipped.is_empty() {
        bail!(
            "not every camera of the rig was measured ({}); the rig file is left as it is: make them answer and calibrate again",
            result.skipped.join("; ")
        );
    }
    match rig_file {
        Some(f) => {
            let saved = write_gains(f, &result, &note)?;
            println!(
                "wrote the gains into {} (the file before is {})",
                a.rig.as_deref().unwrap_or(Path::new("")).display(),
                saved.backup.display()
            );
            super::warn_not_ready(&saved);
        }
        None => println!("the rig file is left as it is"),
    }
    Ok(())
}

fn print_result(r: &Radiometry) {
    println!(
        "the THETA's gain {} sets the unit{}",
        triple(r.theta),
        if r.theta_given {
            " (kept from the rig)"
        } else {
            " (the rig had none)"
        }
    );
    for m in &r.cameras {
        println!(
            "{}: gain {} (R G B), spread {} over {} pixels; over the THETA's: {}",
            m.what,
            triple(m.gain),
            m.spread.map(|s| format!("{:.2}%", s * 100.0)).join(" "),
            m.pixels,
            triple(r.over_theta(m)),
        );
    }
    for s in &r.skipped {
        println!("not measured: {s}");
    }
}

fn triple(v: [f64; 3]) -> String {
    v.map(|x| format!("{}", significant(x, GAIN_DIGITS)))
        .join(" ")
}

/// Significant digits a gain is written with: its spread is a fraction of a percent at best.
const GAIN_DIGITS: i32 = 5;
/// And its spread, which says how far to trust the gain, not more.
const SPREAD_DIGITS: i32 = 2;

fn significant(x: f64, digits: i32) -> f64 {
    if x == 0.0 || !x.is_finite() {
        return x;
    }
    let digits = digits - 1 - x.abs().log10().floor() as i32;
    let scale = 10f64.powi(digits);
    (x * scale).round() / scale
}

fn json(r: &Radiometry, note: &str) -> serde_json::Value {
    serde_json::json!({
        "measured": note,
        "albedo": r.albedo,
        "theta_gain": r.theta,
        "theta_gain_kept": r.theta_given,
        "cameras": r.cameras.iter().map(|m| serde_json::json!({
            "field": m.field,
            "what": m.what,
            "gain": m.gain,
            "spread": m.spread,
            "pixels": m.pixels,
            "over_theta": r.over_theta(m),
        })).collect::<Vec<_>>(),
        "not_measured": r.skipped,
    })
}

/// The rig file, opened for its gains before anything is measured: a file the gains cannot be
/// written into is said before the cameras shoot.
fn open_for_gains(path: &Path) -> anyhow::Result<RigFile> {
    let mut file = RigFile::open(path)?;
    let doc = &mut file.doc;
    // `calibration = { ... }` on one line becomes a table of its own, which can hold the
    // cameras' tables.
    if let Some(inline) = doc.get("calibration").and_then(Item::as_inline_table) {
        let table = inline.clone().into_table();
        doc["calibration"] = Item::Table(table);
    }
    if !doc.get("calibration").is_none_or(Item::is_table) {
        bail!(
            "{}: `calibration` is not a table; make it one ([calibration]) to calibrate",
            path.display()
        );
    }
    Ok(file)
}

/// Writes the gains, keeping the file's comments and layout (a table that was there keeps its
/// place and its comments, only its values change); the file before is kept beside it.
fn write_gains(mut file: RigFile, r: &Radiometry, note: &str) -> anyhow::Result<Saved> {
    let calibration = file
        .doc
        .entry("calibration")
        .or_insert(Item::Table(Table::new()))
        .as_table_mut()
        .context("`calibration` is not a table")?;
    // The ratios of before the gains: what they measured is in the gains now.
    calibration.remove("theta_to_dslr");
    calibration.remove("theta_to_fallback");
    let measured: Vec<&str> = r.cameras.iter().map(|m| table_key(m.field)).collect();
    if !r.theta_given {
        // A new unit: a camera's gain measured against another is of no use now.
        for (field, _) in brdfd_rig::config::GAIN_FIELDS.iter().map(|f| (*f, ())) {
            let key = table_key(field);
            if key != "theta" && !measured.contains(&key) {
                calibration.remove(key);
            }
        }
        let t = table(calibration, "theta");
        t["gain"] = array(r.theta, GAIN_DIGITS);
        t["measured"] =
            value("the bench's unit of radiance: the other gains are measured against it");
    }
    for m in &r.cameras {
        let t = table(calibration, table_key(m.field));
        t["gain"] = array(m.gain, GAIN_DIGITS);
        t["spread"] = array(m.spread, SPREAD_DIGITS);
        t["measured"] = value(format!("{note}, over {} pixels", m.pixels));
    }
    Ok(file.save()?)
}

/// `dslr_raw` of `calibration.dslr_raw`.
fn table_key(field: &str) -> &str {
    field.trim_start_matches("calibration.")
}

/// The sub-table `key` of `calibration`, made if it is not there.
fn table<'a>(calibration: &'a mut Table, key: &str) -> &'a mut Table {
    if !calibration.get(key).is_some_and(Item::is_table) {
        calibration[key] = Item::Table(Table::new());
    }
    calibration[key].as_table_mut().expect("made a table above")
}

fn array(v: [f64; 3], digits: i32) -> Item {
    let mut a = Array::new();
    for x in v {
        a.push(significant(x, digits));
    }
    value(a)
}
