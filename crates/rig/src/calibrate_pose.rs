//! `brdfd calibrate pose` as a flow of the rig: the request checked against the rig before
//! anything is shot, the board (and, when asked, the empty bench and the object) photographed
//! by the rig's object camera or read from photos taken already, the camera's pose solved, the
//! object's placement refined from its silhouette, and the rig file rewritten with what was
//! found. Whoever runs it (the command line) reads its arguments into a [`PoseRequest`], starts
//! the devices when the camera is to shoot, and tells the operator what the flow reports
//! ([`PoseReport`]).

use std::path::{Path, PathBuf};

use brdfd_core::geometry::{Camera, Shape};
use brdfd_pose::board::Board;
use brdfd_pose::silhouette::Refined;
use brdfd_pose::{pinhole, Calibrated, Focal};

use crate::config::Rig;
// The refusals are the rig's errors' (`crate::error`), named here as before.
use crate::error::{refuse, Result, StepExt};
pub use crate::error::{Field, PoseRefused};
use crate::flow::{Context, Keep};
use crate::pose::{self, OnBench, Photo, PhotoView};
use crate::rig_file::{RigFile, RigFileError, Saved};

/// A fit worse than these is not written without `force`: the board's corners are found to
/// a tenth of a pixel, so a pixel means the model (the board's size or place, its flatness,
/// the lens's distortion) is wrong.
pub const MAX_RMS_PX: f64 = 1.0;
pub const MAX_WORST_PX: f64 = 3.0;

/// What to calibrate, and from what.
pub struct PoseRequest {
    /// The rig file: its object camera is read, then written with the pose found.
    pub rig_file: PathBuf,
    pub board: Board,
    pub photos: PhotosFrom,
    pub focal: Focal,
    /// The sensor's width, millimetres, for a photo whose EXIF gives the focal length but
    /// not the focal plane's resolution.
    pub sensor_width_mm: Option<f64>,
    /// Also refine where the object stands, from its silhouette (photos of the object given
    /// imply it).
    pub refine_object: bool,
    /// Write the rig file; else only report.
    pub write: bool,
    /// Write even a poor fit.
    pub force: bool,
}

/// Where the photos of the bench come from.
pub enum PhotosFrom {
    /// The rig's object camera photographs the bench now: `views` of it (else 3 on a rig with
    /// a turntable, 1 otherwise), turned `turn_deg` apart.
    Camera { views: Option<u32>, turn_deg: f64 },
    /// Photos taken already: of the board, and of the object with the empty bench at each
    /// one's exposure.
    Files {
        board: Vec<PathBuf>,
        object: Vec<PathBuf>,
        empty: Vec<PathBuf>,
        /// Views asked for, which photos cannot give beyond one.
        views: Option<u32>,
    },
}

/// What the flow tells the person at the bench as it goes.
pub trait PoseReport {
    /// The board's fit and the camera it gives, against the rig's camera before.
    fn found(&mut self, before: &Camera, found: &Calibrated);
    /// The object's placement refined from its silhouette.
    fn refined(&mut self, refined: &Refined);
    /// Something to know that does not stop the calibration.
    fn warn(&mut self, warning: &str);
    /// Asks for what stands on the bench to be changed, returning once it is; a simulated
    /// bench changes it itself (`simulated`), and is only told.
    fn change_bench(&mut self, what: &str, simulated: bool) -> Result<()>;
}

/// What a calibration found and did.
pub struct PoseOutcome {
    pub found: Calibrated,
    /// The rig file written, or why it could not be, if it was to be (not when only asked
    /// to report). pose.json is written before it.
    pub saved: Option<Result<Saved, RigFileError>>,
    /// The object's placement, when it was asked for: where the mesh stands now, or why it
    /// was not found (the camera's pose is written all the same).
    pub placed: Option<Result<Shape>>,
}

/// A calibration checked against its rig and ready to run: every mistake in the request is
/// said before anything is shot, and the rig file is open.
pub struct PoseCalibration<'a> {
    rig: &'a Rig,
    request: PoseRequest,
    refine_object: bool,
    /// The turntable's angles of the views the camera shoots; none for photos given.
    angles: Option<Vec<f64>>,
    file: Option<RigFile>,
}

impl<'a> PoseCalibration<'a> {
    pub fn new(rig: &'a Rig, request: PoseRequest) -> Result<PoseCalibration<'a>> {
        let r = &request;
        if pinhole(&rig.geometry.camera).is_none() {
            return Err(PoseRefused::Orthographic {
                rig_file: r.rig_file.clone(),
            }
            .into());
        }
        if let Some(s) = r.sensor_width_mm {
            if !(s.is_finite() && s > 0.0) {
                return Err(PoseRefused::SensorWidth(s).into());
            }
        }
        let (refine_object, angles) = match &r.photos {
            PhotosFrom::Camera { views, turn_deg } => {
                let roles = crate::plan::devices(rig)?;
                let n = views.unwrap_or(if roles.turntable { 3 } else { 1 }) as usize;
                if !(turn_deg.is_finite() && turn_deg.abs() > 0.0 && turn_deg.abs() < 80.0) {
                    return Err(PoseRefused::Turn(*turn_deg).into());
                }
                (r.refine_object, Some(pose::view_angles(n, *turn_deg)))
            }
            PhotosFrom::Files {
                board,
                object,
                empty,
                views,
            } => {
                if !object.is_empty() && board.is_empty() {
                    return Err(PoseRefused::ObjectWithoutBoard.into());
                }
                if r.refine_object && object.is_empty() {
                    return Err(PoseRefused::RefineWithoutObject.into());
                }
                if object.len() != empty.len() {
                    return Err(PoseRefused::Unpaired {
                        object: object.len(),
                        empty: empty.len(),
                    }
                    .into());
                }
                if views.is_some_and(|v| v > 1) {
                    return Err(PoseRefused::ViewsOfPhotos.into());
                }
                (r.refine_object || !object.is_empty(), None)
            }
        };
        if refine_object && !matches!(rig.geometry.shape, Some(Shape::Mesh { .. })) {
            return Err(PoseRefused::NoMesh {
                rig_file: r.rig_file.clone(),
            }
            .into());
        }
        // Opened first: a file the pose cannot go into is said before anything is shot.
        let file = if r.write {
            let mut tables = vec![("camera", "pose")];
            if refine_object {
                tables.push(("shape", "object's placement"));
            }
            Some(RigFile::open_for(&r.rig_file, &tables)?)
        } else {
            None
        };
        Ok(PoseCalibration {
            rig,
            request,
            refine_object,
            angles,
            file,
        })
    }

    /// Whether the rig's camera is to photograph the bench (the caller then starts the rig's
    /// devices and gives them to [`PoseCalibration::run`]).
    pub fn shoots(&self) -> bool {
        self.angles.is_some()
    }

    /// Runs the calibration: photographs the bench with `camera` (the rig's devices, and
    /// where their files are kept) or reads the photos given, solves, and writes the rig
    /// file. `out` is where `pose.json` goes (the camera's photos go where `camera` keeps
    /// them). An error once the board's pose is solved leaves that pose good: it is written
    /// all the same, and the object's placement carries its own error
    /// ([`PoseOutcome::placed`]).
    pub fn run(
        self,
        camera: Option<(&Context, &mut dyn Keep)>,
        out: Option<&Path>,
        report: &mut dyn PoseReport,
    ) -> Result<PoseOutcome> {
        let rig_camera = &self.rig.geometry.camera;
        let r = &self.request;
        let focal = r.focal;
        let warn_only = r.force || self.file.is_none();
        let settle = |found: &Calibrated, report: &mut dyn PoseReport| {
            report.found(rig_camera, found);
            if let Some(out) = out {
                write_json(out, &json(found, None, &note(found)))?;
            }
            check_fit(found, warn_only, report)
        };
        let (found, object) = match (&self.angles, camera, &r.photos) {
            (Some(angles), Some((cx, keep)), _) => {
                let mut shooting = pose::Shooting::default();
                let mut shoot = |on_bench, prefix| {
                    pose::shoot(cx, &mut *keep, &mut shooting, on_bench, angles, prefix)
                };
                let views = shoot(OnBench::Board(&r.board), "")?;
                let found = pose::solve(
                    &mut |w: String| report.warn(&w),
                    rig_camera,
                    &r.board,
                    &views,
                    focal,
                    r.sensor_width_mm,
                )?;
                settle(&found, report)?;
                let simulated = cx.devices.sim.is_some();
                let object = self.refine_object.then(|| {
                    report.change_bench(
                        "take the board away, leaving the bench as it was",
                        simulated,
                    )?;
                    let empty = shoot(OnBench::Nothing, "empty-")?;
                    report.change_bench(
                        "stand the object where [geometry.shape] places it, as nearly as you can",
                        simulated,
                    )?;
                    Ok((empty, shoot(OnBench::Object, "object-")?))
                });
                (found, object)
            }
            (Some(_), None, _) => {
                refuse!("the board is to be photographed by the rig's camera, and no devices were given to shoot with")
            }
            (
                None,
                _,
                PhotosFrom::Files {
                    board,
                    object,
                    empty,
                    ..
                },
            ) => {
                let found = pose::solve(
                    &mut |w: String| report.warn(&w),
                    rig_camera,
                    &r.board,
                    &photo_view(board)?,
                    focal,
                    r.sensor_width_mm,
                )?;
                settle(&found, report)?;
                let object = self.refine_object.then(|| {
                    report.warn("one view pins the object's distance from the camera only by its outline's size; photographed by the rig's camera on a rig with a turntable, the slanted views pin it as well as the rest");
                    Ok((photo_view(empty)?, photo_view(object)?))
                });
                (found, object)
            }
            (None, _, PhotosFrom::Camera { .. }) => {
                unreachable!("a camera's request has its angles")
            }
        };
        let note = note(&found);
        let placed = object.map(|photos: Result<(Vec<PhotoView>, Vec<PhotoView>)>| {
            let (empty, object) = photos?;
            let shape = self
                .rig
                .geometry
                .shape
                .as_ref()
                .expect("checked to be a mesh");
            let refined = pose::refine_object(&found.camera, shape, &empty, &object)?;
            report.refined(&refined);
            let placed = refined.offset.placed(shape);
            if let Some(out) = out {
                write_json(out, &json(&found, Some((&refined, &placed)), &note))?;
            }
            Ok(placed)
        });
        let saved = self.file.map(|mut file| {
            file.set_camera(&found.camera, &note)?;
            if let Some(Ok(shape)) = &placed {
                file.set_shape(shape)?;
            }
            file.save()
        });
        Ok(PoseOutcome {
            found,
            saved,
            placed,
        })
    }
}

/// Photos taken already, as the one view they are.
fn photo_view(files: &[PathBuf]) -> Result<Vec<PhotoView>> {
    Ok(vec![PhotoView {
        turn_deg: 0.0,
        photos: files
            .iter()
            .map(|p| {
                let bytes = std::fs::read(p).with_step(|| format!("reading {}", p.display()))?;
                Photo::decode(&p.display().to_string(), &bytes)
            })
            .collect::<Result<Vec<_>>>()?,
    }])
}

/// Where the pose came from, for the rig file's comment and pose.json.
fn note(found: &Calibrated) -> String {
    format!(
        "by `brdfd calibrate pose` on {}: {:.3} px RMS over {} board corners",
        humantime::format_rfc3339_seconds(std::time::SystemTime::now()),
        found.fit.rms_px,
        found.fit.corners
    )
}

/// Writes pose.json into `out`, made if it is not there: a folder is made only for a fit.
fn write_json(out: &Path, v: &serde_json::Value) -> Result<()> {
    std::fs::create_dir_all(out).with_step(|| format!("creating {}", out.display()))?;
    let text = serde_json::to_string_pretty(v)?;
    crate::session::write_atomic(&out.join("pose.json"), text.as_bytes())?;
    Ok(())
}

/// A poor fit is an error, unless it is only reported (`warn_only`: forced, or nothing is
/// written).
fn check_fit(found: &Calibrated, warn_only: bool, report: &mut dyn PoseReport) -> Result<()> {
    if found.fit.rms_px > MAX_RMS_PX || found.fit.worst_px > MAX_WORST_PX {
        let why = format!(
            "the board's corners do not fit one camera well ({:.2} px RMS, {:.2} px at worst; a good fit is under {MAX_RMS_PX} and {MAX_WORST_PX}): check the board's square_mm and [placement], that it is flat, and that it turned with the turntable",
            found.fit.rms_px, found.fit.worst_px
        );
        if !warn_only {
            return Err(PoseRefused::PoorFit(why).into());
        }
        report.warn(&why);
    }
    Ok(())
}

/// What `pose.json` holds: the fit, the camera written, and each view's corners; and the
/// object's placement refined from its silhouette, where it was.
fn json(c: &Calibrated, object: Option<(&Refined, &Shape)>, note: &str) -> serde_json::Value {
    let (k, _) = pinhole(&c.camera).expect("a pinhole camera");
    let pose = match &c.camera {
        Camera::Pinhole { pose, .. } | Camera::Orthographic { pose, .. } => pose,
    };
    let object = object.map(|(r, placed)| {
        let (rotation_deg, position) = match placed {
            Shape::Mesh {
                rotation_deg,
                position,
                ..
            } => (Some(rotation_deg), Some(position)),
            _ => (None, None),
        };
        serde_json::json!({
            "shift_m": r.offset.shift,
            "turn_deg": r.offset.turn_deg,
            "turned_about": r.offset.pivot,
            "iou_before": r.iou_before,
            "iou_after": r.iou_after,
            "rotation_deg": rotation_deg,
            "position": position,
        })
    });
    serde_json::json!({
        "measured": note,
        "object": object,
        "rms_px": c.fit.rms_px,
        "worst_px": c.fit.worst_px,
        "corners": c.fit.corners,
        "photo_size": [c.photo_size.0, c.photo_size.1],
        "focal": {
            "start_fx_px": c.start_fx,
            "start_from": c.start_from,
            "refined_sigma": c.fit.focal.as_ref().ok(),
            "held_because": c.fit.focal.as_ref().err(),
        },
        "camera": {
            "fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy,
            "position": pose.position, "look_at": pose.look_at, "up": pose.up,
        },
        "views": c.views.iter().map(|v| serde_json::json!({
            "photo": v.name,
            "turn_deg": v.turn_deg,
            "corners": v.corners.iter()
                .map(|p| serde_json::json!({ "world": p.world, "pixel": p.pixel }))
                .collect::<Vec<_>>(),
        })).collect::<Vec<_>>(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const POSE_RIG: &str = include_str!("../../../config/rigs/simulated-pose.toml");

    fn request(photos: PhotosFrom, refine_object: bool) -> PoseRequest {
        PoseRequest {
            rig_file: PathBuf::from("rig.toml"),
            board: Board::default(),
            photos,
            focal: Focal::Refine,
            sensor_width_mm: None,
            refine_object,
            write: false,
            force: false,
        }
    }

    fn files(board: usize, object: usize, empty: usize, views: Option<u32>) -> PhotosFrom {
        let names =
            |n: usize, what: &str| (0..n).map(|i| format!("{what}{i}.jpg").into()).collect();
        PhotosFrom::Files {
            board: names(board, "board"),
            object: names(object, "object"),
            empty: names(empty, "empty"),
            views,
        }
    }

    fn refused(rig: &Rig, r: PoseRequest) -> PoseRefused {
        match PoseCalibration::new(rig, r) {
            Ok(_) => panic!("a request with a mistake was taken"),
            Err(crate::error::RigError::Refused(r)) => r,
            Err(e) => panic!("not a refusal: {e:?}"),
        }
    }

    /// A request's mistakes are said when it is checked against the rig, before any device
    /// starts or any photo is read (none of the photos named here exists), in the request's
    /// own words, or in its taker's.
    #[test]
    fn a_request_s_mistakes_are_said_before_anything_is_shot() {
        let rig = Rig::parse("simulated-pose.toml", POSE_RIG).unwrap();
        let cases = [
            (files(0, 1, 1, None), false, PoseRefused::ObjectWithoutBoard),
            (files(1, 0, 0, None), true, PoseRefused::RefineWithoutObject),
            (
                files(1, 2, 1, None),
                false,
                PoseRefused::Unpaired {
                    object: 2,
                    empty: 1,
                },
            ),
            (files(1, 0, 0, Some(3)), false, PoseRefused::ViewsOfPhotos),
            (
                PhotosFrom::Camera {
                    views: None,
                    turn_deg: 90.0,
                },
                false,
                PoseRefused::Turn(90.0),
            ),
        ];
        for (photos, refine, expected) in cases {
            assert_eq!(refused(&rig, request(photos, refine)), expected);
        }
        let mut r = request(files(1, 0, 0, None), false);
        r.sensor_width_mm = Some(-1.0);
        let why = refused(&rig, r);
        assert_eq!(why, PoseRefused::SensorWidth(-1.0));
        assert_eq!(
            why.to_string(),
            "`sensor_width_mm` must be a positive number of millimetres, not -1"
        );
        assert_eq!(
            why.said_with(|_| "--width"),
            "--width must be a positive number of millimetres, not -1"
        );
        // Every field a refusal names is named by the taker's names, none by the request's.
        let all = [
            PoseRefused::ObjectWithoutBoard,
            PoseRefused::RefineWithoutObject,
            PoseRefused::Unpaired {
                object: 2,
                empty: 1,
            },
            PoseRefused::ViewsOfPhotos,
            PoseRefused::NoMesh {
                rig_file: "rig.toml".into(),
            },
            PoseRefused::PoorFit("poor".into()),
        ];
        for r in all {
            let taker = r.said_with(|f| if f == Field::Force { "FORCE" } else { "FLAG" });
            assert!(
                !taker.contains('`') && taker.contains("FLAG") || taker.contains("FORCE"),
                "{taker}"
            );
        }
        // The board's photos alone, and the camera shooting, are what a calibration takes.
        let taken = PoseCalibration::new(&rig, request(files(1, 0, 0, None), false)).unwrap();
        assert!(!taken.shoots());
        let shot = PoseCalibration::new(
            &rig,
            request(
                PhotosFrom::Camera {
                    views: Some(3),
                    turn_deg: 30.0,
                },
                false,
            ),
        )
        .unwrap();
        assert_eq!(shot.angles.as_ref().map(Vec::len), Some(3));
    }

    /// A pose needs a pinhole camera, and a placement a mesh, both named in the rig file.
    #[test]
    fn the_rig_s_camera_and_object_must_be_ones_a_pose_is_found_for() {
        let mesh = Rig::parse("simulated-pose.toml", POSE_RIG).unwrap();
        assert!(PoseCalibration::new(&mesh, request(files(1, 1, 1, None), false)).is_ok());
        let mut sphere = mesh.clone();
        sphere.geometry.shape = Some(Shape::Sphere {
            center: [0.0; 3],
            radius: 0.03,
        });
        assert!(matches!(
            refused(&sphere, request(files(1, 1, 1, None), false)),
            PoseRefused::NoMesh { .. }
        ));
        let ortho = Rig::parse(
            "simulated.toml",
            include_str!("../../../config/rigs/simulated.toml"),
        )
        .unwrap();
        assert!(refused(&ortho, request(files(1, 0, 0, None), false))
            .to_string()
            .contains("the object camera is orthographic"));
    }

    /// With the rig file to be written, a file without the table the pose goes into is said
    /// before anything is shot.
    #[test]
    fn a_rig_file_the_pose_cannot_go_into_is_refused_first() {
        let rig = Rig::parse("simulated-pose.toml", POSE_RIG).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("rig.toml");
        std::fs::write(&path, "simulated = true\n").unwrap();
        let mut r = request(files(1, 0, 0, None), false);
        r.rig_file = path;
        r.write = true;
        let why = match PoseCalibration::new(&rig, r) {
            Ok(_) => panic!("a rig file without the table was taken"),
            Err(e) => crate::error::said(&e),
        };
        assert!(why.contains("has no [geometry.camera] table"), "{why}");
    }
}
