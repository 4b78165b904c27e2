//! The capture flow: panorama bracket, the object camera's bracket per turntable view, HDR
//! merges, estimate, results, as one session on disk.
//!
//! The flow is a list of steps (the panorama, then each view); each step's files are stored
//! in the session as they arrive, and a step is skipped when the session already has it
//! complete. That is what a resume relies on. Device calls run on the devices' workers; the
//! flow itself runs on the caller's thread and is the only writer of the session.

use std::sync::Arc;
use std::time::Instant;

use anyhow::{bail, Context as _};
use brdfd_theta::{BracketPlan, Frame, Theta};
use serde_json::json;

use super::object::{self, FallbackUse, ObjectCamera};
use super::{Cancel, Devices, Event, Operator, Plan, Progress};
use crate::bench::panorama::THETA_SENSOR_GAIN;
use crate::bench::{VirtualBench, HELD_OUT_YAW_DEG};
use crate::config::{MaterialPreset, PixelCount, Rig};
use crate::core::basis::Basis;
use crate::core::bivariate::Bivariate;
use crate::core::envmap::{write_exr, EnvMap, CHOSEN_LIGHTS, DEFAULT_LIGHTS};
use crate::core::estimate::{
    estimate_views, fit_verdict, unused_basis_settings, Estimate, EstimateOptions, Model, View,
};
use crate::core::geometry::SceneGeometry;
use crate::core::merl::MerlBrdf;
use crate::core::nbrdf::NbrdfSet;
use crate::core::raster::Raster;
use crate::core::solve::Colour;
use crate::panorama::merge_bracket;
use crate::report::Context as ReportContext;
use crate::session::{PhaseTime, Session, State};

/// Camera files by name, exactly as the camera sent them.
pub type RawFiles = Vec<(String, Vec<u8>)>;

/// How a capture ended.
#[derive(Debug, Clone)]
pub struct Outcome {
    pub names: Vec<String>,
    pub coefficients: Vec<f64>,
    /// What the `finished` event carries.
    pub summary: super::Summary,
    /// Simulated rig only: the material's own projection onto the basis.
    pub truth: Option<Vec<f64>>,
    pub pixels: usize,
    pub condition: f64,
    /// How well the estimate re-renders the photos (see `Estimate::fit_error`).
    pub fit_error: f64,
}

/// `all` or a positive count.
pub fn parse_pixels(s: &str) -> anyhow::Result<Option<usize>> {
    if s == "all" {
        return Ok(None);
    }
    let n: usize = s
        .parse()
        .with_context(|| format!("--pixels takes a number or `all`, got {s:?}"))?;
    if n == 0 {
        bail!("--pixels must be at least 1");
    }
    Ok(Some(n))
}

/// Everything a run of the flow works with.
pub struct Context<'a> {
    pub rig: &'a Rig,
    pub devices: &'a Devices,
    pub progress: Arc<dyn Progress>,
    pub cancel: Cancel,
    /// Who turns the object between views when the rig has no turntable.
    pub operator: Arc<dyn Operator>,
}

impl Context<'_> {
    pub(super) fn say(&self, text: impl Into<String>) {
        self.progress.event(Event::Message { text: text.into() });
    }
    pub(super) fn warn(&self, text: impl Into<String>) {
        self.progress.event(Event::Warning { text: text.into() });
    }
    /// The simulated devices' own time so far (zero on hardware, where it is unknowable and
    /// real).
    fn device_seconds(&self) -> f64 {
        self.devices
            .sim
            .as_ref()
            .map_or(0.0, |s| s.device_seconds())
    }
}

/// Runs the flow on a session. A failure is recorded in the manifest, and the session stays
/// resumable; either way the last event is `Finished`.
pub fn execute(session: &mut Session, plan: &Plan, cx: &Context) -> anyhow::Result<Outcome> {
    // (result, why it failed, and whether the manifest could not record it), with the failure
    // recorded while the session is still claimed.
    let mut unrecorded = None;
    let (result, reason) = {
        // Refused before anything is written when another process runs this session. The
        // claim ends before `Finished` is sent: a client that saw it may resume at once.
        let _lock = session.claim()?;
        let result = run(session, plan, cx);
        let reason = result.as_ref().err().map(|e| {
            let reason = if cx.cancel.is_cancelled() {
                "cancelled; what was captured is kept".to_string()
            } else if disk_full(e) && !format!("{e:#}").contains("the disk is full") {
                // A derived map or a result, written by the core, says only ENOSPC.
                format!(
                    "{e:#}: the disk is full; free space, then `brdfd session resume {}` continues it (what was captured is kept)",
                    session.manifest.id
                )
            } else {
                format!("{e:#}")
            };
            // Half-written results are of no use, and on a full disk removing them is what
            // makes room to record the failure.
            let _ = std::fs::remove_dir_all(session.dir.join("result.partial"));
            if let Err(record) = session.set_state(State::Failed, Some(reason.clone())) {
                tracing::error!("could not record the failure in the manifest: {record}");
                unrecorded = Some(Unrecorded {
                    reason: reason.clone(),
                    error: record.to_string(),
                });
            }
            reason
        });
        (result, reason)
    };
    let id = session.manifest.id.clone();
    cx.progress.event(Event::Finished {
        session: id.clone(),
        state: if result.is_ok() {
            State::Done
        } else {
            State::Failed
        },
        result: result.as_ref().ok().map(|o| o.summary.clone()),
        error: reason,
    });
    result.map_err(|e| {
        let e = match unrecorded {
            Some(u) => e.context(u),
            None => e,
        };
        e.context(format!(
            "session {id} failed; what was captured is kept: `brdfd session resume {id}` continues it"
        ))
    })
}

/// A failure the manifest could not record (the disk full, no file descriptor left), in the
/// error [`execute`] returns: the daemon records it once it can ([`record_failure`]).
#[derive(Debug, Clone)]
pub struct Unrecorded {
    /// What the manifest should say.
    pub reason: String,
    /// Why it could not.
    pub error: String,
}

impl std::fmt::Display for Unrecorded {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "the failure could not be recorded in the manifest ({})",
            self.error
        )
    }
}

/// Records a failure that [`execute`] could not. `Ok(true)` once the manifest says it (or
/// says the session ended by other means); `Ok(false)` while another process holds it.
pub fn record_failure(state: &std::path::Path, id: &str, reason: &str) -> anyhow::Result<bool> {
    let marked = Session::open(state, id)?.fail_unless_running(|_| reason.to_string())?;
    Ok(marked != crate::session::Marked::Running)
}

/// Whether a full disk (ENOSPC) caused `e`, wherever in its chain: a session file's error, a
/// plain I/O error, or the core's (whose I/O error is a field, not a source).
fn disk_full(e: &anyhow::Error) -> bool {
    const ENOSPC: i32 = 28;
    e.chain().any(|c| {
        c.downcast_ref::<std::io::Error>()
            .and_then(std::io::Error::raw_os_error)
            == Some(ENOSPC)
            || matches!(
                c.downcast_ref::<crate::core::CoreError>(),
                Some(crate::core::CoreError::Io { error, .. }) if error.raw_os_error() == Some(ENOSPC)
            )
            || c.to_string().contains("the disk is full")
    })
}

/// Wall time per phase, with the devices' share; each phase is announced as it starts and
/// ends.
struct Phases<'a> {
    cx: &'a Context<'a>,
    done: Vec<PhaseTime>,
}

/// A phase under way.
struct Running {
    name: String,
    started: Instant,
    device_at_start: f64,
}

impl<'a> Phases<'a> {
    fn start(&self, name: &str, total: u64) -> Running {
        self.cx.progress.event(Event::PhaseStarted {
            phase: name.into(),
            total,
        });
        Running {
            name: name.into(),
            started: Instant::now(),
            device_at_start: self.cx.device_seconds(),
        }
    }

    fn end(&mut self, r: Running) {
        let device = self.cx.device_seconds() - r.device_at_start;
        self.finish(r, device);
    }

    /// Ends a phase that is the simulator's work as a whole.
    fn end_as_device(&mut self, r: Running) {
        let all = r.started.elapsed().as_secs_f64();
        self.finish(r, all);
    }

    fn finish(&mut self, r: Running, device_seconds: f64) {
        let p = PhaseTime {
            name: r.name,
            seconds: r.started.elapsed().as_secs_f64(),
            device_seconds,
        };
        self.cx.progress.event(Event::PhaseDone {
            phase: p.name.clone(),
            seconds: p.seconds,
            device_seconds: p.device_seconds,
        });
        self.done.push(p);
    }
}

fn run(session: &mut Session, plan: &Plan, cx: &Context) -> anyhow::Result<Outcome> {
    let rig = cx.rig;
    let preset = MaterialPreset::embedded(&plan.material).map_err(anyhow::Error::msg)?;
    let mut phases = Phases {
        cx,
        done: Vec::new(),
    };
    let p = phases.start("load the basis", 1);
    let basis = Basis::embedded();
    phases.end(p);
    if let Some(p) = &preset {
        if p.k != basis.header.k {
            bail!(
                "the {} preset is tuned for K = {}, the basis has K = {}",
                plan.material,
                p.k,
                basis.header.k
            );
        }
        // The preset's pixel count only matters to the basis model.
        let model = match plan.model.unwrap_or(p.model) {
            Model::Analytic => "analytic model".to_string(),
            Model::Hybrid => "hybrid model".to_string(),
            Model::Basis => match p.pixels {
                PixelCount::All => "basis model, every pixel".to_string(),
                PixelCount::Count(n) => format!("basis model, {n} pixels"),
            },
        };
        cx.say(format!(
            "material preset {}: {}, {model}{}",
            plan.material,
            if rig.simulated {
                format!("simulated as {}", p.simulate_as)
            } else {
                "on the bench".into()
            },
            if p.notes.is_empty() {
                String::new()
            } else {
                format!(" ({})", p.notes)
            }
        ));
    }
    // The object and its camera come from the rig file; the simulated camera is sized as
    // asked.
    let mut scene = rig.geometry.clone();
    if rig.simulated {
        scene.camera = rig.geometry.camera.resized(plan.size, plan.size);
    }
    let yaw = rig.theta_yaw_deg.to_radians();
    // A simulated rig needs a sample on its bench. Tabulating the material is the
    // simulator's work: a real bench has the object.
    let bench = match &cx.devices.sim {
        Some(sim) => {
            let p = phases.start("simulated bench: place the sample", 1);
            let b = simulated_bench(plan, preset.as_ref(), &scene, yaw, &basis)?;
            sim.show_light(&b);
            phases.end_as_device(p);
            cx.say(format!(
                "simulated rig: {} on a sphere; DSLR: simulated Nikon D5100 on {}, {}×{}",
                b.material_name,
                cx.devices
                    .dslr
                    .as_ref()
                    .map_or("none".into(), |d| d.status().selector),
                plan.size,
                plan.size
            ));
            Some(b)
        }
        None => None,
    };
    let mut relight_truth: Option<Joined<crate::core::Result<Raster>>> = None;
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
    let (n_views, turn_step) = plan.turntable(rig);
    if matches!(session.manifest.state, State::Created | State::Failed) {
        session.set_state(State::Capturing, None)?;
    }

    // The panorama.
    let pano_files = match stored(session, "panorama")? {
        Some((files, _)) => {
            cx.say(format!(
                "panorama: {} frames already in the session",
                files.len()
            ));
            files
        }
        None => {
            let plan = theta_plan(rig);
            let p = phases.start("panorama bracket", plan.shots.len() as u64);
            session.begin_step("panorama", json!({}))?;
            let files = theta_bracket(cx, session, plan)?;
            session.finish_step("panorama")?;
            phases.end(p);
            files
        }
    };
    cx.cancel.check()?;
    let p = phases.start("panorama HDR merge", 1);
    let merged = merge_bracket(&pano_files, THETA_SENSOR_GAIN)?;
    phases.end(p);
    if merged.clipped_pixels > 0 {
        cx.warn(format!(
            "{} pixels clip even in the shortest frame; they carry at least {:.1}% of the light",
            merged.clipped_pixels,
            merged.clipped_share * 100.0
        ));
    }
    if let Some(b) = &bench {
        cx.say(report_panorama(&merged.map, b));
    }
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

    // One object-camera bracket per turntable view.
    let mut views = Vec::with_capacity(n_views);
    // The map's turn for the first view: the preview and the report show its lights.
    let mut first_yaw = None;
    // Radiance at and above which a DSLR pixel was clipped in every frame of its bracket.
    let mut clip_level: Option<f32> = None;
    // The object camera for the views still to shoot; chosen when the first one is.
    // A capture that fell back stays on the fallback, resumed or not, even if the view it fell
    // back in was not finished.
    let mut camera: Option<ObjectCamera> = session
        .manifest
        .steps
        .iter()
        .any(|s| ObjectCamera::of_step(&s.meta) == ObjectCamera::Fallback)
        .then_some(ObjectCamera::Fallback);
    let mut fallback_use = FallbackUse::default();
    for i in 0..n_views {
        cx.cancel.check()?;
        let step = format!("view{}", i + 1);
        let (files, deg, shot_on) = match stored(session, &step)? {
            Some((files, meta)) => {
                let deg = meta["turntable_deg"].as_f64().unwrap_or(0.0);
                cx.say(format!(
                    "{step}: {} files already in the session ({deg:.2}°)",
                    files.len()
                ));
                (files, deg, ObjectCamera::of_step(&meta))
            }
            None => {
                if camera.is_none() {
                    camera = Some(object::choose(cx)?);
                }
                let deg = if n_views == 1 {
                    0.0
                } else if cx.devices.turntable.is_some() {
                    turn_on_turntable(cx, session, i, n_views, i as f64 * turn_step)?
                } else {
                    turn_by_hand(cx, i, n_views, turn_step)?
                };
                let frames = match camera {
                    Some(ObjectCamera::Fallback) => rig.brackets.fallback_shutters.len(),
                    _ => shutters.len(),
                };
                let p = phases.start(&format!("{step}: object bracket"), frames as u64);
                if let (Some(sim), Some(b)) = (&cx.devices.sim, &bench) {
                    // The simulated turntable only reports angles; the object turns here.
                    sim.show_object(&turned_bench(b, deg))?;
                    // The truth the estimate is relit against needs no estimate: it renders
                    // while the camera's modelled exposures wait and the estimate runs. (Not
                    // before the scene's own render: two renders at once only slow each other.)
                    if relight_truth.is_none() {
                        let b = b.clone();
                        relight_truth =
                            Some(Joined(Some(std::thread::spawn(move || b.relight_truth()))));
                    }
                }
                let using = camera.as_mut().expect("chosen above");
                let files = object::shoot_view(cx, session, &step, deg, &shutters, using)?;
                session.finish_step(&step)?;
                phases.end(p);
                (files, deg, *using)
            }
        };
        let (geometry, view_yaw) = turned(&scene, yaw, deg);
        first_yaw.get_or_insert(view_yaw);
        let (w, h) = geometry.camera.size();
        let mut pixels = geometry.pixels(w, h)?;
        let p = phases.start(&format!("{step}: HDR merge"), 1);
        let merged = object::merge_view(cx, shot_on, &files)?;
        if let Some((frames, noise)) = merged.fallback {
            let identity = cx
                .devices
                .fallback
                .as_ref()
                .and_then(|f| f.status().identity);
            fallback_use.add(frames, noise, identity);
        }
        if merged.demosaiced {
            pixels.drop_outline();
        }
        let (photo, white) = (merged.photo, merged.white);
        // Below the lowest level, every view's pixels are measurements (views on different
        // cameras have different levels: the lowest leaves out a few more, never a clipped one).
        clip_level = [clip_level, white].into_iter().flatten().reduce(f32::min);
        save_exr(session, &format!("photo-{step}.exr"), &photo, white)?;
        phases.end(p);
        let (lights, chosen_lights) = env.estimate_lights(DEFAULT_LIGHTS, CHOSEN_LIGHTS, view_yaw);
        views.push((pixels, lights, chosen_lights, photo));
    }
    session.set_state(State::Captured, None)?;
    cx.cancel.check()?;
    let fallback = (fallback_use.views > 0).then(|| fallback_use.describe(n_views));
    if let Some(text) = &fallback {
        cx.warn(text.clone());
    }

    session.set_state(State::Estimating, None)?;
    let options = EstimateOptions {
        model: plan
            .model
            .or(preset.as_ref().map(|p| p.model))
            .unwrap_or_default(),
        pixel_count,
        solver: plan
            .solve
            .or(preset.as_ref().map(|p| p.solve))
            .unwrap_or_default(),
        colour: plan
            .colour
            .or(preset.as_ref().map(|p| p.colour))
            .unwrap_or_default(),
        white: clip_level,
        ..EstimateOptions::default()
    };
    if let Some(warning) = unused_basis_settings(
        options.model,
        &[
            ("pixels", plan.pixels.is_some()),
            ("solve", plan.solve.is_some()),
            ("colour", plan.colour.is_some()),
        ],
    ) {
        cx.warn(warning);
    }
    let as_views: Vec<View> = views
        .iter()
        .map(|(geometry, lights, chosen_lights, photo)| View {
            geometry,
            lights,
            chosen_lights: chosen_lights.as_ref(),
            photo,
        })
        .collect();
    let p = phases.start("estimate", 1);
    let est = estimate_views(&basis, &as_views, &options)?;
    phases.end(p);
    cx.say(crate::results::coefficient_lines(
        "coefficients",
        &est.names,
        &est.solution.coefficients,
    ));
    let (_, lights, _, _) = &views[0];
    let truth = match &bench {
        // The projection is the basis's best answer; an analytic fit has no such reference.
        Some(b) if est.model == Model::Basis => {
            // The simulator knows the answer; comparing with it is the simulator's business,
            // so its time is the devices'.
            let p = phases.start("compare with the ground truth (simulator)", 1);
            let reduced = Bivariate::reduce(&b.material, basis.header.grid);
            let truth = match est.colour {
                Colour::Joint => basis.project(&reduced),
                Colour::PerChannel => basis.project_channels(&reduced),
            };
            phases.end_as_device(p);
            cx.say(crate::results::coefficient_lines(
                "ground truth projected on the basis",
                &est.names,
                &truth,
            ));
            Some(truth)
        }
        _ => None,
    };
    let relight = match &bench {
        Some(b) => {
            let p = phases.start("relight against the ground truth (simulator)", 1);
            let truth = match relight_truth {
                Some(mut render) => render
                    .join()
                    .ok_or_else(|| anyhow::anyhow!("rendering the relight truth panicked"))??,
                // Every view was already on disk (a resumed session): render it now.
                None => b.relight_truth()?,
            };
            let error = b.relight_error_with(&truth, &est.brdf)?;
            phases.end_as_device(p);
            Some(error)
        }
        None => None,
    };
    let p = phases.start("write results", 1);
    write_exr(
        &session.dir.join("derived/panorama.exr"),
        env.width,
        env.height,
        &env.pixels,
    )?;
    // The simulator knows the material: the report overlays it on the estimate's slices.
    let true_brdf = bench
        .as_ref()
        .map(|b| Bivariate::reduce(&b.material, basis.header.grid));
    let m = &session.manifest;
    let mut report = ReportContext {
        title: format!("session {} ({})", m.id, m.material),
        session: Some(m.id.clone()),
        photo: Some(&views[0].3),
        env: Some(&env),
        yaw: first_yaw.unwrap_or(yaw),
        relight_error: relight,
        truth: true_brdf.as_ref(),
        fallback: fallback.clone(),
        record: vec![
            ("session".into(), m.id.clone()),
            ("material".into(), m.material.clone()),
            ("created".into(), m.created.clone()),
            ("views".into(), views.len().to_string()),
            ("devices".into(), m.devices.join("; ")),
            ("software".into(), m.software.clone()),
        ],
    };
    if let Some(text) = &fallback {
        report.record.push(("object camera".into(), text.clone()));
    }
    write_result(session, &basis, &est, lights, &report)?;
    phases.end(p);
    cx.say(format!(
        "{}, condition number {}; the estimate re-renders the photo{} to a relative RMSE of {:.4} over {} pixels ({})",
        est.method_text(),
        est.selection.condition_text(),
        if views.len() > 1 { "s" } else { "" },
        est.fit_error,
        est.candidates,
        fit_verdict(est.fit_error),
    ));
    if let Some(error) = relight {
        cx.say(format!(
            "relit under the bench's map turned {HELD_OUT_YAW_DEG}° (light it was not fitted to), the estimate is {error:.4} from the truth (relative RMSE over the object)"
        ));
    }
    if let Some((text, distrust)) = est.certainty_text() {
        if distrust {
            cx.warn(text);
        } else {
            cx.say(text);
        }
    }
    if est.clipped > 0 {
        cx.say(format!(
            "{} object pixels were clipped in every frame of their bracket and left out; a shorter exposure would keep them",
            est.clipped
        ));
    }
    session.manifest.phases = phases.done;
    session.set_state(State::Done, None)?;
    let fit = est.fit_error;
    Ok(Outcome {
        names: est.names.clone(),
        coefficients: est.solution.coefficients.clone(),
        summary: super::Summary {
            model: est.model.name().to_string(),
            columns: est.names.clone(),
            coefficients: super::Summary::numbers(&est.solution.coefficients),
            fit_error: fit.is_finite().then_some(fit),
            fit_verdict: fit_verdict(fit),
            relight_error: relight,
            fallback,
        },
        truth,
        pixels: est.selection.pixels.len(),
        condition: est.selection.condition,
        fit_error: est.fit_error,
    })
}

/// Results go to a fresh folder that replaces `result/` in one rename.
fn write_result(
    session: &Session,
    basis: &Basis,
    est: &Estimate,
    lights: &crate::core::envmap::LightSet,
    report: &ReportContext,
) -> anyhow::Result<()> {
    let fresh = session.dir.join("result.partial");
    let _ = std::fs::remove_dir_all(&fresh);
    crate::results::write_results(&fresh, basis, est, "fast", lights, report)?;
    let result = session.dir.join("result");
    let _ = std::fs::remove_dir_all(&result);
    std::fs::rename(&fresh, &result).context("moving the results into place")?;
    Ok(())
}

/// The rig's THETA bracket: its own shutter list, or the light probe.
fn theta_plan(rig: &Rig) -> BracketPlan {
    if rig.brackets.theta_shutters.is_empty() {
        return BracketPlan::light_probe();
    }
    BracketPlan {
        shots: rig
            .brackets
            .theta_shutters
            .iter()
            .map(|&shutter_s| brdfd_theta::Exposure {
                shutter_s,
                iso: rig.brackets.theta_iso,
            })
            .collect(),
    }
}

/// A thread the flow started, joined when dropped: a capture that ends early (an error, a
/// cancel) does not leave it running into the next one.
struct Joined<T>(Option<std::thread::JoinHandle<T>>);

impl<T> Joined<T> {
    /// Its result; `None` if it panicked.
    fn join(&mut self) -> Option<T> {
        self.0.take()?.join().ok()
    }
}

impl<T> Drop for Joined<T> {
    fn drop(&mut self) {
        if let Some(h) = self.0.take() {
            let _ = h.join();
        }
    }
}

/// The simulated bench for a plan: the material (preset, MERL name, alias or NBRDF file) on
/// the rig's object, under the plan's light.
fn simulated_bench(
    plan: &Plan,
    preset: Option<&MaterialPreset>,
    scene: &SceneGeometry,
    yaw: f64,
    basis: &Basis,
) -> anyhow::Result<VirtualBench> {
    let simulate_as = preset.map_or(plan.material.as_str(), |p| p.simulate_as.as_str());
    let mut bench = VirtualBench::embedded(simulate_as, plan.size).or_else(|e| {
        // Not an embedded material: the NBRDF file may have it.
        let Some(path) = &plan.nbrdf else {
            return Err(e);
        };
        let set = NbrdfSet::read(path)?;
        let name = crate::bench::resolve_material(simulate_as);
        let mut b = VirtualBench::embedded("gold", plan.size)?;
        b.material = MerlBrdf::tabulate(set.get(name)?);
        b.material_name = name.to_string();
        Ok::<_, crate::core::CoreError>(b)
    })?;
    if plan.in_span {
        let projected = basis.project(&Bivariate::reduce(&bench.material, basis.header.grid));
        bench.material = basis.reconstruct(&projected).to_merl();
        bench.material_name = format!("{} (its projection onto the basis)", bench.material_name);
    }
    bench.geometry = scene.clone();
    bench.yaw = yaw;
    bench.cache = crate::bench::cache::RenderCache::user();
    if let Some(p) = &plan.env {
        bench.env = crate::panorama::load_envmap(p)?;
    }
    Ok(bench)
}

/// The scene as the camera sees it with the turntable at `deg`: in the object's frame, the
/// camera and the light turned by −θ (Camera::turned_about_y).
fn turned(scene: &SceneGeometry, yaw: f64, deg: f64) -> (SceneGeometry, f64) {
    let theta = deg.to_radians();
    let mut g = scene.clone();
    g.camera = scene.camera.turned_about_y(-theta);
    (g, yaw - theta)
}

fn turned_bench(bench: &VirtualBench, deg: f64) -> VirtualBench {
    let (geometry, yaw) = turned(&bench.geometry, bench.yaw, deg);
    VirtualBench {
        geometry,
        yaw,
        ..bench.clone()
    }
}

/// Turns the turntable for view `i` (from 0) of `n`, to `target` degrees; where it stopped.
fn turn_on_turntable(
    cx: &Context,
    session: &mut Session,
    i: usize,
    n: usize,
    target: f64,
) -> anyhow::Result<f64> {
    let at = turn_to(cx, target)?;
    if let Some(t) = &cx.devices.turntable {
        note_device(session, t.status().identity.clone());
        if i == 0 {
            cx.say(format!(
                "turntable: {}",
                t.status().identity.unwrap_or_default()
            ));
        }
    }
    cx.say(format!("view {} of {n}: turntable at {at:.2}°", i + 1));
    Ok(at)
}

/// View `i` (from 0) of `n` on a rig with no turntable: the first is the object as placed;
/// before each of the others the operator turns it by hand `step` degrees further and says
/// so. The angle is the one asked: nothing measures it.
fn turn_by_hand(cx: &Context, i: usize, n: usize, step: f64) -> anyhow::Result<f64> {
    let target = i as f64 * step;
    if i == 0 {
        cx.say(format!(
            "view 1 of {n}: the object as placed (0°); the rig has no turntable, so it is turned by hand between views"
        ));
        return Ok(0.0);
    }
    let text = format!(
        "view {} of {n}: turn the object by hand to {target:.1}° ({step:.1}° further than the last view, the same way), then continue",
        i + 1,
    );
    let announce = || {
        cx.progress.event(Event::WaitingForOperator {
            text: text.clone(),
            view: i + 1,
            degrees: target,
        })
    };
    cx.operator.wait(i + 1, &announce, &cx.cancel)?;
    cx.say(format!(
        "view {} of {n}: turned by hand to {target:.1}°",
        i + 1
    ));
    Ok(target)
}

/// Turns the turntable to `target` degrees by the shortest way; returns where it reports
/// it is.
fn turn_to(cx: &Context, target: f64) -> anyhow::Result<f64> {
    let table = cx.devices.turntable.as_ref().context("no turntable")?;
    table.call(move |t| {
        let here = t.position()?;
        let turn = (target - here + 180.0).rem_euclid(360.0) - 180.0;
        Ok(if turn.abs() > 1e-9 {
            t.rotate(turn)?
        } else {
            here
        })
    })
}

/// A step's files from the session (checksums verified), under the names the camera gave
/// them, if the step is complete.
pub fn stored(
    session: &Session,
    step: &str,
) -> anyhow::Result<Option<(RawFiles, serde_json::Value)>> {
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

/// Writes a merged photo with its white level, so that a later `brdfd estimate` on the file
/// leaves out the pixels the capture left out.
fn save_exr(session: &Session, name: &str, r: &Raster, white: Option<f32>) -> anyhow::Result<()> {
    // Written beside, then renamed: a derived file is whole or absent.
    let tmp = session.dir.join("derived").join(format!(".{name}.tmp.exr"));
    r.write_exr_with_white(&tmp, white)?;
    std::fs::rename(&tmp, session.dir.join("derived").join(name))?;
    Ok(())
}

pub(super) fn note_device(session: &mut Session, identity: Option<String>) {
    if let Some(id) = identity {
        if !session.manifest.devices.contains(&id) {
            session.manifest.devices.push(id);
        }
    }
}

/// Shoots the panorama bracket on the THETA's worker; the frames go into the session as the
/// camera sent them.
fn theta_bracket(
    cx: &Context,
    session: &mut Session,
    plan: BracketPlan,
) -> anyhow::Result<RawFiles> {
    let progress = cx.progress.clone();
    let frames = cx.devices.theta.call(move |theta| {
        progress.event(Event::Message {
            text: format!("panorama: {}", theta.describe()),
        });
        shoot_panorama(theta, &plan, progress.as_ref())
    })?;
    note_device(session, cx.devices.theta.status().identity);
    let mut files = Vec::with_capacity(frames.len());
    for f in frames {
        check_exposure(cx.progress.as_ref(), &f);
        session.add_raw("panorama", &f.name, &f.data)?;
        files.push((f.name, f.data));
    }
    Ok(files)
}

/// Prepares the THETA for light measurement and shoots the plan: the frames as the camera
/// sent them. Progress goes to the "panorama bracket" phase.
pub fn shoot_panorama(
    theta: &mut Theta,
    plan: &BracketPlan,
    progress: &dyn Progress,
) -> anyhow::Result<Vec<Frame>> {
    for line in theta.prepare().context("preparing the THETA")? {
        tracing::info!("THETA: {line}");
    }
    let total = plan.shots.len() as u64;
    let mut last = String::new();
    let frames = theta
        .capture(plan, &mut |phase, fraction| {
            if phase != last {
                progress.event(Event::Message {
                    text: format!("  panorama: {phase}"),
                });
                last = phase.to_string();
            }
            progress.event(Event::Progress {
                phase: "panorama bracket".into(),
                done: (fraction.clamp(0.0, 1.0) * total as f64).round() as u64,
                total,
            });
        })
        .context("shooting the panorama bracket")?;
    Ok(frames)
}

/// How far a frame's EXIF exposure may be from what was asked before it is reported:
/// cameras round speeds (1/3200 s is stored as 0.0003125 or 1/3200), but a different stop
/// means the camera did not take the setting.
const EXPOSURE_MISMATCH: f64 = 0.05;

/// The merge uses each frame's EXIF; a frame whose EXIF disagrees with the request means the
/// camera overrode the setting (auto exposure left on, a model limit), which the operator
/// should know.
pub fn check_exposure(progress: &dyn Progress, f: &Frame) {
    match crate::radiometry::exif_exposure(&f.data, &f.name) {
        Ok(e) => {
            let shutter_off = (e.shutter_s / f.asked.shutter_s - 1.0).abs();
            let iso_off = (e.iso / f.asked.iso as f64 - 1.0).abs();
            if shutter_off > EXPOSURE_MISMATCH || iso_off > EXPOSURE_MISMATCH {
                progress.event(Event::Warning {
                    text: format!(
                        "{}: EXIF says {} s ISO {}, but {} s ISO {} was asked; the merge uses the EXIF values",
                        f.name, e.shutter_s, e.iso, f.asked.shutter_s, f.asked.iso
                    ),
                });
            }
        }
        // The merge reports a missing EXIF exposure as an error, naming the file.
        Err(e) => tracing::debug!("{e}"),
    }
}

/// How far the measured map is from the bench's own (total light, per channel).
fn report_panorama(map: &EnvMap, bench: &VirtualBench) -> String {
    // Total light is independent of the map's resolution (the downsample preserves Σ L·Δω),
    // so the bench's own map is the reference as it is.
    let (measured, truth) = (map.lights(0.0).power(), bench.env.lights(0.0).power());
    format!(
        "  panorama merged to {}×{}; total light vs the bench's map: {:+.2}% {:+.2}% {:+.2}% (R G B)",
        map.width,
        map.height,
        (measured[0] / truth[0] - 1.0) * 100.0,
        (measured[1] / truth[1] - 1.0) * 100.0,
        (measured[2] / truth[2] - 1.0) * 100.0,
    )
}
