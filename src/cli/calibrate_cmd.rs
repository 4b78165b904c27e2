//! `brdfd calibrate radiometry`: measure each camera's gain from a grey card (or another
//! target of known albedo) where the object goes, and write the gains into the rig file with
//! their spread. The target's photos are kept in a folder of their own.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{bail, Context as _};
use brdfd::config::Rig;
use brdfd::rig::calibrate::{self, Radiometry, Target};
use brdfd::rig::flow::{Context, Keep};
use brdfd::rig::{Devices, Progress, KEEP_ALIVE};
use toml_edit::{value, Array, DocumentMut, Item, Table};

use super::progress::{Bars, Terminal};

#[derive(clap::Subcommand)]
pub enum CalibrateCommand {
    /// Measure each camera's gain from a target of known albedo (a grey card) put where the
    /// object goes, and write them into the rig file. The THETA's gain is the bench's unit and
    /// is kept; the DSLR's (RAW and JPEG) and the fallback camera's are measured against it.
    Radiometry(RadiometryArgs),
}

#[derive(clap::Args)]
pub struct RadiometryArgs {
    /// The rig file: read, then written with the gains (the file before is kept beside it
    /// as FILE.bak).
    #[arg(long, conflicts_with = "simulate")]
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
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// The state directory; else BRDFD_STATE_DIR, else the XDG data directory.
    #[arg(long)]
    pub state_dir: Option<PathBuf>,
}

pub fn run(cmd: CalibrateCommand) -> anyhow::Result<()> {
    let CalibrateCommand::Radiometry(a) = cmd;
    let (rig, path) = match (&a.rig, a.simulate) {
        (Some(p), _) => (Rig::read(p)?, Some(p.clone())),
        (None, true) => (Rig::simulated(), None),
        (None, false) => {
            bail!("give --rig FILE (the rig to calibrate), or --simulate for the simulated rig")
        }
    };
    let mut target = match &a.target {
        Some(p) => Target::read(p)?,
        None => Target::default(),
    };
    match a.albedo[..] {
        [] => {}
        [one] => target.albedo.0 = [one; 3],
        [r, g, b] => target.albedo.0 = [r, g, b],
        _ => bail!("--albedo takes one number or three (red,green,blue)"),
    }
    if !target
        .albedo
        .0
        .iter()
        .all(|v| v.is_finite() && *v > 0.0 && *v <= 1.0)
    {
        bail!(
            "--albedo {:?}: an albedo is above 0 and at most 1",
            target.albedo.0
        );
    }
    let out = match &a.out {
        Some(o) => o.clone(),
        None => {
            let state = brdfd::session::state_dir(a.state_dir.as_deref(), None)?;
            let stamp = humantime::format_rfc3339_seconds(std::time::SystemTime::now())
                .to_string()
                .replace(':', "");
            state
                .join("calibrations")
                .join(format!("{stamp}-radiometry"))
        }
    };
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
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
    match path {
        Some(p) if !a.dry_run => {
            write_gains(&p, &result, &note)?;
            println!(
                "wrote the gains into {} (the file before is {}.bak)",
                p.display(),
                p.display()
            );
        }
        _ => println!("the rig file is left as it is"),
    }
    Ok(())
}

/// The target's photos, each under its own name in the calibration's folder.
struct Folder(PathBuf);

impl Keep for Folder {
    fn keep(&mut self, name: &str, bytes: &[u8]) -> anyhow::Result<()> {
        super::write_new(&self.0, name, bytes)?;
        Ok(())
    }
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

/// Writes the gains into the rig file, keeping its comments and layout (the file before is
/// kept as FILE.bak), and checks that the capture can run the rig as written.
fn write_gains(path: &Path, r: &Radiometry, note: &str) -> anyhow::Result<()> {
    let text = std::fs::read_to_string(path)?;
    let mut doc: DocumentMut = text
        .parse()
        .with_context(|| format!("{} is not TOML", path.display()))?;
    let calibration = doc
        .entry("calibration")
        .or_insert(Item::Table(Table::new()))
        .as_table_mut()
        .with_context(|| format!("{}: `calibration` is not a table", path.display()))?;
    // The ratios of before the gains: what they measured is in the gains now.
    calibration.remove("theta_to_dslr");
    calibration.remove("theta_to_fallback");
    let array = |v: [f64; 3], digits: i32| {
        let mut a = Array::new();
        for x in v {
            a.push(significant(x, digits));
        }
        value(a)
    };
    if !r.theta_given {
        let mut t = Table::new();
        t["gain"] = array(r.theta, GAIN_DIGITS);
        t["measured"] =
            value("the bench's unit of radiance: the other gains are measured against it");
        calibration["theta"] = Item::Table(t);
    }
    for m in &r.cameras {
        let key = m.field.trim_start_matches("calibration.");
        let mut t = Table::new();
        t["gain"] = array(m.gain, GAIN_DIGITS);
        t["spread"] = array(m.spread, SPREAD_DIGITS);
        t["measured"] = value(format!("{note}, over {} pixels", m.pixels));
        calibration[key] = Item::Table(t);
    }
    let written = doc.to_string();
    let file = path.display().to_string();
    let rig = Rig::parse(&file, &written).context("the rig as written")?;
    std::fs::copy(path, PathBuf::from(format!("{file}.bak")))
        .with_context(|| format!("keeping {file}.bak"))?;
    brdfd::session::write_atomic(path, written.as_bytes())?;
    if let Err(e) = brdfd::rig::plan::check(&rig) {
        eprintln!("  warning: the rig is not ready to capture yet: {e}");
    }
    Ok(())
}
