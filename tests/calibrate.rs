//! Issue 21, item 5: `brdfd calibrate radiometry` measures each camera's gain from a grey
//! target on the simulated rig, whose sensors' gains are known (the simulators' constants),
//! and writes them into the rig file, which a capture then runs with.

mod common;

use brdfd_bench::camera::SENSOR_GAIN;
use brdfd_bench::panorama::THETA_SENSOR_GAIN;
use brdfd_rig::config::Rig;
use common::{brdfd, out, relit};

/// The calibration's tolerance, from the issue: 2% of the known ratio. (Measured: 0.3% for
/// the DSLR, 0.2% for the webcam; the rest of the margin is the THETA panorama's own error,
/// which every gain carries.)
const TOLERANCE: f64 = 0.02;

/// The simulated rig shooting RAW + JPEG, with only the THETA's gain (the unit), and its
/// cameras at 96² to keep the run short.
fn uncalibrated() -> String {
    let rig = include_str!("../config/rigs/simulated.toml")
        .replace("dslr_files = \"jpeg\"", "dslr_files = \"raw+jpeg\"")
        .replace("width = 256", "width = 96")
        .replace("height = 256", "height = 96");
    let end = rig.find("[calibration.dslr_raw]").unwrap();
    rig[..end].to_string()
}

/// `brdfd calibrate radiometry --rig rig.toml --out shots`, with more arguments, in `dir`.
fn calibrate(dir: &std::path::Path, extra: &[&str]) -> std::process::Output {
    let mut args = vec![
        "calibrate",
        "radiometry",
        "--rig",
        "rig.toml",
        "--out",
        "shots",
    ];
    args.extend_from_slice(extra);
    brdfd(&args, dir)
}

/// `brdfd capture` of gold with `dir/rig.toml` at `size`², sessions in `dir/state`.
fn capture_gold(dir: &std::path::Path, size: &str) -> std::process::Output {
    brdfd(
        &[
            "capture",
            "--rig",
            "rig.toml",
            "--material",
            "gold",
            "--size",
            size,
            "--state-dir",
            "state",
        ],
        dir,
    )
}

/// The calibration's record in `dir/shots`.
fn record(dir: &std::path::Path) -> serde_json::Value {
    let text = std::fs::read_to_string(dir.join("shots/calibration.json")).unwrap();
    serde_json::from_str(&text).unwrap()
}

fn gain(rig: &Rig, table: &str) -> [f64; 3] {
    let c = &rig.calibration;
    let g = match table {
        "theta" => &c.theta,
        "dslr_raw" => &c.dslr_raw,
        "dslr_jpeg" => &c.dslr_jpeg,
        _ => &c.fallback,
    };
    g.as_ref().unwrap_or_else(|| panic!("no {table}")).gain.0
}

fn assert_near(what: &str, got: [f64; 3], want: f64) {
    for (c, g) in got.iter().enumerate() {
        assert!(
            (g / want - 1.0).abs() <= TOLERANCE,
            "{what}, channel {c}: {g} against {want}"
        );
    }
}

#[test]
fn calibration_recovers_the_simulated_sensors_gains_and_the_capture_runs_with_them() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("rig.toml"), uncalibrated()).unwrap();
    // Not calibrated: config check says which gain is missing and what measures it.
    let o = brdfd(&["config", "check", "rig.toml"], dir.path());
    assert!(!o.status.success());
    assert!(
        out(&o).contains("brdfd calibrate radiometry --rig rig.toml"),
        "{}",
        out(&o)
    );

    let o = calibrate(dir.path(), &[]);
    let text = out(&o);
    assert!(o.status.success(), "{text}");
    let rig = Rig::read(&dir.path().join("rig.toml")).unwrap();
    // The THETA's gain is the unit, kept; the others are measured against it.
    assert_eq!(gain(&rig, "theta"), [THETA_SENSOR_GAIN; 3]);
    // The known ratio: the simulated DSLR's sensor over the simulated THETA's.
    let ratio = |g: [f64; 3]| g.map(|v| v / THETA_SENSOR_GAIN);
    let known = SENSOR_GAIN / THETA_SENSOR_GAIN;
    assert_near("RAW", ratio(gain(&rig, "dslr_raw")), known);
    assert_near("JPEG", ratio(gain(&rig, "dslr_jpeg")), known);
    // The webcam: the same sensor at gain 25 of 100, through its f/2 lens, per second.
    let webcam = SENSOR_GAIN * 25.0 / 100.0 / brdfd_sim::v4l::F_NUMBER.powi(2);
    assert_near("fallback", gain(&rig, "fallback"), webcam);
    // With the spread and the measurement's record.
    let raw = rig.calibration.dslr_raw.as_ref().unwrap();
    assert!(
        raw.spread.unwrap().0.iter().all(|s| *s > 0.0 && *s < 0.05),
        "{raw:?}"
    );
    assert!(
        raw.measured.as_deref().unwrap().contains("albedo [0.18"),
        "{raw:?}"
    );
    // The file keeps its comments, the one before is kept, and the photos are in the folder.
    let written = std::fs::read_to_string(dir.path().join("rig.toml")).unwrap();
    assert!(written.contains("# The simulated rig of `brdfd capture --simulate`"));
    assert_eq!(
        std::fs::read_to_string(dir.path().join("rig.toml.bak")).unwrap(),
        uncalibrated()
    );
    let shots: Vec<String> = std::fs::read_dir(dir.path().join("shots"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    for kind in ["theta-", "dslr-", "webcam-", "calibration.json"] {
        assert!(
            shots.iter().any(|s| s.starts_with(kind)),
            "{kind}: {shots:?}"
        );
    }
    assert!(shots.iter().any(|s| s.ends_with(".NEF")), "{shots:?}");

    // The calibrated rig is one the capture runs, and its estimate relights as the shipped
    // rig's does. (At 128²: below it, the RAW path's demosaic leaves the hybrid fit
    // unsteady on gold, calibrated or not; docs/method.md.)
    let o = brdfd(&["config", "check", "rig.toml"], dir.path());
    assert!(o.status.success(), "{}", out(&o));
    let o = capture_gold(dir.path(), "128");
    let text = out(&o);
    assert!(o.status.success(), "{text}");
    assert!(relit(&text) < 0.1, "{text}");
}

/// The albedo is what the gains hang on: a target twice as bright, said so, gives the same
/// gains; a target's albedo that is not one is refused with the field.
#[test]
fn the_target_albedo_is_the_calibration_reference() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("rig.toml"), uncalibrated()).unwrap();
    let o = calibrate(dir.path(), &["--albedo", "0.36", "--dry-run"]);
    let text = out(&o);
    assert!(o.status.success(), "{text}");
    assert!(text.contains("the rig file is left as it is"), "{text}");
    let json = record(dir.path());
    let jpeg = json["cameras"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["field"] == "calibration.dslr_jpeg")
        .unwrap();
    let over: Vec<f64> = serde_json::from_value(jpeg["over_theta"].clone()).unwrap();
    for v in over {
        assert!(
            (v / (SENSOR_GAIN / THETA_SENSOR_GAIN) - 1.0).abs() <= TOLERANCE,
            "{v}"
        );
    }
    // Left as it was.
    assert_eq!(
        std::fs::read_to_string(dir.path().join("rig.toml")).unwrap(),
        uncalibrated()
    );
    let o = brdfd(
        &[
            "calibrate",
            "radiometry",
            "--rig",
            "rig.toml",
            "--albedo",
            "1.5",
        ],
        dir.path(),
    );
    assert!(!o.status.success());
    assert!(
        out(&o).contains("[1.5, 1.5, 1.5] is not an albedo (above 0, at most 1)"),
        "{}",
        out(&o)
    );
    std::fs::write(
        dir.path().join("card.toml"),
        "albedo = 0.18\n[shape]\ntype = \"plane\"\ncenter = [0.0, 0.0, 0.0]\nnormal = [0.0, 0.0, 0.0]\nhalf_size = 0.5\n",
    )
    .unwrap();
    let o = brdfd(&["config", "check", "card.toml"], dir.path());
    assert!(!o.status.success());
    assert!(
        out(&o).contains("card.toml, line 2: field `shape`: shape.normal must not be zero"),
        "{}",
        out(&o)
    );
}

/// A rig from before the gains says how to move its measured ratio over, and the calibration
/// reads it and replaces the ratio with the gains.
#[test]
fn a_rig_with_the_old_ratio_is_told_what_to_do_and_calibrates() {
    let dir = tempfile::tempdir().unwrap();
    let old = uncalibrated().replace(
        "[calibration.theta]\ngain = 100.0\n",
        "[calibration]\ntheta_to_dslr = 1.0\ntheta_to_fallback = 62.5\n",
    );
    std::fs::write(dir.path().join("rig.toml"), &old).unwrap();
    let o = brdfd(&["config", "check", "rig.toml"], dir.path());
    let text = out(&o);
    assert!(!o.status.success());
    assert!(
        text.contains("field `calibration.theta_to_dslr`")
            && text.contains("[calibration.theta] gain = 100")
            && text.contains("[calibration.fallback] gain = 62.5"),
        "{text}"
    );
    let o = calibrate(dir.path(), &[]);
    assert!(o.status.success(), "{}", out(&o));
    let written = std::fs::read_to_string(dir.path().join("rig.toml")).unwrap();
    assert!(!written.contains("theta_to_dslr"), "{written}");
    let o = brdfd(&["config", "check", "rig.toml"], dir.path());
    assert!(o.status.success(), "{}", out(&o));
}

/// The shipped simulated rig's gains are what the calibration measures on it.
#[test]
fn the_shipped_simulated_rig_holds_the_gains_its_calibration_measures() {
    let dir = tempfile::tempdir().unwrap();
    let o = brdfd(
        &["calibrate", "radiometry", "--simulate", "--out", "shots"],
        dir.path(),
    );
    let text = out(&o);
    assert!(o.status.success(), "{text}");
    assert!(text.contains("the rig file is left as it is"), "{text}");
    let json = record(dir.path());
    let shipped = Rig::simulated();
    let cameras = json["cameras"].as_array().unwrap();
    // The shipped rig shoots JPEG: its JPEG gain and the webcam's are measured.
    assert_eq!(cameras.len(), 2, "{json}");
    for c in cameras {
        let table = c["field"]
            .as_str()
            .unwrap()
            .trim_start_matches("calibration.");
        let measured: [f64; 3] = serde_json::from_value(c["gain"].clone()).unwrap();
        let written = gain(&shipped, table);
        for ch in 0..3 {
            assert!(
                (measured[ch] / written[ch] - 1.0).abs() <= TOLERANCE,
                "{table}: measured {measured:?}, shipped {written:?}"
            );
        }
    }
}

/// A session captured before the gains is resumed as it was captured: its stored rig's
/// ratios are taken as the gains that merge as they did.
#[test]
fn a_session_from_before_the_gains_resumes() {
    let dir = tempfile::tempdir().unwrap();
    let small = include_str!("../config/rigs/simulated.toml")
        .replace("width = 256", "width = 32")
        .replace("height = 256", "height = 32")
        .replace("fallback_camera = \"v4l:simulated\"\n", "");
    // The DSLR does not answer: the capture stops after the panorama, resumable.
    std::fs::write(
        dir.path().join("rig.toml"),
        format!("{small}\n[simulation]\ndslr = \"absent\"\n"),
    )
    .unwrap();
    let o = capture_gold(dir.path(), "32");
    assert!(!o.status.success(), "{}", out(&o));
    let session = std::fs::read_dir(dir.path().join("state/sessions"))
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path();
    // Its stored rig as brdfd before the gains wrote it, with the DSLR back.
    let manifest_path = session.join("manifest.json");
    let mut manifest: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&manifest_path).unwrap()).unwrap();
    let old = small[..small.find("# Each camera's gain").unwrap()].to_string()
        + "[calibration]\ntheta_to_dslr = 1.0\n";
    manifest["rig"] = serde_json::Value::String(old);
    std::fs::write(&manifest_path, manifest.to_string()).unwrap();
    let id = session.file_name().unwrap().to_str().unwrap().to_string();
    let o = brdfd(
        &["session", "resume", &id, "--state-dir", "state"],
        dir.path(),
    );
    let text = out(&o);
    assert!(o.status.success(), "{text}");
    assert!(
        text.contains("it is resumed with the gains that merge as it did: calibration.theta 100"),
        "{text}"
    );
    assert!(
        text.contains("panorama: 8 frames already in the session"),
        "{text}"
    );
    assert!(relit(&text) < 0.2, "{text}");
}
