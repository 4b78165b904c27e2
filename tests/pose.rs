//! The camera's pose from a photo of the printed board: photos rendered by the virtual bench
//! at known poses (a 4 × 4 supersampled card, blurred, with sensor noise, through the
//! simulated camera's 8-bit JPEG with EXIF), then found again by `brdfd_pose::calibrate`.

mod common;

use brdfd_bench::board_photo::{self, Spoil};
use brdfd_bench::camera::BenchCamera;
use brdfd_bench::{studio_envmap, VirtualBench};
use brdfd_core::geometry::{Camera, Pose, Shape};
use brdfd_core::raster::Raster;
use brdfd_pose::board::Board;
use brdfd_pose::{angle_between_deg, calibrate, find, pinhole, Calibrated, Focal};
use brdfd_rig::pose::Photo;
use brdfd_sim::{ImageSource, Shot};

const WIDTH: usize = 1600;
const HEIGHT: usize = 1064;
const FX: f64 = 1850.0;

fn camera(position: [f64; 3], look_at: [f64; 3], up: [f64; 3]) -> Camera {
    Camera::Pinhole {
        width: WIDTH,
        height: HEIGHT,
        fx: FX,
        fy: FX,
        cx: WIDTH as f64 / 2.0 + 3.0,
        cy: HEIGHT as f64 / 2.0 - 2.0,
        pose: Pose {
            position,
            look_at,
            up,
        },
    }
}

/// The JPEG the simulated D5100 writes of `radiance`, exposed to put its brightest percent
/// just under white.
fn jpeg(radiance: Raster, camera: &Camera) -> Vec<u8> {
    let mut lum: Vec<f32> = radiance.pixels.iter().map(|p| p[1]).collect();
    lum.sort_by(f32::total_cmp);
    let bright = lum[lum.len() * 99 / 100] as f64;
    let f_number = 8.0;
    let shot = Shot {
        shutter_s: 0.85 * f_number * f_number / (bright * brdfd_bench::camera::SENSOR_GAIN),
        f_number,
        iso: 100,
        raw: false,
        sequence: 1,
    };
    BenchCamera::of_radiance(radiance, camera, "NIKON CORPORATION", "NIKON D5100")
        .photo(&shot)
        .unwrap()
}

/// What the operator typed into the rig before calibrating: the camera about where it is,
/// and a focal length 4% off.
fn rough(truth: &Camera) -> Camera {
    placed_roughly(truth, 1.04)
}

/// The rig's camera with the truth's intrinsics and a rough pose: a camera whose focal length
/// is known (measured once, say), placed again.
fn known_focal(truth: &Camera) -> Camera {
    placed_roughly(truth, 1.0)
}

/// `truth` with its focal lengths scaled by `focal`, standing about where it is.
fn placed_roughly(truth: &Camera, focal: f64) -> Camera {
    let mut c = truth.clone();
    let Camera::Pinhole { fx, fy, pose, .. } = &mut c else {
        unreachable!()
    };
    (*fx, *fy) = (*fx * focal, *fy * focal);
    *pose = Pose {
        position: [0.0, 0.1, 0.6],
        look_at: [0.0; 3],
        up: [0.0, 1.0, 0.0],
    };
    c
}

/// The pose from one photo of the default board as placed.
fn solve_photo(rig: &Camera, p: &Photo, focal: Focal) -> anyhow::Result<Calibrated> {
    let board = Board::default();
    let found = find(&board, &p.grey, &p.name, 0.0)?;
    let lens = brdfd_rig::pose::lens_focal(p.exif, found.size.0, None);
    Ok(calibrate(rig, vec![found], [0.0; 3], lens, focal)?)
}

struct Errors {
    rms_px: f64,
    rotation_deg: f64,
    translation_mm: f64,
    focal: f64,
}

fn errors(truth: &Camera, c: &Calibrated) -> Errors {
    let (kt, et) = pinhole(truth).unwrap();
    let (kf, ef) = pinhole(&c.camera).unwrap();
    Errors {
        rms_px: c.fit.rms_px,
        rotation_deg: angle_between_deg(&et.rotation, &ef.rotation),
        translation_mm: (et.centre() - ef.centre()).norm() * 1000.0,
        focal: kf.fx / kt.fx - 1.0,
    }
}

#[test]
fn board_photos_at_known_poses_give_the_pose_back() {
    let env = studio_envmap(256);
    let board = Board::default();
    // Half a metre from the board: square-on, turned 30° and lower, rolled and from below.
    let poses = [
        camera([0.0, 0.04, 0.5], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0]),
        camera([0.25, 0.1, 0.42], [0.01, -0.01, 0.0], [0.0, 1.0, 0.0]),
        camera([-0.22, -0.16, 0.4], [0.0, 0.01, 0.0], [0.12, 1.0, 0.0]),
    ];
    let mut worst = (0.0f64, 0.0f64, 0.0f64);
    for (i, truth) in poses.iter().enumerate() {
        let radiance = board_photo::render(
            &board,
            truth,
            &env,
            0.0,
            Spoil {
                seed: i as u64 + 1,
                ..Spoil::default()
            },
        )
        .unwrap();
        let photo = Photo::decode("board.jpg", &jpeg(radiance, truth)).unwrap();
        // The pose, the focal length known.
        let e = errors(
            truth,
            &solve_photo(&known_focal(truth), &photo, Focal::Fixed).unwrap(),
        );
        // The focal length 4% off and no EXIF: refined where the view allows.
        let mut stripped = Photo {
            name: photo.name.clone(),
            grey: photo.grey.clone(),
            exif: None,
        };
        let without = solve_photo(&rough(truth), &stripped, Focal::Refine).unwrap();
        // From the EXIF, as the simulated D5100 writes it (as Nikon does: FocalLength and the
        // nominal 35 mm equivalent), refined where the view allows.
        stripped.exif = photo.exif;
        let exif = solve_photo(&rough(truth), &stripped, Focal::Refine).unwrap();
        let refined = |c: &Calibrated| match &c.fit.focal {
            Ok(s) => format!(
                "refined to {:+.3}% (σ {:.3}%)",
                errors(truth, c).focal * 100.0,
                s * 100.0
            ),
            Err(why) => format!("{:+.2}%, {why}", errors(truth, c).focal * 100.0),
        };
        println!(
            "pose {i}: {:.3} px RMS, rotation {:.4}°, position {:.3} mm (focal length known); without EXIF: focal {}; from EXIF ({}): {}",
            e.rms_px,
            e.rotation_deg,
            e.translation_mm,
            refined(&without),
            exif.start_from,
            refined(&exif),
        );
        assert!(e.rms_px <= 0.5, "pose {i}: {} px RMS", e.rms_px);
        assert!(e.rotation_deg <= 0.2, "pose {i}: {}°", e.rotation_deg);
        assert!(e.translation_mm <= 1.0, "pose {i}: {} mm", e.translation_mm);
        // The 35 mm equivalent starts within 2% (36 mm over 1.5 against the D5100's 23.6 mm).
        assert!(
            exif.start_from.contains("35 mm film"),
            "{}",
            exif.start_from
        );
        assert!(
            (exif.start_fx / FX - 1.0).abs() < 0.02,
            "pose {i}: {}",
            exif.start_fx
        );
        if i > 0 {
            // A slanted view pins the focal length down by itself.
            for c in [&without, &exif] {
                assert!(c.fit.focal.is_ok(), "pose {i}: {:?}", c.fit.focal);
                assert!(
                    errors(truth, c).focal.abs() < 0.003,
                    "pose {i}: {}",
                    refined(c)
                );
            }
        }
        worst = (
            worst.0.max(e.rms_px),
            worst.1.max(e.rotation_deg),
            worst.2.max(e.translation_mm),
        );
    }
    println!(
        "worst: {:.3} px RMS, {:.4}°, {:.3} mm",
        worst.0, worst.1, worst.2
    );
}

#[test]
fn a_photo_without_the_board_says_so() {
    let truth = camera([0.0, 0.04, 0.5], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
    let mut bench = VirtualBench::embedded("gold", 64).unwrap();
    bench.geometry.camera = Camera::eval_orthographic(400);
    let photo = jpeg(bench.photo().unwrap(), &truth.resized(400, 400));
    let p = Photo::decode("sphere.jpg", &photo).unwrap();
    // With its cause, as the command line says it: the photo's name, then what is wrong.
    let err = format!(
        "{:#}",
        solve_photo(&truth.resized(400, 400), &p, Focal::Refine).unwrap_err()
    );
    assert!(
        err.starts_with("sphere.jpg: no 9 × 6 ChArUco board"),
        "{err}"
    );
    assert!(err.contains("400×400"), "{err}");
    // A photo of another shape than the rig's camera is refused.
    let mut board = Photo::decode(
        "board.jpg",
        &jpeg(
            board_photo::render(
                &Board::default(),
                &truth,
                &studio_envmap(64),
                0.0,
                Spoil::default(),
            )
            .unwrap(),
            &truth,
        ),
    )
    .unwrap();
    board.name = "board.jpg".into();
    let err = solve_photo(&truth.resized(400, 400), &board, Focal::Fixed)
        .unwrap_err()
        .to_string();
    assert!(err.contains("another shape"), "{err}");
}

/// The figure after "of " in the capture's line on how well the estimate re-renders its photo.
fn refit(said: &str) -> f64 {
    said.split("re-renders the photo to a relative RMSE of ")
        .nth(1)
        .and_then(|s| s.split_whitespace().next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no re-render error in\n{said}"))
}

/// End to end through the binary, on the shipped `simulated-pose.toml`: the grooved block,
/// a pinhole camera whose typed pose is 6 cm and 2.6° off and focal length 4% off, and the
/// block itself 5 mm and 2° from where the rig says. The board is written, photographed on
/// the simulated bench and solved; then the empty bench and the block, whose silhouette
/// places it. Both go into the rig; then gold (its projection onto the basis, so that the
/// estimate can be exact) is captured with the rig as typed, with the camera found and the
/// block as typed, with both found, and as they truly are.
#[test]
fn a_pose_found_from_the_board_estimates_the_material_as_the_true_pose_does() {
    use std::path::Path;
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = std::env::temp_dir().join(format!("brdfd-pose-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let typed = std::fs::read_to_string(root.join("config/rigs/simulated-pose.toml")).unwrap();
    std::fs::write(dir.join("rig.toml"), &typed).unwrap();
    common::succeeds(&["calibrate", "target", "--out", "board"], &dir);
    let said = common::succeeds(
        &[
            "calibrate",
            "pose",
            "--rig",
            "rig.toml",
            "--board",
            "board/board.toml",
            "--refine-object",
            "--out",
            "photos",
            "--state-dir",
            "state",
        ],
        &dir,
    );
    let rms: f64 = said
        .split("reprojection: ")
        .nth(1)
        .and_then(|s| s.split_whitespace().next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no reprojection error in\n{said}"));
    assert!(rms <= 0.5, "{said}");
    assert!(dir.join("rig.toml.bak").exists());
    let found = brdfd_rig::config::Rig::read(&dir.join("rig.toml")).unwrap();
    let truth = found.simulation.clone().unwrap().camera.unwrap();
    let (kf, ef) = pinhole(&found.geometry.camera).unwrap();
    let (kt, et) = pinhole(&truth).unwrap();
    let rotation = angle_between_deg(&ef.rotation, &et.rotation);
    let moved_mm = (ef.centre() - et.centre()).norm() * 1000.0;
    let distance = et.centre().norm();
    eprintln!(
        "pose from the board at {distance:.2} m: {rms} px RMS, rotation {rotation:.4}°, position {moved_mm:.3} mm, fx {:+.3}%",
        (kf.fx / kt.fx - 1.0) * 100.0
    );
    assert!(rotation <= 0.2, "{rotation}°");
    // The figure of 1 mm at 0.5 m, at this camera's distance.
    assert!(moved_mm <= 1.0 * distance / 0.5, "{moved_mm} mm");
    assert!((kf.fx / kt.fx - 1.0).abs() < 0.005, "fx {}", kf.fx);
    assert!(said.contains("silhouette overlap (IoU)"), "{said}");
    let Some(Shape::Mesh {
        rotation_deg: placed_deg,
        position: placed,
        ..
    }) = found.geometry.shape.clone()
    else {
        panic!("no mesh in the rig written");
    };
    let Some(Shape::Mesh {
        rotation_deg: true_deg,
        position: true_position,
        ..
    }) = found.simulation.clone().unwrap().shape
    else {
        panic!("no [simulation.shape] in the shipped rig");
    };
    let shape_mm = (0..3)
        .map(|i| (placed[i] - true_position[i]).powi(2))
        .sum::<f64>()
        .sqrt()
        * 1e3;
    let turn_deg = (placed_deg[1] - true_deg[1]).abs();
    eprintln!("the block's placement from its silhouette: {shape_mm:.3} mm and {turn_deg:.3}° from the truth");
    assert!(shape_mm <= 0.5 && turn_deg <= 0.2, "{said}");
    assert!((placed_deg[0] - true_deg[0]).abs() < 1e-6 && placed_deg[2].abs() < 1e-6);

    // The same from the photos just taken, given as a user with photos already gives them:
    // the first view's board, object and empty bench.
    let photos = |prefix: &str| {
        let mut v: Vec<String> = std::fs::read_dir(dir.join("photos"))
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|n| n.starts_with(prefix))
            .map(|n| format!("photos/{n}"))
            .collect();
        v.sort();
        assert_eq!(v.len(), 5, "{prefix}: {v:?}");
        v
    };
    let (board, object, empty) = (
        photos("view1-"),
        photos("object-view1-"),
        photos("empty-view1-"),
    );
    let given = |object: &[String], empty: &[String]| {
        let mut args = vec!["calibrate", "pose", "--rig", "rig.toml.bak", "--dry-run"];
        args.push("--photo");
        args.extend(board.iter().map(String::as_str));
        args.push("--object-photo");
        args.extend(object.iter().map(String::as_str));
        args.push("--empty-photo");
        args.extend(empty.iter().map(String::as_str));
        args.into_iter().map(String::from).collect::<Vec<String>>()
    };
    fn strs(v: &[String]) -> Vec<&str> {
        v.iter().map(String::as_str).collect()
    }
    let said = common::succeeds(&strs(&given(&object, &empty)), &dir);
    assert!(
        said.contains("object: its middle moved [")
            && said.contains("one view pins the object's distance"),
        "{said}"
    );
    // The empty bench given as the object: nothing differs.
    let said = common::fails(&strs(&given(&empty, &empty)), &dir);
    assert!(said.contains("no object found"), "{said}");
    let said = common::fails(&strs(&given(&object[..2], &empty)), &dir);
    assert!(
        said.contains("2 --object-photo and 5 --empty-photo"),
        "{said}"
    );

    // The same capture with the rig as typed, as found, and the true one; and with the
    // camera found but the block where the rig said.
    let (focal, pose, block) = (
        "fx = 2300.0\nfy = 2300.0",
        "position = [0.03, 0.22, 1.24]\nlook_at = [0.0, 0.01, 0.0]",
        "rotation_deg = [-25.0, 0.0, 0.0]\nposition = [0.0, 0.0, 0.0]",
    );
    assert!(typed.contains(focal) && typed.contains(pose) && typed.contains(block));
    let true_rig = typed
        .replace(focal, "fx = 2400.0\nfy = 2400.0")
        .replace(
            pose,
            "position = [0.0, 0.25, 1.2]\nlook_at = [0.0, 0.0, 0.0]",
        )
        .replace(
            block,
            "rotation_deg = [-25.0, 2.0, 0.0]\nposition = [0.004, 0.0, -0.003]",
        );
    std::fs::write(dir.join("true.toml"), true_rig).unwrap();
    // The rig as written, the camera found, with the block placed elsewhere.
    let block_at = |name: &str, rotation_deg: [f64; 3], position: [f64; 3]| {
        let mut rig: toml_edit::DocumentMut = std::fs::read_to_string(dir.join("rig.toml"))
            .unwrap()
            .parse()
            .unwrap();
        rig["geometry"]["shape"]["rotation_deg"] =
            toml_edit::value(toml_edit::Array::from_iter(rotation_deg));
        rig["geometry"]["shape"]["position"] =
            toml_edit::value(toml_edit::Array::from_iter(position));
        std::fs::write(dir.join(name), rig.to_string()).unwrap();
    };
    block_at("camera-only.toml", [-25.0, 0.0, 0.0], [0.0; 3]);
    block_at("true-block.toml", [-25.0, 2.0, 0.0], [0.004, 0.0, -0.003]);
    let capture = |rig: &str| {
        let said = common::succeeds(
            &[
                "capture",
                "--rig",
                rig,
                "--material",
                "gold",
                "--in-span",
                "--model",
                "basis",
                "--pixels",
                "all",
                "--state-dir",
                "state",
            ],
            &dir,
        );
        (refit(&said), common::relit(&said))
    };
    let as_typed = capture("rig.toml.bak");
    let camera_found = capture("camera-only.toml");
    let camera_found_block_true = capture("true-block.toml");
    let as_found = capture("rig.toml");
    let as_true = capture("true.toml");
    eprintln!(
        "gold (in span), basis model, every pixel: re-render / relight error with the rig as typed {:.4} / {:.4}, the camera found and the block as typed {:.4} / {:.4}, the camera found and the block where it is {:.4} / {:.4}, both found {:.4} / {:.4}, true {:.4} / {:.4}",
        as_typed.0, as_typed.1, camera_found.0, camera_found.1, camera_found_block_true.0, camera_found_block_true.1, as_found.0, as_found.1, as_true.0, as_true.1
    );
    // The camera found from the board estimates as the true camera does.
    assert!(
        camera_found_block_true.0 <= as_true.0 * 1.25 + 0.005,
        "{camera_found_block_true:?} against {as_true:?}"
    );
    assert!(
        camera_found_block_true.1 <= as_true.1 * 1.25 + 0.005,
        "{camera_found_block_true:?} against {as_true:?}"
    );
    // The block's placement matters too: as typed, the estimate does not reproduce its own
    // photo; placed from its silhouette, it relights as the truth does.
    assert!(
        camera_found.0 > 5.0 * as_true.0,
        "{camera_found:?} against {as_true:?}"
    );
    assert!(
        as_found.0 * 5.0 < camera_found.0,
        "{as_found:?} against {camera_found:?}"
    );
    assert!(
        as_found.1 <= as_true.1 * 1.25 + 0.005,
        "{as_found:?} against {as_true:?}"
    );
    // The pose matters: as typed, the estimate does not reproduce its own photo.
    assert!(
        as_typed.0 > 5.0 * as_true.0,
        "{as_typed:?} against {as_true:?}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// A fresh folder named for `name` holding `rig.toml`: the shipped `simulated-pose.toml` with
/// `simulation` (lines of its `[simulation]` table) added; the folder and the rig's text.
fn pose_rig(name: &str, simulation: &str) -> (std::path::PathBuf, String) {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = std::env::temp_dir().join(format!("brdfd-pose-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let shipped = std::fs::read_to_string(root.join("config/rigs/simulated-pose.toml")).unwrap();
    let rig = shipped.replace(
        "\n[simulation.camera]",
        &format!("\n[simulation]\n{simulation}\n\n[simulation.camera]"),
    );
    std::fs::write(dir.join("rig.toml"), &rig).unwrap();
    (dir, rig)
}

/// A rig whose DSLR does not answer: the webcam photographs the board, its frames carry no
/// EXIF, and the focal length (4% off as typed) comes from three views on the turntable.
/// A photo with no board in it is an error that says so.
#[test]
fn the_webcam_and_the_turntable_find_the_focal_length_without_exif() {
    let (dir, _) = pose_rig("webcam", "dslr = \"absent\"");
    let shipped = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("config/rigs/simulated-pose.toml"),
    )
    .unwrap();
    let said = common::succeeds(
        &[
            "calibrate",
            "pose",
            "--rig",
            "rig.toml",
            "--out",
            "photos",
            "--state-dir",
            "state",
        ],
        &dir,
    );
    assert!(said.contains("the rig's fx), refined"), "{said}");
    assert_eq!(said.matches("40 corners in view").count(), 3, "{said}");
    let found = brdfd_rig::config::Rig::read(&dir.join("rig.toml")).unwrap();
    let (kf, ef) = pinhole(&found.geometry.camera).unwrap();
    let (kt, et) = pinhole(&found.simulation.clone().unwrap().camera.unwrap()).unwrap();
    let (focal, rotation, moved_mm) = (
        kf.fx / kt.fx - 1.0,
        angle_between_deg(&ef.rotation, &et.rotation),
        (ef.centre() - et.centre()).norm() * 1000.0,
    );
    eprintln!(
        "webcam, three views, no EXIF: fx {:+.3}%, rotation {rotation:.4}°, position {moved_mm:.3} mm",
        focal * 100.0
    );
    assert!(focal.abs() < 0.005, "{said}");
    assert!(rotation <= 0.2 && moved_mm <= 2.5, "{said}");

    image::GrayImage::from_pixel(640, 424, image::Luma([128]))
        .save(dir.join("grey.png"))
        .unwrap();
    let said = common::fails(
        &[
            "calibrate",
            "pose",
            "--rig",
            "rig.toml",
            "--photo",
            "grey.png",
            "--dry-run",
        ],
        &dir,
    );
    assert!(
        said.contains("grey.png: no 9 × 6 ChArUco board (DICT_4X4_50) found in the 640×424 photo"),
        "{said}"
    );

    // A silhouette places a mesh: a sphere's rig is refused, first where its
    // [simulation.shape] is the mesh elsewhere, then by the command.
    let mesh = "type = \"mesh\"\nfile = \"builtin:grooved-block.obj\"\nunits = \"mm\"\nrotation_deg = [-25.0, 0.0, 0.0]\nposition = [0.0, 0.0, 0.0]";
    assert!(shipped.contains(mesh));
    let sphere = shipped.replace(
        mesh,
        "type = \"sphere\"\ncenter = [0.0, 0.0, 0.0]\nradius = 0.03",
    );
    let refine = [
        "calibrate",
        "pose",
        "--rig",
        "sphere.toml",
        "--refine-object",
        "--dry-run",
    ];
    std::fs::write(dir.join("sphere.toml"), &sphere).unwrap();
    let said = common::out(&common::brdfd(&refine, &dir));
    assert!(
        said.contains("simulation.shape") && said.contains("[geometry.shape] must be a mesh"),
        "{said}"
    );
    let at = sphere.find("\n[simulation.shape]").unwrap();
    let end = at + sphere[at..].find("\n\n").unwrap();
    std::fs::write(
        dir.join("sphere.toml"),
        format!("{}{}", &sphere[..at], &sphere[end..]),
    )
    .unwrap();
    let said = common::fails(&refine, &dir);
    assert!(said.contains("--refine-object aligns the object's mesh with its silhouette, and [geometry.shape] is no mesh"), "{said}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// The DSLR powers off once the board's 15 photos are taken, so the empty bench's are not:
/// the object's placement is not found, and says why, but the board's pose is written all
/// the same (and the photos stay of one camera: the webcam does not take over midway).
/// `--refine-object` with photos of the board alone is refused before anything is read.
#[test]
fn an_object_step_that_fails_keeps_the_board_s_pose() {
    let (dir, rig) = pose_rig("off", "dslr_powers_off_after = 15");
    let args = [
        "calibrate",
        "pose",
        "--rig",
        "rig.toml",
        "--refine-object",
        "--out",
        "photos",
    ];
    let said = common::fails(&args, &dir);
    assert!(
        said.contains("the object's placement was not found; the camera's pose is kept")
            && said.contains("the DSLR stopped answering at the empty bench's photos"),
        "{said}"
    );
    let written = brdfd_rig::config::Rig::read(&dir.join("rig.toml")).unwrap();
    let (k, _) = pinhole(&written.geometry.camera).unwrap();
    assert!((k.fx / 2400.0 - 1.0).abs() < 0.005, "fx {}", k.fx);
    assert_eq!(
        written.geometry.shape,
        brdfd_rig::config::Rig::parse("typed", &rig)
            .unwrap()
            .geometry
            .shape
    );

    let said = common::fails(
        &[
            "calibrate",
            "pose",
            "--rig",
            "rig.toml",
            "--photo",
            "board.jpg",
            "--refine-object",
        ],
        &dir,
    );
    assert!(
        said.contains("with --photo, --refine-object needs the object's photos"),
        "{said}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
