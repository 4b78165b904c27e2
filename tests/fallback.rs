//! The V4L2 fallback camera, as a user meets it: `brdfd capture` on the simulated rig whose
//! DSLR is not there, or powers off mid-bracket, finishes on the simulated webcam; a rig with
//! no fallback ends in an error that says so. The fallback's photo is put in the DSLR's units
//! by the rig's calibration, so the estimate relights as the DSLR's does.

mod common;

use common::{brdfd, out, relit};

const SIMULATED_RIG: &str = include_str!("../config/rigs/simulated.toml");

/// The shipped simulated rig with a `[simulation]` table, and its object camera at 64².
fn rig_with(simulation: &str) -> String {
    format!(
        "{}\n[simulation]\n{simulation}\n",
        SIMULATED_RIG
            .replace("width = 256", "width = 64")
            .replace("height = 256", "height = 64")
    )
}

/// Captures gold with `rig` (and extra arguments); the output and the session's
/// `result/coefficients.json`, if it was written.
fn capture(rig: &str, extra: &[&str]) -> (bool, String, Option<serde_json::Value>) {
    let (ok, text, coefficients, _) = capture_with_manifest(rig, extra);
    (ok, text, coefficients)
}

/// [`capture`], with the session's manifest.
fn capture_with_manifest(
    rig: &str,
    extra: &[&str],
) -> (
    bool,
    String,
    Option<serde_json::Value>,
    Option<serde_json::Value>,
) {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("rig.toml"), rig).unwrap();
    let mut args = vec![
        "capture",
        "--rig",
        "rig.toml",
        "--material",
        "gold",
        "--size",
        "64",
        "--state-dir",
        "state",
    ];
    args.extend_from_slice(extra);
    let o = brdfd(&args, dir.path());
    let text = out(&o);
    let session = std::fs::read_dir(dir.path().join("state/sessions"))
        .ok()
        .and_then(|mut d| d.next())
        .map(|e| e.unwrap().path());
    let read = |name: &str| {
        let text = std::fs::read_to_string(session.as_ref()?.join(name)).ok()?;
        Some(serde_json::from_str(&text).unwrap())
    };
    let (coefficients, manifest) = (read("result/coefficients.json"), read("manifest.json"));
    (o.status.success(), text, coefficients, manifest)
}

#[test]
fn a_missing_dslr_is_replaced_by_the_fallback_camera() {
    let (ok, dslr, _) = capture(&rig_with(""), &[]);
    assert!(ok, "{dslr}");
    let (ok, text, coefficients) = capture(&rig_with("dslr = \"absent\""), &[]);
    assert!(ok, "{text}");
    assert!(
        text.contains("the DSLR does not answer") && text.contains("v4l:simulated"),
        "{text}"
    );
    assert!(text.contains("frames averaged at 0.0003 s"), "{text}");
    // The summary says what the fallback shot and what its noise is.
    let said = coefficients.unwrap()["fallback"]
        .as_str()
        .expect("coefficients.json says the fallback was used")
        .to_string();
    assert!(said.contains("shot 1 of 1 view"), "{said}");
    assert!(said.contains("noise of the averaged frames"), "{said}");
    // In the DSLR's units through the calibration: the estimate relights as the DSLR's does.
    let (with_dslr, with_fallback) = (relit(&dslr), relit(&text));
    assert!(
        with_fallback < 0.1 && (with_fallback - with_dslr).abs() < 0.02,
        "relit error {with_fallback} on the fallback, {with_dslr} on the DSLR"
    );
}

#[test]
fn a_dslr_that_powers_off_mid_capture_hands_over_to_the_fallback() {
    // Two views of five frames: the DSLR powers off when asked for the seventh, in view 2.
    let (ok, text, coefficients) =
        capture(&rig_with("dslr_powers_off_after = 6"), &["--views", "2"]);
    assert!(ok, "{text}");
    assert!(
        text.contains("the DSLR failed during view2")
            && text.contains("view2 is shot again on the fallback camera"),
        "{text}"
    );
    let said = coefficients.unwrap()["fallback"]
        .as_str()
        .unwrap()
        .to_string();
    assert!(said.contains("shot 1 of 2 views"), "{said}");
    assert!(relit(&text) < 0.1, "{text}");
}

#[test]
fn a_missing_dslr_without_a_fallback_is_a_clear_error() {
    let rig = rig_with("dslr = \"absent\"").replace("fallback_camera = \"v4l:simulated\"\n", "");
    let (ok, text, _, manifest) = capture_with_manifest(&rig, &[]);
    assert!(!ok, "{text}");
    assert!(
        text.contains("the DSLR does not answer, and the rig names no fallback_camera"),
        "{text}"
    );
    // With the DSLR's own error, and its code for programs in the manifest.
    assert!(text.contains("could not be opened"), "{text}");
    let manifest = manifest.expect("the session was created");
    let failed = manifest["history"].as_array().unwrap().last().unwrap();
    assert_eq!(
        (&failed["state"], &failed["code"]),
        (
            &serde_json::json!("failed"),
            &serde_json::json!("device_missing")
        ),
        "{failed}"
    );
}

#[test]
fn config_check_names_what_a_fallback_needs() {
    let dir = tempfile::tempdir().unwrap();
    let check = |name: &str, rig: String| {
        std::fs::write(dir.path().join(name), rig).unwrap();
        let o = brdfd(&["config", "check", name], dir.path());
        (o.status.success(), out(&o))
    };
    let (ok, text) = check(
        "uncalibrated.toml",
        SIMULATED_RIG.replace("[calibration.fallback]\ngain = 62.5\n", ""),
    );
    assert!(!ok, "{text}");
    assert!(
        text.contains("calibration.fallback.gain") && text.contains("brdfd calibrate radiometry"),
        "{text}"
    );
    let (ok, text) = check(
        "real-webcam.toml",
        SIMULATED_RIG.replace("v4l:simulated", "v4l:/dev/video0"),
    );
    assert!(!ok, "{text}");
    assert!(
        text.contains("devices.fallback_camera") && text.contains("v4l:simulated"),
        "{text}"
    );
    let (ok, text) = check(
        "no-frames.toml",
        SIMULATED_RIG.replace("fallback_frames = 8", "fallback_frames = 0"),
    );
    assert!(!ok, "{text}");
    assert!(text.contains("brackets.fallback_frames"), "{text}");
    let (ok, text) = check("simulation.toml", rig_with("dslr = \"absent\""));
    assert!(ok, "{text}");
    let (ok, text) = check(
        "not-simulated.toml",
        rig_with("dslr = \"absent\"").replace("simulated = true", "simulated = false"),
    );
    assert!(!ok, "{text}");
    assert!(text.contains("simulation"), "{text}");
}
