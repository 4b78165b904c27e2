//! The bench photographed by the rig's object camera, for `brdfd calibrate pose`: the DSLR's
//! bracket as JPEGs (or the fallback camera's frames), each frame kept as it arrives. The
//! camera's pose is solved from the frame that shows the most of the board; the object's
//! placement, optionally, from its silhouette against the empty bench.
//!
//! A simulated rig shows what stands on it to its DSLR as the virtual bench renders it,
//! through the camera of `[simulation] camera` and with the object where `[simulation] shape`
//! puts it, when the rig has them: what the operator typed into the rig is then what the
//! calibration corrects.

use super::flow::{Context, Keep, Prefixed, RawFiles};
use super::object::{self, FallbackBracket};
use super::plan;
use super::settings::Bracket;
use super::turning::turn_to;
use crate::config::DslrFiles;
use crate::error::said;
use crate::error::{refuse, Result, RigError};
use brdfd_core::geometry::{Camera, Shape};
use brdfd_core::raster::linear_to_srgb;
use brdfd_pose::board::Board;
use brdfd_pose::silhouette::{refine, Mask, Refined, View};
use brdfd_pose::{calibrate, check_photo_size, find, Calibrated, Focal, Found, LensFocal};
use brdfd_radiometry::ExifFocal;

/// A photo of the bench to solve from: 8-bit grey, with the lens's EXIF where it has one.
pub struct Photo {
    pub name: String,
    pub grey: image::GrayImage,
    pub exif: Option<ExifFocal>,
}

impl Photo {
    /// A JPEG or PNG file.
    pub fn decode(name: &str, bytes: &[u8]) -> Result<Photo> {
        let image = image::load_from_memory(bytes).map_err(|e| {
            RigError::invalid(format!(
                "{name}: not a photo brdfd reads for a pose (JPEG or PNG): {e}"
            ))
        })?;
        Ok(Photo {
            name: name.to_string(),
            grey: image.to_luma8(),
            exif: brdfd_radiometry::exif_focal(bytes),
        })
    }
}

/// The photos of one view: the turntable's angle, and a bracket's frames.
pub struct PhotoView {
    pub turn_deg: f64,
    pub photos: Vec<Photo>,
}

/// The turntable's angles for `n` views `step` degrees apart: 0, +step, −step, +2·step, ...
/// (the board seen square-on first, then at slants both ways).
pub(crate) fn view_angles(n: usize, step: f64) -> Vec<f64> {
    (0..n)
        .map(|i| {
            let k = i.div_ceil(2) as f64;
            if i % 2 == 1 {
                k * step
            } else {
                -k * step
            }
        })
        .map(|a| if a == 0.0 { 0.0 } else { a })
        .collect()
}

/// What stands where the object goes while the object camera photographs the bench.
#[derive(Clone, Copy)]
pub enum OnBench<'a> {
    /// The printed board, for the camera's pose.
    Board(&'a Board),
    /// Nothing: the empty bench a silhouette is told from.
    Nothing,
    /// The object itself, for its silhouette.
    Object,
}

impl OnBench<'_> {
    fn name(&self) -> &'static str {
        match self {
            OnBench::Board(_) => "board",
            OnBench::Nothing => "empty bench",
            OnBench::Object => "object",
        }
    }
}

/// Which camera a calibration's photos are of, carried from one [`shoot`] to the next: all of
/// them (the board's, the empty bench's, the object's) must be of one camera, since the pose
/// solved from the board is that camera's, and the object's frames are paired with the empty
/// bench's by exposure.
pub struct Shooting {
    dslr_answers: bool,
    shot_any: bool,
}

impl Default for Shooting {
    fn default() -> Self {
        Shooting {
            dslr_answers: true,
            shot_any: false,
        }
    }
}

/// Photographs the bench with the rig's object camera at each of `angles` (turntable
/// degrees; the turntable is turned back to 0 after), with `on_bench` standing where the
/// object goes: the DSLR's bracket (as JPEGs) if the rig has a DSLR that answers, else the
/// fallback camera's (chosen at the first view of the first shoot, kept in `shooting`).
/// Every file is kept as it arrives, under `prefix`.
pub fn shoot(
    cx: &Context,
    keep: &mut dyn Keep,
    shooting: &mut Shooting,
    on_bench: OnBench,
    angles: &[f64],
    prefix: &str,
) -> Result<Vec<PhotoView>> {
    let turns = angles.iter().any(|a| *a != 0.0);
    if turns && cx.devices.turntable.is_none() {
        refuse!(
            "several views of the {} need the rig's turntable, and it has none",
            on_bench.name()
        );
    }
    let mut views = Vec::new();
    let shot = (|| {
        for (i, &angle) in angles.iter().enumerate() {
            // The turntable says where it is in [0, 360); a view 30° the other way is −30°.
            let at = if turns {
                (turn_to(cx, angle)? + 180.0).rem_euclid(360.0) - 180.0
            } else {
                0.0
            };
            if angles.len() > 1 {
                cx.say(format!(
                    "{} view {} of {}: turntable at {at:.2}°",
                    on_bench.name(),
                    i + 1,
                    angles.len()
                ));
            }
            let prefix = if angles.len() > 1 {
                format!("{prefix}view{}-", i + 1)
            } else {
                prefix.to_string()
            };
            let mut keep = Prefixed(keep, prefix.clone());
            let mut photos = shoot_one(cx, &mut keep, on_bench, at, shooting)?;
            shooting.shot_any = true;
            for p in &mut photos {
                p.name = format!("{prefix}{}", p.name);
            }
            views.push(PhotoView {
                turn_deg: at,
                photos,
            });
        }
        Ok::<_, RigError>(())
    })();
    if turns {
        // Back where the object goes, after an error too; the first error is the one said.
        let back = turn_to(cx, 0.0);
        shot?;
        back?;
    } else {
        shot?;
    }
    Ok(views)
}

/// One view's bracket, the bench turned `turn_deg` on the turntable.
fn shoot_one(
    cx: &Context,
    keep: &mut dyn Keep,
    on_bench: OnBench,
    turn_deg: f64,
    shooting: &mut Shooting,
) -> Result<Vec<Photo>> {
    let first_view = !shooting.shot_any;
    let rig = cx.rig;
    let roles = plan::devices(rig)?;
    if let Some(sim) = &cx.devices.sim {
        sim.show_for_pose(cx, on_bench, turn_deg)?;
    }
    let mut dslr_failed = None;
    if let (true, true, Some(role)) = (roles.dslr, shooting.dslr_answers, &cx.devices.dslr) {
        let mut bracket = Bracket::dslr(rig, rig.brackets.dslr_shutters.clone());
        // The board is found in 8-bit files; a RAW file would add nothing but time.
        bracket.camera.files = Some(DslrFiles::Jpeg);
        let shot = role
            .ping()
            .map_err(RigError::from)
            .and_then(|()| object::bracket(cx, keep, "pose: DSLR", role, &bracket, true));
        match shot {
            Ok(files) => return jpegs(cx, &files),
            // As in a capture, the fallback camera shoots when the DSLR does not answer; but
            // only from the first view, so that all photos are of one camera.
            Err(e) if roles.fallback && first_view && object::the_dslrs_fault(cx, &e) => {
                cx.warn(format!(
                    "the DSLR did not photograph the {} ({}); the fallback camera does",
                    on_bench.name(),
                    said(&e)
                ));
                shooting.dslr_answers = false;
                dslr_failed = Some(e);
            }
            Err(e) if !first_view => {
                return Err(e.step(format!(
                    "the DSLR stopped answering at the {}'s photos (a calibration's photos must all be of one camera): wake it, and run again",
                    on_bench.name()
                )))
            }
            Err(e) => return Err(e),
        }
    }
    if let (true, Some(role)) = (roles.fallback, &cx.devices.fallback) {
        let files = object::bracket(
            cx,
            keep,
            "pose: fallback camera",
            role,
            &Bracket::fallback(rig),
            false,
        )?;
        return frames_as_photos(&files);
    }
    match dslr_failed {
        Some(e) => Err(e),
        None => refuse!(
            "the rig has no object camera to photograph the {} with",
            on_bench.name()
        ),
    }
}

/// The DSLR's JPEGs as photos. RAW files (a body that keeps its own image
/// quality setting) are left out, with a note; a bracket of RAW files only is an error.
fn jpegs(cx: &Context, files: &RawFiles) -> Result<Vec<Photo>> {
    let (raw, jpeg): (Vec<_>, Vec<_>) = files
        .iter()
        .partition(|(name, _)| brdfd_radiometry::raw::is_raw_name(name));
    if jpeg.is_empty() && !raw.is_empty() {
        refuse!(
            "the DSLR sent RAW files only ({}): set its image quality to JPEG or RAW + JPEG on the body",
            raw.len()
        );
    }
    if !raw.is_empty() {
        cx.say(format!(
            "{} RAW files are kept but not read: the board is found in the JPEGs",
            raw.len()
        ));
    }
    jpeg.iter()
        .map(|(name, bytes)| Photo::decode(name, bytes))
        .collect()
}

/// The fallback camera's frames as 8-bit sRGB grey.
fn frames_as_photos(files: &RawFiles) -> Result<Vec<Photo>> {
    let bracket = FallbackBracket::read(files)?;
    Ok(bracket
        .frames
        .iter()
        .enumerate()
        .map(|(i, f)| {
            let v = &f.values;
            let grey = image::GrayImage::from_fn(v.width as u32, v.height as u32, |x, y| {
                let p = v.pixels[y as usize * v.width + x as usize];
                let lum = 0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2];
                image::Luma([(linear_to_srgb(lum.clamp(0.0, 1.0)) * 255.0).round() as u8])
            });
            Photo {
                name: format!("fallback frame {} ({:.4} s)", i + 1, f.exposure.shutter_s),
                grey,
                exif: None,
            }
        })
        .collect())
}

/// The pose from each view's photo that shows the most of the board (the one of most contrast
/// among equals: the bracket's darkest frames are its noisiest), all views solved together. A view where no photo shows the board is left out and said; if
/// none shows it, the error says why for each photo.
pub fn solve(
    warn: &mut dyn FnMut(String),
    rig_camera: &Camera,
    board: &Board,
    views: &[PhotoView],
    focal: Focal,
    sensor_width_mm: Option<f64>,
) -> Result<Calibrated> {
    let mut chosen = Vec::new();
    let mut exif = None;
    let mut failures = Vec::new();
    for view in views {
        let mut best: Option<(Found, Option<ExifFocal>, u8)> = None;
        for p in &view.photos {
            check_photo_size(rig_camera, (p.grey.width(), p.grey.height()), &p.name)?;
            match find(board, &p.grey, &p.name, view.turn_deg) {
                Ok(f) => {
                    let c = contrast(&p.grey);
                    let better = best
                        .as_ref()
                        .is_none_or(|(b, _, bc)| (f.corners.len(), c) > (b.corners.len(), *bc));
                    if better {
                        best = Some((f, p.exif, c));
                    }
                }
                Err(e) => failures.push(said(&e)),
            }
        }
        match best {
            Some((f, e, _)) => {
                exif = exif.or(e);
                chosen.push(f);
            }
            None if views.len() > 1 => warn(format!(
                "no photo of the view at {:.1}° shows the board; it is left out",
                view.turn_deg
            )),
            None => {}
        }
    }
    if chosen.is_empty() {
        let photos: usize = views.iter().map(|v| v.photos.len()).sum();
        refuse!(
            "the board was found in none of the {photos} photos: {}",
            failures.join("; ")
        );
    }
    let centre = board.world([board.size_mm().0 / 2.0, board.size_mm().1 / 2.0]);
    let width = chosen[0].size.0;
    let lens = lens_focal(exif, width, sensor_width_mm);
    Ok(calibrate(rig_camera, chosen, centre, lens, focal)?)
}

/// The lens's focal length from a photo's EXIF, in pixels of a photo `width` wide where the
/// file (or `sensor_width_mm`) says how large the sensor is.
pub fn lens_focal(
    exif: Option<ExifFocal>,
    width: u32,
    sensor_width_mm: Option<f64>,
) -> Option<LensFocal> {
    exif.map(|e| LensFocal {
        mm: e.mm,
        px: e.focal_px(width, sensor_width_mm),
    })
}

/// The spread of a photo's grey levels, unclipped: the 95th percentile less the 5th, or 0
/// where more than 1% of the pixels are white.
fn contrast(grey: &image::GrayImage) -> u8 {
    let mut counts = [0usize; 256];
    for p in grey.pixels() {
        counts[p.0[0] as usize] += 1;
    }
    let n = grey.pixels().len();
    if counts[255] * 100 > n {
        return 0;
    }
    let level = |share: usize| {
        let mut seen = 0;
        (0..256)
            .find(|&v| {
                seen += counts[v];
                seen * 100 >= share * n
            })
            .unwrap_or(255) as u8
    };
    level(95).saturating_sub(level(5))
}

/// The object's placement refined from its silhouette: at each view, the bracket's frame of
/// most contrast of the object (unclipped) against the empty bench's frame of the same
/// exposure, seen through `camera` (the calibrated one). `object` and `empty` are views at
/// the same turntable angles, with as many frames each.
pub fn refine_object(
    camera: &Camera,
    shape: &Shape,
    empty: &[PhotoView],
    object: &[PhotoView],
) -> Result<Refined> {
    let Some(mesh) = shape.mesh()? else {
        refuse!(
            "the rig's [geometry.shape] is {}: a silhouette is aligned for a mesh",
            shape.describe()
        );
    };
    if empty.len() != object.len() {
        refuse!(
            "{} views of the object and {} of the empty bench: each view needs both",
            object.len(),
            empty.len()
        );
    }
    let mut views = Vec::new();
    for (e, o) in empty.iter().zip(object) {
        if (e.turn_deg - o.turn_deg).abs() > 0.05 || e.photos.len() != o.photos.len() {
            refuse!(
                "the empty bench's view at {:.2}° ({} photos) and the object's at {:.2}° ({} photos) are not of one bracket at one angle",
                e.turn_deg,
                e.photos.len(),
                o.turn_deg,
                o.photos.len()
            );
        }
        let Some(best) = (0..o.photos.len()).max_by_key(|&i| contrast(&o.photos[i].grey)) else {
            refuse!("no photo of the object at {:.2}°", o.turn_deg);
        };
        let (oi, ei) = (&o.photos[best], &e.photos[best]);
        check_photo_size(camera, (oi.grey.width(), oi.grey.height()), &oi.name)?;
        let mask = Mask::from_photos(&ei.grey, &oi.grey, &oi.name)?;
        views.push(View {
            camera: camera.resized(mask.width, mask.height),
            turn_deg: o.turn_deg,
            mask,
        });
    }
    Ok(refine(&mesh, &views)?)
}
