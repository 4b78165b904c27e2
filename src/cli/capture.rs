//! `brdfd capture`: capture a material and estimate it. Today this runs the simulated rig
//! in-process, through the real protocols on loopback: the panorama bracket comes from the
//! simulated RICOH THETA V over the THETA Web API (HTTP), merged into a linear map from each
//! frame's EXIF; the DSLR bracket comes from the simulated Nikon D5100 through our PTP/IP
//! client (JPEG, EXIF, HDR merge, as with a real camera). The daemon and the hardware rig
//! plug in behind the same command.

use std::path::PathBuf;

use anyhow::bail;
use brdfd::bench::VirtualBench;
use brdfd::config::{Brackets, MaterialPreset, PixelCount, Rig};
use brdfd::core::basis::Basis;
use brdfd::core::bivariate::Bivariate;
use brdfd::core::envmap::{EnvMap, DEFAULT_LIGHTS};
use brdfd::core::estimate::{estimate_views, EstimateOptions, View};
use brdfd::core::merl::MerlBrdf;
use brdfd::core::nbrdf::NbrdfSet;
use brdfd::core::render::render_bivariate;

use super::estimate_cmd::{parse_pixels, print_estimate};
use brdfd::bench::camera::{BenchCamera, SENSOR_GAIN};
use brdfd::core::raster::Raster;
use brdfd::radiometry::{decode_jpeg, merge_hdr, Frame};
use brdfd_ptp::transport::ptpip::{Initiator, PtpIpTransport};
use brdfd_ptp::{Camera, CaptureOptions, Exposure, Timeouts};
use brdfd_sim::ptp::{ptpip::Server, Profile, Responder};
use brdfd_sim::theta::{OscServer, ThetaConfig};

use super::theta_cmd::{capture_panorama, loopback_timeouts};
use brdfd::bench::panorama::{BenchPanorama, THETA_SENSOR_GAIN};
use std::sync::Arc;
use std::time::Duration;

/// Camera files by name, exactly as the camera sent them.
type RawFiles = Vec<(String, Vec<u8>)>;

/// Shoots the bracket on the simulated D5100 through our PTP/IP client, decodes the JPEGs,
/// reads their EXIF and merges them into radiance. Returns the radiance and the camera files.
fn dslr_bracket(
    bench: &VirtualBench,
    shutters: &[f64],
    plan: &Brackets,
) -> anyhow::Result<(Raster, RawFiles)> {
    let source = Arc::new(BenchCamera::new(
        bench.clone(),
        "NIKON CORPORATION",
        "NIKON D5100",
    ));
    let server = Server::start(
        "127.0.0.1:0",
        Responder::new(Profile::NikonD5100, source).shared(),
    )?;
    let link = PtpIpTransport::connect(server.addr, Initiator::default(), Duration::from_secs(5))?;
    let mut cam = Camera::open(Box::new(link), Timeouts::default())?;
    let applied = cam.set_exposure(&Exposure {
        shutter_s: None,
        f_number: Some(plan.dslr_f_number),
        iso: Some(plan.dslr_iso),
    })?;
    println!(
        "DSLR: {} ({}), f/{} ISO {}",
        cam.describe(),
        cam.info.serial_number,
        applied.f_number.unwrap_or(0.0),
        applied.iso.unwrap_or(0)
    );
    let mut files = Vec::new();
    let mut frames: Vec<Frame> = Vec::new();
    let shots = cam.bracket(shutters, &CaptureOptions::default(), &mut |_, _, _| {})?;
    for (i, (speed, shot)) in shots.into_iter().enumerate() {
        let name = format!("dslr-{:02}-{}", i + 1, shot.info.filename);
        let frame = decode_jpeg(&shot.data, &name)?;
        println!(
            "  {name}: {} bytes, EXIF {:.4} s f/{} ISO {} (camera applied {speed} s)",
            shot.data.len(),
            frame.exposure.shutter_s,
            frame.exposure.f_number,
            frame.exposure.iso
        );
        frames.push(frame);
        files.push((name, shot.data));
    }
    cam.close()?;
    Ok((merge_hdr(&frames, SENSOR_GAIN)?, files))
}

/// The simulated turntable on a pseudo-terminal, driven through the real serial code.
fn sim_turntable() -> anyhow::Result<(brdfd_sim::serial::SerialPeer, brdfd_serial::RigController)> {
    let (peer, port) = brdfd_sim::serial::SerialPeer::start(Default::default())?;
    let rig = brdfd_serial::RigController::new(Box::new(port), Default::default())?;
    println!(
        "turntable: {} {} on serial:{}",
        rig.identity.name, rig.identity.version, peer.path
    );
    Ok((peer, rig))
}

/// Time the simulated THETA takes per frame. A real THETA V takes about a second; the
/// simulation keeps a delay so that the client's polling runs as it would, but a short one.
const SIM_THETA_SHOT_TIME: Duration = Duration::from_millis(20);

/// Shoots the light-probe bracket on the simulated THETA V over HTTP, merges it, and says how
/// far the measured map is from the bench's own (total power, per channel).
fn theta_bracket(bench: &VirtualBench) -> anyhow::Result<(EnvMap, RawFiles)> {
    let source = Arc::new(BenchPanorama::new(&bench.env, 1024, "RICOH THETA V"));
    let config = ThetaConfig {
        shot_time: SIM_THETA_SHOT_TIME,
        ..ThetaConfig::default()
    };
    let server = OscServer::start("127.0.0.1:0", source.clone(), config)?;
    let mut theta = brdfd_theta::Theta::connect_http(&server.url(), None, loopback_timeouts())?;
    println!("panorama: {}", theta.describe());
    let (map, frames) = capture_panorama(
        &mut theta,
        &brdfd_theta::BracketPlan::light_probe(),
        THETA_SENSOR_GAIN,
    )?;
    let (measured, truth) = (map.lights(0.0).power(), source.scene().lights(0.0).power());
    println!(
        "  {} frames merged to {}×{}; total light vs the bench's map: {:+.2}% {:+.2}% {:+.2}% (R G B)",
        frames.len(),
        map.width,
        map.height,
        (measured[0] / truth[0] - 1.0) * 100.0,
        (measured[1] / truth[1] - 1.0) * 100.0,
        (measured[2] / truth[2] - 1.0) * 100.0,
    );
    let files = frames
        .into_iter()
        .map(|f| (format!("theta-{}", f.name), f.data))
        .collect();
    Ok((map, files))
}

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
    /// Pixels to estimate from (a number or `all`); the material preset's, else 20.
    #[arg(long)]
    pub pixels: Option<String>,
    /// Shutter speeds of the DSLR's exposure bracket, in seconds; the material preset's,
    /// else the rig's (`config/rigs/simulated.toml`).
    #[arg(long, value_delimiter = ',')]
    pub bracket: Vec<f64>,
    /// Views on the simulated turntable: the object turned `--turn` degrees between them,
    /// under the same light, for more normals in one estimate.
    #[arg(long, default_value_t = 1)]
    pub views: usize,
    /// Turntable step between views, degrees.
    #[arg(long, default_value_t = 30.0, allow_hyphen_values = true)]
    pub turn: f64,
    /// Write the results (coefficients.json, BRDF files, preview) to this folder.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

pub fn run(a: CaptureArgs) -> anyhow::Result<()> {
    if !a.simulate {
        bail!("capturing from hardware needs the camera drivers, which this build does not have yet; run with --simulate");
    }
    let t = std::time::Instant::now();
    let rig = Rig::simulated();
    let preset = MaterialPreset::embedded(&a.material).map_err(anyhow::Error::msg)?;
    let basis = Basis::embedded();
    if let Some(p) = &preset {
        if p.k != basis.header.k {
            bail!(
                "the {} preset is tuned for K = {}, the basis has K = {}",
                a.material,
                p.k,
                basis.header.k
            );
        }
        println!(
            "material preset {}: simulated as {}, {} pixels{}",
            a.material,
            p.simulate_as,
            match p.pixels {
                PixelCount::All => "all".to_string(),
                PixelCount::Count(n) => n.to_string(),
            },
            if p.notes.is_empty() {
                String::new()
            } else {
                format!(" ({})", p.notes)
            }
        );
    }
    let simulate_as = preset
        .as_ref()
        .map_or(a.material.as_str(), |p| p.simulate_as.as_str());
    let mut bench = VirtualBench::embedded(simulate_as, a.size).or_else(|e| {
        // Not an embedded material: the NBRDF file may have it.
        let Some(path) = &a.nbrdf else { return Err(e) };
        let set = NbrdfSet::read(path)?;
        let name = brdfd::bench::resolve_material(simulate_as);
        let mut b = VirtualBench::embedded("gold", a.size)?;
        b.material = MerlBrdf::tabulate(set.get(name)?);
        b.material_name = name.to_string();
        Ok::<_, brdfd::core::CoreError>(b)
    })?;
    // The object and its camera come from the rig file, at the size asked for.
    bench.geometry = rig.geometry.clone();
    bench.geometry.camera = rig.geometry.camera.resized(a.size, a.size);
    bench.yaw = rig.theta_yaw_deg.to_radians();
    if let Some(p) = &a.env {
        bench.env = brdfd::panorama::load_envmap(p)?;
    }
    let shutters = if !a.bracket.is_empty() {
        a.bracket.clone()
    } else if let Some(s) = preset.as_ref().and_then(|p| p.dslr_shutters.clone()) {
        s
    } else {
        rig.brackets.dslr_shutters.clone()
    };
    let pixel_count = match (&a.pixels, &preset) {
        (Some(p), _) => parse_pixels(p)?,
        (None, Some(p)) => match p.pixels {
            PixelCount::All => None,
            PixelCount::Count(n) => Some(n),
        },
        (None, None) => Some(20),
    };
    println!(
        "simulated rig (in-process): {} on a sphere; DSLR: simulated Nikon D5100 over PTP/IP on loopback, {}×{}",
        bench.material_name, a.size, a.size
    );
    if a.views == 0 {
        bail!("--views must be at least 1");
    }
    let (env, mut frames) = theta_bracket(&bench)?;
    // One view per turntable position. The first is where the turntable stands; each next
    // one is `--turn` degrees on, at the position the turntable reports.
    let mut turntable = if a.views > 1 {
        Some(sim_turntable()?)
    } else {
        None
    };
    let mut shots = Vec::with_capacity(a.views);
    for i in 0..a.views {
        let theta_deg = match &mut turntable {
            Some((_, rig)) if i > 0 => rig.rotate(a.turn)?,
            Some((_, rig)) => rig.position()?,
            None => 0.0,
        };
        let theta = theta_deg.to_radians();
        // In the object's frame the camera and the light turn by −θ (Camera::turned_about_y).
        let mut view = bench.clone();
        view.geometry.camera = bench.geometry.camera.turned_about_y(-theta);
        view.yaw = bench.yaw - theta;
        if a.views > 1 {
            println!(
                "view {} of {}: turntable at {theta_deg:.2}°",
                i + 1,
                a.views
            );
        }
        let (photo, dslr_frames) = dslr_bracket(&view, &shutters, &rig.brackets)?;
        let prefix = if a.views > 1 {
            format!("view{}-", i + 1)
        } else {
            String::new()
        };
        frames.extend(
            dslr_frames
                .into_iter()
                .map(|(n, b)| (format!("{prefix}{n}"), b)),
        );
        let lights = env.compressed(DEFAULT_LIGHTS, view.yaw);
        shots.push((view.pixels()?, lights, photo));
    }
    let options = EstimateOptions {
        pixel_count,
        ridge: preset.as_ref().and_then(|p| p.ridge),
        ..EstimateOptions::default()
    };
    let views: Vec<View> = shots
        .iter()
        .map(|(geometry, lights, photo)| View {
            geometry,
            lights,
            photo,
        })
        .collect();
    let est = estimate_views(&basis, &views, &options)?;
    print_estimate(&est.names, &est.solution.coefficients);
    let (geometry, lights, photo) = &shots[0];
    let truth = Bivariate::reduce(&bench.material, basis.header.grid);
    let projected = basis.project(&truth);
    println!("ground truth projected on the basis:");
    print_estimate(&est.names, &projected);
    let rerender = render_bivariate(geometry, lights, &est.brdf(&basis));
    println!(
        "{} pixels, condition number {:.2}; re-render relative RMSE (first view) {:.4}; {:.2} s",
        est.selection.pixels.len(),
        est.selection.condition,
        rerender.relative_rmse(photo),
        t.elapsed().as_secs_f64()
    );
    if let Some(out) = &a.out {
        let files = brdfd::results::write_results(out, &basis, &est, "fast", lights)?;
        photo.write_exr(&out.join("photo.exr"))?;
        brdfd::core::envmap::write_exr(
            &out.join("panorama.exr"),
            env.width,
            env.height,
            &env.pixels,
        )?;
        let raw = out.join("raw");
        std::fs::create_dir_all(&raw)?;
        for (name, bytes) in &frames {
            std::fs::write(raw.join(name), bytes)?;
        }
        println!("wrote {}", files.coefficients.display());
    }
    Ok(())
}
