//! RAW camera files (NEF, DNG and the other formats rawler reads) to linear camera RGB.
//!
//! What a decoded [`Frame`] holds, in order of the steps:
//! 1. the sensor's values, less the black level (per CFA position), divided by white less
//!    black: 0 is black, 1 is the sensor's clipping point;
//! 2. within the file's crop (the camera's recommended area: for a D5100, 4928 × 3264 of the
//!    4992 × 3280 sensor), so the image has the size the camera's own JPEG has;
//! 3. demosaiced bilinearly: each colour a pixel lacks is the mean of that colour's samples
//!    in its 3 × 3 neighbourhood;
//! 4. clipped samples marked: a channel computed from any sample at or above
//!    [`super::SATURATED`] of the range (a real sensor can saturate a little under its
//!    nominal white level) is set to 1, which the merge ([`super::merge_hdr`]) does not count
//!    as a measurement, rather than a mean of clipped and unclipped samples that would look
//!    like one.
//!
//! White balance is not applied to the values (clipping is a property of the sensor's
//! values) but carried in [`Frame::white_balance`]: the file's as-shot multipliers, or the
//! rig's fixed ones, normalised to green = 1. Values times those multipliers are
//! white-balanced camera RGB: a neutral surface under the shooting light has R = G = B.
//! No colour matrix is applied; camera RGB is what the merge and the estimate use.

use rawler::decoders::RawDecodeParams;
use rawler::rawimage::{RawImage, RawImageData, RawPhotometricInterpretation};
use rawler::rawsource::RawSource;
use rayon::prelude::*;

// Defined at the crate root, where the child-process decoder (`super::isolated`) reads
// it too without importing this module back.
pub use super::WhiteBalance;
use super::{Exposure, Frame, RadiometryError};
use brdfd_core::raster::Raster;

/// File extensions of the RAW formats cameras write (upper or lower case).
const RAW_EXTENSIONS: [&str; 9] = [
    "nef", "nrw", "dng", "cr2", "cr3", "arw", "raf", "orf", "rw2",
];

/// Whether a file name is a RAW file's, by its extension.
pub fn is_raw_name(name: &str) -> bool {
    let ext = name.rsplit_once('.').map_or("", |(_, e)| e);
    RAW_EXTENSIONS.iter().any(|r| r.eq_ignore_ascii_case(ext))
}

/// Decodes a RAW file to linear camera RGB (see the module's description), with the
/// exposure from the file's own EXIF: in a child process bounded in memory and time when the
/// binary asked for one ([`super::isolated`]), else here.
pub fn decode_raw(bytes: &[u8], file: &str, wb: WhiteBalance) -> Result<Frame, RadiometryError> {
    match super::isolated::program() {
        Some(program) => super::isolated::decode(
            program,
            bytes,
            file,
            wb,
            super::isolated::Budget::for_file(bytes.len()),
        ),
        None => decode_raw_here(bytes, file, wb),
    }
}

/// [`decode_raw`] in this process, whatever the file makes the decoder do.
pub fn decode_raw_here(
    bytes: &[u8],
    file: &str,
    wb: WhiteBalance,
) -> Result<Frame, RadiometryError> {
    let (image, exposure) = read_raw(bytes, file)?;
    let white_balance = match wb {
        WhiteBalance::Fixed(m) => m,
        WhiteBalance::AsShot => as_shot(&image, file)?,
    };
    let values = develop(&image, file)?;
    Ok(Frame {
        values,
        exposure,
        white_balance,
    })
}

/// The sensor data and the exposure. The file's structure is checked first, and rawler's
/// decoders can still panic on a damaged file; that is caught and named like any other
/// decoding error, so a bad file never takes the capture down with it.
fn read_raw(bytes: &[u8], file: &str) -> Result<(RawImage, Exposure), RadiometryError> {
    // The decoder trusts the file's structure (super::tiff says how that fails).
    super::tiff::check(bytes)
        .map_err(|e| RadiometryError::decode(file, format!("RAW: the file is damaged: {e}")))?;
    let source = RawSource::new_from_slice(bytes);
    let params = RawDecodeParams::default();
    let read = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        let decoder = rawler::get_decoder(&source)?;
        let metadata = decoder.raw_metadata(&source, &params)?;
        let image = decoder.raw_image(&source, &params, false)?;
        Ok::<_, rawler::RawlerError>((image, metadata))
    }));
    let (image, metadata) = match read {
        Ok(Ok(read)) => read,
        Ok(Err(e)) => return Err(RadiometryError::decode(file, format!("RAW: {e}"))),
        Err(_) => {
            return Err(RadiometryError::decode(
                file,
                "RAW: the decoder failed on this file (it is damaged or of a kind rawler does not read)",
            ))
        }
    };
    let exif = &metadata.exif;
    let missing = |tag| RadiometryError::MissingExif {
        file: file.into(),
        tag,
    };
    let rational = |r: Option<rawler::formats::tiff::Rational>, tag| {
        r.filter(|r| r.d != 0 && r.n != 0)
            .map(|r| r.n as f64 / r.d as f64)
            .ok_or_else(|| missing(tag))
    };
    let iso = exif
        .iso_speed_ratings
        .map(u32::from)
        .or(exif.recommended_exposure_index)
        .or(exif.iso_speed)
        .filter(|&i| i > 0)
        .ok_or_else(|| missing("ISO (ISOSpeedRatings)"))?;
    let exposure = Exposure {
        shutter_s: rational(exif.exposure_time, "ExposureTime")?,
        f_number: rational(exif.fnumber, "FNumber")?,
        iso: iso as f64,
    };
    Ok((image, exposure))
}

/// The file's as-shot multipliers, normalised to green = 1.
fn as_shot(image: &RawImage, file: &str) -> Result<[f32; 3], RadiometryError> {
    let [r, g, b, _] = image.wb_coeffs;
    let m = [r / g, 1.0, b / g];
    if m.iter().all(|v| v.is_finite() && *v > 0.0) {
        Ok(m)
    } else {
        Err(RadiometryError::decode(
            file,
            format!(
                "RAW: no usable as-shot white balance in the file ({:?}); set calibration.raw_white_balance in the rig",
                image.wb_coeffs
            ),
        ))
    }
}

/// Black and white level, crop, demosaic and clip marking, as the module describes.
fn develop(image: &RawImage, file: &str) -> Result<Raster, RadiometryError> {
    let (w, h, cpp) = (image.width, image.height, image.cpp);
    let count = match &image.data {
        RawImageData::Integer(v) => v.len(),
        RawImageData::Float(v) => v.len(),
    };
    if count != w * h * cpp || w < 2 || h < 2 || cpp == 0 {
        return Err(RadiometryError::decode(
            file,
            format!("RAW: {count} samples for a {w} × {h} image of {cpp} per pixel"),
        ));
    }
    let sample = |i: usize| match &image.data {
        RawImageData::Integer(v) => v[i] as f32,
        RawImageData::Float(v) => v[i],
    };
    let area = image
        .crop_area
        .or(image.active_area)
        .filter(|a| a.p.x + a.d.w <= w && a.p.y + a.d.h <= h && a.d.w > 0 && a.d.h > 0)
        .map_or((0, 0, w, h), |a| (a.p.x, a.p.y, a.d.w, a.d.h));
    let white = |c: usize| {
        let levels = &image.whitelevel.0;
        levels
            .get(c)
            .or(levels.first())
            .copied()
            .unwrap_or(u16::MAX as u32) as f32
    };
    let levels = Levels::of(image);
    match &image.photometric {
        RawPhotometricInterpretation::Cfa(config) => {
            if cpp != 1 {
                return Err(RadiometryError::decode(
                    file,
                    format!("RAW: a colour filter array with {cpp} samples per pixel"),
                ));
            }
            let cfa = &config.cfa;
            if cfa.unique_colors() != 3 || !cfa.is_rgb() {
                return Err(RadiometryError::decode(
                    file,
                    "RAW: the sensor's colour filter is not red, green and blue (only RGB sensors are read)",
                ));
            }
            let pattern = Pattern::new(cfa, w, h);
            let whites = [white(0), white(1), white(2)];
            // Normalised samples, with a clipped sample as NaN so the demosaic can tell it.
            let mut norm = vec![0.0f32; w * h];
            norm.par_chunks_mut(w).enumerate().for_each(|(row, out)| {
                for (col, v) in out.iter_mut().enumerate() {
                    let c = pattern.at(row, col);
                    let (s, b, wl) = (sample(row * w + col), levels.black(row, col, 0), whites[c]);
                    let value = (s - b) / (wl - b);
                    *v = if value >= super::SATURATED {
                        f32::NAN
                    } else {
                        value.max(0.0)
                    };
                }
            });
            Ok(demosaic(&norm, w, h, area, &pattern))
        }
        RawPhotometricInterpretation::LinearRaw | RawPhotometricInterpretation::BlackIsZero => {
            let (x0, y0, aw, ah) = area;
            let k = cpp.min(3);
            let mut pixels = vec![[0.0f32; 3]; aw * ah];
            pixels.par_chunks_mut(aw).enumerate().for_each(|(y, out)| {
                let row = y0 + y;
                for (x, p) in out.iter_mut().enumerate() {
                    let col = x0 + x;
                    *p = std::array::from_fn(|c| {
                        let s = sample((row * w + col) * cpp + c.min(k - 1));
                        let (b, wl) = (levels.black(row, col, c), white(c));
                        if s >= wl {
                            1.0
                        } else {
                            ((s - b) / (wl - b)).clamp(0.0, 1.0)
                        }
                    })
                }
            });
            Ok(Raster {
                width: aw,
                height: ah,
                pixels,
            })
        }
    }
}

/// Black levels as a table over their repeating tile (per CFA position, or per channel).
struct Levels {
    width: usize,
    height: usize,
    cpp: usize,
    values: Vec<f32>,
}

impl Levels {
    fn of(image: &RawImage) -> Levels {
        let bl = &image.blacklevel;
        let (width, height, cpp) = (bl.width.max(1), bl.height.max(1), bl.cpp.max(1));
        let values = (0..width * height * cpp)
            .map(|i| {
                bl.levels
                    .get(i)
                    .map_or(0.0, |r| r.n as f32 / r.d.max(1) as f32)
            })
            .collect();
        Levels {
            width,
            height,
            cpp,
            values,
        }
    }

    fn black(&self, row: usize, col: usize, c: usize) -> f32 {
        let i = ((row % self.height) * self.width + col % self.width) * self.cpp;
        self.values[i + c.min(self.cpp - 1)]
    }
}

/// The colour filter's repeating tile, as a table: 0 red, 1 green, 2 blue. With each row's
/// and column's place in the tile looked up, not divided for, as the demosaic asks nine
/// times per pixel.
struct Pattern {
    width: usize,
    colours: Vec<usize>,
    row_phase: Vec<usize>,
    col_phase: Vec<usize>,
}

impl Pattern {
    fn new(cfa: &rawler::CFA, w: usize, h: usize) -> Pattern {
        let (pw, ph) = (cfa.width.max(1), cfa.height.max(1));
        Pattern {
            width: pw,
            colours: (0..ph)
                .flat_map(|r| (0..pw).map(move |c| cfa.color_at(r, c).min(2)))
                .collect(),
            row_phase: (0..h).map(|r| r % ph).collect(),
            col_phase: (0..w).map(|c| c % pw).collect(),
        }
    }

    fn at(&self, row: usize, col: usize) -> usize {
        self.colours[self.row_phase[row] * self.width + self.col_phase[col]]
    }

    /// A Bayer filter: a 2 × 2 tile with green on one diagonal, red and blue on the other.
    fn is_bayer(&self) -> bool {
        let c = &self.colours;
        self.width == 2
            && c.len() == 4
            && ((c[0] == 1 && c[3] == 1 && c[1] + c[2] == 2)
                || (c[1] == 1 && c[2] == 1 && c[0] + c[3] == 2))
    }
}

/// Bilinear demosaic of `norm` (clipped samples as NaN) over `area`: each channel is the
/// mean of that colour's samples in the 3 × 3 neighbourhood, or 1 (clipped) if any of them
/// is clipped. Neighbours outside the crop but on the sensor are used, as at the crop's edge
/// they are real samples.
fn demosaic(
    norm: &[f32],
    w: usize,
    h: usize,
    (x0, y0, aw, ah): (usize, usize, usize, usize),
    pattern: &Pattern,
) -> Raster {
    let mut pixels = vec![[0.0f32; 3]; aw * ah];
    let bayer = pattern.is_bayer();
    pixels.par_chunks_mut(aw).enumerate().for_each(|(y, out)| {
        let row = y0 + y;
        for (x, px) in out.iter_mut().enumerate() {
            let col = x0 + x;
            let interior = row > 0 && row + 1 < h && col > 0 && col + 1 < w;
            let v = if bayer && interior {
                bayer_means(norm, w, row, col, pattern)
            } else {
                neighbourhood_means(norm, w, h, row, col, pattern)
            };
            // NaN: a clipped sample took part.
            *px = v.map(|v| if v.is_nan() { 1.0 } else { v.min(1.0) });
        }
    });
    Raster {
        width: aw,
        height: ah,
        pixels,
    }
}

/// Each colour's mean over the 3 × 3 neighbourhood (within the sensor); the pixel's own
/// colour is its own sample.
fn neighbourhood_means(
    norm: &[f32],
    w: usize,
    h: usize,
    row: usize,
    col: usize,
    pattern: &Pattern,
) -> [f32; 3] {
    let (mut sum, mut n) = ([0.0f32; 3], [0u32; 3]);
    for r in row.saturating_sub(1)..(row + 2).min(h) {
        for c in col.saturating_sub(1)..(col + 2).min(w) {
            let k = pattern.at(r, c);
            sum[k] += norm[r * w + c];
            n[k] += 1;
        }
    }
    let own = pattern.at(row, col);
    sum[own] = norm[row * w + col];
    n[own] = 1;
    std::array::from_fn(|k| sum[k] / n[k].max(1) as f32)
}

/// [`neighbourhood_means`] written out for a Bayer tile away from the sensor's edge: a green
/// pixel takes its horizontal neighbours for one colour and its vertical ones for the other;
/// a red or blue pixel takes its four greens and its four diagonals. Several times faster,
/// which a 16 MP frame needs.
fn bayer_means(norm: &[f32], w: usize, row: usize, col: usize, pattern: &Pattern) -> [f32; 3] {
    let at = |r: usize, c: usize| norm[r * w + c];
    let own = pattern.at(row, col);
    let mut v = [0.0f32; 3];
    v[own] = at(row, col);
    let (l, r, u, d) = (
        at(row, col - 1),
        at(row, col + 1),
        at(row - 1, col),
        at(row + 1, col),
    );
    if own == 1 {
        v[pattern.at(row, col + 1)] = (l + r) * 0.5;
        v[pattern.at(row + 1, col)] = (u + d) * 0.5;
    } else {
        v[1] = (l + r + u + d) * 0.25;
        let diagonal = at(row - 1, col - 1)
            + at(row - 1, col + 1)
            + at(row + 1, col - 1)
            + at(row + 1, col + 1);
        v[2 - own] = diagonal * 0.25;
    }
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_bayer_shortcut_gives_the_neighbourhood_means_for_every_tile() {
        let (w, h) = (9, 7);
        let norm: Vec<f32> = (0..w * h)
            .map(|i| {
                if i == 31 {
                    f32::NAN
                } else {
                    (i * 37 % 101) as f32 / 100.0
                }
            })
            .collect();
        for name in ["RGGB", "BGGR", "GRBG", "GBRG"] {
            let pattern = Pattern::new(&rawler::CFA::new(name), w, h);
            assert!(pattern.is_bayer(), "{name}");
            for row in 1..h - 1 {
                for col in 1..w - 1 {
                    let (a, b) = (
                        bayer_means(&norm, w, row, col, &pattern),
                        neighbourhood_means(&norm, w, h, row, col, &pattern),
                    );
                    for k in 0..3 {
                        let same = (a[k].is_nan() && b[k].is_nan()) || (a[k] - b[k]).abs() < 1e-6;
                        assert!(same, "{name} at {row},{col}: {a:?} against {b:?}");
                    }
                }
            }
        }
    }
}
