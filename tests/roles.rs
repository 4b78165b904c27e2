//! Issue 21, item 3: rig files that mean what they say. Every way the simulated rig can be
//! built that `config check` accepts runs to the end (or, when its only object camera is gone,
//! ends in the clear error that names the fallback), and every rig it refuses names the field
//! and the device. The roles each combination plays are checked in what the capture says.

mod common;

use common::{answering, brdfd, out};

const SIMULATED_RIG: &str = include_str!("../config/rigs/simulated.toml");

#[derive(Debug, Clone, Copy)]
struct Combination {
    /// `present`, `absent`, or `dies` (powers off after the first frame of the first view).
    dslr: &'static str,
    fallback: bool,
    turntable: bool,
    /// `http` or `usb`.
    theta: &'static str,
    shutter: bool,
}

impl Combination {
    /// The simulated rig built so, its cameras small and its brackets short: the point is
    /// which device plays which role, not the estimate.
    fn rig(&self) -> String {
        let mut rig = SIMULATED_RIG
            .replace("width = 256", "width = 16")
            .replace("height = 256", "height = 16")
            .replace(
                "fallback_shutters = [0.0003, 0.001, 0.004, 0.0166, 0.0666, 0.25]",
                "fallback_shutters = [0.0003, 0.004, 0.0666]",
            )
            .replace("fallback_frames = 8", "fallback_frames = 2");
        if !self.fallback {
            rig = rig.replace("fallback_camera = \"v4l:simulated\"\n", "");
        }
        let dslr = match self.dslr {
            "dies" => "dslr_powers_off_after = 1".to_string(),
            presence => format!("dslr = \"{presence}\""),
        };
        let presence = |on: bool| if on { "present" } else { "absent" };
        format!(
            "{rig}\n[simulation]\n{dslr}\nturntable = \"{}\"\ntheta = \"{}\"\nshutter = \"{}\"\n",
            presence(self.turntable),
            self.theta,
            presence(self.shutter),
        )
    }

    /// Whether an object camera is left to shoot with.
    fn can_shoot(&self) -> bool {
        self.dslr == "present" || self.fallback
    }
}

fn every_combination() -> Vec<Combination> {
    let mut all = Vec::new();
    for dslr in ["present", "absent", "dies"] {
        for fallback in [false, true] {
            for turntable in [false, true] {
                for theta in ["http", "usb"] {
                    for shutter in [false, true] {
                        all.push(Combination {
                            dslr,
                            fallback,
                            turntable,
                            theta,
                            shutter,
                        });
                    }
                }
            }
        }
    }
    all
}

/// A capture of two views of gold with the rig in `dir` (`rig.toml`), answering the one
/// question it asks: whether it succeeded, and what it said.
fn capture_two_views(dir: &std::path::Path) -> (bool, String) {
    answering(
        dir,
        &[
            "capture",
            "--rig",
            "rig.toml",
            "--material",
            "gold",
            "--size",
            "16",
            "--views",
            "2",
            "--bracket",
            "0.001,0.0166",
            "--state-dir",
            "state",
        ],
        1,
    )
}

/// A capture of two views on the simulated rig with its DSLR as `body`, fired by a trigger box
/// if `shutter`, with `more` added to its `[simulation]` table.
fn capture_with_body(body: &str, shutter: bool, more: &str) -> (bool, String) {
    let c = Combination {
        dslr: "present",
        fallback: false,
        turntable: true,
        theta: "http",
        shutter,
    };
    let dir = tempfile::tempdir().unwrap();
    let rig = c.rig() + &format!("dslr_body = \"{body}\"\n{more}");
    std::fs::write(dir.path().join("rig.toml"), rig).unwrap();
    capture_two_views(dir.path())
}

/// Checks one combination end to end: `config check`, then a capture of two views.
fn run(c: Combination) {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("rig.toml"), c.rig()).unwrap();
    let check = brdfd(&["config", "check", "rig.toml"], dir.path());
    assert!(check.status.success(), "{c:?}: {}", out(&check));
    let (ok, text) = capture_two_views(dir.path());
    if !c.can_shoot() {
        assert!(!ok, "{c:?}: {text}");
        assert!(
            text.contains("and the rig names no fallback_camera"),
            "{c:?}: {text}"
        );
        return;
    }
    assert!(ok, "{c:?}: {text}");
    // Each role was played by the device the combination gives it.
    let says = |what: &str, yes: bool| {
        assert_eq!(text.contains(what), yes, "{c:?}: {what:?} in\n{text}");
    };
    says("over USB (PTP)", c.theta == "usb");
    says("over HTTP at http://127.0.0.1", c.theta == "http");
    says("view 2 of 2: turntable at 30.00°", c.turntable);
    says("view 2 of 2: turned by hand to 30.0°", !c.turntable);
    says("the V4L2 fallback camera", c.dslr != "present");
    if c.dslr == "dies" {
        says("view1 is shot again on the fallback camera", true);
    }
    // The shutter fires the DSLR whenever the DSLR shoots.
    says(
        "DSLR: fired by the shutter",
        c.shutter && c.dslr != "absent",
    );
}

#[test]
fn every_simulated_rig_that_config_check_accepts_runs() {
    let all = every_combination();
    let next = std::sync::atomic::AtomicUsize::new(0);
    // Most of a capture's time is the simulated devices' modelled waits: three at a time
    // keep two cores busy.
    std::thread::scope(|s| {
        for _ in 0..3 {
            s.spawn(|| loop {
                let i = next.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
                let Some(c) = all.get(i) else { return };
                run(*c);
            });
        }
    });
}

/// A simulated Canon EOS R6 or Sony a7 IV as the rig's DSLR: each shoots every frame of a
/// capture through its own flow (Canon's remote release to the computer, Sony's shutter button
/// to its memory), and the EOS also fired from outside to its card by a trigger box; its image
/// format is left as set on the body, and the operator is told. A Sony with a trigger box is
/// refused by `config check`, with the reason.
#[test]
fn canon_and_sony_bodies_shoot_the_capture_through_their_own_flows() {
    let cases = [
        (
            "canon-eos-r6",
            false,
            "Canon EOS R6",
            "Canon.Inc Canon EOS R6",
            "IMG_0004.JPG",
        ),
        (
            "canon-eos-r6",
            true,
            "Canon EOS R6",
            "Canon.Inc Canon EOS R6",
            "IMG_0004.JPG",
        ),
        (
            "sony-a7m4",
            false,
            "Sony a7 IV",
            "Sony Corporation ILCE-7M4",
            "DSC00004.JPG",
        ),
    ];
    for (body, shutter, simulated, named, last) in cases {
        let (ok, text) = capture_with_body(body, shutter, "");
        assert!(ok, "{body}, shutter {shutter}: {text}");
        let from_computer = if body == "sony-a7m4" {
            "a Sony"
        } else {
            "a Canon EOS"
        };
        for says in [
            format!("DSLR: simulated {simulated} on ptpip:"),
            format!("DSLR: {named} on ptpip:"),
            format!(
                "of {from_computer} from the computer is not offered; it shoots as set on its body"
            ),
            // 1/60 s, the nearest to 0.0166 s on either body's list.
            format!("{last}: JPEG, EXIF 0.0167 s f/8 ISO 100"),
            "(camera applied 0.01667 s)".to_string(),
        ] {
            assert!(
                text.contains(&says),
                "{body}, shutter {shutter}: {says:?} in\n{text}"
            );
        }
        assert_eq!(
            text.contains("DSLR: fired by the shutter"),
            shutter,
            "{text}"
        );
    }
    let dir = tempfile::tempdir().unwrap();
    let fired = Combination {
        dslr: "present",
        fallback: false,
        turntable: true,
        theta: "http",
        shutter: true,
    };
    let rig = fired.rig() + "dslr_body = \"sony-a7m4\"\n";
    std::fs::write(dir.path().join("rig.toml"), rig).unwrap();
    let check = brdfd(&["config", "check", "rig.toml"], dir.path());
    assert!(!check.status.success());
    assert!(
        out(&check).contains(
            "simulation.dslr_body`: a Sony in PC remote mode cannot be fired from outside"
        ),
        "{}",
        out(&check)
    );
}

/// With the gphoto2 feature: the simulated Nikon and Canon EOS shoot the whole capture through
/// the system's libgphoto2, at the exposures brdfd's own driver applies (each body's 1/60 s,
/// which the Nikon's list holds as 0.0166 s), and the capture says which backend drove them.
/// The EOS is also fired by a trigger box, its files found from libgphoto2's events.
#[cfg(feature = "gphoto2")]
#[test]
fn bodies_driven_through_libgphoto2_shoot_the_capture() {
    for (body, named, shutter) in [
        ("nikon-d5100", "D5100", false),
        ("canon-eos-r6", "Canon EOS R6", false),
        ("canon-eos-r6", "Canon EOS R6", true),
    ] {
        let (ok, text) = capture_with_body(body, shutter, "dslr_backend = \"gphoto2\"\n");
        assert!(ok, "{body}: {text}");
        for says in [
            "DSLR: simulated",
            " on gphoto2:ptpip:127.0.0.1:",
            named,
            " through libgphoto2, f/8 ISO 100",
            "through libgphoto2 it shoots as set on its body",
            "(camera applied 0.0166",
            ": JPEG, EXIF 0.016",
            "gold: good estimate",
        ] {
            assert!(text.contains(says), "{body}: {says:?} in\n{text}");
        }
        // Two views of two exposures, each downloaded.
        assert_eq!(
            text.matches("(camera applied ").count(),
            4,
            "{body}: {text}"
        );
        assert_eq!(
            text.contains("DSLR: fired by the shutter"),
            shutter,
            "{body}: {text}"
        );
    }
}

/// What each field may name, written apart from the code that checks it: the device kinds
/// that can play the field's role.
fn fits(field: &str, selector: &str) -> bool {
    let kind = selector.split(':').next().unwrap();
    match field {
        "dslr" => matches!(kind, "usb" | "ptpip"),
        "theta" => matches!(kind, "osc" | "usb" | "ptpip"),
        "fallback_camera" => kind == "v4l",
        "turntable" => matches!(kind, "serial" | "grbl"),
        _ => matches!(kind, "serial" | "cable"),
    }
}

/// A hardware rig with each kind of device in each field: accepted where the device can play
/// the role, refused otherwise with the field and the device named.
#[test]
fn each_field_takes_the_devices_that_can_play_its_role_and_names_the_rest() {
    let bench = include_str!("../config/rigs/bench.toml").to_string()
        + "\n[calibration.theta]\ngain = 1.0\n[calibration.dslr_raw]\ngain = 10.0\n[calibration.dslr_jpeg]\ngain = 10.0\n[calibration.fallback]\ngain = 0.6\n";
    let dir = tempfile::tempdir().unwrap();
    let selectors = [
        "usb:04b0:0429",
        "ptpip:192.0.2.7",
        "osc:http://192.168.1.1",
        "v4l:/dev/video4",
        "serial:/dev/ttyUSB3",
        "cable:rts:/dev/ttyUSB4",
        "grbl:/dev/ttyACM0",
    ];
    let fields = [
        ("dslr", "dslr = \"usb:04b0:0429\""),
        ("theta", "theta = \"osc:http://192.168.1.1\""),
        ("fallback_camera", "fallback_camera = \"v4l:/dev/video0\""),
        ("turntable", "turntable = \"serial:/dev/ttyUSB0\""),
        ("shutter", "# shutter = \"serial:/dev/ttyUSB0\""),
    ];
    let mut checked = 0;
    for (field, line) in fields {
        assert!(bench.contains(line), "{line}");
        for selector in selectors {
            let rig = bench.replace(line, &format!("{field} = \"{selector}\""));
            std::fs::write(dir.path().join("rig.toml"), &rig).unwrap();
            let o = brdfd(&["config", "check", "rig.toml"], dir.path());
            let text = out(&o);
            if fits(field, selector) {
                assert!(o.status.success(), "{field} = {selector}: {text}");
            } else {
                assert!(!o.status.success(), "{field} = {selector}: accepted");
                assert!(
                    text.contains(&format!(
                        "field `devices.{field}`: {selector} cannot be used here"
                    )),
                    "{field} = {selector}: {text}"
                );
            }
            checked += 1;
        }
    }
    assert_eq!(checked, 35);
    // A camera through libgphoto2 is a DSLR, in a brdfd built with the gphoto2 feature; one
    // built without says how to get it.
    for (line, field, feature_needed) in [
        ("dslr = \"usb:04b0:0429\"", "dslr", true),
        ("theta = \"osc:http://192.168.1.1\"", "theta", false),
    ] {
        let rig = bench.replace(line, &format!("{field} = \"gphoto2:usb:001,004\""));
        std::fs::write(dir.path().join("rig.toml"), &rig).unwrap();
        let o = brdfd(&["config", "check", "rig.toml"], dir.path());
        let text = out(&o);
        match (feature_needed, cfg!(feature = "gphoto2")) {
            (true, true) => assert!(o.status.success(), "{text}"),
            (true, false) => assert!(
                text.contains("field `devices.dslr`: gphoto2:usb:001,004 needs a brdfd built with the `gphoto2` feature"),
                "{text}"
            ),
            (false, _) => assert!(
                text.contains("field `devices.theta`: gphoto2:usb:001,004 cannot be used here"),
                "{text}"
            ),
        }
    }
    // The roles a capture needs, and a shutter with nothing to fire.
    for (change, says) in [
        (
            ("dslr = \"usb:04b0:0429\"", ""),
            "field `devices.shutter`: serial:/dev/ttyUSB0 fires a DSLR, and the rig names no `dslr`",
        ),
        (
            ("theta = \"osc:http://192.168.1.1\"", ""),
            "field `devices.theta`: needs a THETA to measure the light",
        ),
    ] {
        let rig = bench
            .replace("# shutter = \"serial:/dev/ttyUSB0\"", "shutter = \"serial:/dev/ttyUSB0\"")
            .replace(change.0, change.1);
        std::fs::write(dir.path().join("rig.toml"), &rig).unwrap();
        let o = brdfd(&["config", "check", "rig.toml"], dir.path());
        assert!(!o.status.success());
        assert!(out(&o).contains(says), "{}", out(&o));
    }
    // One port, one device: a trigger box cannot share a GRBL controller's port.
    let rig = bench
        .replace(
            "turntable = \"serial:/dev/ttyUSB0\"",
            "turntable = \"grbl:x:/dev/ttyUSB0\"",
        )
        .replace(
            "# shutter = \"serial:/dev/ttyUSB0\"",
            "shutter = \"serial:/dev/ttyUSB0\"",
        );
    std::fs::write(dir.path().join("rig.toml"), &rig).unwrap();
    let o = brdfd(&["config", "check", "rig.toml"], dir.path());
    assert!(!o.status.success());
    assert!(
        out(&o).contains("field `devices.shutter`: serial:/dev/ttyUSB0 is on the turntable's port (grbl:x:/dev/ttyUSB0)"),
        "{}",
        out(&o)
    );
    // A simulated rig's devices are its simulators: a selector in one is refused by field.
    let rig = SIMULATED_RIG.replace(
        "[devices]\n",
        "[devices]\nshutter = \"cable:dtr:/dev/ttyUSB0\"\n",
    );
    std::fs::write(dir.path().join("rig.toml"), &rig).unwrap();
    let o = brdfd(&["config", "check", "rig.toml"], dir.path());
    assert!(!o.status.success());
    assert!(
        out(&o).contains("field `devices.shutter`: cable:dtr:/dev/ttyUSB0: a simulated rig's devices are its simulators"),
        "{}",
        out(&o)
    );
}

/// A turntable on a GRBL controller (the simulated GRBL 1.1 on a pseudo-terminal, opened
/// through the `grbl:` selector a bench gives) turns the views, beside a trigger box of its own
/// that fires the DSLR.
#[test]
fn a_grbl_turntable_turns_the_views_beside_a_trigger_box() {
    let dir = tempfile::tempdir().unwrap();
    let rig = Combination {
        dslr: "present",
        fallback: false,
        turntable: true,
        theta: "http",
        shutter: true,
    }
    .rig()
    .replace("turntable = \"present\"", "turntable = \"grbl\"");
    std::fs::write(dir.path().join("rig.toml"), rig).unwrap();
    let (ok, text) = answering(
        dir.path(),
        &[
            "capture",
            "--rig",
            "rig.toml",
            "--material",
            "gold",
            "--size",
            "16",
            "--views",
            "3",
            "--turn",
            "45",
            "--state-dir",
            "state",
        ],
        0,
    );
    assert!(ok, "{text}");
    for says in [
        "turntable: Grbl 1.1h (A axis) on grbl:/dev/pts/",
        "view 2 of 3: turntable at 45.00°",
        "view 3 of 3: turntable at 90.00°",
        "DSLR: fired by the shutter",
    ] {
        assert!(text.contains(says), "{says:?} in\n{text}");
    }
}
