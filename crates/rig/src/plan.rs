//! Whether the capture can run a rig: each device the rig names is of a kind that can play its
//! role, the roles a capture needs are filled, and every camera that may shoot has its gain.
//! `brdfd config check`, the capture and the daemon ask this one question before anything
//! is opened or a session exists, so a rig that passes `config check` is one the capture runs,
//! and one that fails names the field and the device.
//!
//! It does not open anything: a device that is named right but unplugged is the capture's
//! business (the fallback camera, a clear error).

use crate::config::{
    invalid, ConfigError, DslrFiles, Rig, RigDevices, SimulatedPresence, SimulatedTurntable,
    GAIN_FIELDS,
};
use crate::selector::Selector;

/// The roles of the capture, by the rig field that names their device.
pub const DSLR: &str = "devices.dslr";
pub const FALLBACK: &str = "devices.fallback_camera";
pub const THETA: &str = "devices.theta";
pub const TURNTABLE: &str = "devices.turntable";
pub const SHUTTER: &str = "devices.shutter";

/// The simulated rig's fallback camera: `fallback_camera = "v4l:simulated"`.
pub const SIMULATED_WEBCAM: &str = "simulated";

/// The roles a rig fills. A simulated rig's devices are its simulators, so it fills them as
/// its `[simulation]` table says.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Roles {
    /// A DSLR is named (it may still not answer: the fallback camera then shoots).
    pub dslr: bool,
    pub fallback: bool,
    pub turntable: bool,
    /// Something other than the DSLR itself fires it.
    pub shutter: bool,
}

/// The devices, then the calibration: everything a capture needs of the rig file.
pub fn check(rig: &Rig) -> Result<Roles, ConfigError> {
    first(problems(rig))
}

/// The roles the rig fills, and every problem [`check`] would refuse it for (its first).
pub fn problems(rig: &Rig) -> (Roles, Vec<ConfigError>) {
    let (roles, mut found) = device_problems(rig);
    calibration(rig, &roles, &mut found);
    (roles, found)
}

/// The devices alone: what `brdfd calibrate radiometry` needs, on a rig that has no gains
/// yet.
pub fn devices(rig: &Rig) -> Result<Roles, ConfigError> {
    first(device_problems(rig))
}

fn first((roles, found): (Roles, Vec<ConfigError>)) -> Result<Roles, ConfigError> {
    match found.into_iter().next() {
        Some(e) => Err(e),
        None => Ok(roles),
    }
}

fn device_problems(rig: &Rig) -> (Roles, Vec<ConfigError>) {
    let mut found = Vec::new();
    let roles = if rig.simulated {
        simulated(rig, &mut found)
    } else {
        hardware(rig, &mut found)
    };
    let file = rig.file.as_str();
    let b = &rig.brackets;
    if roles.fallback && b.fallback_shutters.is_empty() {
        found.push(invalid(
            file,
            "brackets.fallback_shutters",
            "needs at least one exposure",
        ));
    }
    // Left alone, a webcam's auto gain changes between the bracket's exposures, and the
    // calibration holds for one gain.
    if roles.fallback && b.fallback_gain.is_none() {
        found.push(invalid(
            file,
            "brackets.fallback_gain",
            "a rig with a fallback_camera needs a fixed gain, in the camera's own units (`v4l2-ctl -d /dev/videoN --list-ctrls` shows its range); calibration.fallback is measured at it",
        ));
    }
    (roles, found)
}

/// What each field may name: the kinds of device that can play its role, as the error says
/// them.
fn kinds(field: &str) -> (fn(&Selector) -> bool, &'static str) {
    match field {
        DSLR => (
            |s| matches!(s, Selector::Usb { .. } | Selector::PtpIp(_) | Selector::Gphoto(_)),
            "a PTP camera: usb, usb:VVVV[:PPPP] or ptpip:HOST[:PORT]; or a camera libgphoto2 drives, gphoto2[:PORT]",
        ),
        // A THETA's V4L2 (UVC) mode streams live video: it cannot shoot the bracket the
        // light needs.
        THETA => (
            |s| matches!(s, Selector::Osc(_) | Selector::Usb { .. } | Selector::PtpIp(_)),
            "a THETA the capture can bracket: osc:http://HOST, usb[:05ca:PPPP] or ptpip:HOST (not its V4L2 live view)",
        ),
        FALLBACK => (
            |s| matches!(s, Selector::V4l(_)),
            "a V4L2 camera: v4l:/dev/videoN",
        ),
        TURNTABLE => (
            |s| matches!(s, Selector::Serial(_) | Selector::Grbl { .. }),
            "a turntable: serial:/dev/ttyUSB0 (the brdfd rig protocol) or grbl:[AXIS:]/dev/ttyUSB0 (a GRBL G-code controller) (a release cable, cable:..., cannot turn the object; name it as `shutter` to fire the DSLR)",
        ),
        _ => (
            |s| matches!(s, Selector::Serial(_) | Selector::Cable { .. }),
            "a trigger box that speaks the brdfd rig protocol, serial:/dev/ttyUSB0, or a release cable, cable:dtr|rts:/dev/ttyUSB0",
        ),
    }
}

/// The rig's `[devices]` fields and what each names, in the order devices are started.
pub fn named(d: &RigDevices) -> [(&'static str, &Option<Selector>); 5] {
    [
        (DSLR, &d.dslr),
        (FALLBACK, &d.fallback_camera),
        (THETA, &d.theta),
        (TURNTABLE, &d.turntable),
        (SHUTTER, &d.shutter),
    ]
}

/// Whether two fields naming the same selector are one device in two roles: only a
/// rig-protocol box that turns and fires. (Two cameras both named `usb` are two cameras:
/// plain `usb` for the THETA means the first RICOH camera.)
pub fn shared(a: &str, b: &str, s: &Selector) -> bool {
    matches!(s, Selector::Serial(_)) && [a, b].contains(&TURNTABLE) && [a, b].contains(&SHUTTER)
}

/// The serial port a device is on, if it is on one.
fn port_path(s: &Selector) -> Option<&str> {
    match s {
        Selector::Serial(p) | Selector::Grbl { path: p, .. } | Selector::Cable { path: p, .. } => {
            Some(p)
        }
        _ => None,
    }
}

fn hardware(rig: &Rig, found: &mut Vec<ConfigError>) -> Roles {
    let (file, d) = (rig.file.as_str(), &rig.devices);
    for (field, selector) in named(d) {
        let Some(s) = selector else { continue };
        let (fits, what) = kinds(field);
        if !fits(s) {
            found.push(invalid(
                file,
                field,
                format!("{s} cannot be used here: it must be {what}"),
            ));
        }
    }
    if let (Some(s @ Selector::Gphoto(_)), false) = (&d.dslr, cfg!(feature = "gphoto2")) {
        found.push(invalid(
            file,
            DSLR,
            format!("{s} needs a brdfd built with the `gphoto2` feature (cargo install --path . --features gphoto2), and this one was built without; brdfd's own PTP driver is usb or ptpip:HOST"),
        ));
    }
    if d.dslr.is_none() && d.fallback_camera.is_none() {
        found.push(invalid(
            file,
            "devices",
            "needs a `dslr` or a `fallback_camera` to see the object",
        ));
    }
    if d.theta.is_none() {
        found.push(invalid(file, THETA, "needs a THETA to measure the light"));
    }
    if let Some(s) = &d.shutter {
        if d.dslr.is_none() {
            found.push(invalid(
                file,
                SHUTTER,
                format!("{s} fires a DSLR, and the rig names no `dslr` (the fallback camera streams: it has no shutter to fire)"),
            ));
        }
        // One port is one device: a box that turns and fires serves both roles; a cable, or
        // a box, on a GRBL controller's port, or a cable on a box's, would fight it for the
        // line.
        if let (Some(path), Some(t)) = (port_path(s), &d.turntable) {
            let one_box = matches!((s, t), (Selector::Serial(_), Selector::Serial(_)));
            if port_path(t) == Some(path) && !one_box {
                found.push(invalid(
                    file,
                    SHUTTER,
                    format!("{s} is on the turntable's port ({t}): it needs a port of its own"),
                ));
            }
        }
    }
    Roles {
        dslr: d.dslr.is_some(),
        fallback: d.fallback_camera.is_some(),
        turntable: d.turntable.is_some(),
        shutter: d.shutter.is_some(),
    }
}

fn simulated(rig: &Rig, found: &mut Vec<ConfigError>) -> Roles {
    let (file, d) = (rig.file.as_str(), &rig.devices);
    for (field, named) in [
        (DSLR, &d.dslr),
        (THETA, &d.theta),
        (TURNTABLE, &d.turntable),
        (SHUTTER, &d.shutter),
    ] {
        if let Some(s) = named {
            found.push(invalid(
                file,
                field,
                format!("{s}: a simulated rig's devices are its simulators; say which are there in [simulation] (dslr, theta, turntable, shutter)"),
            ));
        }
    }
    let webcam = Selector::V4l(SIMULATED_WEBCAM.into());
    if let Some(s) = d.fallback_camera.as_ref().filter(|s| **s != webcam) {
        found.push(invalid(
            file,
            FALLBACK,
            format!("{s}: a simulated rig's fallback camera is the simulated webcam, `{webcam}`"),
        ));
    }
    let sim = rig.simulation.clone().unwrap_or_default();
    Roles {
        // An absent simulated DSLR is one that is named and does not answer.
        dslr: true,
        fallback: d.fallback_camera.is_some(),
        turntable: sim.turntable != SimulatedTurntable::Absent,
        shutter: sim.shutter == SimulatedPresence::Present,
    }
}

/// Every camera that may shoot has its gain: the THETA always, the DSLR for the files it is
/// set to make (a RAW + JPEG bracket falls back to its JPEGs when its RAW files cannot be
/// merged), and the fallback camera.
fn calibration(rig: &Rig, roles: &Roles, found: &mut Vec<ConfigError>) {
    let c = &rig.calibration;
    if let Err(e) = c.refuse_ratios(&rig.file) {
        found.push(e);
        return;
    }
    let [theta, dslr_raw, dslr_jpeg, fallback] = GAIN_FIELDS;
    let mut needed = vec![(theta, c.theta.is_some(), "the THETA")];
    if roles.dslr {
        let (raw, jpeg) = match rig.brackets.dslr_files {
            DslrFiles::RawJpeg => (true, true),
            DslrFiles::Raw => (true, false),
            DslrFiles::Jpeg => (false, true),
        };
        if raw {
            needed.push((
                dslr_raw,
                c.dslr_raw.is_some(),
                "each of the DSLR's RAW files",
            ));
        }
        if jpeg {
            needed.push((
                dslr_jpeg,
                c.dslr_jpeg.is_some(),
                "each of the DSLR's JPEG files",
            ));
        }
    }
    if roles.fallback {
        needed.push((fallback, c.fallback.is_some(), "the fallback camera"));
    }
    // One missing gain or four, it is one step to take: the first says which.
    if let Some((field, _, what)) = needed.into_iter().find(|(_, there, _)| !there) {
        found.push(invalid(
            rig.file.as_str(),
            format!("{field}.gain"),
            format!(
                "not measured: {what} needs a gain to put its values in the bench's radiance; `brdfd calibrate radiometry --rig {}` measures every camera's from a grey card and writes them here",
                rig.file
            ),
        ));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const BENCH: &str = include_str!("../../../config/rigs/bench.toml");
    const GAINS: &str = "[calibration.theta]\ngain = 1.0\n[calibration.dslr_raw]\ngain = 10.0\n[calibration.dslr_jpeg]\ngain = 10.0\n[calibration.fallback]\ngain = 0.6\n";

    fn check_text(text: &str) -> Result<Roles, String> {
        let rig = Rig::parse("rig.toml", text).map_err(|e| e.to_string())?;
        check(&rig).map_err(|e| e.to_string())
    }

    #[test]
    fn a_calibrated_bench_fills_every_role() {
        let roles = check_text(&format!("{BENCH}\n{GAINS}")).unwrap();
        assert_eq!(
            roles,
            Roles {
                dslr: true,
                fallback: true,
                turntable: true,
                shutter: false
            }
        );
    }

    #[test]
    fn each_missing_gain_is_named_with_the_command_that_measures_it() {
        let e = check_text(BENCH).unwrap_err();
        assert!(e.contains("field `calibration.theta.gain`"), "{e}");
        assert!(
            e.contains("brdfd calibrate radiometry --rig rig.toml"),
            "{e}"
        );
        let without = |table: &str| {
            let gains: String = GAINS
                .split_inclusive('\n')
                .collect::<Vec<_>>()
                .chunks(2)
                .filter(|pair| !pair[0].contains(table))
                .flatten()
                .copied()
                .collect();
            check_text(&format!("{BENCH}\n{gains}"))
        };
        for table in ["dslr_raw", "dslr_jpeg", "fallback"] {
            let e = without(table).unwrap_err();
            assert!(e.contains(&format!("calibration.{table}.gain")), "{e}");
        }
        // A JPEG-only DSLR needs no RAW gain.
        let jpeg = format!("{BENCH}\n{GAINS}")
            .replace("dslr_files = \"raw+jpeg\"", "dslr_files = \"jpeg\"")
            .replace("[calibration.dslr_raw]\ngain = 10.0\n", "");
        check_text(&jpeg).unwrap();
    }

    #[test]
    fn a_shutter_needs_a_dslr_and_a_port_of_its_own() {
        let rig = format!("{BENCH}\n{GAINS}");
        let cable = rig.replace(
            "turntable = \"serial:/dev/ttyUSB0\"",
            "turntable = \"serial:/dev/ttyUSB0\"\nshutter = \"cable:dtr:/dev/ttyUSB0\"",
        );
        let e = check_text(&cable).unwrap_err();
        assert!(
            e.contains("field `devices.shutter`") && e.contains("port of its own"),
            "{e}"
        );
        // A box that turns and fires is both.
        let boxed = rig.replace(
            "turntable = \"serial:/dev/ttyUSB0\"",
            "turntable = \"serial:/dev/ttyUSB0\"\nshutter = \"serial:/dev/ttyUSB0\"",
        );
        assert!(check_text(&boxed).unwrap().shutter);
        let no_dslr = cable
            .replace("dslr = \"usb:04b0:0429\"", "")
            .replace("cable:dtr:/dev/ttyUSB0", "cable:dtr:/dev/ttyUSB1");
        let e = check_text(&no_dslr).unwrap_err();
        assert!(
            e.contains("field `devices.shutter`") && e.contains("no `dslr`"),
            "{e}"
        );
    }

    #[test]
    fn a_simulated_rig_names_its_devices_in_its_simulation_table() {
        let sim = include_str!("../../../config/rigs/simulated.toml");
        let roles = check_text(sim).unwrap();
        assert!(roles.dslr && roles.fallback && roles.turntable && !roles.shutter);
        let e = check_text(&sim.replace(
            "[devices]\n",
            "[devices]\nturntable = \"serial:/dev/ttyUSB0\"\n",
        ))
        .unwrap_err();
        assert!(
            e.contains("field `devices.turntable`") && e.contains("[simulation]"),
            "{e}"
        );
        let shutter = check_text(&format!(
            "{sim}\n[simulation]\nshutter = \"present\"\nturntable = \"absent\"\n"
        ))
        .unwrap();
        assert!(shutter.shutter && !shutter.turntable);
    }
}
