//! Turning the object between views: by the rig's turntable, or by the operator's hand on a
//! rig without one; and the scene as the camera then sees it (the object turned is the camera
//! and the light turned the other way, in the object's frame).

use super::flow::{note_device, Context};
use super::settings::{CaptureSettings, Turning};
use super::Event;
use crate::error::{Result, StepExt};
use crate::session::Session;
use brdfd_core::geometry::SceneGeometry;

/// Turns the object for view `i` (from 0), as the rig turns it; where it stands.
pub fn turn(cx: &Context, session: &mut Session, s: &CaptureSettings, i: usize) -> Result<f64> {
    match s.turning {
        Turning::None => Ok(0.0),
        Turning::Turntable => turn_on_turntable(cx, session, i, s.views, i as f64 * s.turn_step),
        Turning::ByHand => turn_by_hand(cx, i, s.views, s.turn_step),
    }
}

/// The scene as the camera sees it with the turntable at `deg`: in the object's frame, the
/// camera and the light turned by −θ (Camera::turned_about_y).
pub fn turned(scene: &SceneGeometry, yaw: f64, deg: f64) -> (SceneGeometry, f64) {
    let theta = deg.to_radians();
    let mut g = scene.clone();
    g.camera = scene.camera.turned_about_y(-theta);
    (g, yaw - theta)
}

/// Turns the turntable for view `i` (from 0) of `n`, to `target` degrees; where it stopped.
fn turn_on_turntable(
    cx: &Context,
    session: &mut Session,
    i: usize,
    n: usize,
    target: f64,
) -> Result<f64> {
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
fn turn_by_hand(cx: &Context, i: usize, n: usize, step: f64) -> Result<f64> {
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
pub(crate) fn turn_to(cx: &Context, target: f64) -> Result<f64> {
    let table = cx.devices.turntable.as_ref().step("no turntable")?;
    let turned = table.call(move |t| {
        let here = t.position()?;
        let turn = (target - here + 180.0).rem_euclid(360.0) - 180.0;
        Ok(if turn.abs() > 1e-9 {
            t.rotate(turn)?
        } else {
            here
        })
    })?;
    Ok(turned)
}
