//! The results of a part with two materials ([`brdfd_core::materials`]): each material's own
//! result set in `material-1/`, `material-2/`, and beside the whole part's results the record
//! of the split (`coefficients.json`'s `materials`), a picture of it (`materials.png`), the
//! first view's labels (`materials-mask.png`) and, on a mesh, the object in both materials
//! (`object.gltf`).

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use brdfd_core::basis::Basis;
use brdfd_core::envmap::LightSet;
use brdfd_core::error::{CoreError, Result};
use brdfd_core::materials::{Materials, Split, UNSEEN};
use brdfd_core::raster::Raster;

use crate::export::GltfMaterial;
use crate::html::Context;
use crate::results::{write_results, ResultFiles};

/// `coefficients.json`'s `materials`: the part's materials, each estimated on its own pixels
/// and written in its own folder. Its numbers are finite: a split whose fit is not a number
/// is not kept, and the candidates' values are.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct MaterialsRecord {
    /// How far the photo's colour departs from the whole part's estimate from place to place
    /// (RMS of ln colour shares), which asked for the split.
    pub departure: f64,
    /// The materials' re-render of the photo together (relative RMSE), against the whole
    /// estimate's `fit_error`.
    pub fit_error: f64,
    pub parts: Vec<PartRecord>,
    /// On a mesh, each triangle's material (an index into `parts`; 255 where no view saw
    /// the triangle): what `brdfd render --coefficients` paints the mesh with.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub triangles: Option<Vec<u8>>,
}

/// One material of [`MaterialsRecord`].
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct PartRecord {
    /// Its results' folder, beside `coefficients.json`.
    pub folder: String,
    /// Its pixels, over every view, and their share of the part's.
    pub pixels: usize,
    pub share: f64,
    /// Its estimate's re-render of its own pixels (relative RMSE).
    pub fit_error: f64,
    /// The photo's mean colour over its pixels (linear RGB, the brightest channel 1): what
    /// the report's swatch shows.
    pub colour: [f64; 3],
}

/// What [`write_parts`] wrote: the record, each material's files, and the pictures of the
/// split.
pub struct Parts {
    pub record: MaterialsRecord,
    pub files: Vec<ResultFiles>,
    /// `materials.png` as written, when the first view's photo was given.
    pub picture: Option<image::RgbImage>,
    /// `materials.png` and `materials-mask.png`, when written.
    pub pictures: Vec<PathBuf>,
}

impl Parts {
    /// Each material's exported glTF material, with its name.
    pub fn gltf(&self) -> Vec<(String, &GltfMaterial)> {
        self.files
            .iter()
            .enumerate()
            .map(|(k, f)| (format!("brdfd_material_{}", k + 1), &f.exports.material))
            .collect()
    }
}

/// Every result of an estimate that may have split its part into materials: each material's
/// in its own folder first ([`write_parts`]), then the whole part's beside them
/// ([`write_results`]), which record the split. What an earlier split wrote in `dir` is
/// removed first ([`remove_stale`]).
pub fn write_all(
    dir: &Path,
    basis: &Basis,
    found: &Materials,
    method: &str,
    lights: &LightSet,
    cx: Context,
) -> Result<(ResultFiles, Option<Parts>)> {
    remove_stale(dir)?;
    let parts = match (&found.split, found.departure) {
        (Some(split), Some(departure)) => Some(write_parts(
            dir, basis, split, departure, method, lights, &cx,
        )?),
        _ => None,
    };
    let cx = Context {
        materials: parts.as_ref(),
        ..cx
    };
    let files = write_results(dir, basis, &found.whole, method, lights, &cx)?;
    Ok((files, parts))
}

/// A material's folder, beside the whole part's results.
pub fn folder(k: usize) -> String {
    format!("material-{}", k + 1)
}

/// Writes each material's results into its folder of `dir` ([`write_results`], with `cx`
/// but for the title and the mesh, which is the whole part's), and the split's pictures
/// beside them ([`write_pictures`]).
pub fn write_parts(
    dir: &Path,
    basis: &Basis,
    split: &Split,
    departure: f64,
    method: &str,
    lights: &LightSet,
    cx: &Context,
) -> Result<Parts> {
    let total: usize = split.pixels.iter().sum();
    let mut files = Vec::with_capacity(split.parts.len());
    let mut parts = Vec::with_capacity(split.parts.len());
    for (k, estimate) in split.parts.iter().enumerate() {
        let sub = Context {
            title: format!("{}: material {} of {}", cx.title, k + 1, split.parts.len()),
            session: cx.session.clone(),
            photo: cx.photo,
            env: cx.env,
            yaw: cx.yaw,
            relight_error: None,
            truth: None,
            fallback: cx.fallback.clone(),
            record: cx.record.clone(),
            visibility: cx.visibility,
            object: None,
            exports: cx.exports,
            materials: None,
        };
        files.push(write_results(
            &dir.join(folder(k)),
            basis,
            estimate,
            method,
            lights,
            &sub,
        )?);
        parts.push(PartRecord {
            folder: folder(k),
            pixels: split.pixels[k],
            share: split.pixels[k] as f64 / total.max(1) as f64,
            fit_error: estimate.fit_error,
            colour: mean_colour(estimate),
        });
    }
    let (picture, pictures) = match cx.photo {
        Some(photo) => write_pictures(dir, photo, split)?,
        None => (None, Vec::new()),
    };
    Ok(Parts {
        picture,
        pictures,
        record: MaterialsRecord {
            departure,
            fit_error: split.fit_error,
            parts,
            triangles: split.triangles.clone(),
        },
        files,
    })
}

/// The photo's mean colour over an estimate's candidates, its brightest channel 1.
fn mean_colour(estimate: &brdfd_core::estimate::Estimate) -> [f64; 3] {
    let mut sum = [0.0f64; 3];
    for r in &estimate.rerender {
        for c in 0..3 {
            sum[c] += f64::from(r.observed[c]);
        }
    }
    let top = sum.iter().cloned().fold(0.0, f64::max);
    if top > 0.0 {
        sum.map(|v| v / top)
    } else {
        sum
    }
}

/// Tints over the photo for the materials in `materials.png`: orange, then cyan.
const TINTS: [[f32; 3]; 2] = [[1.0, 0.55, 0.1], [0.1, 0.75, 1.0]];

/// `materials.png`, the first view's photo with each material's pixels tinted (the rest
/// dimmed), and `materials-mask.png`, its labels: 0 off the part, then 1, 2 for the
/// materials. Returns the picture and the two paths.
pub fn write_pictures(
    dir: &Path,
    photo: &Raster,
    split: &Split,
) -> Result<(Option<image::RgbImage>, Vec<PathBuf>)> {
    let Some(first) = split.labels.first() else {
        return Ok((None, Vec::new()));
    };
    let (w, h) = (photo.width, photo.height);
    // The photo at the exposure `compare.png` shows it at, dimmed off the materials.
    let shown = photo.to_srgb8(photo.auto_exposure());
    let mut picture = shown.clone();
    for p in picture.pixels_mut() {
        p.0 = p.0.map(|v| (f32::from(v) * 0.35) as u8);
    }
    let mut mask = image::GrayImage::new(w as u32, h as u32);
    for l in first {
        if l.x as usize >= w || l.y as usize >= h {
            continue;
        }
        let tint = TINTS[l.material as usize % TINTS.len()];
        let grey = shown
            .get_pixel(l.x, l.y)
            .0
            .iter()
            .map(|v| f32::from(*v))
            .sum::<f32>()
            / 3.0;
        let px = [0, 1, 2].map(|c| (0.5 * grey + 0.5 * 255.0 * tint[c]).min(255.0) as u8);
        picture.put_pixel(l.x, l.y, image::Rgb(px));
        mask.put_pixel(l.x, l.y, image::Luma([l.material + 1]));
    }
    let save = |path: PathBuf, result: image::ImageResult<()>| {
        result
            .map_err(|e| CoreError::format(path.display(), format!("could not write PNG: {e}")))
            .map(|_| path)
    };
    let p = dir.join("materials.png");
    let q = dir.join("materials-mask.png");
    let paths = vec![
        save(p.clone(), picture.save(&p))?,
        save(q.clone(), mask.save(&q))?,
    ];
    Ok((Some(picture), paths))
}

/// The material most of the seen triangles have.
pub fn commoner(triangles: &[u8], parts: usize) -> u8 {
    let mut counts = vec![0usize; parts.max(1)];
    for t in triangles {
        if let Some(c) = counts.get_mut(*t as usize) {
            *c += 1;
        }
    }
    (0..counts.len()).max_by_key(|k| counts[*k]).unwrap_or(0) as u8
}

/// The record's triangles with each unseen one given the commoner material: what the
/// object's glTF paints.
pub fn painted(triangles: &[u8], parts: usize) -> Vec<u8> {
    let most = commoner(triangles, parts);
    triangles
        .iter()
        .map(|t| {
            if *t == UNSEEN || *t as usize >= parts {
                most
            } else {
                *t
            }
        })
        .collect()
}

/// Removes what a split into materials wrote in `dir` (the materials' folders and the
/// split's pictures), before results are written there again: an estimate that finds one
/// material must not leave an earlier one's beside its own. Only when the `coefficients.json`
/// there records a split: folders of those names are otherwise not brdfd's to remove.
pub fn remove_stale(dir: &Path) -> Result<()> {
    let split = crate::results::StoredResult::read(&dir.join("coefficients.json"))
        .is_ok_and(|r| r.materials.is_some());
    if !split {
        return Ok(());
    }
    for k in 0..2 {
        let d = dir.join(folder(k));
        if d.is_dir() {
            std::fs::remove_dir_all(&d).map_err(|e| CoreError::io(&d, e))?;
        }
    }
    for name in ["materials.png", "materials-mask.png"] {
        let f = dir.join(name);
        if f.is_file() {
            std::fs::remove_file(&f).map_err(|e| CoreError::io(&f, e))?;
        }
    }
    Ok(())
}
