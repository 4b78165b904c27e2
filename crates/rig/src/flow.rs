//! The capture flow: panorama bracket, the object camera's bracket per turntable view, HDR
//! merges, estimate, results, as one session on disk.
//!
//! The flow works from settings resolved before the session existed
//! ([`super::settings::CaptureSettings`]), and asks its devices for roles, not types
//! ([`super::roles`]). It is a list of steps (the panorama, then each view), one function
//! each; each step's files are stored in the session as they arrive, and a step is skipped
//! when the session already has it complete. That is what a resume relies on. Device calls
//! run on the devices' workers; the flow itself runs on the caller's thread and is the only
//! writer of the session.

use std::sync::Arc;
use std::time::Instant;

use serde_json::json;

use super::error::{disk_full, said, FailureCode};
use super::light::light_bracket;
use super::object::{self, CameraRole, FallbackUse};
use super::prepare::Preparing;
use super::settings::CaptureSettings;
use super::stage::Stage;
use super::turning::{turn, turned};
use super::{Cancel, Devices, Event, Operator, Progress};
use crate::config::Rig;
use crate::error::{Result, RigError, StepExt};
use crate::session::{PhaseTime, Session, State};
use brdfd_core::basis::Basis;
use brdfd_core::bivariate::Bivariate;
use brdfd_core::envmap::{EnvMap, LightSet, CHOSEN_LIGHTS, DEFAULT_LIGHTS};
use brdfd_core::estimate::{fit_verdict, EstimateOptions, View};
use brdfd_core::geometry::PixelGeometry;
use brdfd_core::materials::{estimate_materials, Materials};
use brdfd_core::raster::Raster;
use brdfd_radiometry::panorama::merge_bracket;
use brdfd_report::export::Prepared;
use brdfd_report::html::Context as ReportContext;
use brdfd_report::visibility::Visibility;

/// The failure a cancelled capture records: its manifest's reason, which the API reads back.
pub const CANCELLED: &str = "cancelled; what was captured is kept";

/// Camera files by name, exactly as the camera sent them.
pub type RawFiles = Vec<(String, Vec<u8>)>;

/// Where a bracket's files go as they arrive, each at once, so that a failure later in the
/// bracket loses none already taken: a session's step, or a calibration's folder.
pub trait Keep {
    fn keep(&mut self, name: &str, bytes: &[u8]) -> Result<()>;
}

/// Keeps each file under its name with a prefix (`theta-`, `view2-`).
pub struct Prefixed<'a>(pub &'a mut dyn Keep, pub String);

impl Keep for Prefixed<'_> {
    fn keep(&mut self, name: &str, bytes: &[u8]) -> Result<()> {
        self.0.keep(&format!("{}{name}", self.1), bytes)
    }
}

/// A session's step under way, as a [`Keep`].
pub struct Step<'a> {
    pub session: &'a mut Session,
    pub name: &'a str,
}

impl Keep for Step<'_> {
    fn keep(&mut self, name: &str, bytes: &[u8]) -> Result<()> {
        self.session.add_raw(self.name, name, bytes)?;
        Ok(())
    }
}

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
    pub fn say(&self, text: impl Into<String>) {
        self.progress.event(Event::Message { text: text.into() });
    }
    pub fn warn(&self, text: impl Into<String>) {
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
pub fn execute(session: &mut Session, settings: &CaptureSettings, cx: &Context) -> Result<Outcome> {
    // (result, why it failed, and whether the manifest could not record it), with the failure
    // recorded while the session is still claimed.
    let mut unrecorded = None;
    let (result, failure) = {
        // Refused before anything is written when another process runs this session. The
        // claim ends before `Finished` is sent: a client that saw it may resume at once.
        let _lock = session.claim()?;
        let result = run(session, settings, cx);
        let failure = result.as_ref().err().map(|e| {
            let code = if cx.cancel.is_cancelled() {
                FailureCode::Cancelled
            } else {
                e.code()
            };
            let reason = if code == FailureCode::Cancelled {
                CANCELLED.to_string()
            } else if disk_full(e) && !said(e).contains("the disk is full") {
                // A derived map or a result, written by the core, says only ENOSPC.
                format!(
                    "{}: the disk is full; free space, then `brdfd session resume {}` continues it (what was captured is kept)",
                    said(e),
                    session.manifest().id
                )
            } else {
                said(e)
            };
            // Half-written results are of no use, and on a full disk removing them is what
            // makes room to record the failure.
            let _ = std::fs::remove_dir_all(session.dir.join("result.partial"));
            if let Err(record) = session.fail(reason.clone(), code) {
                tracing::error!("could not record the failure in the manifest: {record}");
                unrecorded = Some(Unrecorded {
                    reason: reason.clone(),
                    code,
                    error: record.to_string(),
                });
            }
            (reason, code)
        });
        (result, failure)
    };
    let id = session.manifest().id.clone();
    cx.progress.event(Event::Finished {
        session: id.clone(),
        state: if result.is_ok() {
            State::Done
        } else {
            State::Failed
        },
        result: result.as_ref().ok().map(|o| Box::new(o.summary.clone())),
        cancelled: failure.as_ref().map(|f| f.1) == Some(FailureCode::Cancelled),
        code: failure.as_ref().map(|f| f.1),
        error: failure.map(|f| f.0),
    });
    result.map_err(|e| {
        let e = match unrecorded {
            Some(unrecorded) => RigError::Unrecorded {
                unrecorded,
                cause: Box::new(e),
            },
            None => e,
        };
        e.step(format!(
            "session {id} failed; what was captured is kept: `brdfd session resume {id}` continues it"
        ))
    })
}

pub use crate::error::Unrecorded;

/// Records a failure that [`execute`] could not. `Ok(true)` once the manifest says it (or
/// says the session ended by other means); `Ok(false)` while another process holds it.
pub fn record_failure(state: &std::path::Path, id: &str, u: &Unrecorded) -> Result<bool> {
    let marked =
        Session::open(state, id)?.fail_unless_running(|_| u.reason.clone(), Some(u.code))?;
    Ok(marked != crate::session::Marked::Running)
}

/// Wall time per phase, with the devices' share; each phase is announced as it starts and
/// ends.
pub struct Phases<'a> {
    cx: &'a Context<'a>,
    done: Vec<PhaseTime>,
}

/// A phase under way.
pub struct Running {
    name: String,
    started: Instant,
    device_at_start: f64,
}

impl<'a> Phases<'a> {
    pub fn start(&self, name: &str, total: u64) -> Running {
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

    pub fn end(&mut self, r: Running) {
        let device = self.cx.device_seconds() - r.device_at_start;
        self.finish(r, device);
    }

    /// Ends a phase that is the simulator's work as a whole.
    pub fn end_as_device(&mut self, r: Running) {
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

fn run(session: &mut Session, s: &CaptureSettings, cx: &Context) -> Result<Outcome> {
    let mut phases = Phases {
        cx,
        done: Vec::new(),
    };
    // Capturing from the first step: a list of sessions must not show a running capture as
    // "created", nor offer to resume it. A session starts new or resumes failed (an
    // interrupted one is recorded as failed first, by `resumable`).
    session.set_state(State::Capturing, None)?;
    let p = phases.start("load the basis", 1);
    let basis = Basis::embedded();
    phases.end(p);
    if let Some(line) = s.preset_line(cx.rig.simulated) {
        cx.say(line);
    }
    for w in &s.warnings {
        cx.warn(w.clone());
    }
    check_turntable(cx, s)?;
    let mut stage = super::stage::of(cx);
    stage.place(cx, s, &basis, &mut phases)?;
    let env = measure_light(cx, session, s, stage.as_ref(), &mut phases)?;
    let mut captured = shoot_views(cx, session, s, (&env, &basis), stage.as_mut(), &mut phases)?;
    session.set_state(State::Captured, None)?;
    cx.cancel.check()?;
    if let Some(text) = &captured.fallback {
        cx.warn(text.clone());
    }
    session.set_state(State::Estimating, None)?;
    let (found, exports) = estimate(cx, s, &basis, &mut captured, &mut phases)?;
    let est = &found.whole;
    let judged = stage.judge(cx, &basis, est, &mut phases)?;
    let relight = judged.relight.as_ref().map(|r| r.0);
    // The last point to stop at: once written, the results are the session's.
    cx.cancel.check()?;
    let p = phases.start("write results", 1);
    env.write_exr(&session.dir.join("derived/panorama.exr"))?;
    let first = &captured.views[0];
    // Under the candidates' lights, whose visibility the estimate has worked out already.
    let visibility = Visibility::of(&first.geometry, &first.lights);
    let object = match &s.scene.shape {
        Some(shape) => shape.mesh()?,
        None => None,
    };
    // A stage that knows the material: the report overlays it on the estimate's slices.
    let mut report = report_context(session, &env, &captured, judged.brdf.as_ref(), relight);
    report.visibility = visibility.as_ref();
    report.object = object.as_ref();
    report.exports = exports.as_ref();
    let (files, parts) = write_result(session, &basis, &found, &captured.views[0].lights, report)?;
    phases.end(p);
    say_result(
        cx,
        session,
        &found,
        captured.views.len(),
        judged.relight,
        (&files, parts.as_ref()),
    );
    let (exports, flags) = (&files.exports, &files.flags);
    session.set_phases(phases.done);
    session.set_state(State::Done, None)?;
    let fit = est.fit_error;
    Ok(Outcome {
        names: est.names.clone(),
        coefficients: est.solution.coefficients.clone(),
        summary: super::Summary {
            model: est.model().name().to_string(),
            anisotropic_lobe: est.chosen_lobe().is_some(),
            columns: est.names.clone(),
            coefficients: super::Summary::numbers(&est.solution.coefficients),
            verdict: Some(files.verdict.word().to_string()),
            verdict_text: Some(files.headline.clone()),
            fit_error: fit.is_finite().then_some(fit),
            fit_verdict: fit_verdict(fit),
            relight_error: relight,
            fallback: captured.fallback,
            export_relight_error: Some(exports.relight_error),
            export_verdict: Some(exports.verdict.clone()),
            mtlx_relight_error: exports.mtlx_relight_error,
            mtlx_verdict: exports.mtlx_verdict.clone(),
            flags: flags
                .iter()
                .map(|f| super::SummaryFlag {
                    reason: f.reason.name().to_string(),
                    text: f.text.clone(),
                })
                .collect(),
            materials: parts
                .as_ref()
                .map(|p| super::summary_materials(&p.record))
                .unwrap_or_default(),
        },
        truth: judged.coefficients,
        pixels: est.pixel_count(),
        condition: est.condition(),
        fit_error: est.fit_error,
    })
}

/// A turntable that cannot turn is found before anything is shot: its device opened, and its
/// role asked of it (a box whose `ID?` lists FIRE alone is no turntable).
fn check_turntable(cx: &Context, s: &CaptureSettings) -> Result<()> {
    match (&cx.devices.turntable, s.turning) {
        (Some(t), super::settings::Turning::Turntable) => {
            t.call(|t| t.position()).step("the rig's turntable")?;
            Ok(())
        }
        _ => Ok(()),
    }
}

/// The panorama step, then its merge: the light around the object as an environment map in
/// the bench's unit, through the THETA's gain.
fn measure_light(
    cx: &Context,
    session: &mut Session,
    s: &CaptureSettings,
    stage: &dyn Stage,
    phases: &mut Phases,
) -> Result<EnvMap> {
    let pano_files = match stored(session, "panorama")? {
        Some((files, _)) => {
            cx.say(format!(
                "panorama: {} frames already in the session",
                files.len()
            ));
            files
        }
        None => {
            let p = phases.start("panorama bracket", s.light.shots.len() as u64);
            session.begin_step("panorama", json!({}))?;
            let mut step = Step {
                session,
                name: "panorama",
            };
            let files = light_bracket(cx, &mut step, s.light.clone())?;
            note_device(session, cx.devices.light_probe.status().identity);
            session.finish_step("panorama")?;
            phases.end(p);
            files
        }
    };
    cx.cancel.check()?;
    let gain = cx
        .rig
        .calibration
        .theta
        .as_ref()
        .map(|g| g.gain.0)
        .step("calibration.theta.gain is not in the rig's calibration: `brdfd calibrate radiometry` measures it")?;
    let p = phases.start("panorama HDR merge", 1);
    let merged = merge_bracket(&pano_files, gain)?;
    phases.end(p);
    if merged.clipped_pixels > 0 {
        cx.warn(format!(
            "{} pixels clip even in the shortest frame; they carry at least {:.1}% of the light",
            merged.clipped_pixels,
            merged.clipped_share * 100.0
        ));
    }
    if let Some(note) = stage.light_note(&merged.map) {
        cx.say(note);
    }
    Ok(EnvMap::from_pixels(
        merged.map.width,
        merged.map.height,
        merged.map.pixels,
        "THETA panorama, in the bench's radiance",
    )?)
}

/// One view as the estimate takes it.
struct CapturedView {
    geometry: PixelGeometry,
    lights: LightSet,
    chosen_lights: Option<LightSet>,
    photo: Raster,
}

/// The object camera's views, with what the estimate and the report need of them.
struct Captured {
    views: Vec<CapturedView>,
    /// Radiance at and above which an object pixel was clipped in every frame of its bracket.
    clip_level: Option<f32>,
    /// The map's turn for the first view: the preview and the report show its lights.
    first_yaw: f64,
    /// When the fallback shot any view: what it cost, in words.
    fallback: Option<String>,
    /// The work on the first view that needs no photo, started once its turn is known.
    preparing: Option<Preparing>,
}

/// One object-camera bracket per view, each stored as it arrives and merged.
fn shoot_views(
    cx: &Context,
    session: &mut Session,
    s: &CaptureSettings,
    (env, basis): (&EnvMap, &Basis),
    stage: &mut dyn Stage,
    phases: &mut Phases,
) -> Result<Captured> {
    let mut captured = Captured {
        views: Vec::with_capacity(s.views),
        clip_level: None,
        first_yaw: s.yaw,
        fallback: None,
        preparing: None,
    };
    // The object camera for the views still to shoot; chosen when the first one is. A
    // capture that fell back stays on the fallback, resumed or not, even if the view it fell
    // back in was not finished.
    let mut camera: Option<CameraRole> = session
        .manifest()
        .steps
        .iter()
        .any(|st| CameraRole::of_step(&st.meta) == CameraRole::Fallback)
        .then_some(CameraRole::Fallback);
    let mut fallback_use = FallbackUse::default();
    for i in 0..s.views {
        cx.cancel.check()?;
        let step = format!("view{}", i + 1);
        let (files, deg, shot_on) = match stored(session, &step)? {
            Some((files, meta)) => {
                let deg = meta["turntable_deg"].as_f64().unwrap_or(0.0);
                cx.say(format!(
                    "{step}: {} files already in the session ({deg:.2}°)",
                    files.len()
                ));
                (files, deg, CameraRole::of_step(&meta))
            }
            None => {
                let using = match camera {
                    Some(c) => c,
                    None => *camera.insert(object::choose(cx)?),
                };
                let deg = turn(cx, session, s, i)?;
                if i == 0 {
                    let options = EstimateOptions {
                        stop: cx.cancel.stop(),
                        ..s.estimate.clone()
                    };
                    let view = turned(&s.scene, s.yaw, deg);
                    let first = (&view.0, view.1);
                    captured.preparing =
                        Some(Preparing::start(env, first, basis, &options, s.views == 1));
                }
                let frames = match using {
                    CameraRole::Fallback => s.fallback.exposures_s.len(),
                    CameraRole::Dslr => s.dslr.exposures_s.len(),
                };
                let p = phases.start(&format!("{step}: object bracket"), frames as u64);
                // A render cut short by a cancel says so as every other step does.
                stage
                    .show(cx, deg)
                    .or_else(|e| cx.cancel.check().and(Err(e)))?;
                let mut using = using;
                let files = object::shoot_view(
                    cx,
                    session,
                    &step,
                    deg,
                    (&s.dslr, &s.fallback),
                    &mut using,
                )?;
                camera = Some(using);
                session.finish_step(&step)?;
                phases.end(p);
                (files, deg, using)
            }
        };
        let (geometry, view_yaw) = turned(&s.scene, s.yaw, deg);
        if i == 0 {
            captured.first_yaw = view_yaw;
        }
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
        // Below the lowest level, every view's pixels are measurements (views on different
        // cameras have different levels: the lowest leaves out a few more, never a clipped one).
        captured.clip_level = [captured.clip_level, merged.white]
            .into_iter()
            .flatten()
            .reduce(f32::min);
        save_exr(
            session,
            &format!("photo-{step}.exr"),
            &merged.photo,
            merged.white,
        )?;
        phases.end(p);
        let (lights, chosen_lights) = captured
            .preparing
            .as_mut()
            .and_then(|p| p.take_lights(view_yaw))
            .unwrap_or_else(|| env.estimate_lights(DEFAULT_LIGHTS, CHOSEN_LIGHTS, view_yaw));
        captured.views.push(CapturedView {
            geometry: pixels,
            lights,
            chosen_lights,
            photo: merged.photo,
        });
    }
    captured.fallback = (fallback_use.views > 0).then(|| fallback_use.describe(s.views));
    Ok(captured)
}

/// The estimate of every view together, with the clip level of their merges (and of each
/// material, when the part holds two); with the exports' renders made while the camera shot,
/// if they were.
fn estimate(
    cx: &Context,
    s: &CaptureSettings,
    basis: &Basis,
    captured: &mut Captured,
    phases: &mut Phases,
) -> Result<(Materials, Option<Prepared>)> {
    let p = phases.start("estimate", 1);
    // A wait for the work started while the camera shot, if it is not done, is the
    // estimate's: the estimate would otherwise do most of it.
    let waited = std::time::Instant::now();
    let ready = captured.preparing.take().map(Preparing::finish);
    if ready.is_some() {
        tracing::debug!(
            "waited {:?} for the renders prepared while the camera shot",
            waited.elapsed()
        );
    }
    let shared = ready.as_ref().map(|r| r.shared.clone()).unwrap_or_default();
    let options = EstimateOptions {
        white: captured.clip_level,
        stop: cx.cancel.stop(),
        ..s.estimate.clone()
    };
    let views: Vec<View> = captured
        .views
        .iter()
        .map(|v| View {
            geometry: &v.geometry,
            lights: &v.lights,
            chosen_lights: v.chosen_lights.as_ref(),
            photo: &v.photo,
        })
        .collect();
    let found = estimate_materials(basis, &views, &options, &shared)?;
    phases.end(p);
    Ok((found, ready.and_then(|r| r.exports)))
}

/// What the report says of the session beside the estimate.
fn report_context<'a>(
    session: &Session,
    env: &'a EnvMap,
    captured: &'a Captured,
    truth: Option<&'a Bivariate>,
    relight: Option<f64>,
) -> ReportContext<'a> {
    let m = &session.manifest();
    let mut report = ReportContext {
        title: format!("session {} ({})", m.id, m.material),
        session: Some(m.id.clone()),
        photo: Some(&captured.views[0].photo),
        env: Some(env),
        yaw: captured.first_yaw,
        relight_error: relight,
        truth,
        fallback: captured.fallback.clone(),
        visibility: None,
        object: None,
        exports: None,
        materials: None,
        record: vec![
            ("session".into(), m.id.clone()),
            ("material".into(), m.material.clone()),
            ("created".into(), m.created.clone()),
            ("views".into(), captured.views.len().to_string()),
            ("devices".into(), m.devices.join("; ")),
            ("software".into(), m.software.clone()),
        ],
    };
    if let Some(text) = &captured.fallback {
        report.record.push(("object camera".into(), text.clone()));
    }
    report
}

/// The estimate in a few judged lines for the operator, the verdict first
/// ([`brdfd_report::summary`]).
fn say_result(
    cx: &Context,
    session: &Session,
    found: &Materials,
    views: usize,
    relight: Option<(f64, String)>,
    (files, parts): (
        &brdfd_report::results::ResultFiles,
        Option<&brdfd_report::materials::Parts>,
    ),
) {
    // Where the results were moved to, not where they were written.
    let report = session.dir.join("result/report.html");
    let extras = brdfd_report::summary::Extras {
        headline: &files.headline,
        relight,
        views,
        bracketed: true,
        export: Some(&files.exports),
        flags: &files.flags,
        report: Some(&report),
        materials: parts.zip(found.split.as_ref().map(|s| s.parts.as_slice())),
    };
    let lines = brdfd_report::summary::lines(&session.manifest().material, &found.whole, &extras);
    if lines[0].contains("do not trust") {
        cx.warn(lines[0].clone());
        cx.say(lines[1..].join("\n"));
    } else {
        cx.say(lines.join("\n"));
    }
}

/// Results go to a fresh folder that replaces `result/` in one rename: with two materials,
/// each material's in its own folder first, then the whole part's, which record the split.
fn write_result(
    session: &Session,
    basis: &Basis,
    found: &Materials,
    lights: &brdfd_core::envmap::LightSet,
    report: ReportContext,
) -> Result<(
    brdfd_report::results::ResultFiles,
    Option<brdfd_report::materials::Parts>,
)> {
    let fresh = session.dir.join("result.partial");
    let _ = std::fs::remove_dir_all(&fresh);
    let (files, parts) =
        brdfd_report::materials::write_all(&fresh, basis, found, "fast", lights, report)?;
    let result = session.dir.join("result");
    let _ = std::fs::remove_dir_all(&result);
    std::fs::rename(&fresh, &result).step("moving the results into place")?;
    Ok((files, parts))
}

/// A step's files from the session (checksums verified), under the names the camera gave
/// them, if the step is complete.
pub fn stored(session: &Session, step: &str) -> Result<Option<(RawFiles, serde_json::Value)>> {
    let Some(s) = session.complete_step(step) else {
        return Ok(None);
    };
    let files = s
        .files
        .iter()
        .map(|f| Ok((f.device_name(s).to_string(), session.read_raw(f)?)))
        .collect::<Result<Vec<_>>>()?;
    Ok(Some((files, s.meta.clone())))
}

/// Writes a merged photo with its white level, so that a later `brdfd estimate` on the file
/// leaves out the pixels the capture left out.
fn save_exr(session: &Session, name: &str, r: &Raster, white: Option<f32>) -> Result<()> {
    // Written beside, then renamed: a derived file is whole or absent.
    let tmp = session.dir.join("derived").join(format!(".{name}.tmp.exr"));
    r.write_exr_with_white(&tmp, white)?;
    std::fs::rename(&tmp, session.dir.join("derived").join(name))?;
    Ok(())
}

pub(super) fn note_device(session: &mut Session, identity: Option<String>) {
    if let Some(id) = identity {
        session.note_device(id);
    }
}
