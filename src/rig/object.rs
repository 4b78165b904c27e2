//! The object camera: the DSLR, or the V4L2 fallback camera when the rig has no DSLR, the DSLR
//! does not answer, or it fails during a bracket. One view is shot whole on one camera; once
//! the capture has fallen back it stays on the fallback, so that its views share units.
//!
//! The DSLR's files are stored as the camera sent them and merged from their EXIF. The
//! fallback's frames are averaged in linear light per exposure (video frames are many and
//! noisy), and each average is stored as an EXR that records its exposure and noise.

use std::sync::mpsc;

use anyhow::{bail, Context as _};
use brdfd_ptp::{CaptureOptions, Exposure, ImageFormat};
use serde_json::json;

use super::flow::{Context, RawFiles};
use super::Event;
use crate::config::DslrFiles;
use crate::core::envmap::{exr_bytes, read_exr_rgb_bytes, ExrAttribute};
use crate::core::raster::Raster;
use crate::radiometry::raw::{decode_raw, is_raw_name, WhiteBalance};
use crate::radiometry::{
    average_frames, averaging_noise, decode_jpeg, merge_hdr, merged_white_level, Frame,
};
use crate::session::Session;

/// EXR attributes of a fallback exposure: the exposure time the camera applied, seconds; the
/// frames averaged; and their noise (the median relative standard error of the average).
const EXPOSURE_ATTRIBUTE: &str = "brdfdExposureSeconds";
const FRAMES_ATTRIBUTE: &str = "brdfdFramesAveraged";
const NOISE_ATTRIBUTE: &str = "brdfdRelativeNoise";

/// Which camera shot a view; stored in the step's `camera` field.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ObjectCamera {
    Dslr,
    Fallback,
}

impl ObjectCamera {
    fn name(self) -> &'static str {
        match self {
            ObjectCamera::Dslr => "dslr",
            ObjectCamera::Fallback => "fallback",
        }
    }

    /// The camera a stored step names (steps from before the fallback name none: the DSLR).
    pub fn of_step(meta: &serde_json::Value) -> ObjectCamera {
        match meta["camera"].as_str() {
            Some("fallback") => ObjectCamera::Fallback,
            _ => ObjectCamera::Dslr,
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
pub fn choose(cx: &Context) -> anyhow::Result<ObjectCamera> {
    let devices = cx.devices;
    let Some(dslr) = &devices.dslr else {
        cx.say("object camera: the V4L2 fallback (the rig has no DSLR)");
        return Ok(ObjectCamera::Fallback);
    };
    // A request the camera must answer: an open handle alone says nothing of a camera that
    // has gone quiet.
    match dslr.call(super::Device::keep_alive) {
        Ok(()) => Ok(ObjectCamera::Dslr),
        Err(e) => match &devices.fallback {
            Some(f) => {
                cx.warn(format!(
                    "the DSLR does not answer ({e:#}); the capture uses the fallback camera {}",
                    f.status().selector
                ));
                Ok(ObjectCamera::Fallback)
            }
            None => Err(e.context(
                "the DSLR does not answer, and the rig names no fallback_camera to use instead",
            )),
        },
    }
}

/// Shoots one view on `camera`. A DSLR that fails during the bracket is replaced by the
/// fallback, if the rig has one: the view is shot again, whole, and `camera` stays the
/// fallback for the views after it.
pub fn shoot_view(
    cx: &Context,
    session: &mut Session,
    step: &str,
    deg: f64,
    shutters: &[f64],
    camera: &mut ObjectCamera,
) -> anyhow::Result<RawFiles> {
    if *camera == ObjectCamera::Dslr {
        session.begin_step(step, json!({ "turntable_deg": deg, "camera": "dslr" }))?;
        match dslr_bracket(cx, session, step, shutters) {
            Ok(files) => return Ok(files),
            // The session's own failures (a full disk) are not the DSLR's: the fallback would
            // fail the same way.
            Err(e)
                if cx.devices.fallback.is_some()
                    && !cx.cancel.is_cancelled()
                    && !e.chain().any(|c| c.is::<crate::session::SessionError>()) =>
            {
                cx.warn(format!(
                    "the DSLR failed during {step} ({e:#}); {step} is shot again on the fallback camera, and so are the views after it"
                ));
                *camera = ObjectCamera::Fallback;
            }
            Err(e) => return Err(e),
        }
    }
    session.begin_step(
        step,
        json!({ "turntable_deg": deg, "camera": camera.name() }),
    )?;
    fallback_bracket(cx, session, step)
}

/// Shoots the DSLR bracket on the DSLR's worker. Each file goes into the session as soon
/// as it is downloaded, so that a failure later in the bracket loses nothing already taken.
fn dslr_bracket(
    cx: &Context,
    session: &mut Session,
    step: &str,
    shutters: &[f64],
) -> anyhow::Result<RawFiles> {
    let dslr = cx.devices.dslr.as_ref().context("the rig has no DSLR")?;
    let b = cx.rig.brackets.clone();
    let (tx, rx) = mpsc::channel::<(String, Vec<u8>, f64, bool)>();
    let (progress, cancel) = (cx.progress.clone(), cx.cancel.clone());
    let total = shutters.len() as u64;
    let shutters = shutters.to_vec();
    let download = format!("{step}: download");
    let job = dslr.submit(move |cam| {
        let applied = cam.set_exposure(&Exposure {
            shutter_s: None,
            f_number: Some(b.dslr_f_number),
            iso: Some(b.dslr_iso),
        })?;
        progress.event(Event::Message {
            text: format!(
                "DSLR: {} ({}), f/{} ISO {}",
                cam.describe(),
                cam.info.serial_number,
                applied.f_number.unwrap_or(0.0),
                applied.iso.unwrap_or(0)
            ),
        });
        set_files(cam, b.dslr_files, progress.as_ref())?;
        let opts = CaptureOptions::default();
        for &s in &shutters {
            cancel.check()?;
            let speed = cam.set_shutter(s)?;
            let mut last = u64::MAX;
            let files = cam.capture_all(&opts, &mut |_, done, total| {
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
            })?;
            let shot_files = files.len();
            for (i, f) in files.into_iter().enumerate() {
                if tx
                    .send((f.info.filename, f.data, speed, i + 1 == shot_files))
                    .is_err()
                {
                    bail!("the capture stopped taking files");
                }
            }
        }
        Ok(())
    });
    let mut files = Arriving::new(cx, step, total);
    for (name, data, speed, shot_done) in rx {
        let said = format!("  {name}: {} bytes (camera applied {speed} s)", data.len());
        files.keep(session, name, data, said, shot_done)?;
    }
    job.wait()?;
    super::flow::note_device(session, dslr.status().identity);
    Ok(files.files)
}

/// Sets the DSLR to make the files the rig asks for. A camera that cannot be set so keeps
/// shooting as set on its body, and the merge takes what comes: RAW files if any, JPEGs
/// otherwise. Either way the operator is told.
fn set_files(
    cam: &mut brdfd_ptp::Camera,
    want: DslrFiles,
    progress: &dyn super::Progress,
) -> anyhow::Result<()> {
    use brdfd_ptp::{codes::rc, PtpError};
    let format = match want {
        DslrFiles::RawJpeg => ImageFormat::RawJpeg,
        DslrFiles::Raw => ImageFormat::Raw,
        DslrFiles::Jpeg => ImageFormat::Jpeg,
    };
    let say = |text: String| progress.event(Event::Message { text });
    match cam.set_format(format) {
        Ok(applied) if applied == format => {}
        Ok(applied) => say(format!(
            "DSLR: asked for {format:?} files, the camera applied {applied:?}"
        )),
        Err(PtpError::Unsupported(what)) => say(format!(
            "DSLR: {what} is not offered; it shoots as set on its body (the merge uses its RAW files if any, else its JPEGs, their tone curve taken as sRGB)"
        )),
        Err(PtpError::Response {
            code: rc::DEVICE_PROP_NOT_SUPPORTED,
            ..
        }) => say(
            "DSLR: it has no image-quality property; it shoots as set on its body".to_string(),
        ),
        Err(e) => return Err(e.into()),
    }
    Ok(())
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
        session: &mut Session,
        name: String,
        bytes: Vec<u8>,
        said: String,
        shot_done: bool,
    ) -> anyhow::Result<()> {
        session.add_raw(self.step, &name, &bytes)?;
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

/// One exposure of the fallback's bracket, as grabbed: the time asked and applied, and the
/// decoded frames.
type Grabbed = (f64, f64, Vec<brdfd_v4l::Rgb8Frame>);

/// Shoots the fallback's bracket on its worker: per exposure, the frames are averaged in
/// linear light and the average stored in the session (an EXR with its exposure).
fn fallback_bracket(cx: &Context, session: &mut Session, step: &str) -> anyhow::Result<RawFiles> {
    let camera = cx
        .devices
        .fallback
        .as_ref()
        .context("the rig names no fallback_camera")?;
    let b = cx.rig.brackets.clone();
    let shutters = b.fallback_shutters.clone();
    let total = shutters.len() as u64;
    let (tx, rx) = mpsc::channel::<Grabbed>();
    let (progress, cancel) = (cx.progress.clone(), cx.cancel.clone());
    let job = camera.submit(move |cam| {
        let src = cam.0.as_mut();
        let (format, w, h) = brdfd_v4l::start(src)?;
        progress.event(Event::Message {
            text: format!(
                "fallback camera: {}, {format:?} {w}×{h}, {} frames per exposure",
                src.describe(),
                b.fallback_frames
            ),
        });
        for &t in &shutters {
            cancel.check()?;
            let settings = brdfd_v4l::Settings {
                exposure_s: Some(t),
                gain: b.fallback_gain,
                white_balance_k: Some(b.fallback_white_balance_k),
            };
            let (applied, frames) = brdfd_v4l::grab(src, &settings, b.fallback_frames)?;
            // Without a manual exposure time the camera stays on auto exposure, and no
            // frame's exposure is known: there is no bracket to merge.
            let Some(applied_s) = applied.exposure_s else {
                bail!(
                    "the fallback camera {} has no manual exposure control ({}), so it cannot shoot a bracket",
                    src.describe(),
                    applied.notes.join(", ")
                );
            };
            if tx.send((t, applied_s, frames)).is_err() {
                bail!("the capture stopped taking frames");
            }
        }
        Ok(())
    });
    let mut files = Arriving::new(cx, step, total);
    for (asked, applied, frames) in rx {
        let exposure = crate::radiometry::Exposure {
            shutter_s: applied,
            f_number: 1.0,
            iso: 100.0,
        };
        let name = format!("fallback-{}.exr", files.files.len() + 1);
        let average = average_frames(&frames, exposure, &name)?;
        let noise = averaging_noise(&frames);
        let v = &average.values;
        let mut attributes = vec![
            (EXPOSURE_ATTRIBUTE, ExrAttribute::F32(applied as f32)),
            (FRAMES_ATTRIBUTE, ExrAttribute::F32(frames.len() as f32)),
        ];
        if let Some(n) = noise {
            attributes.push((NOISE_ATTRIBUTE, ExrAttribute::F32(n)));
        }
        let bytes = exr_bytes(v.width, v.height, &v.pixels, &attributes)?;
        let said = format!(
            "  {name}: {} frames averaged at {applied} s (asked {asked} s){}",
            frames.len(),
            noise.map_or(String::new(), |n| format!(", noise {:.2}%", n * 100.0))
        );
        files.keep(session, name, bytes, said, true)?;
    }
    job.wait()?;
    super::flow::note_device(session, camera.status().identity);
    Ok(files.files)
}

/// A view's bracket merged into radiance in the DSLR's units.
pub struct Merged {
    pub photo: Raster,
    /// The level at and above which the merge had only clipped frames.
    pub white: Option<f32>,
    /// The fallback's frames averaged per exposure and their noise, if it shot the view.
    pub fallback: Option<(usize, Option<f32>)>,
    /// Merged from RAW files, whose demosaic mixes the background into the object's outline.
    pub demosaiced: bool,
}

/// Merges a view's bracket, as the camera that shot it needs.
pub fn merge_view(cx: &Context, camera: ObjectCamera, files: &RawFiles) -> anyhow::Result<Merged> {
    match camera {
        ObjectCamera::Dslr => {
            let (photo, white, demosaiced) = merge_dslr(cx, files)?;
            Ok(Merged {
                photo,
                white,
                fallback: None,
                demosaiced,
            })
        }
        ObjectCamera::Fallback => {
            let bracket = FallbackBracket::read(files)?;
            // Values per second of exposure, then the THETA's calibrations put them in the
            // DSLR's units: the fallback's per THETA radiance, the DSLR's per THETA radiance.
            let c = &cx.rig.calibration;
            let to_fallback = c
                .theta_to_fallback
                .context("calibration.theta_to_fallback is needed to use the fallback camera")?;
            let scale = (c.theta_to_dslr / to_fallback) as f32;
            let mut photo = merge_hdr(&bracket.frames, 1.0)?;
            for p in &mut photo.pixels {
                *p = p.map(|v| v * scale);
            }
            Ok(Merged {
                photo,
                white: merged_white_level(&bracket.frames, 1.0).map(|w| w * scale),
                fallback: Some((bracket.averaged, bracket.noise)),
                demosaiced: false,
            })
        }
    }
}

/// A fallback bracket as stored: its averages, the frames each averaged, and the median of
/// their recorded noise.
struct FallbackBracket {
    frames: Vec<Frame>,
    averaged: usize,
    noise: Option<f32>,
}

impl FallbackBracket {
    fn read(files: &RawFiles) -> anyhow::Result<FallbackBracket> {
        let (mut noise, mut averaged) = (Vec::new(), 0);
        let frames = files
            .iter()
            .map(|(name, bytes)| {
                let (rgb, attributes) = read_exr_rgb_bytes(bytes, name)?;
                let shutter_s = attributes
                    .get(EXPOSURE_ATTRIBUTE)
                    .copied()
                    .filter(|t| t.is_finite() && *t > 0.0)
                    .with_context(|| {
                        format!("{name}: no exposure time ({EXPOSURE_ATTRIBUTE}) in its header")
                    })?;
                noise.extend(attributes.get(NOISE_ATTRIBUTE).copied());
                averaged = attributes
                    .get(FRAMES_ATTRIBUTE)
                    .map_or(averaged, |n| *n as usize);
                Ok(Frame {
                    values: Raster {
                        width: rgb.width,
                        height: rgb.height,
                        pixels: rgb.pixels,
                    },
                    exposure: crate::radiometry::Exposure {
                        shutter_s: shutter_s as f64,
                        f_number: 1.0,
                        iso: 100.0,
                    },
                    white_balance: [1.0; 3],
                })
            })
            .collect::<anyhow::Result<Vec<_>>>()?;
        noise.sort_by(f32::total_cmp);
        Ok(FallbackBracket {
            frames,
            averaged,
            noise: noise.get(noise.len() / 2).copied(),
        })
    }
}

/// Decodes a DSLR bracket and merges it into radiance, from each file's own exposure. Also
/// returns the level at and above which the merge had only clipped frames, and whether the
/// merge was of RAW files.
///
/// RAW files are preferred: they are linear. If the bracket has none, or they cannot be
/// decoded and there are JPEGs beside them, the JPEGs are merged, their tone curve taken as
/// sRGB (a camera's own curve differs, which the estimate then absorbs).
fn merge_dslr(cx: &Context, files: &RawFiles) -> anyhow::Result<(Raster, Option<f32>, bool)> {
    use crate::bench::camera::SENSOR_GAIN;
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
            Ok(frames) => {
                return Ok((
                    merge_hdr(&frames, SENSOR_GAIN)?,
                    merged_white_level(&frames, SENSOR_GAIN),
                    true,
                ))
            }
            Err(e) if !jpeg.is_empty() => cx.warn(format!(
                "the RAW files cannot be merged ({e:#}); merging the JPEG files instead, their tone curve taken as sRGB"
            )),
            Err(e) => return Err(e),
        }
    }
    let frames = jpeg
        .iter()
        .map(|(name, bytes)| {
            let f = decode_jpeg(bytes, name)?;
            cx.say(format!(
                "  {name}: JPEG, EXIF {:.4} s f/{} ISO {}",
                f.exposure.shutter_s, f.exposure.f_number, f.exposure.iso
            ));
            Ok(f)
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    Ok((
        merge_hdr(&frames, SENSOR_GAIN)?,
        merged_white_level(&frames, SENSOR_GAIN),
        false,
    ))
}

/// The RAW files of a bracket decoded, with the rig's fixed white balance if it has one.
fn decode_raw_bracket(cx: &Context, files: &[&(String, Vec<u8>)]) -> anyhow::Result<Vec<Frame>> {
    let wb = match cx.rig.calibration.raw_white_balance {
        Some(m) => WhiteBalance::Fixed(m),
        None => WhiteBalance::AsShot,
    };
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
