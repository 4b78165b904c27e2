//! `brdfd estimate` and `brdfd render`.

use std::path::PathBuf;

use anyhow::{bail, Context};
use brdfd_core::analytic::{Microfacet, MAX_LOBES};
use brdfd_core::basis::Basis;
use brdfd_core::bivariate::Bivariate;
use brdfd_core::bounce;
use brdfd_core::brdf::{tangent_frame, IsotropicBrdf};
use brdfd_core::envmap::LightSet;
use brdfd_core::envmap::{CHOSEN_LIGHTS, DEFAULT_LIGHTS};
use brdfd_core::estimate::{
    BasisOptions, EstimateOptions, Model, ModelOptions, SelectionMethod, Shared, View,
    DEFAULT_LOBES, DEFAULT_MAX_CANDIDATES,
};
use brdfd_core::geometry::PixelGeometry;
use brdfd_core::hybrid::{HybridFit, MixWeight};
use brdfd_core::materials::{estimate_materials, triangles_of};
use brdfd_core::merl::MerlBrdf;
use brdfd_core::nbrdf::NbrdfSet;
use brdfd_core::raster::Raster;
use brdfd_core::render::{render_anisotropic, render_bivariate, render_merl};
use brdfd_core::select::SwapParams;
use brdfd_core::solve::{ColourChoice, Solver};
use brdfd_report::export::Prepared;
use brdfd_report::html::Context as ReportContext;
use brdfd_report::materials::{commoner, folder, painted, write_all};
use brdfd_report::visibility::Visibility;
use brdfd_rig::settings::unused_basis_settings;

use super::GeometryArgs;

#[derive(clap::Args)]
pub struct EstimateArgs {
    /// The object photo: linear EXR, or sRGB PNG/JPEG (decoded to linear).
    #[arg(long)]
    pub photo: PathBuf,
    /// The environment map: Radiance .hdr, OpenEXR, or a 360° camera's JPEG (GPano XMP and
    /// EXIF exposure read), equirectangular.
    #[arg(long)]
    pub env: PathBuf,
    /// Yaw of the panorama about +Y, degrees (right-handed).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true, value_parser = finite_degrees)]
    pub yaw: f64,
    #[command(flatten)]
    pub geometry: GeometryArgs,
    /// The BRDF model: hybrid (the default: Lambert + GGX lobes plus a non-negative mix of
    /// measured materials, fitted on pixels spread over the object; it relights most
    /// accurately, see docs/evaluation.md), analytic (Lambert + GGX lobes alone, fitted to every
    /// candidate pixel), or the data-driven PCA basis
    /// (the paper's; --pixels, --method, --solve and --colour are its settings).
    #[arg(long, value_enum, default_value = "hybrid")]
    pub model: ModelArg,
    /// Specular lobes of the hybrid and analytic models: 2 (a clear coat over a rougher base,
    /// or a metal's core and halo), or 1.
    #[arg(long, default_value_t = DEFAULT_LOBES as u64, value_parser = clap::value_parser!(u64).range(1..=MAX_LOBES as u64))]
    pub lobes: u64,
    /// Basis model: pixels to use, a number or `all` [default: 20].
    #[arg(long)]
    pub pixels: Option<brdfd_rig::PixelCount>,
    /// Basis model: how pixels are selected [default: fast].
    #[arg(long, value_enum)]
    pub method: Option<MethodArg>,
    /// Basis model: how the coefficients are solved, with the training set's prior, or by
    /// plain least squares as in the paper (docs/evaluation.md) [default: prior].
    #[arg(long, value_enum)]
    pub solve: Option<SolveArg>,
    /// Basis model: how colour is modelled, one set of coefficients for all channels (the
    /// paper's), one per channel, which leaves colour free, or both, keeping the better fit to
    /// the photo (docs/method.md) [default: auto].
    #[arg(long, value_enum)]
    pub colour: Option<ColourArg>,
    /// Basis model: solve without keeping the BRDF ≥ 0 in every cell. With --pixels 20
    /// --solve least-squares --colour joint, this is the paper's method exactly as published;
    /// its BRDF can go negative (coefficients.json's plausibility counts the cells).
    #[arg(long)]
    pub allow_negative: bool,
    /// Basis stem (STEM.exr + STEM.json); the embedded default if absent.
    #[arg(long)]
    pub basis: Option<PathBuf>,
    /// Lights the map is compressed to, for every candidate pixel's row.
    #[arg(long, default_value_t = DEFAULT_LIGHTS)]
    pub lights: usize,
    /// Lights for the chosen pixels' rows, which are rebuilt before the solve (a finer sky
    /// where it matters; docs/method.md). 0, or no more than --lights, keeps the
    /// candidates' rows.
    #[arg(long, default_value_t = CHOSEN_LIGHTS)]
    pub chosen_lights: usize,
    /// Object pixels considered as candidates at most (a random spread of them beyond it):
    /// the selection's conditioning stops improving long before a photo's millions.
    #[arg(long, default_value_t = DEFAULT_MAX_CANDIDATES)]
    pub max_candidates: usize,
    /// The photo's white level: pixels with a channel at or above it were clipped and are left
    /// out. Default: 1.0 for PNG and JPEG (the top code); for EXR, the level brdfd recorded
    /// when it merged the photo from a bracket, else none. `inf` turns it off.
    #[arg(long, value_parser = white_level)]
    pub white: Option<f32>,
    /// Seed of the paper's random restarts.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Output folder.
    #[arg(short, long, default_value = "estimate")]
    pub out: PathBuf,
    /// Also print the estimate's coefficients (they are in `coefficients.json`).
    #[arg(long, short)]
    pub verbose: bool,
    /// Fit the photo as if every pixel saw only the room: leave in the light a concave mesh
    /// throws on itself, which is otherwise taken out before the fit (up to two bounces).
    #[arg(long)]
    pub no_bounce: bool,
    /// Fit one BRDF to the whole part, even where its colour departs from place to place:
    /// otherwise such a part is split into two materials, each estimated on its own pixels
    /// and written in its own folder (material-1/, material-2/).
    #[arg(long)]
    pub one_material: bool,
}

#[derive(clap::ValueEnum, Clone, Copy)]
pub enum ModelArg {
    Basis,
    Analytic,
    Hybrid,
}

impl From<ModelArg> for Model {
    fn from(a: ModelArg) -> Model {
        match a {
            ModelArg::Basis => Model::Basis,
            ModelArg::Analytic => Model::Analytic,
            ModelArg::Hybrid => Model::Hybrid,
        }
    }
}

#[derive(clap::ValueEnum, Clone, Copy)]
pub enum SolveArg {
    Prior,
    LeastSquares,
}

impl From<SolveArg> for Solver {
    fn from(a: SolveArg) -> Solver {
        match a {
            SolveArg::Prior => Solver::Prior,
            SolveArg::LeastSquares => Solver::LeastSquares,
        }
    }
}

#[derive(clap::ValueEnum, Clone, Copy)]
pub enum ColourArg {
    Joint,
    PerChannel,
    Auto,
}

impl From<ColourArg> for ColourChoice {
    fn from(a: ColourArg) -> ColourChoice {
        match a {
            ColourArg::Joint => ColourChoice::Joint,
            ColourArg::PerChannel => ColourChoice::PerChannel,
            ColourArg::Auto => ColourChoice::Auto,
        }
    }
}

#[derive(clap::ValueEnum, Clone, Copy)]
pub enum MethodArg {
    Fast,
    Paper,
}

/// An angle in degrees: any finite number (`inf` and `NaN` would turn every light into NaN).
fn finite_degrees(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        Ok(v) => Err(format!("{v} is not an angle; give a number of degrees")),
        Err(e) => Err(e.to_string()),
    }
}

/// A white level: a positive number, or `inf` for none (`NaN` would clip nothing, silently).
fn white_level(s: &str) -> Result<f32, String> {
    match s.parse::<f32>() {
        Ok(v) if v > 0.0 => Ok(v),
        Ok(v) => Err(format!(
            "{v} is not a white level; give a positive number, or inf for none"
        )),
        Err(e) => Err(e.to_string()),
    }
}

pub fn load_basis(path: &Option<PathBuf>) -> anyhow::Result<Basis> {
    Ok(match path {
        Some(p) => Basis::read(p).with_context(|| format!("reading basis {}", p.display()))?,
        None => Basis::embedded(),
    })
}

pub fn estimate(a: EstimateArgs) -> anyhow::Result<()> {
    let total = std::time::Instant::now();
    let basis = load_basis(&a.basis)?;
    let yaw = a.yaw.to_radians();
    // The photo, and the map with its lights, side by side: each read has a serial part
    // (a 16-megapixel photo's decoding leaves most of a core idle). The photo's error first.
    let (photo, env) = rayon::join(
        || Raster::read_with_white(&a.photo).with_context(|| "reading the photo"),
        || {
            let env = brdfd_radiometry::panorama::load_envmap(&a.env)
                .with_context(|| "reading the environment map")?;
            let lights = env.estimate_lights(a.lights, a.chosen_lights, yaw);
            anyhow::Ok((env, lights))
        },
    );
    let (photo, file_white) = photo?;
    let (env, (lights, chosen_lights)) = env?;
    let scene = a.geometry.scene()?;
    let geometry = scene.pixels(photo.width, photo.height)?;
    // On a mesh, `object.gltf` shows the export on the object.
    let object = match &scene.shape {
        Some(shape) => shape.mesh()?,
        None => None,
    };
    let model: Model = a.model.into();
    if let Some(warning) = unused_basis_settings(
        model,
        &[
            ("--pixels", a.pixels.is_some()),
            ("--method", a.method.is_some()),
            ("--solve", a.solve.is_some()),
            ("--colour", a.colour.is_some()),
            ("--allow-negative", a.allow_negative),
        ],
    ) {
        eprintln!("warning: {warning}");
    }
    let method_arg = a.method.unwrap_or(MethodArg::Fast);
    let method = match method_arg {
        MethodArg::Fast => SelectionMethod::Fast,
        MethodArg::Paper => SelectionMethod::Paper,
    };
    let lobes = a.lobes as usize;
    let options = EstimateOptions {
        model: match model {
            Model::Basis => ModelOptions::Basis(BasisOptions {
                pixel_count: a
                    .pixels
                    .map_or(Some(brdfd_rig::settings::DEFAULT_PIXELS), |p| p.limit()),
                method,
                swap: SwapParams {
                    seed: a.seed,
                    ..SwapParams::default()
                },
                solver: a.solve.unwrap_or(SolveArg::Prior).into(),
                colour: a.colour.unwrap_or(ColourArg::Auto).into(),
                nonnegative: !a.allow_negative,
            }),
            Model::Analytic => ModelOptions::Analytic { lobes },
            Model::Hybrid => ModelOptions::Hybrid { lobes },
        },
        max_candidates: a.max_candidates,
        white: a.white.or(file_white),
        checks: true,
        bounce: !a.no_bounce,
        materials: !a.one_material,
        // Ctrl-C ends the process: nothing is written before the estimate is done.
        stop: Default::default(),
    };
    let view = View {
        geometry: &geometry,
        lights: &lights,
        chosen_lights: chosen_lights.as_ref(),
        photo: &photo,
    };
    // The exports' maps and coarse renders need only the map: made on a thread of their own
    // while the estimate runs, in the share of the cores its serial steps leave idle, as a
    // capture makes them while its camera shoots. If they fail (or panic, which the panic's
    // own message reports), the results make them, as a capture's do.
    let grid = basis.header.grid;
    let (found, exports) = std::thread::scope(|s| {
        let exports = s.spawn(|| Prepared::new(Some((env.clone(), yaw)), grid));
        let found = estimate_materials(&basis, &[view], &options, &Shared::default());
        let exports = exports.join().unwrap_or_else(|_| {
            Err(brdfd_core::CoreError::Invalid(
                "the thread preparing them panicked".into(),
            ))
        });
        (found, exports)
    });
    let found = found?;
    let exports = exports
        .inspect_err(|e| {
            tracing::warn!("preparing the exports' renders: {e}; made with the results")
        })
        .ok();
    let method_name = match method_arg {
        MethodArg::Fast => "fast",
        MethodArg::Paper => "paper",
    };
    let visibility = Visibility::of(&geometry, &lights);
    let cx = ReportContext {
        visibility: visibility.as_ref(),
        object: object.as_ref(),
        title: format!("{} under {}", a.photo.display(), a.env.display()),
        photo: Some(&photo),
        env: Some(&env),
        yaw,
        exports: exports.as_ref(),
        record: vec![
            ("photo".into(), a.photo.display().to_string()),
            ("environment map".into(), a.env.display().to_string()),
            (
                "software".into(),
                format!("brdfd {}", env!("CARGO_PKG_VERSION")),
            ),
        ],
        ..ReportContext::default()
    };
    let (files, parts) = write_all(&a.out, &basis, &found, method_name, &lights, cx)?;
    let est = &found.whole;
    if a.verbose {
        print_estimate(&est.names, &est.solution.coefficients);
    }
    println!(
        "{}, relative residual {:.4} on the pixels solved from, {:.2} s",
        est.method_text(),
        est.solution.relative_residual,
        total.elapsed().as_secs_f64()
    );
    // Whole, as a capture prints it: a terminal opens it from anywhere.
    let report = std::path::absolute(&files.report).unwrap_or_else(|_| files.report.clone());
    let extras = brdfd_report::summary::Extras {
        headline: &files.headline,
        relight: None,
        views: 1,
        bracketed: false,
        export: Some(&files.exports),
        flags: &files.flags,
        report: Some(&report),
        materials: parts
            .as_ref()
            .zip(found.split.as_ref().map(|s| s.parts.as_slice())),
    };
    let lines = brdfd_report::summary::lines("the estimate", est, &extras);
    if lines[0].contains("do not trust") {
        eprintln!("warning: {}", lines[0]);
        println!("{}", lines[1..].join("\n"));
    } else {
        println!("{}", lines.join("\n"));
    }
    // Relative to the folder: each material's files are in its own.
    let names: Vec<String> = files
        .written
        .iter()
        .map(|p| p.strip_prefix(&a.out).unwrap_or(p).display().to_string())
        .collect();
    println!(
        "wrote {} files in {}: {}",
        names.len(),
        a.out.display(),
        names.join(", ")
    );
    Ok(())
}

pub fn print_estimate(names: &[String], coefficients: &[f64]) {
    println!(
        "{}",
        brdfd_report::results::coefficient_lines("coefficients", names, coefficients)
    );
}

#[derive(clap::Args)]
pub struct RenderArgs {
    /// An NBRDF material name (from --nbrdf, or the embedded test materials).
    #[arg(short, long, conflicts_with_all = ["merl", "coefficients", "gltf"])]
    pub material: Option<String>,
    /// A glTF file's first material (an export's `material.gltf`), as glTF's own BRDF:
    /// what a renderer that reads the export shows.
    #[arg(long, conflicts_with_all = ["merl", "coefficients"])]
    pub gltf: Option<PathBuf>,
    /// The NBRDF file (merl_nbrdf.json) --material is taken from; the embedded test
    /// materials if absent.
    #[arg(long, requires = "material")]
    pub nbrdf: Option<PathBuf>,
    /// A MERL .binary file.
    #[arg(long)]
    pub merl: Option<PathBuf>,
    /// A coefficients.json from `brdfd estimate` (rendered on --basis or the embedded basis);
    /// of a part split into two materials, each painted on its own triangles of the mesh.
    #[arg(long)]
    pub coefficients: Option<PathBuf>,
    /// The basis --coefficients were estimated on (STEM.exr + STEM.json); the embedded
    /// default if absent.
    #[arg(long, requires = "coefficients")]
    pub basis: Option<PathBuf>,
    /// The environment map; the procedural studio if absent.
    #[arg(long)]
    pub env: Option<PathBuf>,
    /// Yaw of the map about +Y, degrees (right-handed).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true, value_parser = finite_degrees)]
    pub yaw: f64,
    #[command(flatten)]
    pub geometry: GeometryArgs,
    /// Image size for built-in shapes and normal maps, 8 to 8192 pixels [default: 256]. A
    /// geometry file's camera has its own, and the two are not given together.
    #[arg(long, value_parser = super::image_size, conflicts_with = "geometry")]
    pub size: Option<usize>,
    /// Lights the map is compressed to for the render.
    #[arg(long, default_value_t = 16384)]
    pub lights: usize,
    /// Output image: .exr (linear) or .png (tone-mapped sRGB).
    #[arg(short, long)]
    pub out: PathBuf,
    /// Leave out the light a concave mesh throws on itself (up to two bounces, added by default):
    /// direct light only.
    #[arg(long)]
    pub no_bounce: bool,
}

pub fn render(a: RenderArgs) -> anyhow::Result<()> {
    let env = match &a.env {
        Some(p) => brdfd_radiometry::panorama::load_envmap(p)?,
        None => brdfd_bench::studio_envmap(512),
    };
    let lights = env.compressed(a.lights, a.yaw.to_radians());
    let scene = a.geometry.scene_or_sphere()?;
    // A geometry file's camera describes a photo: the render is the camera's size, so that
    // it lines up with a photo of that size pixel for pixel. --size is the built-in shapes'
    // (and a normal map's, which must match it).
    let (width, height) = match (&a.geometry.geometry, a.size) {
        (Some(_), _) => scene.camera.size(),
        (None, size) => (size.unwrap_or(256), size.unwrap_or(256)),
    };
    let geometry = scene.pixels(width, height)?;
    // Each branch's render, with the light a concave mesh throws on itself added through the
    // same BRDF (unless --no-bounce).
    let bounce = !a.no_bounce;
    let isotropic = |mut img: Raster, brdf: &dyn IsotropicBrdf| {
        if bounce {
            bounce::add_to(&mut img, &geometry, &lights, tangent_frame, |wi, wo| {
                brdf.eval_dirs(wi, wo)
            });
        }
        img
    };
    let img = if let Some(name) = &a.material {
        let set = match &a.nbrdf {
            Some(p) => NbrdfSet::read(p)?,
            None => brdfd_bench::embedded_materials(),
        };
        let table = MerlBrdf::tabulate(set.get(brdfd_bench::resolve_material(name))?);
        isotropic(render_merl(&geometry, &lights, &table), &table)
    } else if let Some(p) = &a.merl {
        let table = MerlBrdf::read(p)?;
        isotropic(render_merl(&geometry, &lights, &table), &table)
    } else if let Some(p) = &a.gltf {
        brdfd_report::export::GltfMaterial::read(p)?.render_bounced(&geometry, &lights, bounce)
    } else if let Some(p) = &a.coefficients {
        render_result(p, &a.basis, &geometry, &lights, bounce)?
    } else {
        bail!("say what to render: --material, --merl, --coefficients or --gltf");
    };
    finish_render(&a.out, img)
}

/// The render of a `coefficients.json`: of each material on its own triangles when the
/// estimate split the part into materials and the geometry is of its mesh; of the one BRDF
/// otherwise.
fn render_result(
    p: &std::path::Path,
    basis: &Option<PathBuf>,
    geometry: &PixelGeometry,
    lights: &LightSet,
    bounce: bool,
) -> anyhow::Result<Raster> {
    let r = brdfd_report::results::StoredResult::read(p)?;
    let painted = r.materials.as_ref().and_then(|m| {
        let (count, triangles) = triangles_of(geometry)?;
        let labels = m.triangles.as_ref().filter(|t| t.len() == count)?;
        Some((m, painted(labels, m.parts.len()), triangles))
    });
    let Some((m, labels, triangles)) = painted else {
        if let Some(m) = &r.materials {
            let why = if m.triangles.is_some() {
                "they are painted on its mesh's triangles, and this geometry is not that mesh"
            } else {
                "the split was made off a mesh, with no triangles to paint them on"
            };
            eprintln!(
                "note: {} holds {} materials, but {why}: the one BRDF fitted to the whole part is rendered",
                p.display(),
                m.parts.len()
            );
        }
        return render_one(p, r, &mut LazyBasis::new(basis), geometry, lights, bounce);
    };
    let mut img = Raster::black(geometry.width, geometry.height);
    let dir = p.parent().unwrap_or(std::path::Path::new("."));
    // Read once for both materials, and only if one needs it.
    let mut basis = LazyBasis::new(basis);
    // A pixel whose triangle is not found (rarely, at an edge) takes the commoner material.
    let commoner = commoner(&labels, m.parts.len());
    for (k, part) in m.parts.iter().enumerate() {
        // The folder is brdfd's own name for the material, never a path the file chooses.
        if part.folder != folder(k) {
            bail!(
                "{}: field `materials.parts[{k}].folder` is {:?}, not {:?}",
                p.display(),
                part.folder,
                folder(k)
            );
        }
        let mine = PixelGeometry {
            width: geometry.width,
            height: geometry.height,
            pixels: geometry
                .pixels
                .iter()
                .zip(&triangles)
                .filter(|(_, t)| t.map_or(commoner, |t| labels[t as usize]) as usize == k)
                .map(|(px, _)| px.clone())
                .collect(),
        };
        if mine.pixels.is_empty() {
            continue;
        }
        let path = dir.join(&part.folder).join("coefficients.json");
        let stored = brdfd_report::results::StoredResult::read(&path)
            .with_context(|| format!("material {} of {}", k + 1, p.display()))?;
        let own = render_one(&path, stored, &mut basis, &mine, lights, bounce)?;
        for px in &mine.pixels {
            let (x, y) = (px.x as usize, px.y as usize);
            img.set(x, y, own.get(x, y));
        }
    }
    Ok(img)
}

/// The basis `--basis` names (the embedded one if none), read when first asked for.
struct LazyBasis<'a> {
    path: &'a Option<PathBuf>,
    read: Option<Basis>,
}

impl<'a> LazyBasis<'a> {
    fn new(path: &'a Option<PathBuf>) -> LazyBasis<'a> {
        LazyBasis { path, read: None }
    }

    fn get(&mut self) -> anyhow::Result<&Basis> {
        if self.read.is_none() {
            self.read = Some(load_basis(self.path)?);
        }
        Ok(self.read.as_ref().expect("just read"))
    }
}

/// The render of one estimate's `coefficients.json` (read as `r`) on `geometry`.
fn render_one(
    p: &std::path::Path,
    r: brdfd_report::results::StoredResult,
    basis: &mut LazyBasis,
    geometry: &PixelGeometry,
    lights: &LightSet,
    bounce: bool,
) -> anyhow::Result<Raster> {
    let isotropic = |mut img: Raster, brdf: &dyn IsotropicBrdf| {
        if bounce {
            bounce::add_to(&mut img, geometry, lights, tangent_frame, |wi, wo| {
                brdf.eval_dirs(wi, wo)
            });
        }
        img
    };
    // An estimate that chose an anisotropic lobe relights with it, not with its
    // (isotropic) model, and needs no basis.
    if let Some(lobe) = r
        .chosen_lobe()
        .map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?
    {
        let mut img = render_anisotropic(geometry, lights, &lobe);
        if bounce {
            let frame = |n| lobe.frame(n);
            bounce::add_to(&mut img, geometry, lights, frame, |wi, wo| {
                lobe.eval_local(wi, wo)
            });
        }
        return Ok(img);
    }
    let basis = basis.get()?;
    if r.model == "analytic" || r.model == "hybrid" {
        let m: Microfacet = r
            .analytic_model()
            .with_context(|| format!("{}: field `analytic`", p.display()))?
            .with_context(|| {
                format!(
                    "{}: a {} estimate without its field `analytic`",
                    p.display(),
                    r.model
                )
            })?;
        m.check()
            .map_err(|e| anyhow::anyhow!("{}: field `analytic`: {e}", p.display()))?;
        let mixture: Vec<MixWeight> = r
            .mixture_weights()
            .with_context(|| format!("{}: field `mixture`", p.display()))?;
        if !mixture.is_empty() && r.basis_id != basis.header.id {
            bail!(
                "{} mixes the measured materials of basis {:?}, not {}; pass that basis with --basis",
                p.display(),
                r.basis_id,
                basis.header.id
            );
        }
        let b = HybridFit::rebuild(&m, &mixture, basis)
            .map_err(|e| anyhow::anyhow!("{}: field `mixture`: {e}", p.display()))?;
        return Ok(isotropic(render_bivariate(geometry, lights, &b), &b));
    }
    let coeffs: Vec<f64> = r
        .coefficients
        .iter()
        .enumerate()
        .map(|(i, c)| {
            c.with_context(|| {
                let n = i + 1;
                format!(
                    "{}: field `coefficients`: coefficient {n} is not a number",
                    p.display()
                )
            })
        })
        .collect::<anyhow::Result<_>>()?;
    if r.basis_id != basis.header.id {
        bail!(
            "{} was estimated on basis {:?}, not {}; pass that basis with --basis",
            p.display(),
            r.basis_id,
            basis.header.id
        );
    }
    let b: Bivariate = basis
        .reconstruct_solution(&coeffs)
        .with_context(|| format!("{}: field `coefficients`", p.display()))?;
    Ok(isotropic(render_bivariate(geometry, lights, &b), &b))
}

fn finish_render(out: &std::path::Path, img: Raster) -> anyhow::Result<()> {
    match out.extension().and_then(|e| e.to_str()) {
        Some("exr") => img.write_exr(out)?,
        _ => img.write_png(out, img.auto_exposure())?,
    }
    println!("wrote {}", out.display());
    Ok(())
}
