//! The light probe's part of a capture: its bracket shot on its worker and kept as the camera
//! sent it, each frame's EXIF checked against what was asked. The merge into an environment
//! map is [`brdfd_radiometry::panorama`]'s; the step that strings them together is the flow's.

use brdfd_theta::{BracketPlan, Frame};

use super::error::DeviceError;
use super::flow::{Context, Keep, RawFiles};
use super::roles::LightProbe;
use super::{Event, Progress};
use crate::error::Result;

/// Shoots the light probe's bracket on its worker; the frames are kept as the camera sent
/// them.
pub(crate) fn light_bracket(
    cx: &Context,
    keep: &mut dyn Keep,
    plan: BracketPlan,
) -> Result<RawFiles> {
    let probe = &cx.devices.light_probe;
    // The heading names the camera before the shoot's progress lines: its worker opens it
    // first, with an empty job.
    probe.call(|_| Ok(()))?;
    let status = probe.status();
    cx.say(format!(
        "panorama: {}",
        status.identity.as_deref().unwrap_or(&status.selector)
    ));
    let progress = cx.progress.clone();
    let frames = probe.call(move |probe| shoot_panorama(probe, &plan, progress.as_ref()))?;
    let mut files = Vec::with_capacity(frames.len());
    for f in frames {
        check_exposure(cx.progress.as_ref(), &f);
        keep.keep(&f.name, &f.data)?;
        files.push((f.name, f.data));
    }
    Ok(files)
}

/// Prepares the THETA for light measurement and shoots the plan: the frames as the camera
/// sent them. Progress goes to the "panorama bracket" phase.
pub fn shoot_panorama(
    probe: &mut dyn LightProbe,
    plan: &BracketPlan,
    progress: &dyn Progress,
) -> Result<Vec<Frame>, DeviceError> {
    for line in probe
        .prepare()
        .map_err(|e| e.during("preparing the THETA"))?
    {
        tracing::info!("THETA: {line}");
    }
    let total = plan.shots.len() as u64;
    let mut last = String::new();
    let frames = probe
        .shoot(plan, &mut |phase, fraction| {
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
        .map_err(|e| e.during("shooting the panorama bracket"))?;
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
    match brdfd_radiometry::exif_exposure(&f.data, &f.name) {
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
