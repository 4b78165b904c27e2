//! The THETA over USB: PTP with RICOH's vendor properties (THETA USB API), on the transaction
//! engine of `brdfd-ptp`. Generic PTP capture (InitiateCapture, then ObjectAdded) works on
//! every THETA; the exposure is set through properties before each shot.
//!
//! Property codes and values follow RICOH's THETA USB API reference.

use std::time::{Duration, Instant};

use brdfd_ptp::codes::prop;
use brdfd_ptp::dataset::Value;
use brdfd_ptp::{Camera, CaptureOptions, Captured, PtpError, Target};

use crate::error::{Result, ThetaError};

/// RICOH's USB vendor id and the THETA product ids.
pub const RICOH_VENDOR: u16 = 0x05CA;
pub const PRODUCTS: [(u16, &str); 4] = [
    (0x0366, "THETA S"),
    (0x0367, "THETA SC"),
    (0x0368, "THETA V"),
    (0x036D, "THETA Z1"),
];

/// Vendor property codes (THETA USB API).
pub mod code {
    /// UINT64: a TIFF RATIONAL in wire order, numerator in the low 32 bits (sent first),
    /// denominator in the high 32 bits; 0 means automatic. RICOH's note on this property words
    /// the halves the other way round but also says it follows TIFF RATIONAL; the wire order
    /// is what matters, and TIFF puts the numerator first.
    pub const SHUTTER_SPEED: u16 = 0xD00F;
    /// UINT16 seconds, 0 = never (V and later: 0 or 60..65534).
    pub const SLEEP_DELAY: u16 = 0xD803;
    /// UINT8: 0 off, 1 noise reduction, 2 DR compensation, 3 HDR, 4 hand-held HDR.
    pub const FILTER: u16 = 0xD80B;
    /// UINT8: 1 while asleep; writing 0 wakes the camera.
    pub const SLEEP_MODE: u16 = 0xD80E;
    /// UINT16 kelvin, for white balance "color temperature".
    pub const COLOR_TEMPERATURE: u16 = 0xD813;
    /// UINT32 seconds, 0 = never (V and later).
    pub const AUTO_POWER_OFF_DELAY_SEC: u16 = 0xD81B;
}

/// ExposureProgramMode (0x500E) value for manual exposure.
const PROGRAM_MANUAL: i64 = 1;
/// WhiteBalance (0x5005) value 4: daylight, a fixed preset (auto white balance would change
/// the colour of the light between frames of a bracket).
const WHITE_BALANCE_DAYLIGHT: i64 = 4;
/// The THETA V, Z1 and SC2 apertures are fixed; EXIF reports the real value per frame.
pub const THETA_F_NUMBER: f64 = 2.0;
/// How long a THETA takes to come out of sleep before it accepts a capture.
pub const WAKE_TIMEOUT: Duration = Duration::from_secs(10);
const WAKE_POLL: Duration = Duration::from_millis(100);

/// What [`prepare`] set, as the camera reports it afterwards.
#[derive(Debug, Clone, Default)]
pub struct Prepared {
    pub woke_up: bool,
    /// Settings the model does not have (older firmware), skipped with a warning.
    pub skipped: Vec<&'static str>,
}

/// Wakes the camera if it sleeps; returns whether it was asleep.
pub fn wake(cam: &mut Camera) -> Result<bool> {
    if !cam.info.properties.contains(&code::SLEEP_MODE) {
        return Ok(false);
    }
    let desc = cam.prop_desc(code::SLEEP_MODE)?;
    if desc.current.as_i64() != Some(1) {
        return Ok(false);
    }
    tracing::info!("THETA is asleep; waking it");
    cam.set_prop(&desc, &Value::UInt(0))?;
    let start = Instant::now();
    while start.elapsed() < WAKE_TIMEOUT {
        if cam.prop_value(code::SLEEP_MODE, desc.datatype)?.as_i64() == Some(0) {
            return Ok(true);
        }
        std::thread::sleep(WAKE_POLL);
    }
    Err(ThetaError::Unsupported(format!(
        "the THETA did not wake up within {WAKE_TIMEOUT:?}; press its power button once"
    )))
}

/// Settings for light measurement: awake and staying awake, manual exposure, no filter,
/// fixed white balance, single shots.
pub fn prepare(cam: &mut Camera) -> Result<Prepared> {
    let mut out = Prepared {
        woke_up: wake(cam)?,
        ..Prepared::default()
    };
    let settings: [(u16, i64, &'static str, bool); 6] = [
        (
            prop::EXPOSURE_PROGRAM_MODE,
            PROGRAM_MANUAL,
            "manual exposure",
            true,
        ),
        (prop::STILL_CAPTURE_MODE, 1, "single-shot mode", true),
        (code::FILTER, 0, "filter off", false),
        (
            prop::WHITE_BALANCE,
            WHITE_BALANCE_DAYLIGHT,
            "daylight white balance",
            false,
        ),
        (code::SLEEP_DELAY, 0, "sleep delay off", false),
        (
            code::AUTO_POWER_OFF_DELAY_SEC,
            0,
            "auto power-off off",
            false,
        ),
    ];
    for (code, value, name, required) in settings {
        if !cam.info.properties.contains(&code) {
            if required {
                return Err(ThetaError::Unsupported(format!(
                    "this THETA has no {name} over USB (property {code:#06x})"
                )));
            }
            tracing::warn!("THETA has no property {code:#06x}; {name} skipped");
            out.skipped.push(name);
            continue;
        }
        let desc = cam.prop_desc(code)?;
        let applied = cam.set_prop(&desc, &Value::UInt(value as u64))?;
        if applied.as_i64() != Some(value) {
            return Err(ThetaError::Unsupported(format!(
                "setting {name} (property {code:#06x}) to {value}: the THETA kept {applied:?}"
            )));
        }
    }
    Ok(out)
}

/// A shutter speed from its 0xD00F value; None for automatic or a zero denominator.
pub fn shutter_from_u64(v: u64) -> Option<f64> {
    let (num, den) = (v & 0xFFFF_FFFF, v >> 32);
    (num > 0 && den > 0).then(|| num as f64 / den as f64)
}

pub fn shutter_to_u64(num: u32, den: u32) -> u64 {
    num as u64 | (den as u64) << 32
}

/// Sets the nearest shutter speed the camera offers (in log terms); returns the one applied.
pub fn set_shutter(cam: &mut Camera, seconds: f64) -> Result<f64> {
    let desc = cam.prop_desc(code::SHUTTER_SPEED)?;
    let best = desc
        .allowed()
        .into_iter()
        .filter_map(|v| shutter_from_u64(v as u64).map(|s| (v, s)))
        .min_by(|a, b| {
            let d = |s: f64| (s / seconds).ln().abs();
            d(a.1).total_cmp(&d(b.1))
        })
        .ok_or_else(|| {
            ThetaError::Unsupported(
                "the THETA offers no manual shutter speed; is it in manual exposure mode?".into(),
            )
        })?;
    let applied = cam.set_prop(&desc, &Value::UInt(best.0 as u64))?;
    applied
        .as_i64()
        .and_then(|v| shutter_from_u64(v as u64))
        .ok_or_else(|| {
            ThetaError::Ptp(PtpError::Protocol(format!(
                "shutter speed read back as {applied:?}"
            )))
        })
}

/// One exposure, downloaded. The THETA stores every shot on its own memory and keeps it (the
/// session copy is brdfd's; the camera's copy is the operator's to delete).
pub fn shoot(cam: &mut Camera, progress: &mut dyn FnMut(&str, f64)) -> Result<Captured> {
    let opts = CaptureOptions {
        target: Target::Card,
        delete_after: false,
    };
    Ok(cam.capture(&opts, &mut |phase, done, total| {
        let f = if total > 0 {
            done as f64 / total as f64
        } else {
            0.0
        };
        progress(phase, f)
    })?)
}
