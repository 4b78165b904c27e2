//! RAW files of the simulated DSLR: the bench's radiance as a Bayer sensor records it, with
//! its noise and clipping, written as a Nikon NEF (uncompressed 14-bit, the layout of a
//! D5100's) or as a DNG (12- or 14-bit).
//!
//! The simulated sensor sees the bench's linear RGB through colour filters of unequal
//! sensitivity, as a real one does (red and blue respond less than green to daylight). The
//! white balance the file records undoes exactly that, so a decoded and balanced RAW frame
//! is in the same units as the simulated JPEG: a balanced value of 1 at an exposure factor
//! of 1/SENSOR_GAIN per unit radiance.

use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

use super::tiff::{self, ByteOrder, Ifd, Value};
use brdfd_core::raster::{linear_to_srgb, Raster};

/// Which RAW file the simulated camera writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RawFormat {
    /// Nikon's NEF, uncompressed, 14 bits: the D5100's only depth.
    Nef,
    /// Adobe's DNG at 14 bits.
    Dng,
    /// DNG at 12 bits.
    Dng12,
}

/// Damage the simulated camera does to each RAW file it writes, to rehearse a camera (or a
/// card) that writes a bad one: what a decoder that trusts the file's structure fails on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RawDamage {
    /// The raw image's IFD declares 131,072 × 131,072 pixels (34 GB at 16 bits).
    Oversized,
    /// IFD0's link to the next IFD points back at IFD0 itself: a four-byte change.
    IfdLoop,
}

/// Applies `damage` to a NEF or DNG this module wrote.
pub fn damage(file: &mut [u8], damage: RawDamage) {
    let big = file.starts_with(b"MM");
    let u16_at = |b: &[u8], at: usize| {
        let v = [b[at], b[at + 1]];
        if big {
            u16::from_be_bytes(v)
        } else {
            u16::from_le_bytes(v)
        }
    };
    let u32_at = |b: &[u8], at: usize| {
        let v = [b[at], b[at + 1], b[at + 2], b[at + 3]];
        if big {
            u32::from_be_bytes(v)
        } else {
            u32::from_le_bytes(v)
        }
    };
    let put = |b: &mut [u8], at: usize, v: u32| {
        let v = if big {
            v.to_be_bytes()
        } else {
            v.to_le_bytes()
        };
        b[at..at + 4].copy_from_slice(&v);
    };
    // (tag, entry offset) of each entry of the IFD at `ifd`.
    let entries = |b: &[u8], ifd: usize| {
        (0..u16_at(b, ifd) as usize)
            .map(|i| (u16_at(b, ifd + 2 + 12 * i), ifd + 2 + 12 * i))
            .collect::<Vec<_>>()
    };
    let ifd0 = u32_at(file, 4) as usize;
    match damage {
        RawDamage::IfdLoop => {
            let link = ifd0 + 2 + 12 * u16_at(file, ifd0) as usize;
            put(file, link, ifd0 as u32);
        }
        RawDamage::Oversized => {
            let sub = entries(file, ifd0)
                .into_iter()
                .find(|(tag, _)| *tag == 0x014A)
                .map(|(_, at)| u32_at(file, at + 8) as usize)
                .expect("the writers give IFD0 a SubIFD");
            for (tag, at) in entries(file, sub) {
                if tag == 0x0100 || tag == 0x0101 {
                    put(file, at + 8, 131_072);
                }
            }
        }
    }
}

/// How the simulated sensor records light.
#[derive(Debug, Clone, Copy)]
pub struct Sensor {
    pub bits: u32,
    pub black: u16,
    /// The value at which the sensor clips.
    pub white: u16,
    /// Red, green and blue filter sensitivity relative to green.
    pub sensitivity: [f32; 3],
    /// Electrons at the white level, at ISO 100 (shot noise).
    pub full_well: f32,
    /// Read noise, in values.
    pub read_noise: f32,
    /// Columns and rows around the recommended crop: left, top, right, bottom. The last
    /// `masked` columns on the right are covered (they read black).
    pub margins: [usize; 4],
    pub masked: usize,
}

/// A D5100's sensor: 14 bits, black level 0 (Nikon subtracts it in the camera), white at
/// 15892, 8 pixels of margin around the recommended crop and 44 covered columns at the
/// right of 56 (the layout rawler and dcraw expect of a D5100 NEF).
pub const D5100: Sensor = Sensor {
    bits: 14,
    black: 0,
    white: 15892,
    sensitivity: [0.52, 1.0, 0.68],
    full_well: 30_000.0,
    read_noise: 1.5,
    margins: [8, 8, 56, 8],
    masked: 44,
};

impl Sensor {
    /// The same sensor at 12 bits: levels scaled down, read noise with them.
    pub fn at_12_bits(self) -> Sensor {
        Sensor {
            bits: 12,
            black: self.black >> 2,
            white: self.white >> 2,
            read_noise: self.read_noise / 4.0,
            ..self
        }
    }

    /// The whole sensor's size around an image of `radiance`'s size (its recommended crop).
    pub fn size_around(&self, radiance: &Raster) -> (usize, usize) {
        let [left, top, right, bottom] = self.margins;
        (
            radiance.width + left + right,
            radiance.height + top + bottom,
        )
    }

    /// The white balance the camera records: the inverse of the filters' sensitivity.
    pub fn white_balance(&self) -> [f32; 3] {
        self.sensitivity.map(|s| 1.0 / s)
    }

    /// The sensor's values for `radiance` scaled by `k` (1 = green's white level), in the
    /// RGGB mosaic over the whole sensor, margins included. `iso` scales the noise: a higher
    /// ISO amplifies fewer electrons. `seed` makes each shot's noise its own.
    pub fn expose(&self, radiance: &Raster, k: f32, iso: u32, seed: u64) -> Vec<u16> {
        let [left, top, ..] = self.margins;
        let (w, h) = self.size_around(radiance);
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let unit = Normal::new(0.0f32, 1.0).expect("unit normal");
        let range = (self.white - self.black) as f32;
        let electrons_per_value = self.full_well / range / (iso as f32 / 100.0).max(0.01);
        let mut out = Vec::with_capacity(w * h);
        for row in 0..h {
            for col in 0..w {
                if col >= w - self.masked {
                    let noise = unit.sample(&mut rng) * self.read_noise;
                    out.push((self.black as f32 + noise).round().max(0.0) as u16);
                    continue;
                }
                // RGGB: red at even rows and columns, blue at odd ones.
                let c = (row % 2) + (col % 2);
                let x = col.saturating_sub(left).min(radiance.width - 1);
                let y = row.saturating_sub(top).min(radiance.height - 1);
                let signal = (radiance.pixels[y * radiance.width + x][c] * k * self.sensitivity[c])
                    .max(0.0)
                    * range;
                let shot = (signal / electrons_per_value).sqrt();
                let noise = unit.sample(&mut rng) * (shot * shot + self.read_noise.powi(2)).sqrt();
                let v = self.black as f32 + signal + noise;
                out.push(v.round().clamp(0.0, self.white as f32) as u16);
            }
        }
        out
    }
}

/// What the camera records of a shot, for the file's EXIF and maker note.
pub struct ShotInfo<'a> {
    pub make: &'a str,
    pub model: &'a str,
    pub shutter_s: f64,
    pub f_number: f64,
    pub iso: u32,
}

/// ExposureTime as cameras write it: 1/n below a second, tenths above.
fn exposure_rational(s: f64) -> (u32, u32) {
    if s >= 1.0 {
        ((s * 10.0).round() as u32, 10)
    } else {
        (10_000, (10_000.0 / s).round() as u32)
    }
}

/// The Exif IFD a camera writes: exposure, aperture, ISO, and the given extra tags.
pub fn exif_ifd(shot: &ShotInfo, extra: impl IntoIterator<Item = (u16, Value)>) -> Ifd {
    let mut exif = Ifd::new();
    exif.set(
        0x829A,
        Value::Rational(vec![exposure_rational(shot.shutter_s)]),
    )
    .set(
        0x829D,
        Value::Rational(vec![((shot.f_number * 100.0).round() as u32, 100)]),
    )
    .set(0x8822, Value::Short(vec![1])) // ExposureProgram: manual
    .set(0x8827, Value::Short(vec![shot.iso.min(65535) as u16]));
    for (tag, v) in extra {
        exif.set(tag, v);
    }
    exif
}

/// An 8-bit sRGB thumbnail, as IFD0 of a NEF or DNG holds: 160 × 120 for a real sensor's
/// size, an eighth of a small simulated image (readers such as dcraw take the largest image
/// for the raw data).
fn thumbnail(radiance: &Raster, k: f32) -> (u32, u32, Vec<u8>) {
    let (tw, th) = (
        (radiance.width / 8).clamp(1, 160),
        (radiance.height / 8).clamp(1, 120),
    );
    let mut rgb = Vec::with_capacity(tw * th * 3);
    for y in 0..th {
        for x in 0..tw {
            let p = radiance.pixels
                [(y * radiance.height / th) * radiance.width + x * radiance.width / tw];
            rgb.extend(p.map(|v| (linear_to_srgb((v * k).clamp(0.0, 1.0)) * 255.0).round() as u8));
        }
    }
    (tw as u32, th as u32, rgb)
}

/// IFD0 with the thumbnail, make and model, pointing to the raw data's IFD and the Exif IFD.
fn ifd0(radiance: &Raster, k: f32, shot: &ShotInfo, raw: Ifd, exif: Ifd) -> Ifd {
    let (tw, th, rgb) = thumbnail(radiance, k);
    let mut ifd = Ifd::new();
    ifd.set(0x00FE, Value::Long(vec![1]))
        .set(0x0100, Value::Long(vec![tw]))
        .set(0x0101, Value::Long(vec![th]))
        .set(0x0102, Value::Short(vec![8, 8, 8]))
        .set(0x0103, Value::Short(vec![1]))
        .set(0x0106, Value::Short(vec![2]))
        .set(0x010F, Value::Ascii(shot.make.into()))
        .set(0x0110, Value::Ascii(shot.model.into()))
        .set(0x0112, Value::Short(vec![1]))
        .set(0x0115, Value::Short(vec![3]))
        .set(0x0131, Value::Ascii("brdfd simulated camera".into()))
        .set(0x014A, Value::Ifds(vec![raw]))
        .set(0x8769, Value::Ifds(vec![exif]))
        .strip(th, rgb);
    ifd
}

/// The IFD of the Bayer data: uncompressed, 16-bit containers in the file's byte order.
/// `bits` is what BitsPerSample says: a NEF gives the sensor's depth in 16-bit containers,
/// a DNG says 16 (an uncompressed DNG of 12 or 14 bits would be bit-packed).
fn raw_ifd(width: usize, height: usize, bits: u16, data: &[u16], order: ByteOrder) -> Ifd {
    let bytes: Vec<u8> = data
        .iter()
        .flat_map(|v| match order {
            ByteOrder::Little => v.to_le_bytes(),
            ByteOrder::Big => v.to_be_bytes(),
        })
        .collect();
    let mut ifd = Ifd::new();
    ifd.set(0x00FE, Value::Long(vec![0]))
        .set(0x0100, Value::Long(vec![width as u32]))
        .set(0x0101, Value::Long(vec![height as u32]))
        .set(0x0102, Value::Short(vec![bits]))
        .set(0x0103, Value::Short(vec![1]))
        .set(0x0106, Value::Short(vec![32803])) // CFA
        .set(0x0115, Value::Short(vec![1]))
        .set(0x011C, Value::Short(vec![1]))
        .set(0x828D, Value::Short(vec![2, 2])) // CFARepeatPatternDim
        .set(0x828E, Value::Byte(vec![0, 1, 1, 2])) // CFAPattern: RGGB
        .set(0xA217, Value::Short(vec![2])) // SensingMethod: one-chip colour area
        .strip(height as u32, bytes);
    ifd
}

/// A NEF as a Nikon writes it (big-endian), uncompressed: the thumbnail in IFD0, the Bayer
/// data in a sub-IFD, the exposure in EXIF, and the white balance (WB_RBLevels), black
/// level and compression in Nikon's maker note.
pub fn nef(radiance: &Raster, k: f32, sensor: &Sensor, shot: &ShotInfo, seed: u64) -> Vec<u8> {
    let (w, h) = sensor.size_around(radiance);
    let data = sensor.expose(radiance, k, shot.iso, seed);
    let wb = sensor.white_balance();
    let rational = |v: f32| ((v * 256.0).round() as u32, 256);
    let mut maker = Ifd::new();
    maker
        .set(0x0001, Value::Undefined(b"0210".to_vec()))
        .set(0x0002, Value::Short(vec![0, shot.iso.min(65535) as u16]))
        .set(
            0x000C,
            Value::Rational(vec![rational(wb[0]), rational(wb[2]), (1, 1), (1, 1)]),
        )
        .set(
            0x003D,
            Value::Short(vec![sensor.black << 14u32.saturating_sub(sensor.bits); 4]),
        )
        .set(0x0093, Value::Short(vec![2])); // NEFCompression: uncompressed
                                             // Nikon's type-3 maker note: a signature, then a TIFF whose offsets count from its own
                                             // header.
    let mut note = b"Nikon\0\x02\x10\0\0".to_vec();
    note.extend(tiff::write(ByteOrder::Big, &maker));
    let exif = exif_ifd(shot, [(0x927C, Value::Undefined(note))]);
    let raw = raw_ifd(w, h, sensor.bits as u16, &data, ByteOrder::Big);
    tiff::write(ByteOrder::Big, &ifd0(radiance, k, shot, raw, exif))
}

/// A DNG (little-endian): the same sensor and layout, with DNG's own tags for the levels,
/// the crop, the as-shot white balance and a colour matrix (XYZ to camera: the sRGB
/// primaries through the filters' sensitivity).
pub fn dng(radiance: &Raster, k: f32, sensor: &Sensor, shot: &ShotInfo, seed: u64) -> Vec<u8> {
    let (w, h) = sensor.size_around(radiance);
    let [left, top, ..] = sensor.margins;
    let data = sensor.expose(radiance, k, shot.iso, seed);
    let mut raw = raw_ifd(w, h, 16, &data, ByteOrder::Little);
    let milli = |v: f32| ((v * 10_000.0).round() as u32, 10_000);
    const XYZ_TO_SRGB: [[f32; 3]; 3] = [
        [3.2406, -1.5372, -0.4986],
        [-0.9689, 1.8758, 0.0415],
        [0.0557, -0.2040, 1.0570],
    ];
    let matrix = (0..9)
        .map(|i| {
            let v = XYZ_TO_SRGB[i / 3][i % 3] * sensor.sensitivity[i / 3];
            ((v * 10_000.0).round() as i32, 10_000)
        })
        .collect();
    raw.set(0xC61A, Value::Short(vec![sensor.black])) // BlackLevel
        .set(0xC61D, Value::Long(vec![sensor.white as u32])) // WhiteLevel
        .set(0xC61F, Value::Long(vec![left as u32, top as u32])) // DefaultCropOrigin: x, y within the active area
        .set(
            0xC620,
            Value::Long(vec![radiance.width as u32, radiance.height as u32]),
        ) // DefaultCropSize
        .set(
            0xC68D,
            Value::Long(vec![0, 0, h as u32, (w - sensor.masked) as u32]),
        ); // ActiveArea: top, left, bottom, right
    let mut ifd = ifd0(radiance, k, shot, raw, exif_ifd(shot, []));
    ifd.set(0xC612, Value::Byte(vec![1, 4, 0, 0])) // DNGVersion
        .set(0xC613, Value::Byte(vec![1, 1, 0, 0])) // DNGBackwardVersion
        .set(
            0xC614,
            Value::Ascii(format!("{} {}", shot.make, shot.model)),
        )
        .set(0xC621, Value::SRational(matrix)) // ColorMatrix1
        .set(
            0xC628,
            Value::Rational(sensor.sensitivity.map(milli).to_vec()),
        ) // AsShotNeutral
        .set(0xC65A, Value::Short(vec![21])); // CalibrationIlluminant1: D65
    tiff::write(ByteOrder::Little, &ifd)
}
