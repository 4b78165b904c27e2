//! Radiometric calibration: each camera's gain, from a target of known albedo (a grey card,
//! or a reflectance standard) put where the object goes.
//!
//! The light probe measures the light around the target, and the object cameras photograph
//! it, each with the rig's own bracket and merged as a capture merges it, but with unit gain.
//! A Lambertian target of albedo ρ with normal n shows the radiance ρ/π · Σ L·max(0, n·ω)·Δω
//! of the measured light; a camera's value over that, per pixel and channel, is its gain over
//! the light probe's. The median over the target's pixels is the measurement, and the robust
//! spread (1.4826 × the median absolute deviation, relative) says how much to trust it.
//!
//! Nothing measures radiance absolutely at a bench, so the light probe's gain is the unit:
//! it is kept as the rig has it (1 if it has none), and the others are measured against it.
//! Not here: writing the gains into the rig file (`brdfd calibrate radiometry` does that).

use std::f64::consts::PI;
use std::path::{Path, PathBuf};

use serde::Deserialize;

use super::flow::{Context, Keep, Prefixed, RawFiles};
use super::light::light_bracket;
use super::object::{self, dslr_frames, DslrFrames, FallbackBracket};
use super::plan;
use super::settings::{light_plan, Bracket};
use crate::config::{invalid, ConfigError, Gain};
use crate::error::said;
use crate::error::{refuse, Result, RigError, StepExt};
use brdfd_core::envmap::{LightSet, DEFAULT_LIGHTS};
use brdfd_core::geometry::{PixelGeometry, SceneGeometry, Shape};
use brdfd_core::raster::Raster;
use brdfd_radiometry::panorama::merge_bracket;
use brdfd_radiometry::{merge_hdr, merged_white_level, Frame};

/// The albedo of a photographer's grey card (18% reflectance), the target assumed when
/// none is given.
pub const GREY_CARD_ALBEDO: f64 = 0.18;

/// Target pixels whose predicted radiance is below this share of the median are left out:
/// a card's edge turned from the light, where noise and the map's resolution dominate.
const DIM_SHARE: f64 = 0.05;

/// The folder a calibration's photos and results go to (this one's and the pose's): `out`,
/// else a new one under the state directory's `calibrations/` (`state_dir` as
/// [`crate::session::state_dir`] finds it), named by the time and `what`. Made if it is not
/// there.
pub fn calibration_dir(
    out: Option<&Path>,
    state_dir: Option<&Path>,
    what: &str,
) -> Result<PathBuf> {
    let out = match out {
        Some(o) => o.to_path_buf(),
        None => {
            let state = crate::session::state_dir(state_dir, None)?;
            let stamp = humantime::format_rfc3339_seconds(std::time::SystemTime::now())
                .to_string()
                .replace(':', "");
            state.join("calibrations").join(format!("{stamp}-{what}"))
        }
    };
    std::fs::create_dir_all(&out).with_step(|| format!("creating {}", out.display()))?;
    Ok(out)
}

/// A calibration's photos, each under its own name in the calibration's folder.
pub struct Folder(pub PathBuf);

impl Keep for Folder {
    fn keep(&mut self, name: &str, bytes: &[u8]) -> Result<()> {
        crate::session::write_new(&self.0, name, bytes)?;
        Ok(())
    }
}

/// A calibration target: its albedo, and its shape where the object goes.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Target {
    /// Diffuse albedo, per channel or one number: 0.18 for a grey card.
    #[serde(default = "grey_card")]
    pub albedo: Gain,
    /// The target's shape (as a geometry file's `[shape]`); the rig's own object if absent
    /// (a grey sphere in the simulated rig).
    #[serde(default)]
    pub shape: Option<Shape>,
}

fn grey_card() -> Gain {
    Gain([GREY_CARD_ALBEDO; 3])
}

impl Default for Target {
    fn default() -> Self {
        Target {
            albedo: grey_card(),
            shape: None,
        }
    }
}

impl Target {
    /// A target file: `albedo` and a `[shape]` table.
    pub fn read(path: &std::path::Path) -> Result<Target> {
        let file = path.display().to_string();
        let text = std::fs::read_to_string(path).with_step(|| format!("reading {file}"))?;
        let t: Target = crate::config::parse(&file, &text)?;
        t.check(&file)?;
        Ok(t)
    }

    /// The albedo is one, and the shape one the rasteriser can draw.
    pub fn check(&self, file: &str) -> Result<(), ConfigError> {
        if !self
            .albedo
            .0
            .iter()
            .all(|a| a.is_finite() && *a > 0.0 && *a <= 1.0)
        {
            return Err(invalid(
                file,
                "albedo",
                format!("{:?} is not an albedo (above 0, at most 1)", self.albedo.0),
            ));
        }
        if let Some(shape) = &self.shape {
            // The shape's numbers, checked as a geometry file's are (the camera is the rig's).
            SceneGeometry {
                camera: brdfd_core::geometry::Camera::eval_orthographic(8),
                shape: Some(shape.clone()),
                normal_map: None,
            }
            .check()
            .map_err(|e| invalid(file, "shape", e))?;
        }
        Ok(())
    }
}

/// One camera's gain as measured.
#[derive(Debug, Clone, PartialEq)]
pub struct Measured {
    /// The calibration table it goes in (`calibration.dslr_raw`).
    pub field: &'static str,
    /// What it is, in words ("the DSLR's RAW files").
    pub what: &'static str,
    /// Linear value per unit of exposure per unit of the bench's radiance, per channel.
    pub gain: [f64; 3],
    /// Relative spread over the target's pixels (1σ, robust), per channel.
    pub spread: [f64; 3],
    /// Target pixels measured.
    pub pixels: usize,
}

/// A calibration's result.
#[derive(Debug, Clone)]
pub struct Radiometry {
    /// The light probe's gain, kept: the bench's unit.
    pub theta: [f64; 3],
    /// Whether the rig had it (else it is 1, and sets the unit from now on).
    pub theta_given: bool,
    pub cameras: Vec<Measured>,
    pub albedo: [f64; 3],
    /// Cameras that could not be measured, and why.
    pub skipped: Vec<String>,
}

impl Radiometry {
    /// A camera's gain over the light probe's: what `theta_to_dslr` meant before the gains.
    pub fn over_theta(&self, m: &Measured) -> [f64; 3] {
        [0, 1, 2].map(|c| m.gain[c] / self.theta[c])
    }
}

/// Shoots the target with every camera of the rig and measures their gains. Each camera
/// file is kept as it arrives.
pub fn radiometry(cx: &Context, keep: &mut dyn Keep, target: &Target) -> Result<Radiometry> {
    let rig = cx.rig;
    let roles = plan::devices(rig)?;
    let scene = SceneGeometry {
        shape: target.shape.clone().or(rig.geometry.shape.clone()),
        normal_map: target
            .shape
            .as_ref()
            .map_or(rig.geometry.normal_map.clone(), |_| None),
        camera: rig.geometry.camera.clone(),
    };
    let yaw = rig.theta_yaw_deg.to_radians();
    if let Some(sim) = &cx.devices.sim {
        sim.show_target(cx, &scene, target.albedo.0)?;
        cx.say(format!(
            "simulated rig: a Lambertian target of albedo {:?} on the rig's {}",
            target.albedo.0,
            if target.shape.is_some() {
                "target shape"
            } else {
                "object"
            }
        ));
    }
    let theta_given = rig.calibration.theta.is_some();
    let theta = rig
        .calibration
        .theta
        .as_ref()
        .map_or([1.0; 3], |g| g.gain.0);
    // The light, in the light probe's values per unit of exposure.
    let light = light_bracket(cx, &mut Prefixed(keep, "theta-".into()), light_plan(rig))?;
    let map = merge_bracket(&light, [1.0; 3])?;
    if map.clipped_pixels > 0 {
        cx.warn(format!(
            "{} panorama pixels clip even in the shortest frame ({:.1}% of the light): the irradiance, and so every gain, is a little high; shorten the THETA's shortest exposure",
            map.clipped_pixels,
            map.clipped_share * 100.0
        ));
    }
    let lights = map.map.compressed(DEFAULT_LIGHTS, yaw);
    let (w, h) = scene.camera.size();
    let pixels = scene.pixels(w, h)?;
    let predicted = lambertian(&pixels, &lights, target.albedo.0);

    let mut cameras = Vec::new();
    let mut skipped = Vec::new();
    // Each camera on its own: one that fails is said, and the others are still measured.
    let mut each = |what: &str, measured: Result<Vec<Measured>>| match measured {
        Ok(m) => cameras.extend(m),
        Err(e) => {
            cx.warn(format!("{what} is not measured: {}", said(&e)));
            skipped.push(format!("{what}: {}", said(&e)));
        }
    };
    if let (true, Some(role)) = (roles.dslr, &cx.devices.dslr) {
        let bracket = Bracket::dslr(rig, rig.brackets.dslr_shutters.clone());
        let measured = role
            .ping()
            .map_err(RigError::from)
            .and_then(|()| {
                object::bracket(
                    cx,
                    &mut Prefixed(keep, "dslr-".into()),
                    "calibration: DSLR",
                    role,
                    &bracket,
                    true,
                )
            })
            .and_then(|files| dslr_gains(cx, &files, &pixels, &predicted, theta));
        each("the DSLR", measured);
    }
    if let (true, Some(role)) = (roles.fallback, &cx.devices.fallback) {
        let bracket = Bracket::fallback(rig);
        let measured = object::bracket(
            cx,
            &mut Prefixed(keep, "webcam-".into()),
            "calibration: fallback camera",
            role,
            &bracket,
            false,
        )
        .and_then(|files| {
            let frames = FallbackBracket::read(&files)?.frames;
            Ok(vec![measure(
                "calibration.fallback",
                "the fallback camera",
                &frames,
                &pixels,
                &predicted,
                theta,
            )?])
        });
        each("the fallback camera", measured);
    }
    if cameras.is_empty() {
        refuse!(
            "no camera of the rig could photograph the target: {}",
            skipped.join("; ")
        );
    }
    Ok(Radiometry {
        theta,
        theta_given,
        cameras,
        albedo: target.albedo.0,
        skipped,
    })
}

/// The DSLR's gains: its RAW files' and its JPEGs', as many as the bracket has.
fn dslr_gains(
    cx: &Context,
    files: &RawFiles,
    pixels: &PixelGeometry,
    predicted: &[[f64; 3]],
    theta: [f64; 3],
) -> Result<Vec<Measured>> {
    let (raw, jpeg): (RawFiles, RawFiles) = files
        .iter()
        .cloned()
        .partition(|(name, _)| brdfd_radiometry::raw::is_raw_name(name));
    let mut out = Vec::new();
    if !raw.is_empty() {
        if let DslrFrames::Raw(frames) = dslr_frames(cx, &raw)? {
            // The demosaic mixes the background into the target's outline.
            let mut inner = pixels.clone();
            inner.drop_outline();
            let predicted = predicted_for(pixels, &inner, predicted);
            out.push(measure(
                "calibration.dslr_raw",
                "the DSLR's RAW files",
                &frames,
                &inner,
                &predicted,
                theta,
            )?);
        }
    }
    if !jpeg.is_empty() {
        if let DslrFrames::Jpeg(frames) = dslr_frames(cx, &jpeg)? {
            out.push(measure(
                "calibration.dslr_jpeg",
                "the DSLR's JPEG files",
                &frames,
                pixels,
                predicted,
                theta,
            )?);
        }
    }
    Ok(out)
}

/// The predictions of `all`'s pixels that `some` keeps.
fn predicted_for(
    all: &PixelGeometry,
    some: &PixelGeometry,
    predicted: &[[f64; 3]],
) -> Vec<[f64; 3]> {
    let index: std::collections::HashMap<(u32, u32), usize> = all
        .pixels
        .iter()
        .enumerate()
        .map(|(i, p)| ((p.x, p.y), i))
        .collect();
    some.pixels
        .iter()
        .map(|p| predicted[index[&(p.x, p.y)]])
        .collect()
}

/// The radiance a Lambertian target of `albedo` shows at each pixel under `lights`, in the
/// lights' unit: ρ/π · Σ L·max(0, n·ω)·Δω over the lights the pixel sees (a mesh target's
/// own shape hides some, as the renderers count it).
pub(crate) fn lambertian(
    pixels: &PixelGeometry,
    lights: &LightSet,
    albedo: [f64; 3],
) -> Vec<[f64; 3]> {
    brdfd_core::render::irradiance(pixels, lights)
        .into_iter()
        .map(|e| [0, 1, 2].map(|c| albedo[c] / PI * e[c]))
        .collect()
}

/// A camera's gain from its frames of the target: the median over the target's pixels of its
/// merged value over the predicted radiance, times the light probe's gain.
fn measure(
    field: &'static str,
    what: &'static str,
    frames: &[Frame],
    pixels: &PixelGeometry,
    predicted: &[[f64; 3]],
    theta: [f64; 3],
) -> Result<Measured> {
    let merged = merge_hdr(frames, 1.0)?;
    let white = merged_white_level(frames, 1.0).unwrap_or(f32::INFINITY);
    check_size(&merged, pixels, what)?;
    let mut floor = [0.0; 3];
    for c in 0..3 {
        let mut v: Vec<f64> = predicted.iter().map(|p| p[c]).collect();
        floor[c] = median(&mut v).unwrap_or(0.0) * DIM_SHARE;
    }
    let mut ratios: [Vec<f64>; 3] = Default::default();
    for (p, pred) in pixels.pixels.iter().zip(predicted) {
        let v = merged.pixels[p.y as usize * merged.width + p.x as usize];
        // A clipped channel is a lower bound, not a measurement.
        if v.iter().any(|&x| !(x.is_finite() && x < white)) {
            continue;
        }
        if (0..3).any(|c| pred[c] <= floor[c]) {
            continue;
        }
        for c in 0..3 {
            ratios[c].push(v[c] as f64 / pred[c]);
        }
    }
    let pixels_used = ratios[0].len();
    let mut gain = [0.0; 3];
    let mut spread = [0.0; 3];
    for c in 0..3 {
        let Some(m) = median(&mut ratios[c]) else {
            refuse!("{what}: no pixel of the target is lit and unclipped in the bracket; check that the target fills the object's place and the exposures reach it");
        };
        let mut deviation: Vec<f64> = ratios[c].iter().map(|r| (r - m).abs()).collect();
        let mad = median(&mut deviation).unwrap_or(0.0);
        gain[c] = m * theta[c];
        spread[c] = 1.4826 * mad / m;
    }
    Ok(Measured {
        field,
        what,
        gain,
        spread,
        pixels: pixels_used,
    })
}

fn check_size(photo: &Raster, pixels: &PixelGeometry, what: &str) -> Result<()> {
    if (photo.width, photo.height) != (pixels.width, pixels.height) {
        refuse!(
            "{what}: the photos are {}×{}, the rig's camera is {}×{}: set [geometry.camera] width and height to the camera's",
            photo.width,
            photo.height,
            pixels.width,
            pixels.height
        );
    }
    Ok(())
}

fn median(v: &mut [f64]) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    let mid = v.len() / 2;
    Some(*v.select_nth_unstable_by(mid, f64::total_cmp).1)
}
