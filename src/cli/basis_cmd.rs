//! `brdfd basis build`, `brdfd basis show` and `brdfd basis export`.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use brdfd_core::basis::{Basis, CellWeight, Normalisation, DEFAULT_K};
use brdfd_core::bivariate::{Bivariate, Grid, PhiReduction, ThetaHBinning};
use brdfd_core::merl::MerlBrdf;
use brdfd_core::nbrdf::NbrdfSet;
use brdfd_eval::paper::TEST_SET;

#[derive(clap::Subcommand)]
pub enum BasisCommand {
    /// Build a basis from MERL .binary files or an NBRDF file.
    Build(BuildArgs),
    /// Print a basis header (the embedded default if no path is given).
    Show {
        /// The basis (a `.exr` with its `.json` beside it).
        path: Option<PathBuf>,
    },
    /// Write a basis (the embedded default unless --basis names one) as `STEM.exr` and
    /// `STEM.json`, so that an estimate's coefficients can be turned back into a BRDF outside
    /// brdfd (docs/formats.md describes both files).
    Export {
        /// The basis to export (a `.exr` with its `.json` beside it).
        #[arg(long)]
        basis: Option<PathBuf>,
        /// Where to write: `STEM.exr` and `STEM.json` (an extension is replaced).
        #[arg(long)]
        out: PathBuf,
    },
}

#[derive(clap::Args)]
pub struct BuildArgs {
    /// NBRDF file (merl_nbrdf.json).
    #[arg(
        long,
        conflicts_with = "merl_dir",
        required_unless_present = "merl_dir"
    )]
    pub nbrdf: Option<PathBuf>,
    /// Folder of MERL .binary files (material name = file stem).
    #[arg(long)]
    pub merl_dir: Option<PathBuf>,
    /// Materials: `training` (all but the 10 test materials), `all`, or a comma-separated list.
    #[arg(long, default_value = "training")]
    pub materials: String,
    /// Principal components to keep.
    #[arg(short, long, default_value_t = DEFAULT_K)]
    pub k: usize,
    /// `rms` divides each material by its RMS so that every one weighs the same (the paper's
    /// choice); `none` lets specular materials dominate the components.
    #[arg(long, value_enum, default_value = "rms")]
    pub normalisation: NormArg,
    /// Per-cell weight before the PCA: `solid-angle` weighs cells as they weigh in images;
    /// `none` lets the specular peak and grazing cells dominate.
    #[arg(long, value_enum, default_value = "solid-angle")]
    pub cell_weight: WeightArg,
    /// Build without a mean term.
    #[arg(long)]
    pub no_mean: bool,
    /// θh bins: `sqrt` (MERL's, uniform in √θh: fine near the specular peak) or `uniform`
    /// (1° each).
    #[arg(long, value_enum, default_value = "sqrt")]
    pub theta_h: BinArg,
    /// How φd is reduced: `valid-mean` (the mean over the measured cells) or `slice90` (the
    /// φd = 90° slice).
    #[arg(long, value_enum, default_value = "valid-mean")]
    pub phi: PhiArg,
    /// Output stem: writes STEM.exr and STEM.json.
    #[arg(short, long)]
    pub out: PathBuf,
}

#[derive(clap::ValueEnum, Clone, Copy)]
pub enum NormArg {
    None,
    Rms,
}

#[derive(clap::ValueEnum, Clone, Copy)]
pub enum WeightArg {
    None,
    SolidAngle,
}

#[derive(clap::ValueEnum, Clone, Copy)]
pub enum BinArg {
    Sqrt,
    Uniform,
}

#[derive(clap::ValueEnum, Clone, Copy)]
pub enum PhiArg {
    ValidMean,
    Slice90,
}

pub fn run(cmd: BasisCommand) -> anyhow::Result<()> {
    match cmd {
        BasisCommand::Show { path } => {
            let b = match path {
                Some(p) => Basis::read(&p)?,
                None => Basis::embedded(),
            };
            println!("{}", serde_json::to_string_pretty(&b.header)?);
            Ok(())
        }
        BasisCommand::Build(a) => build(a),
        BasisCommand::Export { basis, out } => {
            let b = match basis {
                Some(p) => Basis::read(&p)?,
                None => Basis::embedded(),
            };
            for f in [out.with_extension("exr"), out.with_extension("json")] {
                if f.exists() {
                    bail!("{} exists; brdfd does not overwrite it", f.display());
                }
            }
            let (exr, json) = b.write(&out)?;
            println!(
                "basis {} (K = {}, {} measured materials) written to {} and {}",
                b.header.id,
                b.header.k,
                b.atoms.len(),
                exr.display(),
                json.display()
            );
            Ok(())
        }
    }
}

fn choose(all: Vec<String>, spec: &str) -> anyhow::Result<Vec<String>> {
    Ok(match spec {
        "all" => all,
        "training" => all
            .into_iter()
            .filter(|m| !TEST_SET.contains(&m.as_str()))
            .collect(),
        list => {
            let wanted: Vec<String> = list
                .split(',')
                .map(|s| s.trim().to_string())
                .filter(|s| !s.is_empty())
                .collect();
            for w in &wanted {
                if !all.contains(w) {
                    bail!(
                        "material {w:?} is not in the source; it has: {}",
                        all.join(", ")
                    );
                }
            }
            wanted
        }
    })
}

fn merl_names(dir: &Path) -> anyhow::Result<Vec<(String, PathBuf)>> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir(dir).with_context(|| format!("listing {}", dir.display()))? {
        let path = entry?.path();
        if path.extension().and_then(|e| e.to_str()) == Some("binary") {
            let name = path
                .file_stem()
                .and_then(|s| s.to_str())
                .unwrap_or_default()
                .to_string();
            out.push((name, path));
        }
    }
    out.sort();
    if out.is_empty() {
        bail!("{} holds no .binary files", dir.display());
    }
    Ok(out)
}

fn build(a: BuildArgs) -> anyhow::Result<()> {
    let t = std::time::Instant::now();
    let grid = Grid {
        theta_h_binning: match a.theta_h {
            BinArg::Sqrt => ThetaHBinning::Sqrt,
            BinArg::Uniform => ThetaHBinning::Uniform,
        },
        phi_reduction: match a.phi {
            PhiArg::ValidMean => PhiReduction::ValidMean,
            PhiArg::Slice90 => PhiReduction::Slice90,
        },
    };
    let training: Vec<(String, Bivariate)> = if let Some(path) = &a.nbrdf {
        let set = NbrdfSet::read(path)?;
        let names = choose(set.materials.keys().cloned().collect(), &a.materials)?;
        names
            .into_iter()
            .map(|n| {
                let b = Bivariate::reduce(&set.materials[&n], grid);
                (n, b)
            })
            .collect()
    } else {
        let dir = a.merl_dir.as_ref().expect("clap requires one source");
        let files = merl_names(dir)?;
        let names = choose(files.iter().map(|(n, _)| n.clone()).collect(), &a.materials)?;
        let mut out = Vec::new();
        for (n, p) in files.into_iter().filter(|(n, _)| names.contains(n)) {
            let m = MerlBrdf::read(&p)?;
            out.push((n, Bivariate::reduce(&m, grid)));
        }
        out
    };
    let normalisation = match a.normalisation {
        NormArg::None => Normalisation::None,
        NormArg::Rms => Normalisation::Rms,
    };
    let weight = match a.cell_weight {
        WeightArg::None => CellWeight::None,
        WeightArg::SolidAngle => CellWeight::SolidAngle,
    };
    let basis = Basis::build(&training, a.k, normalisation, weight, !a.no_mean)?;
    let (exr, json) = basis.write(&a.out)?;
    println!(
        "basis {} from {} materials, K = {}, built in {:.1} s",
        basis.header.id,
        training.len(),
        a.k,
        t.elapsed().as_secs_f64()
    );
    println!("explained variance (cumulative):");
    for (k, v) in basis.header.explained_variance.iter().enumerate() {
        println!("  K = {:2}: {:.4}", k + 1, v);
    }
    println!("wrote {} and {}", exr.display(), json.display());
    Ok(())
}
