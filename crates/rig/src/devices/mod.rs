//! The rig's devices, each on its worker, and the roles they fill: the object camera (the
//! DSLR), the fallback object camera, the light probe, the turntable and the shutter. A
//! device that plays two roles (a box that turns and fires) is one worker behind both.
//!
//! The role traits are implemented here for each kind of device: [`ptp`] (a DSLR), [`theta`]
//! (a THETA on HTTP or USB), [`video`] (a V4L2 camera), [`serial`] (a rig-protocol box, a
//! release cable) and, with the `gphoto2` feature, `gphoto` (any camera libgphoto2 drives).

#[cfg(feature = "gphoto2")]
pub mod gphoto;
pub mod ptp;
pub mod serial;
pub mod theta;
pub mod video;

use std::sync::Arc;
use std::time::Duration;

use super::error::DeviceError;
use super::plan;
use super::roles::{
    self, DeviceWorker, LightProbe, ObjectCamera, RigDevice, Role, Shutter, Turntable,
};
use super::simulation::{self, SimulatedRig};
use super::worker::{DeviceStatus, Opener, Worker};
use crate::config::Rig;
use crate::error::{Result, StepExt};
use crate::selector::Selector;

/// A device to start: the rig fields whose roles it plays, the selector it is shown by, and
/// how it is opened (again after it is lost).
pub struct Planned {
    pub fields: Vec<&'static str>,
    pub selector: String,
    pub open: Opener<Box<dyn RigDevice>>,
}

impl Planned {
    /// The device a selector names, opened as `field`'s role needs it. `loopback`: a
    /// simulator on this machine, whose THETA is polled faster than a real one.
    pub fn from_selector(field: &'static str, s: Selector, loopback: bool) -> Planned {
        let selector = s.to_string();
        let open: Opener<Box<dyn RigDevice>> =
            Box::new(move || -> Result<Box<dyn RigDevice>, DeviceError> {
                Ok(match (field, &s) {
                    (plan::THETA, _) => {
                        let timeouts = if loopback {
                            super::open::loopback_timeouts()
                        } else {
                            brdfd_theta::HttpTimeouts::default()
                        };
                        Box::new(super::open::theta(&s, None, timeouts)?)
                    }
                    (_, Selector::Usb { .. } | Selector::PtpIp(_)) => {
                        Box::new(super::open::ptp_camera(&s)?)
                    }
                    (_, Selector::V4l(_)) => Box::new(super::open::video_camera(&s)?),
                    (_, Selector::Serial(path)) => Box::new(super::open::turntable(path)?),
                    (_, Selector::Grbl { axis, path }) => Box::new(super::open::grbl(path, *axis)?),
                    (_, Selector::Cable { rts, path }) => Box::new(super::open::cable(*rts, path)?),
                    (_, Selector::Gphoto(port)) => super::open::gphoto_camera(port.as_deref())?,
                    (_, Selector::Osc(_)) => {
                        return Err(DeviceError::WrongSelector(format!(
                            "{s} is a THETA, not a {field}"
                        )))
                    }
                })
            });
        Planned {
            fields: vec![field],
            selector,
            open,
        }
    }
}

/// The rig's devices in their roles. The object camera is the DSLR, or the V4L2 fallback
/// camera when the rig has no DSLR or it does not answer.
pub struct Devices {
    pub dslr: Option<Role<dyn ObjectCamera>>,
    pub fallback: Option<Role<dyn ObjectCamera>>,
    pub light_probe: Role<dyn LightProbe>,
    pub turntable: Option<Role<dyn Turntable>>,
    pub shutter: Option<Role<dyn Shutter>>,
    /// Every device once, in the rig's order, for the device list.
    workers: Vec<Arc<DeviceWorker>>,
    /// The simulators behind the workers when the rig is simulated (they stop when this is
    /// dropped, after the workers).
    pub sim: Option<Box<dyn SimulatedRig>>,
}

impl Devices {
    /// Starts a worker per device the rig names; each opens its device in the background.
    /// A simulated rig starts its simulators first, on loopback. The rig's devices are
    /// checked first ([`plan::devices`]), so a rig that `config check` refuses never starts.
    pub fn start(rig: &Rig, keep_alive: Duration) -> Result<Devices> {
        plan::devices(rig)?;
        let (planned, sim) = if rig.simulated {
            let sim = simulation::simulator()?
                .start(rig)
                .step("starting the simulated rig")?;
            (sim.devices(), Some(sim))
        } else {
            (hardware(rig), None)
        };
        let (mut dslr, mut fallback, mut light_probe, mut turntable, mut shutter) =
            (None, None, None, None, None);
        let mut workers = Vec::new();
        for p in planned {
            let role = p
                .fields
                .iter()
                .map(|f| f.trim_start_matches("devices."))
                .collect::<Vec<_>>()
                .join(", ");
            let w = Arc::new(Worker::spawn(&role, &p.selector, p.open, keep_alive));
            for field in &p.fields {
                match *field {
                    plan::DSLR => dslr = Some(roles::object_camera(&w)),
                    plan::FALLBACK => fallback = Some(roles::object_camera(&w)),
                    plan::THETA => light_probe = Some(roles::light_probe(&w)),
                    plan::TURNTABLE => turntable = Some(roles::turntable(&w)),
                    _ => shutter = Some(roles::shutter(&w)),
                }
            }
            workers.push(w);
        }
        Ok(Devices {
            dslr,
            fallback,
            light_probe: light_probe.step(
                "the rig names no theta; add `theta = \"...\"` under [devices] (`brdfd devices` lists what is connected)",
            )?,
            turntable,
            shutter,
            workers,
            sim,
        })
    }

    pub fn status(&self) -> Vec<DeviceStatus> {
        self.workers.iter().map(|w| w.status()).collect()
    }
}

/// A hardware rig's devices from its selectors. A box named as both turntable and shutter is
/// one device; every other field is a device of its own.
fn hardware(rig: &Rig) -> Vec<Planned> {
    let mut planned: Vec<Planned> = Vec::new();
    for (field, selector) in plan::named(&rig.devices) {
        let Some(s) = selector else { continue };
        let one = planned
            .iter_mut()
            .find(|p| p.selector == s.to_string() && plan::shared(p.fields[0], field, s));
        match one {
            Some(shared) => shared.fields.push(field),
            None => planned.push(Planned::from_selector(field, s.clone(), false)),
        }
    }
    planned
}

#[cfg(test)]
mod tests {
    use super::*;

    fn planned(devices: &str) -> Vec<Vec<&'static str>> {
        let bench = include_str!("../../../../config/rigs/bench.toml");
        let start = bench.find("[devices]").unwrap();
        let end = bench.find("# The object camera and the object").unwrap();
        let text = format!("{}[devices]\n{devices}\n{}", &bench[..start], &bench[end..]);
        let rig = Rig::parse("rig.toml", &text).unwrap();
        hardware(&rig).into_iter().map(|p| p.fields).collect()
    }

    #[test]
    fn only_a_box_that_turns_and_fires_is_one_device_in_two_roles() {
        // Two cameras both given as plain `usb` are two cameras (the THETA's `usb` means the
        // first RICOH camera).
        assert_eq!(
            planned("dslr = \"usb\"\ntheta = \"usb\"\n"),
            [vec![plan::DSLR], vec![plan::THETA]]
        );
        assert_eq!(
            planned("dslr = \"usb\"\ntheta = \"osc:http://192.168.1.1\"\nturntable = \"serial:/dev/ttyUSB0\"\nshutter = \"serial:/dev/ttyUSB0\"\n"),
            [
                vec![plan::DSLR],
                vec![plan::THETA],
                vec![plan::TURNTABLE, plan::SHUTTER]
            ]
        );
    }
}
