//! Every file shipped in `config/` loads, through the same readers brdfd uses.

use std::path::{Path, PathBuf};

use brdfd_core::geometry::SceneGeometry;
use brdfd_rig::config::{DaemonConfig, MaterialPreset, PixelCount, Rig};

fn files(sub: &str) -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("config")
        .join(sub);
    let mut v: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    v.sort();
    v
}

#[test]
fn every_shipped_geometry_loads_and_sees_the_object() {
    let mut n = 0;
    for path in files("geometry") {
        let g = SceneGeometry::read(&path).unwrap_or_else(|e| panic!("{e}"));
        // At a tenth of the resolution, so the D5100 file does not cast 16 million rays.
        let (w, h) = g.camera.size();
        let px = g.pixels(w / 10, h / 10).unwrap();
        assert!(
            px.pixels.len() > (w / 10) * (h / 10) / 50,
            "{}: object covers {} pixels",
            path.display(),
            px.pixels.len()
        );
        n += 1;
    }
    assert!(n >= 2);
}

#[test]
fn every_shipped_rig_material_and_daemon_file_loads() {
    let daemon =
        DaemonConfig::read(&Path::new(env!("CARGO_MANIFEST_DIR")).join("config/brdfd.toml"))
            .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(daemon.api, "127.0.0.1:7878");
    assert_eq!(DaemonConfig::embedded().api, daemon.api);

    let rigs = files("rigs");
    assert!(rigs.len() >= 2);
    for path in &rigs {
        let rig = Rig::read(path).unwrap_or_else(|e| panic!("{e}"));
        // The rig's object camera sees its object (at a tenth of the resolution).
        let (w, h) = rig.geometry.camera.size();
        let px = rig.geometry.pixels(w / 10, h / 10).unwrap();
        assert!(
            !px.pixels.is_empty(),
            "{}: the camera misses the object",
            path.display()
        );
    }
    assert!(Rig::simulated().simulated);

    let presets = files("materials");
    assert!(presets.len() >= 4);
    for path in &presets {
        let m = MaterialPreset::read(path).unwrap_or_else(|e| panic!("{e}"));
        // The simulated rig can render it.
        brdfd_bench::VirtualBench::embedded(&m.simulate_as, 8)
            .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        // The embedded copy is the same file.
        let name = path.file_stem().unwrap().to_str().unwrap();
        let embedded = MaterialPreset::embedded(name).unwrap().expect("embedded");
        assert_eq!(embedded.simulate_as, m.simulate_as);
    }
    assert_eq!(
        MaterialPreset::embedded("chrome").unwrap().unwrap().pixels,
        PixelCount::All
    );
    assert!(MaterialPreset::embedded("../gold").is_err());
}

/// Issue 20, D14: a rig file with an impossible number is refused by `config check` (and so by
/// every reader), with the field named: each of these passed before.
#[test]
fn rig_files_with_impossible_numbers_are_refused() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    // Calibrated, as `brdfd calibrate radiometry` leaves it: the shipped template is not.
    let bench = std::fs::read_to_string(root.join("config/rigs/bench.toml")).unwrap()
        + "\n[calibration.theta]\ngain = 1.0\n[calibration.dslr_raw]\ngain = 10.0\n[calibration.dslr_jpeg]\ngain = 10.0\n[calibration.fallback]\ngain = 0.6\n";
    let dir = tempfile::tempdir().unwrap();
    for (from, to, says) in [
        ("fx = 7000.0", "fx = nan", "camera.fx"),
        ("width = 4928", "width = 0", "camera.width"),
        (
            "look_at = [0.0, 0.0, 0.0]",
            "look_at = [0.0, 0.3, 1.2]",
            "look_at equals position",
        ),
        ("half_size = 0.05", "half_size = -5.0", "shape.half_size"),
        // Issue 40: a 9,000-exposure bracket was accepted.
        (
            "dslr_shutters = [0.001, 0.004, 0.0166, 0.0666, 0.25]",
            &format!("dslr_shutters = [{}]", ["0.01"; 9000].join(", ")),
            "field `brackets.dslr_shutters`: 9000 exposures; a bracket has at most 32",
        ),
        (
            "views = 3",
            "views = 100000000000",
            "views must be 1 to 360",
        ),
        // Devices the capture cannot run in their role are refused by name, not when opened.
        (
            "theta = \"osc:http://192.168.1.1\"",
            "theta = \"v4l:/dev/video2\"",
            "field `devices.theta`: v4l:/dev/video2 cannot be used here: it must be a THETA the capture can bracket",
        ),
        (
            "turntable = \"serial:/dev/ttyUSB0\"",
            "turntable = \"cable:dtr:/dev/ttyUSB0\"",
            "field `devices.turntable`: cable:dtr:/dev/ttyUSB0 cannot be used here",
        ),
        (
            "turntable = \"serial:/dev/ttyUSB0\"",
            "turntable = \"serial:/dev/ttyUSB0\"\nshutter = \"v4l:/dev/video1\"",
            "field `devices.shutter`: v4l:/dev/video1 cannot be used here: it must be a trigger box",
        ),
        (
            "fallback_camera = \"v4l:/dev/video0\"",
            "fallback_camera = \"usb\"",
            "field `devices.fallback_camera`: usb cannot be used here: it must be a V4L2 camera",
        ),
        // Every camera that may shoot needs its gain.
        (
            "[calibration.fallback]\ngain = 0.6\n",
            "",
            "field `calibration.fallback.gain`: not measured",
        ),
        (
            "[calibration.dslr_jpeg]\ngain = 10.0\n",
            "",
            "field `calibration.dslr_jpeg.gain`: not measured",
        ),
        // The ratio of before the gains says how to move it over.
        (
            "[calibration]\n",
            "[calibration]\ntheta_to_dslr = 2.0\n",
            "[calibration.theta] gain = 50",
        ),
    ] {
        assert!(bench.contains(from), "{from}");
        let path = dir.path().join("rig.toml");
        std::fs::write(&path, bench.replace(from, to)).unwrap();
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_brdfd"))
            .args(["config", "check"])
            .arg(&path)
            .output()
            .unwrap();
        // The per-file verdicts go to stdout, the summary to stderr.
        let err = String::from_utf8_lossy(&o.stdout) + String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{to}: accepted");
        assert!(err.contains(says), "{to}: {err}");
    }
}

/// Issue 40: `config check` on a geometry file ran none of the geometry checks a rig's
/// `[geometry]` gets, so `fx = nan` passed.
#[test]
fn a_geometry_file_with_impossible_numbers_is_refused() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(root.join("config/geometry/corrugated-d5100.toml")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("corrugated-d5100.toml");
    let fx = text.lines().find(|l| l.starts_with("fx = ")).unwrap();
    std::fs::write(&path, text.replace(fx, "fx = nan")).unwrap();
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_brdfd"))
        .args(["config", "check", "--kind", "geometry"])
        .arg(&path)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stdout) + String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "accepted: {err}");
    // On the line of the field (issue 42).
    let line = text.lines().position(|l| l == fx).unwrap() + 1;
    assert!(
        err.contains(&format!(
            ", line {line}: field `camera.fx`: camera.fx must be a positive number, not NaN"
        )),
        "{err}"
    );
}

/// Issue 42: docs/bench-setup.md promises every mistake with its line and field, and
/// `config check` stopped at the first value that made no sense, without a line.
#[test]
fn every_mistake_in_a_rig_is_reported_with_its_line_and_field() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let bench = std::fs::read_to_string(root.join("config/rigs/bench.toml")).unwrap()
        + "\n[calibration.theta]\ngain = 1.0\n[calibration.dslr_raw]\ngain = 10.0\n[calibration.dslr_jpeg]\ngain = 10.0\n[calibration.fallback]\ngain = 0.6\n";
    let mistakes = [
        // (in the file, written instead, the field the error names)
        (
            "turntable = \"serial:/dev/ttyUSB0\"",
            "turntable = \"cable:dtr:/dev/ttyUSB0\"",
            "devices.turntable",
        ),
        (
            "dslr_shutters = [0.001, 0.004, 0.0166, 0.0666, 0.25]",
            "dslr_shutters = [0.001, -0.004, 0.0166, 0.0666, 0.25]",
            "brackets.dslr_shutters[1]",
        ),
        (
            "dslr_f_number = 8.0",
            "dslr_f_number = 100.0",
            "brackets.dslr_f_number",
        ),
    ];
    let mut rig = bench.clone();
    for (from, to, _) in mistakes {
        assert!(rig.contains(from), "{from}");
        rig = rig.replace(from, to);
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("my-rig.toml");
    std::fs::write(&path, &rig).unwrap();
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_brdfd"))
        .args(["config", "check"])
        .arg(&path)
        .output()
        .unwrap();
    assert!(!o.status.success());
    let out = String::from_utf8_lossy(&o.stdout);
    let errors: Vec<&str> = out.lines().filter(|l| l.starts_with("ERR ")).collect();
    assert_eq!(errors.len(), 3, "{out}");
    // In the file's order, each with the line the mistake is on.
    for (error, (_, to, field)) in errors.iter().zip(mistakes) {
        let line = rig.lines().position(|l| l.starts_with(to)).unwrap() + 1;
        assert!(
            error.contains(&format!("my-rig.toml, line {line}: field `{field}`: ")),
            "{error}"
        );
    }
}
