//! Equirectangular (latitude-longitude) environment maps: loading Radiance `.hdr` and OpenEXR,
//! the direction and solid angle of each pixel, yaw, and compression to a few thousand lights.
//!
//! Convention (docs/bench-setup.md, "Conventions"): world frame right-handed, +Y up. Row 0 looks straight up
//! (+Y); rows span the polar angle θ from 0 to π. Column centre u ∈ [0, 1) has azimuth
//! φ = 2π(u − ½), and the direction is (sin θ sin φ, cos θ, −sin θ cos φ): the centre column
//! faces −Z (the camera's forward), the column at u = ¾ faces +X, and u = ¼ faces −X. This is
//! how a viewer inside the sphere sees the panorama: turning right moves right in the image.
//! A yaw ψ rotates the map into the world by a right-handed rotation of ψ about +Y: with
//! ψ = +90° the map's centre column faces −X.
//! Radiance is linear RGB; nothing here applies a camera response.

use std::path::Path;
use std::sync::Arc;

use super::error::{CoreError, Result};
use super::sharp::SkyMap;

/// Negative radiance smaller than this (relative to the map's mean) is resampling ringing and is
/// clamped to zero with a warning; anything more negative is an error.
pub const NEGATIVE_TOLERANCE: f32 = 0.05;
/// Default number of lights after compression: enough that re-renders change by little
/// (measured in `tests/core.rs` and docs/evaluation.md), few enough for a fast rendering matrix.
pub const DEFAULT_LIGHTS: usize = 4096;
/// Lights for the chosen pixels' rows (see `estimate::chosen_rows`): sixteen times the
/// default. A few chosen pixels carry the whole estimate, so their rows are worth the finer
/// sky; what compression leaves in one row is an error the solve cannot average away.
pub const CHOSEN_LIGHTS: usize = 65_536;
/// Compression first cuts the map into this many columns × half as many rows (22.5° cells),
/// so that no light stands for more than a small part of the sky.
const COARSE_COLUMNS: usize = 16;

/// A linear HDR equirectangular map.
#[derive(Clone, Debug)]
pub struct EnvMap {
    pub width: usize,
    pub height: usize,
    /// Row-major, row 0 at the top (+Y).
    pub pixels: Vec<[f32; 3]>,
    /// How many slightly negative values were clamped to zero when the map was loaded.
    pub clamped_negatives: usize,
}

/// Discrete lights: a direction (world frame, unit), radiance, the solid angle each covers,
/// and how far its power spreads around its direction.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LightSet {
    pub directions: Vec<[f32; 3]>,
    pub radiance: Vec<[f32; 3]>,
    pub solid_angle: Vec<f32>,
    /// Angular radius (radians) of the disc that holds the light's power as evenly as the map
    /// does: √(Δω/π) for one map pixel, less for a cell whose power sits in a small bright
    /// patch. The renderers average the BRDF over this footprint.
    pub spread: Vec<f32>,
    /// The map the lights were made from, which the renderers read directly where a lobe is
    /// sharper than the lights (`crate::sharp`); `None` for lights placed by hand.
    pub map: Option<Arc<SkyMap>>,
}

impl LightSet {
    pub fn len(&self) -> usize {
        self.directions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.directions.is_empty()
    }

    /// The irradiance Σ L·cos·Δω per channel on an unshadowed surface facing `normal`
    /// (unit).
    pub fn irradiance_facing(&self, normal: [f64; 3]) -> [f64; 3] {
        let mut e = [0.0f64; 3];
        for ((d, l), w) in self
            .directions
            .iter()
            .zip(&self.radiance)
            .zip(&self.solid_angle)
        {
            let cos = (0..3)
                .map(|c| d[c] as f64 * normal[c])
                .sum::<f64>()
                .max(0.0);
            for c in 0..3 {
                e[c] += l[c] as f64 * cos * *w as f64;
            }
        }
        e
    }

    /// Total irradiance-weighted power, Σ L·Δω per channel: what compression must preserve.
    pub fn power(&self) -> [f64; 3] {
        let mut p = [0.0; 3];
        for (l, w) in self.radiance.iter().zip(&self.solid_angle) {
            for c in 0..3 {
                p[c] += (l[c] * w) as f64;
            }
        }
        p
    }
}

/// Direction of the point (u, v) of the map, u across and v down, both in [0, 1].
pub fn direction(u: f64, v: f64, yaw: f64) -> [f64; 3] {
    direction_of(sin_cos(polar(v)), sin_cos(azimuth(u, yaw)))
}

/// The polar angle θ (from +Y) of the map's row coordinate `v`.
fn polar(v: f64) -> f64 {
    std::f64::consts::PI * v
}

/// The azimuth φ of the map's column coordinate `u`, turned by `yaw`.
fn azimuth(u: f64, yaw: f64) -> f64 {
    2.0 * std::f64::consts::PI * (u - 0.5) - yaw
}

fn sin_cos(angle: f64) -> (f64, f64) {
    (angle.sin(), angle.cos())
}

/// [`direction`] from the sines and cosines of θ and φ: what a table made row by row and
/// column by column computes once per row and column, with the same values.
fn direction_of((sin_t, cos_t): (f64, f64), (sin_p, cos_p): (f64, f64)) -> [f64; 3] {
    [sin_t * sin_p, cos_t, -sin_t * cos_p]
}

/// Inverse of [`direction`] with yaw 0: (u, v) for a unit world direction.
pub fn uv_of(d: [f64; 3]) -> (f64, f64) {
    let theta = d[1].clamp(-1.0, 1.0).acos();
    let phi = d[0].atan2(-d[2]);
    let u = (phi / (2.0 * std::f64::consts::PI) + 0.5).rem_euclid(1.0);
    (u, theta / std::f64::consts::PI)
}

impl EnvMap {
    /// Loads `.hdr` or `.exr`, checking every value. NaN or infinity is an error naming the
    /// pixel; small negatives are clamped (see [`NEGATIVE_TOLERANCE`]).
    pub fn load(path: &Path) -> Result<EnvMap> {
        let what = path.display().to_string();
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(|e| e.to_ascii_lowercase());
        let (width, height, pixels) = match ext.as_deref() {
            Some("hdr") => {
                let img = image::ImageReader::open(path)
                    .map_err(|e| CoreError::io(path, e))?
                    .with_guessed_format()
                    .map_err(|e| CoreError::io(path, e))?
                    .decode()
                    .map_err(|e| {
                        CoreError::format(&what, format!("not a readable Radiance HDR: {e}"))
                    })?
                    .into_rgb32f();
                let (w, h) = (img.width() as usize, img.height() as usize);
                (w, h, img.pixels().map(|p| p.0).collect::<Vec<_>>())
            }
            Some("exr") => {
                let e = read_exr_rgb(path)?;
                (e.width, e.height, e.pixels)
            }
            _ => {
                return Err(CoreError::format(
                    &what,
                    "unknown environment map type; use a Radiance .hdr or an OpenEXR .exr",
                ))
            }
        };
        Self::from_pixels(width, height, pixels, &what)
    }

    /// Validates raw pixels (see [`EnvMap::load`]).
    pub fn from_pixels(
        width: usize,
        height: usize,
        mut pixels: Vec<[f32; 3]>,
        what: &str,
    ) -> Result<EnvMap> {
        if width < 2 || height < 1 || pixels.len() != width * height {
            return Err(CoreError::format(
                what,
                format!("bad size {width}×{height} for {} pixels", pixels.len()),
            ));
        }
        if width != 2 * height {
            tracing::warn!(
                width,
                height,
                map = what,
                "environment map is not 2:1; it is read as latitude-longitude anyway"
            );
        }
        let mut sum = 0.0f64;
        for (i, p) in pixels.iter().enumerate() {
            for (c, v) in p.iter().enumerate() {
                if !v.is_finite() {
                    return Err(CoreError::NonFinite {
                        what: what.into(),
                        x: i % width,
                        y: i / width,
                        channel: c,
                        value: *v,
                    });
                }
                sum += v.abs() as f64;
            }
        }
        let floor = -(NEGATIVE_TOLERANCE as f64 * sum / (3 * pixels.len()) as f64) as f32;
        let mut clamped = 0;
        for (i, p) in pixels.iter_mut().enumerate() {
            for (c, v) in p.iter_mut().enumerate() {
                if *v < 0.0 {
                    if *v < floor {
                        return Err(CoreError::format(what, format!(
                            "negative radiance {v} at pixel (x={}, y={}), channel {c}: larger than resampling leaves behind; is this a linear radiance map?",
                            i % width, i / width)));
                    }
                    *v = 0.0;
                    clamped += 1;
                }
            }
        }
        if clamped > 0 {
            tracing::warn!(
                count = clamped,
                map = what,
                "clamped small negative radiance values to zero"
            );
        }
        Ok(EnvMap {
            width,
            height,
            pixels,
            clamped_negatives: clamped,
        })
    }
    /// Writes the map as a float EXR that carries OpenEXR's standard `envmap` attribute
    /// (latitude-longitude), so that renderers and viewers take it for a panorama.
    ///
    /// OpenEXR's lat-long (ImfEnvmap) has +Y up and +Z at the centre column; brdfd's frame
    /// (module header) has −Z there. A tool that follows OpenEXR's axes to the letter sees
    /// the map turned 180° about +Y, which is how tools that load a lat-long map as a sky
    /// differ among themselves anyway; the pixels' layout is the same.
    pub fn write_exr(&self, path: &Path) -> Result<()> {
        let bytes = encode_exr(
            self.width,
            self.height,
            &self.pixels,
            &[],
            Some(exr::meta::attribute::EnvironmentMap::LatitudeLongitude),
        )?;
        std::fs::write(path, bytes).map_err(|e| CoreError::io(path, e))
    }

    /// Solid angle of a pixel in row `y`.
    pub fn pixel_solid_angle(&self, y: usize) -> f64 {
        let pi = std::f64::consts::PI;
        let t0 = pi * y as f64 / self.height as f64;
        let t1 = pi * (y + 1) as f64 / self.height as f64;
        2.0 * pi / self.width as f64 * (t0.cos() - t1.cos())
    }

    /// Every pixel as a light, rotated by `yaw` radians.
    pub fn lights(&self, yaw: f64) -> LightSet {
        let mut set = LightSet {
            map: Some(Arc::new(SkyMap::new(self, yaw))),
            ..LightSet::default()
        };
        for y in 0..self.height {
            let dw = self.pixel_solid_angle(y) as f32;
            for x in 0..self.width {
                let u = (x as f64 + 0.5) / self.width as f64;
                let v = (y as f64 + 0.5) / self.height as f64;
                set.directions.push(direction(u, v, yaw).map(|c| c as f32));
                set.radiance.push(self.pixels[y * self.width + x]);
                set.solid_angle.push(dw);
                set.spread.push((dw / std::f32::consts::PI).sqrt());
            }
        }
        set
    }

    /// Area-weighted downsampling to `width × height`: each output pixel's radiance is the
    /// solid-angle-weighted mean of the source pixels whose centres fall in it, so the total
    /// power Σ L·Δω is preserved.
    pub fn downsample(&self, width: usize, height: usize) -> EnvMap {
        let mut acc = vec![[0.0f64; 3]; width * height];
        let mut weight = vec![0.0f64; width * height];
        for y in 0..self.height {
            let dw = self.pixel_solid_angle(y);
            let ty = ((y as f64 + 0.5) / self.height as f64 * height as f64) as usize;
            for x in 0..self.width {
                let tx = ((x as f64 + 0.5) / self.width as f64 * width as f64) as usize;
                let t = ty.min(height - 1) * width + tx.min(width - 1);
                for c in 0..3 {
                    acc[t][c] += self.pixels[y * self.width + x][c] as f64 * dw;
                }
                weight[t] += dw;
            }
        }
        let pixels = acc
            .iter()
            .zip(&weight)
            .map(|(a, w)| {
                if *w > 0.0 {
                    a.map(|v| (v / w) as f32)
                } else {
                    [0.0; 3]
                }
            })
            .collect();
        EnvMap {
            width,
            height,
            pixels,
            clamped_negatives: 0,
        }
    }

    /// Compresses to `count` lights, or returns every pixel if the map is no larger.
    ///
    /// Adaptive, because a uniform grid fails on the maps that matter: a 4° grid cell of
    /// Grace Cathedral holds a window a tenth its size, and a mirror-like metal's render
    /// changed by 40% between 4,096 and 8,192 grid lights. Here the map is cut into
    /// rectangles of pixels, and the rectangle with the largest power × spread (how far its power lies from its centre) is
    /// halved across its longer side until there are `count`. Bright, structured parts end as
    /// many small lights, dim ones as few large ones. Each light sits at the power-weighted
    /// centre of its rectangle and carries the rectangle's power exactly.
    pub fn compressed(&self, count: usize, yaw: f64) -> LightSet {
        self.compressed_levels(&[count], yaw).remove(0)
    }

    /// An estimate's lights, from one compression pass: `candidates` lights for every
    /// candidate pixel's row, and `chosen` for the chosen pixels' rows (see
    /// `estimate::chosen_rows`), or none if that is no finer.
    pub fn estimate_lights(
        &self,
        candidates: usize,
        chosen: usize,
        yaw: f64,
    ) -> (LightSet, Option<LightSet>) {
        if chosen <= candidates {
            return (self.compressed(candidates, yaw), None);
        }
        let mut levels = self.compressed_levels(&[candidates, chosen], yaw);
        let fine = levels.pop();
        (levels.remove(0), fine)
    }

    /// [`EnvMap::compressed`] to each of `counts` (ascending) in one pass: each coarser set is
    /// the finer one's splitting stopped earlier, so it is the same as compressing to it
    /// alone, and the map's sums are built once (most of the cost on a large map).
    pub fn compressed_levels(&self, counts: &[usize], yaw: f64) -> Vec<LightSet> {
        assert!(
            counts.windows(2).all(|w| w[0] <= w[1]),
            "compression counts must ascend: {counts:?}"
        );
        let pixels = self.width * self.height;
        if counts.iter().all(|c| *c >= pixels) {
            return counts.iter().map(|_| self.lights(yaw)).collect();
        }
        let sums = CellSums::new(self, yaw);
        let sky = Arc::new(SkyMap::new(self, yaw));
        let (cols, rows) = (
            COARSE_COLUMNS.min(self.width),
            (COARSE_COLUMNS / 2).min(self.height),
        );
        let mut heap = std::collections::BinaryHeap::new();
        for j in 0..rows {
            for i in 0..cols {
                let rect = Rect {
                    x0: i * self.width / cols,
                    x1: (i + 1) * self.width / cols,
                    y0: j * self.height / rows,
                    y1: (j + 1) * self.height / rows,
                };
                heap.push(sums.cell(rect));
            }
        }
        let mut out = Vec::with_capacity(counts.len());
        for (i, &count) in counts.iter().enumerate() {
            if count >= pixels {
                out.push(self.lights(yaw));
                continue;
            }
            while heap.len() < count {
                let Some(top) = heap.peek() else { break };
                let Some((a, b)) = top.rect.halves(self) else {
                    break; // the largest cell is one pixel: nothing left worth splitting
                };
                heap.pop();
                heap.push(sums.cell(a));
                heap.push(sums.cell(b));
            }
            let mut set = LightSet {
                map: Some(sky.clone()),
                ..LightSet::default()
            };
            // The last level can take the heap; coarser ones leave it to be split further.
            let cells = if i + 1 == counts.len() {
                std::mem::take(&mut heap)
            } else {
                heap.clone()
            };
            for cell in cells.into_sorted_vec() {
                set.directions.push(cell.direction);
                set.radiance.push(cell.radiance);
                set.solid_angle.push(cell.solid_angle);
                set.spread.push(cell.spread);
            }
            out.push(set);
        }
        out
    }

    /// Reads an EXR's RGB without radiance checks (normal maps hold negative components).
    pub(crate) fn load_raw_exr(path: &Path) -> Result<(usize, usize, Vec<[f32; 3]>)> {
        read_exr_rgb(path).map(|e| (e.width, e.height, e.pixels))
    }

    /// The same map mirrored left to right: what a wrongly oriented export looks like.
    pub fn mirrored(&self) -> EnvMap {
        let mut out = self.clone();
        for y in 0..self.height {
            out.pixels[y * self.width..(y + 1) * self.width].reverse();
        }
        out
    }
}

/// The EXR attribute (f32) in which brdfd records a merged photo's white level: a pixel with
/// a channel at or above it clipped in every frame of its bracket, so its value is only a
/// lower bound. Kept in the file so that a later `brdfd estimate` on it knows, as the capture
/// did.
pub const WHITE_LEVEL_ATTRIBUTE: &str = "brdfdWhiteLevel";

/// An RGB EXR as read: size, linear pixels (row-major), and its [`WHITE_LEVEL_ATTRIBUTE`].
pub struct ExrRgb {
    pub width: usize,
    pub height: usize,
    pub pixels: Vec<[f32; 3]>,
    pub white: Option<f32>,
}

/// The most pixels an OpenEXR file may declare: a 16384 × 8192 panorama. The header's size is
/// checked before anything is allocated for it, so a small file claiming a huge image is an
/// error, not an abort.
pub const MAX_EXR_PIXELS: usize = 16384 * 8192;

/// How many times smaller than its pixels an OpenEXR file can be: deflate (ZIP) packs at most
/// about 1032 to 1, and PXR24 deflates floats cut to 24 bits (so about 1376 to 1 of 32-bit
/// data); with room to spare.
const MAX_EXR_COMPRESSION: usize = 1500;

/// The largest tile side accepted whatever the image's size: small images are often stored in
/// tiles larger than themselves (64, 128 or 256 pixels a side).
const MAX_SMALL_TILE: usize = 256;

/// Refuses an OpenEXR file whose headers declare more than [`MAX_EXR_PIXELS`] in a layer,
/// tiles larger than the layer, or more pixel data than its `file_bytes` could hold
/// compressed: a small file claiming a large image (or tile) would otherwise cost the whole
/// image's memory before its data runs out.
pub(crate) fn check_exr_size(
    meta: &exr::meta::MetaData,
    what: &str,
    file_bytes: usize,
) -> Result<()> {
    for header in &meta.headers {
        let size = header.layer_size;
        if size.area() > MAX_EXR_PIXELS {
            return Err(CoreError::format(
                what,
                format!(
                    "the header declares {} × {} pixels, more than the {MAX_EXR_PIXELS} brdfd reads",
                    size.width(),
                    size.height()
                ),
            ));
        }
        // A tile is decoded whole, so its size is allocated too: larger than the image (or a
        // common tile, for small images) it can only be a damaged header.
        if let exr::meta::BlockDescription::Tiles(t) = &header.blocks {
            let (tw, th) = (t.tile_size.width(), t.tile_size.height());
            if tw > size.width().max(MAX_SMALL_TILE) || th > size.height().max(MAX_SMALL_TILE) {
                return Err(CoreError::format(
                    what,
                    format!(
                        "tiles of {tw} × {th} pixels in a {} × {} image: the header is damaged",
                        size.width(),
                        size.height()
                    ),
                ));
            }
        }
        let sample_bytes: usize = header
            .channels
            .list
            .iter()
            .map(|c| c.sample_type.bytes_per_sample())
            .sum();
        let declared = size.area().saturating_mul(sample_bytes);
        if declared > file_bytes.saturating_mul(MAX_EXR_COMPRESSION) {
            return Err(CoreError::format(
                what,
                format!(
                    "the header declares {} × {} pixels ({declared} bytes), more than a file of {file_bytes} bytes can hold: it is truncated or corrupt",
                    size.width(),
                    size.height()
                ),
            ));
        }
    }
    Ok(())
}

/// Why the OpenEXR library could not read a file of `len` bytes as `part`, in words: a file
/// that ends early is called truncated, as the size check above calls it when it can tell.
/// The library reports the end of the file where more was due as "reference to missing
/// bytes", an `Invalid` error.
fn exr_failure(part: &str, e: &exr::error::Error, len: usize) -> String {
    let ended = matches!(e, exr::error::Error::Invalid(why) if why.contains("missing bytes"));
    if ended {
        format!("the file ends before its {part} does, at {len} bytes: it is truncated or corrupt (OpenEXR: {e})")
    } else {
        format!("not a readable OpenEXR {part}: {e}")
    }
}

pub(crate) fn read_exr_rgb(path: &Path) -> Result<ExrRgb> {
    let file = std::fs::File::open(path).map_err(|e| CoreError::io(path, e))?;
    let len = file.metadata().map_err(|e| CoreError::io(path, e))?.len();
    // Streamed from the file: a panorama's bytes are not held beside its pixels.
    let reader = std::io::BufReader::new(file);
    read_exr_rgb_from(reader, len as usize, &path.display().to_string()).map(|(rgb, _)| rgb)
}

/// An RGB EXR from its bytes (`what` names it in errors), with its float attributes.
pub fn read_exr_rgb_bytes(
    bytes: &[u8],
    what: &str,
) -> Result<(ExrRgb, std::collections::BTreeMap<String, f32>)> {
    read_exr_rgb_from(std::io::Cursor::new(bytes), bytes.len(), what)
}

/// [`read_exr_rgb_bytes`] from a reader of `len` bytes: the header is read and checked
/// ([`check_exr_size`]) before the pixels.
fn read_exr_rgb_from(
    mut reader: impl std::io::Read + std::io::Seek,
    len: usize,
    what: &str,
) -> Result<(ExrRgb, std::collections::BTreeMap<String, f32>)> {
    use exr::prelude::*;
    let meta = exr::meta::MetaData::read_from_buffered(&mut reader, false)
        .map_err(|e| CoreError::format(what, exr_failure("header", &e, len)))?;
    check_exr_size(&meta, what, len)?;
    reader
        .seek(std::io::SeekFrom::Start(0))
        .map_err(|e| CoreError::format(what, format!("rereading the file: {e}")))?;
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .rgba_channels(
            |res, _| {
                (
                    res.width(),
                    res.height(),
                    vec![[0f32; 3]; res.width() * res.height()],
                )
            },
            |(w, _, px): &mut (usize, usize, Vec<[f32; 3]>),
             pos,
             (r, g, b, _a): (f32, f32, f32, f32)| {
                px[pos.y() * *w + pos.x()] = [r, g, b];
            },
        )
        .first_valid_layer()
        .all_attributes()
        .from_buffered(reader)
        .map_err(|e| CoreError::format(what, exr_failure("RGB image", &e, len)))?;
    let floats: std::collections::BTreeMap<String, f32> = image
        .layer_data
        .attributes
        .other
        .iter()
        .filter_map(|(k, v)| match v {
            AttributeValue::F32(f) => Some((k.to_string(), *f)),
            _ => None,
        })
        .collect();
    let white = image
        .layer_data
        .attributes
        .other
        .get(&Text::from(WHITE_LEVEL_ATTRIBUTE))
        .map(|v| match v {
            AttributeValue::F32(w) if w.is_finite() && *w > 0.0 => Ok(*w),
            other => Err(CoreError::format(
                what,
                format!(
                    "attribute {WHITE_LEVEL_ATTRIBUTE} should be a positive float, not {other:?}"
                ),
            )),
        })
        .transpose()?;
    let (width, height, pixels) = image.layer_data.channel_data.pixels;
    Ok((
        ExrRgb {
            width,
            height,
            pixels,
            white,
        },
        floats,
    ))
}

/// Writes a linear RGB image as a float EXR.
pub fn write_exr(path: &Path, width: usize, height: usize, pixels: &[[f32; 3]]) -> Result<()> {
    write_exr_with_white(path, width, height, pixels, None)
}

/// [`write_exr`], recording `white` (if any) as the [`WHITE_LEVEL_ATTRIBUTE`].
pub fn write_exr_with_white(
    path: &Path,
    width: usize,
    height: usize,
    pixels: &[[f32; 3]],
    white: Option<f32>,
) -> Result<()> {
    let attributes: Vec<(&str, ExrAttribute)> = white
        .map(|w| (WHITE_LEVEL_ATTRIBUTE, ExrAttribute::F32(w)))
        .into_iter()
        .collect();
    write_exr_attributed(path, width, height, pixels, &attributes)
}

/// A header attribute of an EXR brdfd writes: a number, or text (OpenEXR's text attributes
/// hold Latin-1; brdfd writes ASCII).
#[derive(Clone, Debug)]
pub enum ExrAttribute {
    F32(f32),
    Text(String),
}

/// [`write_exr`] with header attributes that say what the pixels are (axes, units, software).
pub fn write_exr_attributed(
    path: &Path,
    width: usize,
    height: usize,
    pixels: &[[f32; 3]],
    attributes: &[(&str, ExrAttribute)],
) -> Result<()> {
    let bytes = exr_bytes(width, height, pixels, attributes)?;
    std::fs::write(path, bytes).map_err(|e| CoreError::io(path, e))
}

/// An RGB float EXR with header attributes, in memory (a file's bytes, or a session's).
pub fn exr_bytes(
    width: usize,
    height: usize,
    pixels: &[[f32; 3]],
    attributes: &[(&str, ExrAttribute)],
) -> Result<Vec<u8>> {
    encode_exr(width, height, pixels, attributes, None)
}

/// [`exr_bytes`], with OpenEXR's standard `envmap` attribute when the image is a panorama.
fn encode_exr(
    width: usize,
    height: usize,
    pixels: &[[f32; 3]],
    attributes: &[(&str, ExrAttribute)],
    environment_map: Option<exr::meta::attribute::EnvironmentMap>,
) -> Result<Vec<u8>> {
    use exr::prelude::*;
    let channels = SpecificChannels::rgb(|Vec2(x, y): Vec2<usize>| {
        let p = pixels[y * width + x];
        (p[0], p[1], p[2])
    });
    let mut layer_attributes = LayerAttributes {
        software_name: Some(Text::from(
            format!("brdfd {}", env!("CARGO_PKG_VERSION")).as_str(),
        )),
        environment_map,
        ..LayerAttributes::default()
    };
    for (name, value) in attributes {
        let value = match value {
            ExrAttribute::F32(v) => AttributeValue::F32(*v),
            ExrAttribute::Text(t) => {
                AttributeValue::Text(Text::new_or_none(t).ok_or_else(|| {
                    CoreError::Invalid(format!("EXR attribute {name}: {t:?} is not plain text"))
                })?)
            }
        };
        layer_attributes.other.insert(Text::from(*name), value);
    }
    let attributes = layer_attributes;
    let layer = Layer::new((width, height), attributes, Encoding::default(), channels);
    let mut out = std::io::Cursor::new(Vec::new());
    Image::from_layer(layer)
        .write()
        .to_buffered(&mut out)
        .map_err(|e| CoreError::Invalid(format!("encoding an EXR: {e}")))?;
    Ok(out.into_inner())
}

/// A rectangle of map pixels, `x0..x1` × `y0..y1`.
#[derive(Clone, Copy, Debug)]
struct Rect {
    x0: usize,
    x1: usize,
    y0: usize,
    y1: usize,
}

impl Rect {
    /// The two halves across the longer side, measured as angles on the sphere (a row near a
    /// pole is short); `None` for a single pixel.
    fn halves(&self, map: &EnvMap) -> Option<(Rect, Rect)> {
        let pi = std::f64::consts::PI;
        let (w, h) = (self.x1 - self.x0, self.y1 - self.y0);
        if w <= 1 && h <= 1 {
            return None;
        }
        let mid_theta = pi * (self.y0 + self.y1) as f64 / 2.0 / map.height as f64;
        let across = w as f64 * 2.0 * pi / map.width as f64 * mid_theta.sin();
        let down = h as f64 * pi / map.height as f64;
        if h <= 1 || (w > 1 && across >= down) {
            let xm = self.x0 + w / 2;
            Some((Rect { x1: xm, ..*self }, Rect { x0: xm, ..*self }))
        } else {
            let ym = self.y0 + h / 2;
            Some((Rect { y1: ym, ..*self }, Rect { y0: ym, ..*self }))
        }
    }
}

/// One compressed light, ordered by how much splitting it would help.
#[derive(Clone)]
struct Cell {
    rect: Rect,
    priority: f64,
    direction: [f32; 3],
    radiance: [f32; 3],
    solid_angle: f32,
    spread: f32,
}

impl PartialEq for Cell {
    fn eq(&self, other: &Self) -> bool {
        self.priority == other.priority
    }
}
impl Eq for Cell {}
impl PartialOrd for Cell {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Cell {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.priority.total_cmp(&other.priority)
    }
}

/// Summed-area tables over the map, so that any rectangle's sums cost four lookups:
/// Δω, power per channel, and the power-weighted and area-weighted direction.
struct CellSums {
    width: usize,
    /// `(width + 1) × (height + 1)` entries of [`SUMS`] values each.
    table: Vec<[f64; SUMS]>,
}

/// Δω, Δω·L (3), Δω·Y·d (3), Δω·d (3).
const SUMS: usize = 10;

impl CellSums {
    fn new(map: &EnvMap, yaw: f64) -> CellSums {
        use rayon::prelude::*;
        let (w, h) = (map.width, map.height);
        // `direction`'s sines and cosines, once per column (φ) and row (θ) instead of once per
        // pixel, through the same functions, so the same values: per pixel they were most of
        // the cost, and a 2048 × 1024 map is compressed several times per estimate.
        let phi: Vec<(f64, f64)> = (0..w)
            .map(|x| sin_cos(azimuth((x as f64 + 0.5) / w as f64, yaw)))
            .collect();
        let mut table = vec![[0.0; SUMS]; (w + 1) * (h + 1)];
        // Each row's running sums, rows side by side; then each row adds the one above, as
        // `row + above` per entry, in the order the one-pass loop added them.
        table
            .par_chunks_mut(w + 1)
            .skip(1)
            .enumerate()
            .for_each(|(y, out)| {
                let dw = map.pixel_solid_angle(y);
                let theta = sin_cos(polar((y as f64 + 0.5) / h as f64));
                let mut row = [0.0; SUMS];
                for (x, out) in out[1..].iter_mut().enumerate() {
                    let d = direction_of(theta, phi[x]);
                    let v = CellSums::of_pixel(dw, map.pixels[y * w + x], d);
                    for k in 0..SUMS {
                        row[k] += v[k];
                    }
                    *out = row;
                }
            });
        for y in 1..h {
            let (above, rest) = table[y * (w + 1)..].split_at_mut(w + 1);
            for (out, above) in rest[..w + 1].iter_mut().zip(above.iter()).skip(1) {
                for k in 0..SUMS {
                    out[k] += above[k];
                }
            }
        }
        CellSums { width: w, table }
    }

    /// One pixel's share of the sums: its solid angle `dw`, radiance `l` and direction `d`.
    fn of_pixel(dw: f64, l: [f32; 3], d: [f64; 3]) -> [f64; SUMS] {
        let l = l.map(|c| c as f64);
        let lum = (l[0] + l[1] + l[2]) / 3.0;
        [
            dw,
            dw * l[0],
            dw * l[1],
            dw * l[2],
            dw * lum * d[0],
            dw * lum * d[1],
            dw * lum * d[2],
            dw * d[0],
            dw * d[1],
            dw * d[2],
        ]
    }

    fn cell(&self, r: Rect) -> Cell {
        let at = |x: usize, y: usize| &self.table[y * (self.width + 1) + x];
        let (a, b, c, d) = (
            at(r.x0, r.y0),
            at(r.x1, r.y0),
            at(r.x0, r.y1),
            at(r.x1, r.y1),
        );
        let s: [f64; SUMS] = std::array::from_fn(|k| d[k] - b[k] - c[k] + a[k]);
        let dw = s[0].max(f64::MIN_POSITIVE);
        let power = (s[1] + s[2] + s[3]) / 3.0;
        // Where the power is, if there is any; else the middle of the rectangle.
        let (m, norm) = if power > 0.0 {
            ([s[4], s[5], s[6]], power)
        } else {
            ([s[7], s[8], s[9]], dw)
        };
        let len = (m[0] * m[0] + m[1] * m[1] + m[2] * m[2]).sqrt();
        // |mean of unit vectors|² = 1 − E[chord²]; a uniform disc of radius R has E[θ²] = R²/2.
        let mean_len = (len / norm).min(1.0);
        let spread = (2.0 * (1.0 - mean_len * mean_len)).max(0.0).sqrt();
        let direction = if len > 0.0 {
            m.map(|v| (v / len) as f32)
        } else {
            [0.0, 1.0, 0.0]
        };
        Cell {
            rect: r,
            // Measured against other orders (docs/evaluation.md, "Measured choices"): splitting where the
            // power is uneven, or by power × spread², left mirror-like renders worse.
            priority: power * spread,
            direction,
            radiance: [s[1] / dw, s[2] / dw, s[3] / dw].map(|v| v as f32),
            solid_angle: s[0] as f32,
            spread: spread as f32,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cell_sums_made_row_by_row_equal_the_one_pass_table_to_the_bit() {
        let (w, h) = (37, 19);
        let pixels = (0..w * h)
            .map(|i| {
                let f = i as f32;
                [(f * 0.37).sin().abs(), (f * 0.11).cos().abs(), f % 7.0]
            })
            .collect();
        let map = EnvMap::from_pixels(w, h, pixels, "test").unwrap();
        let yaw = 0.7;
        let sums = CellSums::new(&map, yaw);
        // The summed-area table in one pass, pixel by pixel, as `direction` gives each
        // pixel's direction.
        let mut table = vec![[0.0; SUMS]; (w + 1) * (h + 1)];
        for y in 0..h {
            let dw = map.pixel_solid_angle(y);
            let mut row = [0.0; SUMS];
            for x in 0..w {
                let d = direction(
                    (x as f64 + 0.5) / w as f64,
                    (y as f64 + 0.5) / h as f64,
                    yaw,
                );
                let v = CellSums::of_pixel(dw, map.pixels[y * w + x], d);
                let above = table[y * (w + 1) + x + 1];
                let out = &mut table[(y + 1) * (w + 1) + x + 1];
                for k in 0..SUMS {
                    row[k] += v[k];
                    out[k] = row[k] + above[k];
                }
            }
        }
        assert_eq!(sums.width, w);
        assert!(sums.table == table, "the tables differ");
    }

    /// A 32 × 32 image in tiles of 117 million × 64 pixels (found by fuzzing `image_files`:
    /// 2 KB that cost 800 MB) is refused as damaged.
    #[test]
    fn a_tile_larger_than_its_image_is_refused() {
        // The fuzz input's first byte picks the reader; the EXR follows.
        let input = include_bytes!("../../../fuzz/seeds/image_files/tile-of-117m-pixels.bin");
        let e = read_exr_rgb_bytes(&input[1..], "tiles.exr")
            .err()
            .unwrap()
            .to_string();
        assert!(
            e.contains("tiles of 117506112 × 64 pixels in a 32 × 32 image"),
            "{e}"
        );
    }

    /// A header that declares far more pixels than its file could hold, compressed, is
    /// refused before anything is allocated for them; the same image whole reads.
    #[test]
    fn a_truncated_exr_is_refused_before_its_pixels_are_allocated() {
        let (w, h) = (2048, 1024);
        let pixels: Vec<[f32; 3]> = (0..w * h).map(|i| [i as f32, 0.25, 0.125]).collect();
        let bytes = exr_bytes(w, h, &pixels, &[]).unwrap();
        let (whole, _) = read_exr_rgb_bytes(&bytes, "whole.exr").unwrap();
        assert_eq!((whole.width, whole.height), (w, h));
        let cut = &bytes[..2000];
        let e = read_exr_rgb_bytes(cut, "cut.exr")
            .err()
            .unwrap()
            .to_string();
        assert!(
            e.contains("cut.exr") && e.contains("more than a file of 2000 bytes can hold"),
            "{e}"
        );
    }

    /// A file cut short where its size cannot tell (a small image, cut after its header, or
    /// inside it) is called truncated too, with the size it was cut at, not in the OpenEXR
    /// library's words alone.
    #[test]
    fn an_exr_cut_short_is_called_truncated() {
        let (w, h) = (64, 64);
        let pixels: Vec<[f32; 3]> = (0..w * h).map(|i| [i as f32, 0.25, 0.125]).collect();
        let bytes = exr_bytes(w, h, &pixels, &[]).unwrap();
        for (cut, part) in [(bytes.len() / 2, "RGB image"), (100, "header")] {
            let e = read_exr_rgb_bytes(&bytes[..cut], "cut.exr")
                .err()
                .unwrap()
                .to_string();
            assert!(
                e.contains(&format!(
                    "cut.exr: the file ends before its {part} does, at {cut} bytes: it is truncated"
                )),
                "{e}"
            );
        }
    }

    #[test]
    fn a_small_file_declaring_a_huge_image_is_refused_before_reading() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("huge.exr");
        write_exr(&path, 2, 2, &[[1.0; 3]; 4]).unwrap();
        // dataWindow (box2i: xMin, yMin, xMax, yMax) made 100000 × 100000.
        let mut bytes = std::fs::read(&path).unwrap();
        let key = b"dataWindow\0box2i\0";
        let at = bytes.windows(key.len()).position(|w| w == key).unwrap() + key.len() + 4;
        bytes[at + 8..at + 12].copy_from_slice(&99_999i32.to_le_bytes());
        bytes[at + 12..at + 16].copy_from_slice(&99_999i32.to_le_bytes());
        std::fs::write(&path, &bytes).unwrap();
        let e = EnvMap::load(&path).unwrap_err().to_string();
        assert!(e.contains("huge.exr"), "{e}");
        assert!(e.contains("declares 100000 × 100000 pixels"), "{e}");
    }

    /// A panorama says what it is in OpenEXR's own terms: `envmap` = latlong (0).
    #[test]
    fn a_written_map_is_tagged_latlong() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("panorama.exr");
        let map = EnvMap::from_pixels(4, 2, vec![[0.5, 1.0, 2.0]; 8], "test").unwrap();
        map.write_exr(&path).unwrap();
        let meta = exr::meta::MetaData::read_from_file(&path, false).unwrap();
        assert_eq!(
            meta.headers[0].own_attributes.environment_map,
            Some(exr::meta::attribute::EnvironmentMap::LatitudeLongitude)
        );
        let key = b"envmap\0envmap\0";
        let bytes = std::fs::read(&path).unwrap();
        let at = bytes.windows(key.len()).position(|w| w == key).unwrap() + key.len();
        // The attribute's size (4 bytes, little-endian 1), then its value: 0 is LATLONG.
        assert_eq!(&bytes[at..at + 5], &[1, 0, 0, 0, 0]);
        let back = EnvMap::load(&path).unwrap();
        assert_eq!(back.pixels, map.pixels);
        // An image that is not a panorama is not tagged.
        write_exr(&path, 4, 2, &map.pixels).unwrap();
        let meta = exr::meta::MetaData::read_from_file(&path, false).unwrap();
        assert_eq!(meta.headers[0].own_attributes.environment_map, None);
    }

    #[test]
    fn direction_convention() {
        let close = |a: [f64; 3], b: [f64; 3]| a.iter().zip(&b).all(|(x, y)| (x - y).abs() < 1e-12);
        assert!(close(direction(0.5, 0.0, 0.0), [0.0, 1.0, 0.0]));
        assert!(close(direction(0.5, 0.5, 0.0), [0.0, 0.0, -1.0]));
        assert!(close(direction(0.75, 0.5, 0.0), [1.0, 0.0, 0.0]));
        assert!(close(direction(0.25, 0.5, 0.0), [-1.0, 0.0, 0.0]));
        // Yaw +90° is a right-handed turn about +Y: the map's forward (−Z) goes to −X.
        assert!(close(
            direction(0.5, 0.5, std::f64::consts::FRAC_PI_2),
            [-1.0, 0.0, 0.0]
        ));
        let (u, v) = uv_of(direction(0.3, 0.7, 0.0));
        assert!((u - 0.3).abs() < 1e-12 && (v - 0.7).abs() < 1e-12);
    }

    #[test]
    fn solid_angles_cover_the_sphere() {
        let m = EnvMap::from_pixels(64, 32, vec![[1.0; 3]; 64 * 32], "t").unwrap();
        let total: f64 = m.lights(0.0).solid_angle.iter().map(|w| *w as f64).sum();
        // f32 accumulation over 2048 entries: relative error well below 1e-5.
        assert!((total - 4.0 * std::f64::consts::PI).abs() < 1e-4, "{total}");
    }

    #[test]
    fn rejects_nan_and_clamps_small_negatives() {
        let mut px = vec![[1.0f32; 3]; 8 * 4];
        px[8 * 2 + 3][1] = f32::NAN;
        let e = EnvMap::from_pixels(8, 4, px.clone(), "probe.exr")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("probe.exr") && e.contains("x=3, y=2") && e.contains("channel 1"),
            "{e}"
        );
        px[8 * 2 + 3][1] = -0.001;
        px[0][0] = -0.002;
        let m = EnvMap::from_pixels(8, 4, px.clone(), "probe.exr").unwrap();
        assert_eq!(m.clamped_negatives, 2);
        assert_eq!(m.pixels[0][0], 0.0);
        px[0][0] = -10.0;
        assert!(EnvMap::from_pixels(8, 4, px, "probe.exr").is_err());
    }

    #[test]
    fn downsampling_preserves_power() {
        let px: Vec<[f32; 3]> = (0..100 * 50)
            .map(|i| [(i % 7) as f32, (i % 13) as f32, 1.0])
            .collect();
        let m = EnvMap::from_pixels(100, 50, px, "t").unwrap();
        let a = m.lights(0.0).power();
        let b = m.compressed(512, 0.0).power();
        for c in 0..3 {
            // Uneven bin assignment (100 → 32 columns) moves power between rows by < 1%.
            assert!((a[c] - b[c]).abs() / a[c] < 1e-2, "{a:?} {b:?}");
        }
    }
}
