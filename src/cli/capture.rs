//! `brdfd capture`: capture a material and estimate it, as one session on disk. Today this
//! runs the simulated rig in-process, through the real protocols on loopback: the panorama
//! bracket comes from the simulated RICOH THETA V over the THETA Web API (HTTP), the DSLR
//! brackets from the simulated Nikon D5100 through our PTP/IP client, the turntable from a
//! simulated peer on a pseudo-terminal. The daemon and the hardware rig plug in behind the
//! same flow.
//!
//! The flow is a list of steps (the panorama, then each turntable view); each step's files
//! are stored in the session as they arrive, and a step is skipped when the session already
//! has it complete. That is what `brdfd session resume` relies on.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use anyhow::{bail, Context};
use brdfd::bench::camera::{BenchCamera, SENSOR_GAIN};
use brdfd::bench::panorama::{BenchPanorama, THETA_SENSOR_GAIN};
use brdfd::bench::VirtualBench;
use brdfd::config::{Brackets, MaterialPreset, PixelCount, Rig};
use brdfd::core::basis::Basis;
use brdfd::core::bivariate::Bivariate;
use brdfd::core::envmap::{write_exr, EnvMap, DEFAULT_LIGHTS};
use brdfd::core::estimate::{estimate_views, EstimateOptions, View};
use brdfd::core::merl::MerlBrdf;
use brdfd::core::nbrdf::NbrdfSet;
use brdfd::core::raster::Raster;
use brdfd::core::render::render_bivariate;
use brdfd::panorama::merge_bracket;
use brdfd::radiometry::{decode_jpeg, merge_hdr};
use brdfd::session::{PhaseTime, Session, State};
use brdfd_ptp::transport::ptpip::{Initiator, PtpIpTransport};
use brdfd_ptp::{Camera, CaptureOptions, Exposure, Timeouts};
use brdfd_sim::ptp::{ptpip::Server, Profile, Responder};
use brdfd_sim::theta::{OscServer, ThetaConfig};
use brdfd_sim::Timed;
use serde::{Deserialize, Serialize};
use serde_json::json;

use super::estimate_cmd::{parse_pixels, print_estimate};
use super::theta_cmd::{loopback_timeouts, shoot_panorama};

/// Camera files by name, exactly as the camera sent them.
type RawFiles = Vec<(String, Vec<u8>)>;

/// Time the simulated THETA takes per frame. A real THETA V takes about a second; the
/// simulation keeps a delay so that the client's polling runs as it would, but a short one.
const SIM_THETA_SHOT_TIME: Duration = Duration::from_millis(20);

#[derive(clap::Args)]
pub struct CaptureArgs {
    /// Material name (a preset in config/materials, a MERL name, or an alias: gold, chrome,
    /// plastic, paint, fabric, latex).
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
    /// Where sessions are stored; else BRDFD_STATE_DIR, else the XDG data directory.
    #[arg(long)]
    pub state_dir: Option<PathBuf>,
    /// Also write the results and the raw files to this folder.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// What a capture was asked to do, stored in the manifest so that a resume repeats it.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Plan {
    pub material: String,
    pub size: usize,
    pub pixels: Option<String>,
    pub bracket: Vec<f64>,
    pub views: usize,
    pub turn: f64,
    pub env: Option<PathBuf>,
    pub nbrdf: Option<PathBuf>,
}

pub fn run(a: CaptureArgs) -> anyhow::Result<()> {
    if !a.simulate {
        bail!("capturing from hardware needs the camera drivers, which this build does not have yet; run with --simulate");
    }
    if a.views == 0 {
        bail!("--views must be at least 1");
    }
    if let Some(p) = &a.pixels {
        parse_pixels(p)?;
    }
    let plan = Plan {
        material: a.material,
        size: a.size,
        pixels: a.pixels,
        bracket: a.bracket,
        views: a.views,
        turn: a.turn,
        // Stored absolute, so a resume from another folder finds them.
        env: a.env.map(|p| std::path::absolute(&p).unwrap_or(p)),
        nbrdf: a.nbrdf.map(|p| std::path::absolute(&p).unwrap_or(p)),
    };
    let preset = MaterialPreset::embedded(&plan.material).map_err(anyhow::Error::msg)?;
    let state = brdfd::session::state_dir(a.state_dir.as_deref(), None)?;
    let mut session = Session::create(
        &state,
        &plan.material,
        include_str!("../../config/rigs/simulated.toml"),
        preset
            .is_some()
            .then(|| preset_text(&plan.material))
            .flatten(),
        serde_json::to_value(&plan)?,
    )?;
    println!(
        "session {} in {}",
        session.manifest.id,
        session.dir.display()
    );
    execute(&mut session, &plan, a.out.as_deref())
}

/// Continues a session from its last complete step.
pub fn resume(session: &mut Session) -> anyhow::Result<()> {
    if session.manifest.state == State::Done {
        println!("session {} is already done", session.manifest.id);
        return Ok(());
    }
    let plan: Plan = serde_json::from_value(session.manifest.options.clone())
        .context("the manifest's capture options")?;
    println!(
        "resuming session {} (was {:?})",
        session.manifest.id, session.manifest.state
    );
    execute(session, &plan, None)
}

fn preset_text(name: &str) -> Option<&'static str> {
    match name {
        "gold" => Some(include_str!("../../config/materials/gold.toml")),
        "chrome" => Some(include_str!("../../config/materials/chrome.toml")),
        "paint" => Some(include_str!("../../config/materials/paint.toml")),
        "fabric" => Some(include_str!("../../config/materials/fabric.toml")),
        _ => None,
    }
}

/// Runs the flow; a failure is recorded in the manifest (the session stays resumable).
fn execute(session: &mut Session, plan: &Plan, out: Option<&Path>) -> anyhow::Result<()> {
    match flow(session, plan, out) {
        Ok(()) => Ok(()),
        Err(e) => {
            let reason = format!("{e:#}");
            let _ = session.set_state(State::Failed, Some(reason));
            Err(e.context(format!(
                "session {} failed; what was captured is kept: `brdfd session resume {}` continues it",
                session.manifest.id, session.manifest.id
            )))
        }
    }
}

fn flow(session: &mut Session, plan: &Plan, out: Option<&Path>) -> anyhow::Result<()> {
    let started = std::time::Instant::now();
    let rig = Rig::simulated();
    let preset = MaterialPreset::embedded(&plan.material).map_err(anyhow::Error::msg)?;
    let mut phases = Phases::default();
    let t = std::time::Instant::now();
    let basis = Basis::embedded();
    phases.add("load the basis", t, 0.0);
    // Tabulating the simulated material is the simulator's work: a real bench has the object.
    let t = std::time::Instant::now();
    let bench = simulated_bench(plan, preset.as_ref(), &rig, &basis)?;
    let build = t.elapsed().as_secs_f64();
    phases.add("simulated bench: tabulate the material", t, build);
    println!(
        "simulated rig (in-process): {} on a sphere; DSLR: simulated Nikon D5100 over PTP/IP on loopback, {}×{}",
        bench.material_name, plan.size, plan.size
    );
    let shutters = if !plan.bracket.is_empty() {
        plan.bracket.clone()
    } else if let Some(s) = preset.as_ref().and_then(|p| p.dslr_shutters.clone()) {
        s
    } else {
        rig.brackets.dslr_shutters.clone()
    };
    let pixel_count = match (&plan.pixels, &preset) {
        (Some(p), _) => parse_pixels(p)?,
        (None, Some(p)) => match p.pixels {
            PixelCount::All => None,
            PixelCount::Count(n) => Some(n),
        },
        (None, None) => Some(20),
    };
    if matches!(session.manifest.state, State::Created | State::Failed) {
        session.set_state(State::Capturing, None)?;
    }

    // The panorama.
    let pano_files = match stored(session, "panorama")? {
        Some((files, _)) => {
            println!("panorama: {} frames already in the session", files.len());
            files
        }
        None => {
            session.begin_step("panorama", json!({}))?;
            let t = std::time::Instant::now();
            let (files, device) = theta_bracket(&bench, session)?;
            phases.add("panorama: shoot and download (THETA over HTTP)", t, device);
            session.finish_step("panorama")?;
            files
        }
    };
    let t = std::time::Instant::now();
    let merged = merge_bracket(&pano_files, THETA_SENSOR_GAIN)?;
    phases.add("panorama: HDR merge", t, 0.0);
    if merged.clipped_pixels > 0 {
        eprintln!(
            "  warning: {} pixels clip even in the shortest frame; they carry at least {:.1}% of the light",
            merged.clipped_pixels,
            merged.clipped_share * 100.0
        );
    }
    report_panorama(&merged.map, &bench);
    // The THETA's radiance in the DSLR's units, from the rig's calibration.
    let scale = rig.calibration.theta_to_dslr as f32;
    let env = EnvMap::from_pixels(
        merged.map.width,
        merged.map.height,
        merged
            .map
            .pixels
            .iter()
            .map(|p| p.map(|v| v * scale))
            .collect(),
        "THETA panorama, calibrated to the DSLR",
    )?;

    // One DSLR bracket per turntable view.
    let mut turntable = None;
    let mut views = Vec::with_capacity(plan.views);
    let mut raw_out: RawFiles = pano_files
        .iter()
        .map(|(name, b)| (format!("theta-{name}"), b.clone()))
        .collect();
    for i in 0..plan.views {
        let step = format!("view{}", i + 1);
        let (files, theta_deg) = match stored(session, &step)? {
            Some((files, meta)) => {
                let deg = meta["turntable_deg"].as_f64().unwrap_or(0.0);
                println!(
                    "{step}: {} frames already in the session ({deg:.2}°)",
                    files.len()
                );
                (files, deg)
            }
            None => {
                let deg = if plan.views > 1 {
                    if turntable.is_none() {
                        turntable = Some(sim_turntable()?);
                    }
                    let (_, rig) = turntable.as_mut().expect("just set");
                    let target = i as f64 * plan.turn;
                    let here = rig.position()?;
                    let turn = (target - here + 180.0).rem_euclid(360.0) - 180.0;
                    let at = if turn.abs() > 1e-9 {
                        rig.rotate(turn)?
                    } else {
                        here
                    };
                    println!("view {} of {}: turntable at {at:.2}°", i + 1, plan.views);
                    at
                } else {
                    0.0
                };
                session.begin_step(&step, json!({ "turntable_deg": deg }))?;
                let view = turned(&bench, deg);
                let t = std::time::Instant::now();
                let (files, device) =
                    dslr_bracket(&view, &shutters, &rig.brackets, session, &step)?;
                phases.add(
                    &format!("{step}: shoot and download (DSLR over PTP/IP)"),
                    t,
                    device,
                );
                session.finish_step(&step)?;
                (files, deg)
            }
        };
        let prefix = if plan.views > 1 {
            format!("view{}-", i + 1)
        } else {
            String::new()
        };
        let t = std::time::Instant::now();
        let photo = merge_dslr(&files)?;
        phases.add(&format!("{step}: HDR merge"), t, 0.0);
        raw_out.extend(
            files
                .iter()
                .enumerate()
                .map(|(k, (name, b))| (format!("{prefix}dslr-{:02}-{name}", k + 1), b.clone())),
        );
        let view = turned(&bench, theta_deg);
        let lights = env.compressed(DEFAULT_LIGHTS, view.yaw);
        save_exr(session, &format!("photo-{step}.exr"), &photo)?;
        views.push((view.pixels()?, lights, photo));
    }
    drop(turntable);
    session.set_state(State::Captured, None)?;

    session.set_state(State::Estimating, None)?;
    let options = EstimateOptions {
        pixel_count,
        ridge: preset.as_ref().and_then(|p| p.ridge),
        ..EstimateOptions::default()
    };
    let as_views: Vec<View> = views
        .iter()
        .map(|(geometry, lights, photo)| View {
            geometry,
            lights,
            photo,
        })
        .collect();
    let t_est = std::time::Instant::now();
    let est = estimate_views(&basis, &as_views, &options)?;
    phases.add("estimate", t_est, 0.0);
    print_estimate(&est.names, &est.solution.coefficients);
    let t_report = std::time::Instant::now();
    let truth = Bivariate::reduce(&bench.material, basis.header.grid);
    println!("ground truth projected on the basis:");
    print_estimate(&est.names, &basis.project(&truth));
    let (geometry, lights, photo) = &views[0];
    let rerender = render_bivariate(geometry, lights, &est.brdf(&basis));
    println!(
        "{} pixels, condition number {:.2}; re-render relative RMSE (first view) {:.4}; {:.2} s",
        est.selection.pixels.len(),
        est.selection.condition,
        rerender.relative_rmse(photo),
        started.elapsed().as_secs_f64()
    );
    phases.add("compare with the ground truth (re-render)", t_report, 0.0);
    let t_write = std::time::Instant::now();
    let pano_path = session.dir.join("derived/panorama.exr");
    write_exr(&pano_path, env.width, env.height, &env.pixels)?;

    // Results go to a fresh folder that replaces `result/` in one rename.
    let fresh = session.dir.join("result.partial");
    let _ = std::fs::remove_dir_all(&fresh);
    brdfd::results::write_results(&fresh, &basis, &est, "fast", lights)?;
    let result = session.dir.join("result");
    let _ = std::fs::remove_dir_all(&result);
    std::fs::rename(&fresh, &result).context("moving the results into place")?;
    phases.add("write results", t_write, 0.0);
    phases.print();
    session.manifest.phases = phases.0;
    session.set_state(State::Done, None)?;
    println!(
        "session {} done: {}",
        session.manifest.id,
        session.dir.display()
    );

    if let Some(out) = out {
        let files = brdfd::results::write_results(out, &basis, &est, "fast", lights)?;
        photo.write_exr(&out.join("photo.exr"))?;
        write_exr(
            &out.join("panorama.exr"),
            env.width,
            env.height,
            &env.pixels,
        )?;
        let raw = out.join("raw");
        std::fs::create_dir_all(&raw)?;
        for (name, bytes) in &raw_out {
            std::fs::write(raw.join(name), bytes)?;
        }
        println!("wrote {}", files.coefficients.display());
    }
    Ok(())
}

/// Wall time per phase, with the devices' share.
#[derive(Default)]
struct Phases(Vec<PhaseTime>);

impl Phases {
    fn add(&mut self, name: &str, since: std::time::Instant, device_seconds: f64) {
        self.0.push(PhaseTime {
            name: name.into(),
            seconds: since.elapsed().as_secs_f64(),
            device_seconds,
        });
    }

    fn print(&self) {
        let (all, device): (f64, f64) = self.0.iter().fold((0.0, 0.0), |(a, d), p| {
            (a + p.seconds, d + p.device_seconds)
        });
        println!("phases (wall time; of it, the simulated devices' own):");
        for p in &self.0 {
            println!(
                "  {:<52} {:>7.3} s  ({:.3} s)",
                p.name, p.seconds, p.device_seconds
            );
        }
        println!(
            "  {:<52} {:>7.3} s  ({:.3} s); brdfd's own: {:.3} s",
            "all phases",
            all,
            device,
            all - device
        );
    }
}

/// The simulated bench for a plan: the material (preset, MERL name, alias or NBRDF file), the
/// rig's object and camera at the plan's size, and the light.
fn simulated_bench(
    plan: &Plan,
    preset: Option<&MaterialPreset>,
    rig: &Rig,
    basis: &Basis,
) -> anyhow::Result<VirtualBench> {
    if let Some(p) = preset {
        if p.k != basis.header.k {
            bail!(
                "the {} preset is tuned for K = {}, the basis has K = {}",
                plan.material,
                p.k,
                basis.header.k
            );
        }
        println!(
            "material preset {}: simulated as {}, {} pixels{}",
            plan.material,
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
    let simulate_as = preset.map_or(plan.material.as_str(), |p| p.simulate_as.as_str());
    let mut bench = VirtualBench::embedded(simulate_as, plan.size).or_else(|e| {
        // Not an embedded material: the NBRDF file may have it.
        let Some(path) = &plan.nbrdf else {
            return Err(e);
        };
        let set = NbrdfSet::read(path)?;
        let name = brdfd::bench::resolve_material(simulate_as);
        let mut b = VirtualBench::embedded("gold", plan.size)?;
        b.material = MerlBrdf::tabulate(set.get(name)?);
        b.material_name = name.to_string();
        Ok::<_, brdfd::core::CoreError>(b)
    })?;
    // The object and its camera come from the rig file, at the size asked for.
    bench.geometry = rig.geometry.clone();
    bench.geometry.camera = rig.geometry.camera.resized(plan.size, plan.size);
    bench.yaw = rig.theta_yaw_deg.to_radians();
    if let Some(p) = &plan.env {
        bench.env = brdfd::panorama::load_envmap(p)?;
    }
    Ok(bench)
}

/// The bench as the camera sees it with the turntable at `deg`: in the object's frame, the
/// camera and the light turned by −θ (Camera::turned_about_y).
fn turned(bench: &VirtualBench, deg: f64) -> VirtualBench {
    let theta = deg.to_radians();
    let mut view = bench.clone();
    view.geometry.camera = bench.geometry.camera.turned_about_y(-theta);
    view.yaw = bench.yaw - theta;
    view
}

/// A step's files from the session (checksums verified), under the names the camera gave
/// them, if the step is complete.
fn stored(session: &Session, step: &str) -> anyhow::Result<Option<(RawFiles, serde_json::Value)>> {
    let Some(s) = session.complete_step(step) else {
        return Ok(None);
    };
    let prefix = format!("{step}-a{}-", s.attempt);
    let files = s
        .files
        .iter()
        .map(|f| {
            let name = f.name.strip_prefix(&prefix).unwrap_or(&f.name).to_string();
            Ok((name, session.read_raw(f)?))
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    Ok(Some((files, s.meta.clone())))
}

fn save_exr(session: &Session, name: &str, r: &Raster) -> anyhow::Result<()> {
    // Written beside, then renamed: a derived file is whole or absent.
    let tmp = session.dir.join("derived").join(format!(".{name}.tmp.exr"));
    r.write_exr(&tmp)?;
    std::fs::rename(&tmp, session.dir.join("derived").join(name))?;
    Ok(())
}

/// Shoots the bracket on the simulated D5100 through our PTP/IP client; each file goes into
/// the session as soon as it is downloaded. Also returns the seconds the simulated camera
/// spent rendering its scene and exposing.
fn dslr_bracket(
    bench: &VirtualBench,
    shutters: &[f64],
    plan: &Brackets,
    session: &mut Session,
    step: &str,
) -> anyhow::Result<(RawFiles, f64)> {
    let camera = BenchCamera::new(bench.clone(), "NIKON CORPORATION", "NIKON D5100");
    // The scene is rendered once, as a real camera's scene simply exists: device time.
    let render = std::time::Instant::now();
    camera
        .prepare()
        .map_err(|e| anyhow::anyhow!("rendering the simulated scene: {e}"))?;
    let render = render.elapsed().as_secs_f64();
    let source = Arc::new(Timed::new(Arc::new(camera)));
    let server = Server::start(
        "127.0.0.1:0",
        Responder::new(Profile::NikonD5100, source.clone()).shared(),
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
    if !session.manifest.devices.iter().any(|d| d.contains("D5100")) {
        session.manifest.devices.push(format!(
            "{} (serial {})",
            cam.describe(),
            cam.info.serial_number
        ));
    }
    let mut files = Vec::new();
    let opts = CaptureOptions::default();
    for &s in shutters {
        let speed = cam.set_shutter(s)?;
        let shot = cam.capture(&opts, &mut |_, _, _| {})?;
        session.add_raw(step, &shot.info.filename, &shot.data)?;
        println!(
            "  {}: {} bytes (camera applied {speed} s)",
            shot.info.filename,
            shot.data.len()
        );
        files.push((shot.info.filename, shot.data));
    }
    cam.close()?;
    Ok((files, render + source.seconds()))
}

/// Decodes a DSLR bracket and merges it into radiance, from each file's EXIF.
fn merge_dslr(files: &RawFiles) -> anyhow::Result<Raster> {
    let frames = files
        .iter()
        .map(|(name, bytes)| {
            let f = decode_jpeg(bytes, name)?;
            println!(
                "  {name}: EXIF {:.4} s f/{} ISO {}",
                f.exposure.shutter_s, f.exposure.f_number, f.exposure.iso
            );
            Ok(f)
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    Ok(merge_hdr(&frames, SENSOR_GAIN)?)
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

/// Shoots the light-probe bracket on the simulated THETA V over HTTP; the frames go into the
/// session as the camera sent them.
/// Also returns the seconds the simulated camera spent exposing and rendering.
fn theta_bracket(bench: &VirtualBench, session: &mut Session) -> anyhow::Result<(RawFiles, f64)> {
    let source = Arc::new(Timed::new(Arc::new(BenchPanorama::new(
        &bench.env,
        1024,
        "RICOH THETA V",
    ))));
    let config = ThetaConfig {
        shot_time: SIM_THETA_SHOT_TIME,
        ..ThetaConfig::default()
    };
    let server = OscServer::start("127.0.0.1:0", source.clone(), config)?;
    let mut theta = brdfd_theta::Theta::connect_http(&server.url(), None, loopback_timeouts())?;
    println!("panorama: {}", theta.describe());
    session.manifest.devices.push(theta.describe());
    let frames = shoot_panorama(&mut theta, &brdfd_theta::BracketPlan::light_probe())?;
    let device = SIM_THETA_SHOT_TIME.as_secs_f64() * frames.len() as f64 + source.seconds();
    let mut files = Vec::with_capacity(frames.len());
    for f in frames {
        session.add_raw("panorama", &f.name, &f.data)?;
        files.push((f.name, f.data));
    }
    Ok((files, device))
}

/// How far the measured map is from the bench's own (total light, per channel).
fn report_panorama(map: &EnvMap, bench: &VirtualBench) {
    // Total light is independent of the map's resolution (the downsample preserves Σ L·Δω),
    // so the bench's own map is the reference as it is.
    let (measured, truth) = (map.lights(0.0).power(), bench.env.lights(0.0).power());
    println!(
        "  panorama merged to {}×{}; total light vs the bench's map: {:+.2}% {:+.2}% {:+.2}% (R G B)",
        map.width,
        map.height,
        (measured[0] / truth[0] - 1.0) * 100.0,
        (measured[1] / truth[1] - 1.0) * 100.0,
        (measured[2] / truth[2] - 1.0) * 100.0,
    );
}
