//! The board photographed by the rig's object camera, for `brdfd calibrate pose`: the DSLR's
//! bracket as JPEGs (or the fallback camera's frames), each frame kept as it arrives, and the
//! pose solved from the frame that shows the most of the board.
//!
//! A simulated rig shows the board to its DSLR as the virtual bench renders it, through the
//! camera of `[simulation] camera` when the rig has one: the pose the operator typed into the
//! rig is then what the calibration corrects.

use anyhow::bail;

use super::flow::{Context, Keep, RawFiles};
use super::object::{self, FallbackBracket};
use super::plan;
use super::settings::Bracket;
use crate::bench::board_photo::{self, Spoil};
use crate::config::DslrFiles;
use crate::core::raster::linear_to_srgb;
use crate::pose::board::Board;
use crate::pose::{calibrate, Calibrated, Focal};
use crate::radiometry::ExifFocal;

/// A photo of the board to solve from: 8-bit grey, with the lens's EXIF where it has one.
pub struct BoardPhoto {
    pub name: String,
    pub grey: image::GrayImage,
    pub exif: Option<ExifFocal>,
}

impl BoardPhoto {
    /// A JPEG or PNG file.
    pub fn decode(name: &str, bytes: &[u8]) -> anyhow::Result<BoardPhoto> {
        let image = image::load_from_memory(bytes).map_err(|e| {
            anyhow::anyhow!("{name}: not a photo brdfd reads for a pose (JPEG or PNG): {e}")
        })?;
        Ok(BoardPhoto {
            name: name.to_string(),
            grey: image.to_luma8(),
            exif: crate::radiometry::exif_focal(bytes),
        })
    }
}

/// Photographs the board with the rig's object camera: the DSLR's bracket (as JPEGs) if the
/// rig has a DSLR, else the fallback camera's. Every file is kept as it arrives.
pub fn shoot(cx: &Context, keep: &mut dyn Keep, board: &Board) -> anyhow::Result<Vec<BoardPhoto>> {
    let rig = cx.rig;
    let roles = plan::devices(rig)?;
    if let Some(sim) = &cx.devices.sim {
        let camera = rig.bench_camera(&rig.geometry.camera);
        let env = crate::bench::studio_envmap(512);
        let radiance = board_photo::render(
            board,
            &camera,
            &env,
            rig.theta_yaw_deg.to_radians(),
            Spoil::default(),
        )?;
        sim.show_radiance(radiance, &camera)?;
        cx.say("simulated rig: the board stands where the object goes, under the studio light");
    }
    if let (true, Some(role)) = (roles.dslr, &cx.devices.dslr) {
        let mut bracket = Bracket::dslr(rig, rig.brackets.dslr_shutters.clone());
        // The board is found in 8-bit files; a RAW file would add nothing but time.
        bracket.camera.files = Some(DslrFiles::Jpeg);
        let files = object::bracket(cx, keep, "pose: DSLR", role, &bracket, true)?;
        return files
            .iter()
            .map(|(name, bytes)| BoardPhoto::decode(name, bytes))
            .collect();
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
        return Ok(frames_as_photos(&files)?);
    }
    bail!("the rig has no object camera that answers, to photograph the board with")
}

/// The fallback camera's frames as 8-bit sRGB grey.
fn frames_as_photos(files: &RawFiles) -> anyhow::Result<Vec<BoardPhoto>> {
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
            BoardPhoto {
                name: format!("fallback frame {} ({} s)", i + 1, f.exposure.shutter_s),
                grey,
                exif: None,
            }
        })
        .collect())
}

/// The pose from the photo that shows the most of the board (the lowest reprojection error
/// among equals). The errors of photos where no board was found are said if none had one.
pub fn solve_best(
    rig_camera: &crate::core::geometry::Camera,
    board: &Board,
    photos: &[BoardPhoto],
    focal: Focal,
    sensor_width_mm: Option<f64>,
) -> anyhow::Result<(Calibrated, String)> {
    let mut best: Option<(Calibrated, String)> = None;
    let mut failures = Vec::new();
    for p in photos {
        match calibrate(
            rig_camera,
            board,
            &p.grey,
            &p.name,
            p.exif,
            focal,
            sensor_width_mm,
        ) {
            Ok(c) => {
                let better = best.as_ref().is_none_or(|(b, _)| {
                    (c.fit.corners, -c.fit.rms_px) > (b.fit.corners, -b.fit.rms_px)
                });
                if better {
                    best = Some((c, p.name.clone()));
                }
            }
            Err(e) => failures.push(format!("{e:#}")),
        }
    }
    best.ok_or_else(|| {
        anyhow::anyhow!(
            "the board was found in none of the {} photos: {}",
            photos.len(),
            failures.join("; ")
        )
    })
}
