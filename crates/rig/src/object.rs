//! The object camera's views: shot on the DSLR, or on the V4L2 fallback camera when the rig has
//! no DSLR, the DSLR does not answer, or it fails during a bracket; then merged into radiance
//! in the bench's unit, through the camera's gain from the rig's calibration. One view is shot
//! whole on one camera; once the capture has fallen back it stays on the fallback, so that
//! its views share units.
//!
//! The DSLR's files are stored as the camera sent them and merged from their EXIF. The
//! fallback's frames are averaged in linear light per exposure (video frames are many and
//! noisy), and each average is stored as an EXR that records its exposure and noise.

use std::sync::mpsc;

use serde_json::json;

use super::error::{chain, said, DeviceError};
use super::flow::{note_device, Context, Keep, RawFiles, Step};
use super::roles::{ObjectCamera, Output, Role};
use super::settings::Bracket;
use super::Event;
use crate::config::{Calibration, CameraGain};
use crate::error::{Result, RigError, StepExt};
use crate::session::Session;
use brdfd_core::raster::Raster;
use brdfd_radiometry::averaged::averaged_exr;
pub use brdfd_radiometry::averaged::FallbackBracket;
use brdfd_radiometry::raw::{decode_raw, is_raw_name, WhiteBalance};
use brdfd_radiometry::{decode_jpeg, merge_hdr, merged_white_level, with_gain, Frame};

/// How long the rig's shutter holds the DSLR's release. The camera exposes for the time it
/// was set to (never bulb), so the press only has to be one the camera sees: remote sockets
/// need some tens of milliseconds.
pub const SHUTTER_PRESS: std::time::Duration = std::time::Duration::from_millis(200);

/// Which of the rig's object cameras shot a view; stored in the step's `camera` field.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CameraRole {
    Dslr,
    Fallback,
}

impl CameraRole {
    fn name(self) -> &'static str {
        match self {
            CameraRole::Dslr => "dslr",
            CameraRole::Fallback => "fallback",
        }
    }

    /// The camera a stored step names (steps from before the fallback name none: the DSLR).
    pub(crate) fn of_step(meta: &serde_json::Value) -> CameraRole {
        match meta["camera"].as_str() {
            Some("fallback") => CameraRole::Fallback,
            _ => CameraRole::Dslr,
        }
    }
}

/// What the fallback cost, for the summary and the report.
#[derive(Debug, Clone, Default)]
pub struct FallbackUse {
    pub views: usize,
    pub identity: Option<String>,
    pub frames: usize,
    /// Each view's median relative noise of its averaged frames.
    pub noise: Vec<f32>,
}

impl FallbackUse {
    /// Adds a view the fallback shot: its frames averaged per exposure, and their noise.
    pub fn add(&mut self, frames: usize, noise: Option<f32>, identity: Option<String>) {
        self.views += 1;
        self.frames = frames;
        self.noise.extend(noise);
        self.identity = identity.or(self.identity.take());
    }

    pub fn describe(&self, of_views: usize) -> String {
        let mean = (!self.noise.is_empty())
            .then(|| self.noise.iter().sum::<f32>() / self.noise.len() as f32);
        let noise = match mean {
            Some(n) => format!(
                "; noise of the averaged frames {:.2}% (one frame alone: {:.2}%)",
                n * 100.0,
                n * 100.0 * (self.frames.max(1) as f32).sqrt()
            ),
            None => String::new(),
        };
        format!(
            "the V4L2 fallback camera ({}) shot {} of {of_views} view{}, {} frames averaged per exposure{noise}",
            self.identity.as_deref().unwrap_or("unknown"),
            self.views,
            if of_views == 1 { "" } else { "s" },
            self.frames,
        )
    }
}

/// The camera the capture starts on: the DSLR if the rig has one and it answers, else the
/// fallback. Neither is an error that says what was tried.
pub fn choose(cx: &Context) -> Result<CameraRole> {
    let devices = cx.devices;
    let Some(dslr) = &devices.dslr else {
        cx.say("object camera: the V4L2 fallback (the rig has no DSLR)");
        return Ok(CameraRole::Fallback);
    };
    match dslr.ping() {
        // A shutter that cannot fire is found before the first shot, and is its own fault:
        // the DSLR answers, so the capture does not hand over to the fallback.
        Ok(()) => match &devices.shutter {
            Some(s) => match s.call(|_| Ok(())) {
                Ok(()) => Ok(CameraRole::Dslr),
                Err(e) => Err(DeviceError::ShutterFailed {
                    selector: s.status().selector,
                    cause: Box::new(e),
                }
                .into()),
            },
            None => Ok(CameraRole::Dslr),
        },
        Err(e) => match &devices.fallback {
            Some(f) => {
                cx.warn(format!(
                    "the DSLR does not answer ({}); the capture uses the fallback camera {}",
                    said(&e),
                    f.status().selector
                ));
                Ok(CameraRole::Fallback)
            }
            None => Err(RigError::from(e).step(
                "the DSLR does not answer, and the rig names no fallback_camera to use instead",
            )),
        },
    }
}

/// Shoots one view on `camera`. A DSLR that fails during the bracket is replaced by the
/// fallback, if the rig has one: the view is shot again, whole, and `camera` stays the
/// fallback for the views after it.
pub(crate) fn shoot_view(
    cx: &Context,
    session: &mut Session,
    step: &str,
    deg: f64,
    brackets: (&Bracket, &Bracket),
    camera: &mut CameraRole,
) -> Result<RawFiles> {
    let (dslr_bracket, fallback_bracket) = brackets;
    if *camera == CameraRole::Dslr {
        session.begin_step(step, json!({ "turntable_deg": deg, "camera": "dslr" }))?;
        let dslr = cx.devices.dslr.as_ref().step("the rig has no DSLR")?;
        let mut keep = Step {
            session,
            name: step,
        };
        match bracket(cx, &mut keep, step, dslr, dslr_bracket, true) {
            Ok(files) => {
                note_device(session, dslr.status().identity);
                return Ok(files);
            }
            Err(e) if !the_dslrs_fault(cx, &e) => return Err(e),
            Err(e) if cx.devices.fallback.is_some() => {
                cx.warn(format!(
                    "the DSLR failed during {step} ({}); {step} is shot again on the fallback camera, and so are the views after it",
                    said(&e)
                ));
                *camera = CameraRole::Fallback;
            }
            Err(e) => {
                return Err(e.step(format!(
                    "the DSLR failed during {step}, and the rig names no fallback_camera to shoot it on instead"
                )))
            }
        }
    }
    session.begin_step(
        step,
        json!({ "turntable_deg": deg, "camera": camera.name() }),
    )?;
    let fallback = cx
        .devices
        .fallback
        .as_ref()
        .step("the rig names no fallback_camera")?;
    let mut keep = Step {
        session,
        name: step,
    };
    let files = bracket(cx, &mut keep, step, fallback, fallback_bracket, false)?;
    note_device(session, fallback.status().identity);
    Ok(files)
}

/// Whether a bracket's failure is the DSLR's, which the fallback camera can make good: not a
/// cancel, not the session's own (a full disk: the fallback would fail the same way), not the
/// rig's shutter (the DSLR is there and would shoot if fired).
pub(super) fn the_dslrs_fault(cx: &Context, e: &RigError) -> bool {
    !cx.cancel.is_cancelled()
        && !chain(e).any(|c| {
            c.is::<crate::session::SessionError>()
                || matches!(
                    c.downcast_ref::<DeviceError>(),
                    Some(DeviceError::ShutterFailed { .. })
                )
        })
}

/// One exposure as it came from the camera's worker.
enum Arrived {
    File {
        name: String,
        bytes: Vec<u8>,
        applied_s: f64,
        last_of_shot: bool,
    },
    Frames {
        asked_s: f64,
        applied_s: f64,
        frames: Vec<brdfd_v4l::Rgb8Frame>,
    },
}

/// Shoots a bracket on an object camera's worker, labelled `step` in its progress. Each file
/// is kept as soon as it is in. The DSLR (`fires`) is fired by the rig's shutter when the rig
/// has one.
pub fn bracket(
    cx: &Context,
    keep: &mut dyn Keep,
    step: &str,
    camera: &Role<dyn ObjectCamera>,
    bracket: &Bracket,
    fires: bool,
) -> Result<RawFiles> {
    let (tx, rx) = mpsc::channel::<Arrived>();
    let (progress, cancel) = (cx.progress.clone(), cx.cancel.clone());
    let shutter = cx.devices.shutter.clone().filter(|_| fires);
    let exposures = bracket.exposures_s.clone();
    let settings = bracket.camera.clone();
    let total = exposures.len() as u64;
    let download = format!("{step}: download");
    let job = camera.submit(move |cam| {
        for line in cam.prepare(&settings)? {
            progress.event(Event::Message { text: line });
        }
        if let Some(s) = &shutter {
            progress.event(Event::Message {
                text: format!(
                    "DSLR: fired by the shutter {}",
                    s.status().identity.unwrap_or(s.status().selector)
                ),
            });
        }
        for &t in &exposures {
            if cancel.is_cancelled() {
                return Err(DeviceError::Cancelled);
            }
            let mut last = u64::MAX;
            let mut bytes = |done: u64, total: u64| {
                // One event per tenth: enough for a bar, few enough for a stream.
                let tenth = (done * 10).checked_div(total).unwrap_or(0);
                if tenth != last {
                    last = tenth;
                    progress.event(Event::Progress {
                        phase: download.clone(),
                        done,
                        total,
                    });
                }
            };
            let exposed = match &shutter {
                Some(s) => {
                    // The shutter's own failure, kept whole: the camera's driver sees only
                    // that the press failed.
                    let mut failed = None;
                    let mut fire = || {
                        s.call(|s| s.fire(SHUTTER_PRESS)).map_err(|e| {
                            let words = DeviceError::Cannot(said(&e));
                            failed = Some(e);
                            words
                        })
                    };
                    let exposed = cam.expose_fired_by(t, &mut fire, &mut bytes);
                    if let Some(e) = failed {
                        return Err(DeviceError::ShutterFailed {
                            selector: s.status().selector,
                            cause: Box::new(e),
                        });
                    }
                    exposed.unwrap_or_else(|| {
                        Err(DeviceError::Cannot(
                            "the object camera cannot be fired by the rig's shutter".into(),
                        ))
                    })?
                }
                None => cam.expose(t, &mut bytes)?,
            };
            let sent = match exposed.output {
                Output::Files(files) => {
                    let n = files.len();
                    files.into_iter().enumerate().all(|(i, (name, bytes))| {
                        tx.send(Arrived::File {
                            name,
                            bytes,
                            applied_s: exposed.applied_s,
                            last_of_shot: i + 1 == n,
                        })
                        .is_ok()
                    })
                }
                Output::Frames(frames) => tx
                    .send(Arrived::Frames {
                        asked_s: t,
                        applied_s: exposed.applied_s,
                        frames,
                    })
                    .is_ok(),
            };
            if !sent {
                return Err(DeviceError::Abandoned);
            }
        }
        Ok(())
    });
    let mut files = Arriving::new(cx, step, total);
    for arrived in rx {
        match arrived {
            Arrived::File {
                name,
                bytes,
                applied_s,
                last_of_shot,
            } => {
                let said = format!(
                    "  {name}: {} bytes (camera applied {} s)",
                    bytes.len(),
                    four_digits(applied_s)
                );
                files.keep(keep, name, bytes, said, last_of_shot)?;
            }
            Arrived::Frames {
                asked_s,
                applied_s,
                frames,
            } => {
                let name = format!("fallback-{}.exr", files.files.len() + 1);
                let (bytes, noise) = averaged_exr(&frames, applied_s, &name)?;
                let said = format!(
                    "  {name}: {} frames averaged at {applied_s} s (asked {asked_s} s){}",
                    frames.len(),
                    noise.map_or(String::new(), |n| format!(", noise {:.2}%", n * 100.0))
                );
                files.keep(keep, name, bytes, said, true)?;
            }
        }
    }
    job.wait()?;
    Ok(files.files)
}

/// A bracket's files as they arrive: each stored in the session at once, said, and counted
/// on the step's bar (by shot: a RAW + JPEG shot is two files).
struct Arriving<'a> {
    cx: &'a Context<'a>,
    step: &'a str,
    total: u64,
    shots: u64,
    files: RawFiles,
}

impl<'a> Arriving<'a> {
    fn new(cx: &'a Context<'a>, step: &'a str, total: u64) -> Self {
        Arriving {
            cx,
            step,
            total,
            shots: 0,
            files: Vec::with_capacity(total as usize),
        }
    }

    /// Keeps one file; `shot_done` when it is its shot's last.
    fn keep(
        &mut self,
        to: &mut dyn Keep,
        name: String,
        bytes: Vec<u8>,
        said: String,
        shot_done: bool,
    ) -> Result<()> {
        to.keep(&name, &bytes)?;
        self.cx.say(said);
        self.files.push((name, bytes));
        if shot_done {
            self.shots += 1;
            self.cx.progress.event(Event::Progress {
                phase: format!("{}: object bracket", self.step),
                done: self.shots,
                total: self.total,
            });
        }
        Ok(())
    }
}

/// A view's bracket merged into radiance in the bench's unit.
pub struct Merged {
    pub photo: Raster,
    /// The level at and above which the merge had only clipped frames.
    pub white: Option<f32>,
    /// The fallback's frames averaged per exposure and their noise, if it shot the view.
    pub fallback: Option<(usize, Option<f32>)>,
    /// Merged from RAW files, whose demosaic mixes the background into the object's outline.
    pub demosaiced: bool,
}

/// A camera's gain from the rig's calibration, or the field to measure.
fn gain(g: &Option<CameraGain>, field: &str) -> Result<[f64; 3]> {
    g.as_ref().map(|g| g.gain.0).with_step(|| {
        format!("{field}.gain is not in the rig's calibration: `brdfd calibrate radiometry` measures it")
    })
}

/// Merges frames through a camera's gain: radiance in the bench's unit, and the level at and
/// above which only clipped frames were there.
fn merge_with_gain(mut frames: Vec<Frame>, gain: [f64; 3]) -> Result<(Raster, Option<f32>)> {
    with_gain(&mut frames, gain);
    Ok((merge_hdr(&frames, 1.0)?, merged_white_level(&frames, 1.0)))
}

/// Merges a view's bracket, as the camera that shot it needs.
pub(crate) fn merge_view(cx: &Context, camera: CameraRole, files: &RawFiles) -> Result<Merged> {
    let c = &cx.rig.calibration;
    match camera {
        CameraRole::Dslr => {
            let frames = dslr_frames(cx, files)?;
            let ((photo, white), demosaiced) = match frames {
                DslrFrames::Raw(f) => (
                    merge_with_gain(f, gain(&c.dslr_raw, "calibration.dslr_raw")?)?,
                    true,
                ),
                DslrFrames::Jpeg(f) => (
                    merge_with_gain(f, gain(&c.dslr_jpeg, "calibration.dslr_jpeg")?)?,
                    false,
                ),
            };
            Ok(Merged {
                photo,
                white,
                fallback: None,
                demosaiced,
            })
        }
        CameraRole::Fallback => {
            let bracket = FallbackBracket::read(files)?;
            let (photo, white) =
                merge_with_gain(bracket.frames, gain(&c.fallback, "calibration.fallback")?)?;
            Ok(Merged {
                photo,
                white,
                fallback: Some((bracket.averaged, bracket.noise)),
                demosaiced: false,
            })
        }
    }
}

/// A DSLR bracket decoded: its RAW files if it can be merged from them, else its JPEGs.
pub enum DslrFrames {
    Raw(Vec<Frame>),
    Jpeg(Vec<Frame>),
}

/// Decodes a DSLR bracket, each frame with its own exposure.
///
/// RAW files are preferred: they are linear. If the bracket has none, or they cannot be
/// decoded and there are JPEGs beside them, the JPEGs are used, their tone curve taken as
/// sRGB (a camera's own curve differs, which the estimate then absorbs).
pub(crate) fn dslr_frames(cx: &Context, files: &RawFiles) -> Result<DslrFrames> {
    let (raw, jpeg): (Vec<_>, Vec<_>) = files.iter().partition(|(name, _)| is_raw_name(name));
    // A RAW file missing from some shots would merge fewer exposures than were shot.
    let whole = jpeg.is_empty() || raw.len() == jpeg.len();
    if !raw.is_empty() && !whole {
        cx.warn(format!(
            "the bracket has {} RAW files for {} JPEGs; merging the JPEGs, their tone curve taken as sRGB",
            raw.len(),
            jpeg.len()
        ));
    }
    if !raw.is_empty() && whole {
        match decode_raw_bracket(cx, &raw) {
            Ok(frames) => return Ok(DslrFrames::Raw(frames)),
            Err(e) if !jpeg.is_empty() => cx.warn(format!(
                "the RAW files cannot be merged ({}); merging the JPEG files instead, their tone curve taken as sRGB",
                said(&e)
            )),
            Err(e) => return Err(e),
        }
    }
    decode_jpeg_bracket(cx, &jpeg).map(DslrFrames::Jpeg)
}

/// The JPEG files of a bracket decoded, each said with its EXIF exposure.
pub(crate) fn decode_jpeg_bracket(cx: &Context, jpeg: &[&(String, Vec<u8>)]) -> Result<Vec<Frame>> {
    jpeg.iter()
        .map(|(name, bytes)| {
            let f = decode_jpeg(bytes, name)?;
            cx.say(format!(
                "  {name}: JPEG, EXIF {:.4} s f/{} ISO {}",
                f.exposure.shutter_s, f.exposure.f_number, f.exposure.iso
            ));
            Ok(f)
        })
        .collect()
}

/// The RAW files of a bracket decoded, with the rig's fixed white balance if it has one.
pub(crate) fn decode_raw_bracket(cx: &Context, files: &[&(String, Vec<u8>)]) -> Result<Vec<Frame>> {
    let wb = raw_white_balance(&cx.rig.calibration);
    files
        .iter()
        .map(|(name, bytes)| {
            let f = decode_raw(bytes, name, wb)?;
            let [r, _, b] = f.white_balance;
            cx.say(format!(
                "  {name}: RAW {}×{}, EXIF {:.4} s f/{} ISO {}, white balance red ×{r:.3} blue ×{b:.3}",
                f.values.width, f.values.height,
                f.exposure.shutter_s, f.exposure.f_number, f.exposure.iso
            ));
            Ok(f)
        })
        .collect()
}

fn raw_white_balance(c: &Calibration) -> WhiteBalance {
    match c.raw_white_balance {
        Some(m) => WhiteBalance::Fixed(m),
        None => WhiteBalance::AsShot,
    }
}

/// A shutter speed to four significant digits, without trailing zeros: a Canon's 1/60 s reads
/// 0.01667, a Nikon's 0.0166 as it is.
fn four_digits(seconds: f64) -> String {
    if !(seconds.is_finite() && seconds > 0.0) {
        return seconds.to_string();
    }
    let decimals = (3 - seconds.log10().floor() as i32).max(0) as usize;
    let text = format!("{seconds:.decimals$}");
    match text.contains('.') {
        true => text.trim_end_matches('0').trim_end_matches('.').to_string(),
        false => text,
    }
}
