//! `brdfd capture`: capture a material and estimate it. Today this runs the simulated rig
//! in-process on the virtual bench; the device drivers and the daemon plug in behind the same
//! command.

use std::path::PathBuf;

use anyhow::bail;
use brdfd::bench::VirtualBench;
use brdfd::core::basis::Basis;
use brdfd::core::bivariate::Bivariate;
use brdfd::core::envmap::{EnvMap, DEFAULT_LIGHTS};
use brdfd::core::estimate::{estimate, EstimateOptions};
use brdfd::core::merl::MerlBrdf;
use brdfd::core::nbrdf::NbrdfSet;
use brdfd::core::render::render_bivariate;

use super::estimate_cmd::{parse_pixels, print_estimate};

#[derive(clap::Args)]
pub struct CaptureArgs {
    /// Material name (MERL name, or an alias: gold, chrome, plastic, paint, fabric, latex).
    #[arg(long)]
    pub material: String,
    /// Use the simulated rig (required until the hardware drivers land).
    #[arg(long)]
    pub simulate: bool,
    /// Environment map for the simulated rig; the embedded procedural studio if absent.
    #[arg(long)]
    pub env: Option<PathBuf>,
    /// NBRDF file for the simulated material; the embedded test materials if absent.
    #[arg(long)]
    pub nbrdf: Option<PathBuf>,
    /// Image size of the simulated camera.
    #[arg(long, default_value_t = 256)]
    pub size: usize,
    #[arg(long, default_value = "20")]
    pub pixels: String,
    /// Write the results (coefficients.json, BRDF files, preview) to this folder.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

pub fn run(a: CaptureArgs) -> anyhow::Result<()> {
    if !a.simulate {
        bail!("capturing from hardware needs the camera drivers, which this build does not have yet; run with --simulate");
    }
    let t = std::time::Instant::now();
    let mut bench = VirtualBench::embedded(&a.material, a.size).or_else(|e| {
        // Not an embedded material: the NBRDF file may have it.
        let Some(path) = &a.nbrdf else { return Err(e) };
        let set = NbrdfSet::read(path)?;
        let name = brdfd::bench::resolve_material(&a.material);
        let mut b = VirtualBench::embedded("gold", a.size)?;
        b.material = MerlBrdf::tabulate(set.get(name)?);
        b.material_name = name.to_string();
        Ok::<_, brdfd::core::CoreError>(b)
    })?;
    if let Some(p) = &a.env {
        bench.env = EnvMap::load(p)?;
    }
    println!(
        "simulated rig (in-process virtual bench): {} on a sphere, {}×{} camera",
        bench.material_name, a.size, a.size
    );
    let photo = bench.photo()?;
    let geometry = bench.pixels()?;
    let lights = bench.env.compressed(DEFAULT_LIGHTS, bench.yaw);
    let basis = Basis::embedded();
    let options = EstimateOptions {
        pixel_count: parse_pixels(&a.pixels)?,
        ..EstimateOptions::default()
    };
    let est = estimate(&basis, &geometry, &lights, &photo, &options)?;
    print_estimate(&est.names, &est.solution.coefficients);
    let truth = Bivariate::reduce(&bench.material, basis.header.grid);
    let projected = basis.project(&truth);
    println!("ground truth projected on the basis:");
    print_estimate(&est.names, &projected);
    let rerender = render_bivariate(&geometry, &lights, &est.brdf(&basis));
    println!(
        "{} pixels, condition number {:.2}; re-render relative RMSE {:.4}; {:.2} s",
        est.selection.pixels.len(),
        est.selection.condition,
        rerender.relative_rmse(&photo),
        t.elapsed().as_secs_f64()
    );
    if let Some(out) = &a.out {
        let files = brdfd::results::write_results(out, &basis, &est, "fast", &lights)?;
        photo.write_exr(&out.join("photo.exr"))?;
        println!("wrote {}", files.coefficients.display());
    }
    Ok(())
}
