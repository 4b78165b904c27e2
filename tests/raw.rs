//! RAW radiometry: the simulated DSLR's NEF and DNG files decoded back to the light the
//! bench rendered, a RAW bracket's merge against a JPEG bracket's, and damaged files.

mod common;

use brdfd_bench::camera::{BenchCamera, SENSOR_GAIN};
use brdfd_bench::raw_file::{self, RawFormat, ShotInfo, D5100};
use brdfd_bench::VirtualBench;
use brdfd_core::raster::Raster;
use brdfd_radiometry::raw::{decode_raw, WhiteBalance};
use brdfd_radiometry::{decode_jpeg, merge_hdr, Frame};
use brdfd_sim::{ImageSource, Shot};
use common::shared_data;

/// A scene of known radiance: a ramp across, a colour per third down, one very bright
/// column that clips.
fn scene(w: usize, h: usize) -> Raster {
    let mut r = Raster::black(w, h);
    for y in 0..h {
        for x in 0..w {
            let ramp = 0.05 + 0.9 * x as f32 / (w - 1) as f32;
            let tint = [[1.0, 0.6, 0.3], [0.4, 1.0, 0.5], [0.5, 0.6, 1.0]][3 * y / h];
            r.pixels[y * w + x] = if x == w / 2 {
                [5.0; 3]
            } else {
                tint.map(|t| t * ramp)
            };
        }
    }
    r
}

fn info(shutter_s: f64) -> ShotInfo<'static> {
    ShotInfo {
        make: "NIKON CORPORATION",
        model: "NIKON D5100",
        shutter_s,
        f_number: 8.0,
        iso: 100,
    }
}

/// Median relative error of the white-balanced values against `truth · k`, over pixels the
/// sensor did not clip, and how many were clipped.
fn compare(frame: &Frame, truth: &Raster, k: f32) -> (f64, usize) {
    let (mut errors, mut clipped) = (Vec::new(), 0);
    for (v, t) in frame.values.pixels.iter().zip(&truth.pixels) {
        for c in 0..3 {
            if v[c] >= 1.0 {
                clipped += 1;
            } else {
                let want = t[c] * k;
                errors.push(((v[c] * frame.white_balance[c] - want) / want).abs() as f64);
            }
        }
    }
    errors.sort_by(f64::total_cmp);
    (errors[errors.len() / 2], clipped)
}

#[test]
fn nef_and_dng_from_the_simulated_sensor_decode_to_the_scene() {
    let truth = scene(96, 60);
    let k = 0.8;
    for (name, bytes) in [
        ("a.NEF", raw_file::nef(&truth, k, &D5100, &info(0.004), 1)),
        ("a.DNG", raw_file::dng(&truth, k, &D5100, &info(0.004), 1)),
        (
            "a12.DNG",
            raw_file::dng(&truth, k, &D5100.at_12_bits(), &info(0.004), 1),
        ),
    ] {
        let f = decode_raw(&bytes, name, WhiteBalance::AsShot).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(
            (f.values.width, f.values.height),
            (96, 60),
            "{name}: the crop is the rendered image"
        );
        assert_eq!(f.exposure.shutter_s, 0.004, "{name}");
        assert_eq!(
            (f.exposure.f_number, f.exposure.iso),
            (8.0, 100.0),
            "{name}"
        );
        let wb = D5100.white_balance();
        for c in 0..3 {
            assert!(
                (f.white_balance[c] - wb[c]).abs() < 0.01 * wb[c],
                "{name}: white balance {:?}, the sensor's {wb:?}",
                f.white_balance
            );
        }
        let (median, clipped) = compare(&f, &truth, k);
        // The sensor's noise and the demosaic's averaging across the ramp; a few tenths of
        // a per cent.
        assert!(median < 0.01, "{name}: median error {median}");
        // The bright column and its neighbours (the demosaic reaches one pixel across).
        assert!(
            (3 * 60..=9 * 60).contains(&clipped),
            "{name}: {clipped} clipped"
        );
    }
}

#[test]
fn a_fixed_white_balance_replaces_the_files() {
    let truth = scene(32, 24);
    let k = 0.5;
    let bytes = raw_file::nef(&truth, k, &D5100, &info(0.01), 2);
    // Multipliers of 1 leave the sensor's own response: its filters' sensitivity.
    let f = decode_raw(&bytes, "b.NEF", WhiteBalance::Fixed([1.0; 3])).unwrap();
    assert_eq!(f.white_balance, [1.0; 3]);
    for c in 0..3 {
        let mut ratios: Vec<f32> = f
            .values
            .pixels
            .iter()
            .zip(&truth.pixels)
            .filter(|(v, _)| v[c] < 1.0)
            .map(|(v, t)| v[c] / (t[c] * k))
            .collect();
        ratios.sort_by(f32::total_cmp);
        let median = ratios[ratios.len() / 2];
        let want = D5100.sensitivity[c];
        assert!(
            (median / want - 1.0).abs() < 0.02,
            "channel {c}: {median}, the sensor's {want}"
        );
    }
}

#[test]
fn damaged_raw_files_are_named_and_do_not_panic() {
    let bytes = raw_file::nef(&scene(64, 32), 0.5, &D5100, &info(0.01), 3);
    for cut in [0, 8, 200, bytes.len() / 2, bytes.len() - 10] {
        let e = match decode_raw(&bytes[..cut], "DSC_0001.NEF", WhiteBalance::AsShot) {
            Ok(_) => panic!("a NEF cut to {cut} bytes decoded"),
            Err(e) => e.to_string(),
        };
        println!("cut to {cut} bytes: {e}");
        assert!(e.starts_with("DSC_0001.NEF: "), "{cut}: {e}");
    }
    // A file that is no RAW at all.
    let e = decode_raw(b"not a raw file", "x.dng", WhiteBalance::AsShot)
        .err()
        .expect("refused");
    assert!(e.to_string().starts_with("x.dng: RAW: "), "{e}");
}

#[test]
fn a_real_nef_without_its_raw_data_is_refused_clearly() {
    let Some(data) = shared_data() else { return };
    // Exiftool's test file: a real D70 NEF's structure with the raw strips removed.
    let bytes = std::fs::read(data.join("nef/Nikon_D70_metadata_only.nef")).unwrap();
    let e = decode_raw(&bytes, "Nikon.nef", WhiteBalance::AsShot)
        .err()
        .expect("refused");
    println!("{e}");
    assert!(e.to_string().starts_with("Nikon.nef: "), "{e}");
}

/// The simulated D5100's bracket of the gold sphere: every shutter speed as NEF and as
/// JPEG, each merged, against the radiance the bench rendered.
#[test]
fn a_raw_bracket_merges_to_the_bench_truth_within_one_per_cent() {
    let bench = VirtualBench::embedded("gold", 128).unwrap();
    let truth = bench.photo().unwrap();
    let camera = BenchCamera::new(bench, "NIKON CORPORATION", "NIKON D5100");
    let shutters = [1.0 / 1000.0, 1.0 / 250.0, 1.0 / 60.0, 1.0 / 15.0, 1.0 / 4.0];
    let (mut raw, mut jpeg) = (Vec::new(), Vec::new());
    for (i, &s) in shutters.iter().enumerate() {
        let shot = Shot {
            shutter_s: s,
            f_number: 8.0,
            iso: 100,
            raw: true,
            sequence: i as u32 + 1,
        };
        let (_, nef) = camera.raw(&shot).unwrap().unwrap();
        raw.push(decode_raw(&nef, "DSC.NEF", WhiteBalance::AsShot).unwrap());
        jpeg.push(decode_jpeg(&camera.photo(&shot).unwrap(), "DSC.JPG").unwrap());
    }
    let error = |frames: &[Frame]| {
        let merged = merge_hdr(frames, SENSOR_GAIN).unwrap();
        // Pixels the bracket resolves: the object, not black, not beyond the shortest
        // exposure's white.
        let top = (0.9 / (shutters[0] / 64.0 * SENSOR_GAIN)) as f32;
        let mut e: Vec<f64> = merged
            .pixels
            .iter()
            .zip(&truth.pixels)
            .flat_map(|(m, t)| (0..3).map(move |c| (m[c], t[c])))
            .filter(|&(_, t)| t > 1e-3 && t < top)
            .map(|(m, t)| ((m - t) / t).abs() as f64)
            .collect();
        e.sort_by(f64::total_cmp);
        (e[e.len() / 2], e.len())
    };
    let ((raw_error, n), (jpeg_error, _)) = (error(&raw), error(&jpeg));
    println!(
        "median relative error of the merged radiance over {n} values: RAW {:.3}%, JPEG {:.3}%",
        raw_error * 100.0,
        jpeg_error * 100.0
    );
    assert!(raw_error < 0.01, "RAW: {raw_error}");
    assert!(raw_error < jpeg_error, "RAW {raw_error}, JPEG {jpeg_error}");
}

#[test]
fn the_simulated_camera_writes_the_raw_format_it_is_set_to() {
    let bench = VirtualBench::embedded("gold", 32).unwrap();
    let shot = Shot {
        shutter_s: 0.01,
        f_number: 8.0,
        iso: 200,
        raw: true,
        sequence: 1,
    };
    for (format, ext) in [
        (RawFormat::Nef, "NEF"),
        (RawFormat::Dng, "DNG"),
        (RawFormat::Dng12, "DNG"),
    ] {
        let cam =
            BenchCamera::new(bench.clone(), "NIKON CORPORATION", "NIKON D5100").with_raw(format);
        let (got, bytes) = cam.raw(&shot).unwrap().unwrap();
        assert_eq!(got, ext);
        let f = decode_raw(&bytes, got, WhiteBalance::AsShot).unwrap();
        assert_eq!((f.values.width, f.exposure.iso), (32, 200.0), "{format:?}");
    }
}

const SIMULATED_RIG: &str = include_str!("../config/rigs/simulated.toml");

/// `brdfd capture` of gold at 64² on the simulated rig with its DSLR set to `files` and
/// `simulation` as its `[simulation]`: the output, and the names of the files stored for
/// view 1.
fn capture(files: &str, simulation: &str) -> (String, Vec<String>) {
    let dir = tempfile::tempdir().unwrap();
    assert!(SIMULATED_RIG.contains("dslr_files = \"jpeg\""));
    write_rig(dir.path(), files, simulation);
    let args = [
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
    let o = common::brdfd(&args, dir.path());
    let text = common::out(&o);
    assert!(o.status.success(), "{text}");
    let session = std::fs::read_dir(dir.path().join("state/sessions"))
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path();
    let mut names: Vec<String> = std::fs::read_dir(session.join("raw"))
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with("view1"))
        .collect();
    names.sort();
    (text, names)
}

#[test]
fn a_capture_keeps_both_files_of_each_shot_and_merges_the_raw_ones() {
    for (raw, ext) in [("nef", "NEF"), ("dng12", "DNG")] {
        let (text, names) = capture("raw+jpeg", &format!("dslr_raw = \"{raw}\""));
        assert_eq!(names.len(), 10, "{raw}: five shots of two files: {names:?}");
        assert_eq!(
            names.iter().filter(|n| n.ends_with(ext)).count(),
            5,
            "{names:?}"
        );
        assert!(
            text.contains(&format!(
                "DSC_0001.{ext}: RAW 64×64, EXIF 0.0010 s f/8 ISO 100"
            )),
            "{text}"
        );
        assert!(
            !text.contains(": JPEG, EXIF"),
            "{raw}: the JPEGs were merged\n{text}"
        );
    }
    // Told to shoot JPEG (as the shipped simulated rig is), the camera makes one file per
    // shot, and the JPEGs are merged.
    let (text, names) = capture("jpeg", "");
    assert_eq!(names.len(), 5, "{names:?}");
    assert!(text.contains("DSC_0001.JPG: JPEG, EXIF 0.0010 s"), "{text}");
}

/// The shipped simulated rig at 64², its DSLR shooting `files`, with `simulation` as its
/// `[simulation]`, written to `dir/rig.toml`.
fn write_rig(dir: &std::path::Path, files: &str, simulation: &str) -> std::path::PathBuf {
    let rig = format!(
        "{}\n[simulation]\n{simulation}\n",
        SIMULATED_RIG
            .replace("width = 256", "width = 64")
            .replace("height = 256", "height = 64")
            .replace(
                "dslr_files = \"jpeg\"",
                &format!("dslr_files = \"{files}\"")
            )
    );
    let path = dir.join("rig.toml");
    std::fs::write(&path, rig).unwrap();
    path
}

/// Issue 40: a camera's RAW file that declares a 34 GB image, or whose IFDs loop, used to
/// abort the daemon (or grow it without end) on capture and again on every resume. Through
/// the daemon: the session fails with the file and the fault named, keeps the file, says
/// the same on resume, and the daemon serves on. Given JPEGs beside the RAW files, the
/// capture merges those instead.
#[test]
fn a_damaged_raw_file_fails_its_capture_clearly_and_the_daemon_serves_on() {
    for (damage, says) in [
        ("oversized", "declares an image of 131072 × 131072 pixels"),
        ("ifd_loop", "the file's IFDs form a loop"),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let simulation = format!("dslr_raw = \"dng\"\ndslr_raw_damage = \"{damage}\"");
        let rig = write_rig(dir.path(), "raw", &simulation);
        let daemon =
            common::Daemon::start(&dir.path().join("state"), &["--rig", rig.to_str().unwrap()]);
        let (status, started) = daemon.post(
            "/sessions",
            serde_json::json!({ "material": "gold", "size": 64 }),
        );
        assert_eq!(status, 202, "{started}");
        let id = started["id"].as_str().unwrap().to_string();
        let last = daemon.events(&id).last().cloned().unwrap();
        assert_eq!(last["state"], "failed", "{damage}: {last}");
        let error = last["error"].as_str().unwrap();
        assert!(
            error.contains("DSC_0001.DNG") && error.contains(says),
            "{damage}: {error}"
        );
        // The files are kept, each with its checksum.
        let (status, shown) = daemon.get(&format!("/sessions/{id}"));
        assert_eq!(status, 200);
        let kept: usize = shown["manifest"]["steps"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|s| s["name"] == "view1")
            .map(|s| s["files"].as_array().unwrap().len())
            .sum();
        assert_eq!(kept, 5, "{damage}: {shown}");
        // Resumed, it fails again for the same reason, and the daemon is still there.
        let (status, body) = daemon.post(&format!("/sessions/{id}/resume"), serde_json::json!({}));
        assert_eq!(status, 202, "{body}");
        let last = daemon.events(&id).last().cloned().unwrap();
        assert_eq!(last["state"], "failed", "{damage}: {last}");
        assert!(last["error"].as_str().unwrap().contains(says), "{last}");
        assert_eq!(daemon.get("/health").0, 200);
    }

    // RAW + JPEG: the JPEGs are merged, and the warning says why.
    let (text, names) = capture(
        "raw+jpeg",
        "dslr_raw = \"dng\"\ndslr_raw_damage = \"ifd_loop\"",
    );
    assert_eq!(names.len(), 10, "{names:?}");
    assert!(
        text.contains("the file's IFDs form a loop")
            && text.contains("merging the JPEG files instead"),
        "{text}"
    );
}

/// Issue 40: a camera that reuses a file name across a bracket (after a card change, or
/// shooting to memory) failed every capture ("already captured"). Every file is kept, under
/// a name with its frame, and merged.
#[test]
fn a_camera_that_reuses_file_names_loses_no_file() {
    let (text, names) = capture("raw+jpeg", "dslr_reuses_file_names = true");
    assert_eq!(names.len(), 10, "{names:?}");
    for frame in 1..=10 {
        assert!(
            names
                .iter()
                .any(|n| n.starts_with(&format!("view1-a1-{frame:02}-DSC_0001."))),
            "frame {frame}: {names:?}"
        );
    }
    assert_eq!(text.matches("DSC_0001.NEF: RAW 64×64").count(), 5, "{text}");
}

/// Issue 40: the binary decodes each RAW file in a child process. Its answer is the frame the
/// library decodes in-process, and a child past its memory or its time fails the file with a
/// clear error instead of taking the caller with it.
#[test]
fn the_decoder_process_answers_exactly_and_is_stopped_past_its_budget() {
    use brdfd_radiometry::isolated::{decode, Budget};
    use brdfd_radiometry::raw::decode_raw_here;
    use std::time::Duration;

    let program = std::path::Path::new(env!("CARGO_BIN_EXE_brdfd"));
    let truth = scene(96, 64);
    let dng = raw_file::dng(&truth, 0.5, &D5100, &info(0.01), 7);
    let budget = Budget::for_file(dng.len());
    let child = decode(program, &dng, "DSC_0001.DNG", WhiteBalance::AsShot, budget).unwrap();
    let here = decode_raw_here(&dng, "DSC_0001.DNG", WhiteBalance::AsShot).unwrap();
    assert_eq!(child.values.pixels, here.values.pixels);
    assert_eq!(child.exposure, here.exposure);
    assert_eq!(child.white_balance, here.white_balance);
    // The fixed white balance reaches the child.
    let fixed = WhiteBalance::Fixed([2.0, 1.0, 1.5]);
    let child = decode(program, &dng, "DSC_0001.DNG", fixed, budget).unwrap();
    assert_eq!(child.white_balance, [2.0, 1.0, 1.5]);

    let starved = Budget {
        memory: 16 << 20,
        ..budget
    };
    let e = decode(program, &dng, "DSC_0001.DNG", WhiteBalance::AsShot, starved)
        .err()
        .unwrap()
        .to_string();
    assert!(
        e.starts_with("DSC_0001.DNG: RAW: the decoder needed more than its 16 MB of memory")
            && e.contains("(memory allocation of"),
        "{e}"
    );
    let hurried = Budget {
        time: Duration::from_millis(1),
        ..budget
    };
    let e = decode(program, &dng, "DSC_0001.DNG", WhiteBalance::AsShot, hurried)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("took longer than 1ms on this file"), "{e}");

    // A file the decoder refuses is refused in the child's words.
    let mut damaged = dng.clone();
    raw_file::damage(&mut damaged, raw_file::RawDamage::IfdLoop);
    let e = decode(
        program,
        &damaged,
        "DSC_0001.DNG",
        WhiteBalance::AsShot,
        budget,
    )
    .err()
    .unwrap()
    .to_string();
    assert!(
        e.starts_with("DSC_0001.DNG: RAW: the file is damaged: IFD0"),
        "{e}"
    );
}
