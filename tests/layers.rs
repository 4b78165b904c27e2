//! The workspace's floor plan (docs/architecture.md), checked from Cargo's own dependency
//! graph: the estimation core depends on no runtime, HTTP stack, device driver or the API's
//! schema crate, and stays near a hundred packages. Cargo itself refuses cycles between
//! crates; this refuses a dependency that points up.

use std::process::Command;

/// The packages a build of `package` compiles (normal dependencies, itself included).
fn packages(package: &str, features: &[&str]) -> Vec<String> {
    let mut args = vec![
        "tree",
        "--offline",
        "-p",
        package,
        "-e",
        "normal",
        "--prefix",
        "none",
    ];
    if !features.is_empty() {
        args.extend(["--features", features[0]]);
    }
    let o = Command::new(env!("CARGO"))
        .args(&args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("cargo runs");
    assert!(
        o.status.success(),
        "cargo tree: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let mut names: Vec<String> = String::from_utf8_lossy(&o.stdout)
        .lines()
        .filter_map(|l| l.split_whitespace().next())
        .map(str::to_string)
        .collect();
    names.sort();
    names.dedup();
    names
}

#[test]
fn the_core_knows_no_runtime_http_driver_or_schema() {
    let core = packages("brdfd-core", &[]);
    let forbidden = [
        "tokio",
        "hyper",
        "axum",
        "reqwest",
        "utoipa",
        "rusb",
        "serialport",
        "v4l",
        "brdfd",
        "brdfd-ptp",
        "brdfd-theta",
        "brdfd-serial",
        "brdfd-v4l",
        "brdfd-sim",
        "brdfd-eval",
    ];
    let found: Vec<&String> = core
        .iter()
        .filter(|p| forbidden.contains(&p.as_str()))
        .collect();
    assert!(found.is_empty(), "brdfd-core depends on {found:?}");
    // Issue 39's figure: at most 100 packages (98 when it was split out).
    assert!(
        core.len() <= 100,
        "brdfd-core builds {} packages",
        core.len()
    );
    // With its schema feature, utoipa and nothing of the daemon's.
    let schema = packages("brdfd-core", &["schema"]);
    assert!(schema.iter().any(|p| p == "utoipa"), "{schema:?}");
    assert!(
        !schema.iter().any(|p| p == "tokio" || p == "axum"),
        "{schema:?}"
    );
}

#[test]
fn the_evaluation_sits_on_the_core_alone() {
    let eval = packages("brdfd-eval", &[]);
    for p in [
        "brdfd",
        "brdfd-rig",
        "brdfd-daemon",
        "tokio",
        "axum",
        "brdfd-ptp",
        "brdfd-sim",
    ] {
        assert!(!eval.iter().any(|e| e == p), "brdfd-eval depends on {p}");
    }
    assert!(eval.iter().any(|e| e == "brdfd-core"));
}

/// Asserts that `package` builds none of `forbidden`, and builds the core.
fn sits_on_the_core(package: &str, forbidden: &[&str]) {
    let built = packages(package, &[]);
    for p in forbidden {
        assert!(!built.iter().any(|e| e == p), "{package} depends on {p}");
    }
    assert!(built.iter().any(|e| e == "brdfd-core"));
}

/// The layers above the drivers: none of them may build the binary's runtime or HTTP stack.
const ABOVE_THE_CORE: [&str; 9] = [
    "brdfd",
    "tokio",
    "axum",
    "hyper",
    "utoipa",
    "brdfd-ptp",
    "brdfd-theta",
    "brdfd-serial",
    "brdfd-sim",
];

#[test]
fn radiometry_sits_on_the_core_and_the_fallback_s_frame_type() {
    let mut forbidden = ABOVE_THE_CORE.to_vec();
    forbidden.push("brdfd-eval");
    sits_on_the_core("brdfd-radiometry", &forbidden);
}

/// Pose needs a photo's pixels and the core's geometry, not how the photo's file was read: the
/// lens's focal length comes in as numbers, not as EXIF.
#[test]
fn pose_sits_on_the_core_alone() {
    let mut forbidden = ABOVE_THE_CORE.to_vec();
    forbidden.extend(["brdfd-eval", "brdfd-radiometry", "brdfd-v4l"]);
    sits_on_the_core("brdfd-pose", &forbidden);
}

/// The exports, the report and its pictures need an estimate and the core's rendering, not how
/// it was captured: nothing of the rig, the camera files or the evaluation.
#[test]
fn the_report_and_the_exports_sit_on_the_core_alone() {
    let mut forbidden = ABOVE_THE_CORE.to_vec();
    forbidden.extend(["brdfd-eval", "brdfd-radiometry", "brdfd-pose", "brdfd-v4l"]);
    sits_on_the_core("brdfd-report", &forbidden);
}

/// The contract between the daemon and its clients is data: any client can build it without
/// the daemon's runtime, HTTP stack or drivers, and without the rest of brdfd. With its schema
/// feature (the daemon's OpenAPI description) it adds utoipa and nothing else of the daemon's.
#[test]
fn the_api_contract_sits_on_the_core_alone() {
    let mut forbidden = ABOVE_THE_CORE.to_vec();
    forbidden.extend([
        "reqwest",
        "brdfd-eval",
        "brdfd-radiometry",
        "brdfd-pose",
        "brdfd-report",
        "brdfd-v4l",
    ]);
    sits_on_the_core("brdfd-api", &forbidden);
    let schema = packages("brdfd-api", &["schema"]);
    assert!(schema.iter().any(|p| p == "utoipa"), "{schema:?}");
    for p in ["brdfd", "tokio", "axum", "hyper"] {
        assert!(
            !schema.iter().any(|e| e == p),
            "brdfd-api with its schema builds {p}"
        );
    }
}

/// The virtual bench renders what the simulated cameras photograph: it needs the core, the
/// printed board, the reference lights and the simulators (whose image source its cameras
/// are), and nothing of the rig, the daemon's contract or schema, or the evaluation. The
/// simulated rig depends on it; the rig and the daemon do not (below).
#[test]
fn the_virtual_bench_sits_below_the_rig() {
    let built = packages("brdfd-bench", &[]);
    for p in ["brdfd", "brdfd-api", "brdfd-eval", "utoipa"] {
        assert!(!built.iter().any(|e| e == p), "brdfd-bench depends on {p}");
    }
    for p in ["brdfd-core", "brdfd-sim"] {
        assert!(built.iter().any(|e| e == p), "brdfd-bench lacks {p}");
    }
}

/// The rig runs captures for the binary and the daemon alike, and builds neither (Cargo would
/// refuse that cycle before this test could), nor the command line, the evaluation or
/// (without its schema feature) the API's description. Nor the simulated rig: its
/// simulators and the virtual bench they photograph sit above the rig, behind its
/// simulation seam. Its devices' drivers bring their own HTTP (the THETA's Web API), which
/// is why tokio is not refused here.
#[test]
fn the_rig_sits_below_the_daemon_and_the_binary() {
    let built = packages("brdfd-rig", &[]);
    for p in [
        "brdfd-eval",
        "clap",
        "indicatif",
        "utoipa",
        "brdfd-bench",
        "brdfd-sim",
        "brdfd-simrig",
    ] {
        assert!(!built.iter().any(|e| e == p), "brdfd-rig depends on {p}");
    }
    for p in ["brdfd-core", "brdfd-api", "brdfd-ptp", "brdfd-report"] {
        assert!(built.iter().any(|e| e == p), "brdfd-rig lacks {p}");
    }
    let schema = packages("brdfd-rig", &["schema"]);
    assert!(schema.iter().any(|p| p == "utoipa"), "{schema:?}");
}

/// The daemon serves the rig over HTTP, and the binary starts it: it needs neither the
/// command line nor the evaluation, nor the simulated rig, which the binary provides.
#[test]
fn the_daemon_sits_below_the_binary() {
    let built = packages("brdfd-daemon", &[]);
    for p in [
        "brdfd-eval",
        "clap",
        "indicatif",
        "brdfd-bench",
        "brdfd-sim",
        "brdfd-simrig",
    ] {
        assert!(!built.iter().any(|e| e == p), "brdfd-daemon depends on {p}");
    }
    for p in ["brdfd-rig", "brdfd-api", "axum", "tokio"] {
        assert!(built.iter().any(|e| e == p), "brdfd-daemon lacks {p}");
    }
}

/// The simulated rig fills the rig's simulation seam with the simulators and the virtual
/// bench: it sits on the rig, and below the daemon and the command line; only the binary
/// joins them. (Its THETA simulator serves the Web API with axum, as the daemon does.)
#[test]
fn the_simulated_rig_sits_on_the_rig() {
    let built = packages("brdfd-simrig", &[]);
    for p in ["brdfd", "brdfd-daemon", "brdfd-eval", "clap", "utoipa"] {
        assert!(!built.iter().any(|e| e == p), "brdfd-simrig depends on {p}");
    }
    for p in ["brdfd-rig", "brdfd-bench", "brdfd-sim"] {
        assert!(built.iter().any(|e| e == p), "brdfd-simrig lacks {p}");
    }
}
