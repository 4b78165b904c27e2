//! Configuration files (TOML), shipped in `config/` and embedded in the binary:
//!
//! - `brdfd.toml`: the daemon's defaults (state directory, API address, token, log filter);
//! - `rigs/<name>.toml`: a rig: which devices (as selectors), the object camera's intrinsics
//!   and pose and the object's geometry, the THETA's yaw, the bracket plans, the calibration
//!   between the two cameras, and the turntable's views;
//! - `materials/<name>.toml`: a material preset: pixel count, K, exposure plan, notes.
//!
//! Unknown fields are rejected. A syntax or type error names the file, line and field (from
//! the TOML parser); a value that parses but makes no sense names the file, the field's path
//! (`brackets.dslr_shutters[2]`) and its line ([`ConfigError::locate`]). A rig's checks run
//! all of them ([`Rig::problems`]), so that `brdfd config check` can list every mistake.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Deserializer};

pub use brdfd_api::plan::{PixelCount, MAX_BRACKET, MAX_EXPOSURE_S};

use crate::selector::Selector;
use brdfd_core::estimate::Model;
use brdfd_core::geometry::{SceneGeometry, Shape};
use brdfd_core::solve::{ColourChoice, Solver};

#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("{file}: {reason}")]
    Read { file: String, reason: String },
    /// A board file whose numbers make no board brdfd can draw and find, and what about the
    /// board (in the message, as every variant here says its reason: not also a source).
    #[error("{file}: {error}")]
    Board {
        file: String,
        error: brdfd_pose::PoseError,
    },
    /// Syntax, types and unknown fields; the parser's message has the line and column.
    #[error("{file}: {message}")]
    Parse {
        file: String,
        message: String,
        /// The line (from 1) where the error is, when the parser points at one.
        line: Option<usize>,
    },
    /// A value the schema accepts but the rig cannot use.
    #[error("{file}{}: field `{field}`: {reason}", line.map(|l| format!(", line {l}")).unwrap_or_default())]
    Invalid {
        file: String,
        field: String,
        reason: String,
        /// The line (from 1) of the field, or of the table it is missing from, once the
        /// error is [located](ConfigError::locate) in the file's text.
        line: Option<usize>,
    },
}

pub fn invalid(file: &str, field: impl Into<String>, reason: impl Into<String>) -> ConfigError {
    ConfigError::Invalid {
        file: file.into(),
        field: field.into(),
        reason: reason.into(),
        line: None,
    }
}

impl ConfigError {
    /// Gives an invalid value the line it is on in `text`, the file's TOML: the field's own
    /// line, else (a field that is missing) that of the nearest table above it that is
    /// there. Other errors are returned as they are.
    pub fn locate(self, text: &str) -> ConfigError {
        match self {
            ConfigError::Invalid {
                file,
                field,
                reason,
                line: None,
            } => {
                let line = line_of_field(text, &field);
                ConfigError::Invalid {
                    file,
                    field,
                    reason,
                    line,
                }
            }
            e => e,
        }
    }
}

/// The line (from 1) in `text` of a field's path as errors spell it (`devices.theta`,
/// `brackets.dslr_shutters[2]`), or of the deepest part of the path that is in the file.
fn line_of_field(text: &str, field: &str) -> Option<usize> {
    use toml_edit::Item;
    let doc = toml_edit::Document::parse(text).ok()?;
    let mut span: Option<std::ops::Range<usize>> = None;
    let mut item: &Item = doc.as_item();
    for part in field.split('.') {
        let (key, index) = match part.split_once('[') {
            Some((key, rest)) => (key, rest.trim_end_matches(']').parse::<usize>().ok()),
            None => (part, None),
        };
        let Some((k, next)) = item.as_table_like().and_then(|t| t.get_key_value(key)) else {
            break;
        };
        // A table's own span is its header; a key's is the line it is set on.
        span = next.span().or_else(|| k.span()).or(span);
        item = next;
        if let Some(i) = index {
            // An array's elements are values, not items: nothing below one is looked for.
            if let Some(element) = item.as_array().and_then(|a| a.get(i)) {
                span = element.span().or(span);
            }
            break;
        }
    }
    let start = span?.start.min(text.len());
    Some(text[..start].matches('\n').count() + 1)
}

impl<'de> Deserialize<'de> for Selector {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Selector, D::Error> {
        let s = String::deserialize(d)?;
        s.parse().map_err(serde::de::Error::custom)
    }
}

/// `brdfd.toml`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DaemonConfig {
    /// Where sessions are stored. Absent: `BRDFD_STATE_DIR`, else the XDG data directory.
    #[serde(default)]
    pub state_dir: Option<PathBuf>,
    /// Address of the HTTP API. Change it only together with `token`: any address but
    /// loopback needs one.
    #[serde(default = "default_api")]
    pub api: String,
    /// Bearer token the API requires; required for non-loopback addresses.
    #[serde(default)]
    pub token: Option<String>,
    /// Log filter (`info`, `debug`, `brdfd_theta=debug`, ...).
    #[serde(default = "default_log")]
    pub log: String,
    /// Host names the API answers to, besides IP addresses and `localhost` (say, the bench
    /// PC's name on the lab network). A request naming any other host is refused: that is
    /// what a web page does after DNS rebinding.
    #[serde(default)]
    pub hosts: Vec<String>,
}

fn default_api() -> String {
    "127.0.0.1:7878".into()
}

fn default_log() -> String {
    "info".into()
}

/// The devices of a rig, by selector. The DSLR or the fallback camera sees the object; the
/// THETA sees the light.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RigDevices {
    #[serde(default)]
    pub dslr: Option<Selector>,
    #[serde(default)]
    pub theta: Option<Selector>,
    /// Used when no DSLR answers. On a simulated rig, `v4l:simulated` adds the simulated
    /// V4L2 camera, which sees what the simulated DSLR sees.
    #[serde(default)]
    pub fallback_camera: Option<Selector>,
    /// A turntable: a box that speaks the brdfd rig protocol, or a GRBL controller.
    #[serde(default)]
    pub turntable: Option<Selector>,
    /// What fires the DSLR, when the camera is not fired over PTP: a rig-protocol trigger
    /// box (which may be the turntable's device), or a remote-release cable on a serial
    /// adapter's modem line.
    #[serde(default)]
    pub shutter: Option<Selector>,
}

/// Exposure plans.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Brackets {
    /// DSLR shutter speeds, seconds.
    pub dslr_shutters: Vec<f64>,
    /// The files the DSLR is set to make per shot: `raw+jpeg` (the default), `raw` or
    /// `jpeg`. The merge uses the RAW files when there are any, the JPEGs otherwise.
    #[serde(default)]
    pub dslr_files: DslrFiles,
    pub dslr_f_number: f64,
    pub dslr_iso: u32,
    /// THETA shutter speeds, seconds; the light probe (1/16000 s to 1 s) if empty.
    #[serde(default)]
    pub theta_shutters: Vec<f64>,
    #[serde(default = "default_theta_iso")]
    pub theta_iso: u32,
    /// The V4L2 fallback camera's exposure times, seconds (V4L2 sets them in 100 µs steps).
    #[serde(default = "default_fallback_shutters")]
    pub fallback_shutters: Vec<f64>,
    /// Frames averaged per exposure: averaging N frames lowers the noise by √N.
    #[serde(default = "default_fallback_frames")]
    pub fallback_frames: usize,
    /// The fallback camera's gain, in its own units (auto gain is switched off); a rig with a
    /// fallback camera needs it. The calibration's `[calibration.fallback]` holds for it only.
    #[serde(default)]
    pub fallback_gain: Option<i64>,
    /// The fallback camera's white balance, kelvin (auto white balance is switched off).
    #[serde(default = "default_fallback_white_balance")]
    pub fallback_white_balance_k: i64,
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
pub enum DslrFiles {
    #[default]
    #[serde(rename = "raw+jpeg")]
    RawJpeg,
    #[serde(rename = "raw")]
    Raw,
    #[serde(rename = "jpeg")]
    Jpeg,
}

fn default_theta_iso() -> u32 {
    100
}

fn default_fallback_shutters() -> Vec<f64> {
    vec![0.001, 0.004, 0.0166, 0.0666, 0.25]
}

fn default_fallback_frames() -> usize {
    8
}

fn default_fallback_white_balance() -> i64 {
    5000
}

/// Frames a fallback bracket averages per exposure at most.
pub const MAX_FALLBACK_FRAMES: usize = 256;

/// Each camera's response, so that every camera's values become radiance in one unit: a
/// camera's gain is its linear value per unit of exposure per unit of radiance, per colour
/// channel. The exposure is t·ISO/100/N² for the DSLR and the THETA (as their EXIF records
/// it), and the exposure time in seconds for the fallback camera, at its fixed gain (V4L2
/// reports no aperture).
///
/// The THETA's gain sets the unit: nothing on a bench measures radiance absolutely, so
/// `brdfd calibrate radiometry` keeps the THETA's gain as it is in the rig (1 if it is not
/// there yet) and measures the others against it, from a target of known albedo that both
/// cameras see. The estimate depends only on their ratios.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Calibration {
    /// The THETA's gain: the bench's unit of radiance.
    #[serde(default)]
    pub theta: Option<CameraGain>,
    /// The DSLR's gain for its RAW files (camera RGB after black level, white level and
    /// white balance, in [0, 1]).
    #[serde(default)]
    pub dslr_raw: Option<CameraGain>,
    /// The DSLR's gain for its JPEG files (decoded as sRGB). A camera's JPEG rendering places
    /// its values differently from its RAW files, so the two are measured apart.
    #[serde(default)]
    pub dslr_jpeg: Option<CameraGain>,
    /// The V4L2 fallback camera's gain, per second of exposure, at `brackets.fallback_gain`.
    #[serde(default)]
    pub fallback: Option<CameraGain>,
    /// Fixed white balance for the DSLR's RAW files (red, green, blue multipliers), for a
    /// bench whose light does not change; without it each file's as-shot balance is used.
    #[serde(default)]
    pub raw_white_balance: Option<[f32; 3]>,
    /// Replaced by the gains: read only to say how to move a measured ratio over.
    #[serde(default)]
    pub theta_to_dslr: Option<f64>,
    /// Replaced by the gains, as `theta_to_dslr`.
    #[serde(default)]
    pub theta_to_fallback: Option<f64>,
}

/// One camera's gain as measured, with how much the measurement spread.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraGain {
    /// Linear value per unit of exposure per unit of radiance: red, green, blue (or one
    /// number for all three).
    pub gain: Gain,
    /// The measurement's spread, relative to the gain (1σ over the target's pixels).
    #[serde(default)]
    pub spread: Option<Gain>,
    /// How and when it was measured, in words.
    #[serde(default)]
    pub measured: Option<String>,
}

/// A value per colour channel; a rig file may give one number for all three.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Gain(pub [f64; 3]);

impl<'de> Deserialize<'de> for Gain {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Gain, D::Error> {
        #[derive(Deserialize)]
        #[serde(untagged)]
        enum Raw {
            One(f64),
            Three([f64; 3]),
        }
        Ok(match Raw::deserialize(d)? {
            Raw::One(g) => Gain([g; 3]),
            Raw::Three(g) => Gain(g),
        })
    }
}

/// The gains of a rig's calibration, by the field that holds them (for errors).
pub const GAIN_FIELDS: [&str; 4] = [
    "calibration.theta",
    "calibration.dslr_raw",
    "calibration.dslr_jpeg",
    "calibration.fallback",
];

impl Calibration {
    fn gains(&self) -> [(&'static str, Option<&CameraGain>); 4] {
        [
            (GAIN_FIELDS[0], self.theta.as_ref()),
            (GAIN_FIELDS[1], self.dslr_raw.as_ref()),
            (GAIN_FIELDS[2], self.dslr_jpeg.as_ref()),
            (GAIN_FIELDS[3], self.fallback.as_ref()),
        ]
    }

    /// Gains must be positive numbers.
    fn check(&self, file: &str) -> Result<(), ConfigError> {
        for (field, gain) in self.gains() {
            let Some(g) = gain else { continue };
            if !g.gain.0.iter().all(|v| v.is_finite() && *v > 0.0) {
                return Err(invalid(
                    file,
                    format!("{field}.gain"),
                    format!("{:?}: a gain is a positive number per channel", g.gain.0),
                ));
            }
            if let Some(s) = &g.spread {
                if !s.0.iter().all(|v| v.is_finite() && *v >= 0.0) {
                    return Err(invalid(
                        file,
                        format!("{field}.spread"),
                        "a spread is a number at or above 0 per channel",
                    ));
                }
            }
        }
        if let Some(wb) = self.raw_white_balance {
            if !wb.iter().all(|m| m.is_finite() && *m > 0.0) {
                return Err(invalid(
                    file,
                    "calibration.raw_white_balance",
                    format!("{wb:?}: the three multipliers must be positive"),
                ));
            }
        }
        Ok(())
    }

    /// The ratios of before the gains are refused, with what to write instead. (They are
    /// read, so that `brdfd calibrate radiometry` can read the rig and replace them.)
    pub(crate) fn refuse_ratios(&self, file: &str) -> Result<(), ConfigError> {
        let Some(field) = self.ratio_field() else {
            return Ok(());
        };
        let keep = match self.ratio_gains() {
            Some(g) => format!(
                ", or keep the ratio measured before by writing {} in place of theta_to_dslr and theta_to_fallback",
                g.iter()
                    .map(|(table, gain)| format!("[{table}] gain = {gain}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
            None => String::new(),
        };
        Err(invalid(
            file,
            field,
            format!("the calibration is now each camera's gain: measure them with `brdfd calibrate radiometry --rig {file}`{keep}"),
        ))
    }

    /// The ratios of before the gains, as the gains that make the merges what they were: what
    /// a session captured before them is resumed with. `None` if there are none to adopt.
    pub fn adopt_ratios(&mut self) -> Option<String> {
        self.ratio_field()?;
        let gains = self.ratio_gains()?;
        let g = |table: &str| {
            gains
                .iter()
                .find(|(t, _)| *t == table)
                .map(|(_, v)| CameraGain {
                    gain: Gain([*v; 3]),
                    spread: None,
                    measured: Some("from theta_to_dslr and theta_to_fallback".into()),
                })
        };
        self.theta = g("calibration.theta");
        self.dslr_raw = g("calibration.dslr_raw");
        self.dslr_jpeg = g("calibration.dslr_jpeg");
        self.fallback = g("calibration.fallback");
        self.theta_to_dslr = None;
        self.theta_to_fallback = None;
        Some(format!(
            "the rig stored in the session calibrates by theta_to_dslr, as before each camera had its gain; it is resumed with the gains that merge as it did: {}",
            gains
                .iter()
                .map(|(t, v)| format!("{t} {v}"))
                .collect::<Vec<_>>()
                .join(", ")
        ))
    }

    fn ratio_field(&self) -> Option<&'static str> {
        if self.theta_to_dslr.is_some() {
            Some("calibration.theta_to_dslr")
        } else if self.theta_to_fallback.is_some() {
            Some("calibration.theta_to_fallback")
        } else {
            None
        }
    }

    /// What the merges did with the ratios: the THETA's values over [`RATIO_THETA_GAIN`] per
    /// unit of exposure, times `theta_to_dslr`; the DSLR's over [`RATIO_DSLR_GAIN`]; the
    /// fallback's per second, times `theta_to_dslr / theta_to_fallback`. `None` where a ratio
    /// is not a positive number.
    fn ratio_gains(&self) -> Option<Vec<(&'static str, f64)>> {
        let ok = |k: f64| k.is_finite() && k > 0.0;
        let k = self.theta_to_dslr.filter(|k| ok(*k))?;
        let mut v = vec![
            ("calibration.theta", RATIO_THETA_GAIN / k),
            ("calibration.dslr_raw", RATIO_DSLR_GAIN),
            ("calibration.dslr_jpeg", RATIO_DSLR_GAIN),
        ];
        if let Some(f) = self.theta_to_fallback {
            if !ok(f) {
                return None;
            }
            v.push(("calibration.fallback", f / k));
        }
        Some(v)
    }
}

/// The sensor gains the merges divided by before each camera had its own (the simulated
/// THETA's and DSLR's): what a rig's `theta_to_dslr` was measured against.
const RATIO_THETA_GAIN: f64 = 100.0;
const RATIO_DSLR_GAIN: f64 = 1000.0;

/// A simulated rig's devices, to rehearse failures at the bench (a DSLR that is not there,
/// or one whose battery runs out mid-capture) and to run each way a bench can be built.
#[derive(Debug, Clone, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Simulation {
    /// `present` (the default) or `absent` (nothing answers at its address).
    pub dslr: SimulatedPresence,
    /// Which body the simulated DSLR is: `nikon-d5100` (the default: Nikon's capture to
    /// SDRAM), `canon-eos-r6` (Canon's EOS remote release) or `sony-a7m4` (Sony's shutter
    /// button, the shot in its memory; not with a `shutter`); the last two write JPEG files.
    pub dslr_body: SimulatedBody,
    /// What drives the simulated DSLR: `brdfd` (the default: brdfd's own PTP driver) or
    /// `gphoto2` (the system's libgphoto2, in a brdfd built with the `gphoto2` feature), as
    /// a bench names it `ptpip:HOST` or `gphoto2:ptpip:HOST`.
    pub dslr_backend: DslrBackend,
    /// The simulated DSLR powers off when asked for the frame after this many.
    pub dslr_powers_off_after: Option<u32>,
    /// `present` (the default: a box that speaks the brdfd rig protocol), `grbl` (a GRBL 1.1
    /// G-code controller turning the table on its A axis) or `absent`: views are then turned
    /// by hand.
    pub turntable: SimulatedTurntable,
    /// The RAW files the simulated DSLR writes: `nef` (the default; 14-bit, a D5100's),
    /// `dng` (14-bit) or `dng12` (12-bit).
    pub dslr_raw: Option<SimulatedRaw>,
    /// Damage the simulated DSLR does to every RAW file: `oversized` (the raw image declares
    /// 131,072 × 131,072 pixels) or `ifd_loop` (IFD0 links back to itself). None by default.
    pub dslr_raw_damage: Option<SimulatedRawDamage>,
    /// The simulated DSLR names every file as its first (`DSC_0001.NEF`, `DSC_0001.JPG`), as
    /// a camera can after a card change or when it shoots to its memory.
    pub dslr_reuses_file_names: bool,
    /// How the simulated THETA is reached: `http` (the default: the THETA Web API on
    /// loopback) or `usb` (PTP over an in-memory USB pipe, with USB's framing).
    pub theta: SimulatedLink,
    /// `absent` (the default) or `present`: a trigger box fires the DSLR through its shutter
    /// line, as at a bench whose camera is not fired over PTP. It is the simulated
    /// turntable's box when the turntable is present, a box of its own otherwise.
    pub shutter: SimulatedPresence,
    /// The object camera as it truly stands on the simulated bench (a `[geometry.camera]`
    /// table), where the rig's `[geometry.camera]` is what the operator believes: to
    /// rehearse `brdfd calibrate pose`, which finds it from a photo of the board. The rig's
    /// camera when absent.
    pub camera: Option<brdfd_core::geometry::Camera>,
    /// The object as it truly stands on the simulated bench (a `[geometry.shape]` table of
    /// the same mesh), where the rig's `[geometry.shape]` is where the operator believes it
    /// stands: to rehearse `brdfd calibrate pose --refine-object`, which finds it from the
    /// object's silhouette. The rig's shape when absent.
    pub shape: Option<brdfd_core::geometry::Shape>,
}

impl Default for Simulation {
    fn default() -> Self {
        Simulation {
            dslr: SimulatedPresence::Present,
            dslr_body: SimulatedBody::NikonD5100,
            dslr_backend: DslrBackend::Brdfd,
            dslr_powers_off_after: None,
            turntable: SimulatedTurntable::Present,
            dslr_raw: None,
            dslr_raw_damage: None,
            dslr_reuses_file_names: false,
            theta: SimulatedLink::Http,
            shutter: SimulatedPresence::Absent,
            camera: None,
            shape: None,
        }
    }
}

/// The simulated DSLR's body, by its `sim camera --profile` name.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SimulatedBody {
    #[default]
    NikonD5100,
    CanonEosR6,
    SonyA7m4,
}

/// What drives a DSLR: brdfd's own PTP driver, or the system's libgphoto2.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum DslrBackend {
    #[default]
    Brdfd,
    Gphoto2,
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SimulatedPresence {
    #[default]
    Present,
    Absent,
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SimulatedTurntable {
    /// A box that speaks the brdfd rig protocol (and is the shutter's box, if there is one).
    #[default]
    Present,
    /// A GRBL G-code controller, the table on its A axis.
    Grbl,
    Absent,
}

/// The RAW files the simulated DSLR writes (`[simulation] dslr_raw`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SimulatedRaw {
    /// Nikon's NEF, 14 bits.
    Nef,
    /// Adobe's DNG at 14 bits.
    Dng,
    /// DNG at 12 bits.
    Dng12,
}

/// Damage the simulated DSLR does to every RAW file it writes (`[simulation]
/// dslr_raw_damage`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SimulatedRawDamage {
    /// The raw image declares 131,072 × 131,072 pixels.
    Oversized,
    /// IFD0 links back to itself.
    IfdLoop,
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SimulatedLink {
    #[default]
    Http,
    Usb,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TurntablePlan {
    /// Views to shoot (1: no turning).
    pub views: usize,
    /// Degrees between views.
    pub step_deg: f64,
}

/// `rigs/<name>.toml`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Rig {
    /// A simulated rig: the devices are the simulators on loopback.
    #[serde(default)]
    pub simulated: bool,
    pub devices: RigDevices,
    /// Object camera intrinsics and pose, and the object's geometry (as in geometry files).
    pub geometry: SceneGeometry,
    /// Yaw of the THETA's panorama in the world, degrees (its front relative to −Z).
    #[serde(default)]
    pub theta_yaw_deg: f64,
    pub brackets: Brackets,
    /// Each camera's gain; `brdfd calibrate radiometry` measures and writes them.
    #[serde(default)]
    pub calibration: Calibration,
    #[serde(default)]
    pub turntable: Option<TurntablePlan>,
    /// Simulated rigs only: devices that are missing or fail.
    #[serde(default)]
    pub simulation: Option<Simulation>,
    /// The file the rig was read from, for errors that name it.
    #[serde(skip)]
    pub file: String,
    /// Whether this is the shipped simulated rig (`--simulate`), whose sphere a preset's
    /// `simulate_on` replaces.
    #[serde(skip)]
    pub shipped: bool,
}

/// `[simulation.shape]` is the rig's object placed elsewhere: the same mesh, its numbers
/// checked as `[geometry.shape]`'s are.
fn check_true_shape(
    file: &str,
    geometry: &SceneGeometry,
    truth: &Shape,
) -> Result<(), ConfigError> {
    let same = match (&geometry.shape, truth) {
        (
            Some(Shape::Mesh {
                file: a, units: ua, ..
            }),
            Shape::Mesh {
                file: b, units: ub, ..
            },
        ) => a == b && ua == ub,
        _ => false,
    };
    if !same {
        return Err(invalid(
            file,
            "simulation.shape",
            "is where the rig's mesh truly stands: [geometry.shape] must be a mesh, and this the same file in the same units, placed elsewhere",
        ));
    }
    SceneGeometry {
        shape: Some(truth.clone()),
        ..geometry.clone()
    }
    .check()
    .map_err(|e| invalid(file, "simulation.shape", e))
}

/// The fallback bracket's values. Whether the rig needs them is the capture's question
/// ([`crate::plan`]).
fn check_fallback_bracket(file: &str, b: &Brackets) -> Result<(), ConfigError> {
    check_exposures(file, "brackets.fallback_shutters", &b.fallback_shutters)?;
    if !(1..=MAX_FALLBACK_FRAMES).contains(&b.fallback_frames) {
        return Err(invalid(
            file,
            "brackets.fallback_frames",
            format!("must be 1 to {MAX_FALLBACK_FRAMES}"),
        ));
    }
    Ok(())
}

/// `materials/<name>.toml`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialPreset {
    /// MERL name the simulated rig renders for this material.
    pub simulate_as: String,
    pub pixels: PixelCount,
    /// Basis size the preset was tuned for; must match the basis used.
    #[serde(default = "default_k")]
    pub k: usize,
    /// DSLR shutter speeds for this material (shiny materials need shorter ones); the rig's
    /// if absent.
    #[serde(default)]
    pub dslr_shutters: Option<Vec<f64>>,
    /// The BRDF model: `hybrid` (the default: GGX lobes plus measured materials), `analytic`
    /// (Lambert + GGX) or `basis` (the paper's PCA basis, which `pixels`, `solve` and `colour`
    /// configure).
    #[serde(default)]
    pub model: Model,
    /// How coefficients are solved: `prior` (the default) or `least-squares` (the paper's).
    #[serde(default)]
    pub solve: Solver,
    /// How colour is modelled: `joint` (the paper's), `per-channel`, or `auto` (the default:
    /// both, keeping the better fit to the photo).
    #[serde(default)]
    pub colour: ColourChoice,
    #[serde(default)]
    pub notes: String,
    /// The shipped object the simulated rig (`--simulate`) puts the material on, instead of
    /// its sphere: `grooved-block`, the concave test part of `config/geometry/`, framed as
    /// `config/rigs/simulated-grooved-block.toml` frames it. A rig file's own object is kept.
    #[serde(default)]
    pub simulate_on: Option<SimulatedObject>,
}

/// An object the simulated rig can hold, shipped with brdfd.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SimulatedObject {
    GroovedBlock,
}

impl SimulatedObject {
    /// Its camera and shape: those of `config/rigs/simulated-grooved-block.toml`, the mesh
    /// compiled in.
    pub fn scene(self) -> SceneGeometry {
        let text = include_str!("../../../config/rigs/simulated-grooved-block.toml");
        let mut rig = Rig::parse("config/rigs/simulated-grooved-block.toml", text)
            .expect("the shipped rigs are checked by tests");
        if let Some(brdfd_core::geometry::Shape::Mesh { file, .. }) = &mut rig.geometry.shape {
            *file = PathBuf::from(format!(
                "{}grooved-block.obj",
                brdfd_core::mesh::BUILTIN_PREFIX
            ));
        }
        rig.geometry
    }

    pub fn name(self) -> &'static str {
        match self {
            SimulatedObject::GroovedBlock => "the grooved block",
        }
    }
}

fn default_k() -> usize {
    5
}

/// Material and session names: lower-case letters, digits and dashes, 1 to 64 characters,
/// so a name can never leave the state directory or clash with the file system.
pub fn validate_name(kind: &str, name: &str) -> Result<(), String> {
    if brdfd_api::plan::is_valid_name(name) {
        Ok(())
    } else {
        Err(brdfd_api::plan::invalid_name(kind, name))
    }
}

/// Where brdfd.toml is looked for when no `--config` is given: `BRDFD_CONFIG`, else
/// `$XDG_CONFIG_HOME/brdfd/brdfd.toml`, else `~/.config/brdfd/brdfd.toml`.
pub(crate) fn default_config_path() -> Option<PathBuf> {
    let var = |k: &str| {
        std::env::var_os(k)
            .filter(|v| !v.is_empty())
            .map(PathBuf::from)
    };
    var("BRDFD_CONFIG").or_else(|| {
        var("XDG_CONFIG_HOME")
            .or_else(|| var("HOME").map(|h| h.join(".config")))
            .map(|d| d.join("brdfd/brdfd.toml"))
    })
}

/// The field a geometry check's message is about (`camera.fx must be ...`), under `table`:
/// `geometry.camera.fx`, else `table` itself.
pub fn geometry_field(table: &str, message: &str) -> String {
    let first = message.split([' ', ',']).next().unwrap_or("");
    match (
        table,
        first.starts_with("camera.") || first.starts_with("shape."),
    ) {
        (_, false) => table.to_string(),
        ("", true) => first.to_string(),
        (_, true) => format!("{table}.{first}"),
    }
}

/// Any configuration file's TOML as `T`; errors carry the file, the parser's message and the
/// line.
pub fn parse<T: serde::de::DeserializeOwned>(file: &str, text: &str) -> Result<T, ConfigError> {
    toml::from_str(text).map_err(|e| ConfigError::Parse {
        file: file.into(),
        message: e.to_string().trim_end().to_string(),
        line: e
            .span()
            .map(|s| text[..s.start.min(text.len())].matches('\n').count() + 1),
    })
}

/// A board file (`brdfd calibrate target` writes one), read and checked: the line of a
/// mistake in its TOML, or what about the board cannot be drawn.
pub fn read_board(path: &Path) -> Result<brdfd_pose::board::Board, ConfigError> {
    let (file, text) = read(path)?;
    let board: brdfd_pose::board::Board = parse(&file, &text)?;
    board
        .check()
        .map_err(|error| ConfigError::Board { file, error })?;
    Ok(board)
}

fn read(path: &Path) -> Result<(String, String), ConfigError> {
    let file = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|e| ConfigError::Read {
        file: file.clone(),
        reason: e.to_string(),
    })?;
    Ok((file, text))
}

fn check_exposures(file: &str, field: &str, values: &[f64]) -> Result<(), ConfigError> {
    if values.len() > MAX_BRACKET {
        return Err(invalid(
            file,
            field.to_string(),
            format!(
                "{} exposures; a bracket has at most {MAX_BRACKET}",
                values.len()
            ),
        ));
    }
    for (i, &s) in values.iter().enumerate() {
        if !(s.is_finite() && s > 0.0 && s <= MAX_EXPOSURE_S) {
            return Err(invalid(
                file,
                format!("{field}[{i}]"),
                format!("{s} s is not an exposure time (0 to {MAX_EXPOSURE_S} s)"),
            ));
        }
    }
    Ok(())
}

/// Shortest token accepted when the API listens beyond loopback.
pub const MIN_TOKEN_CHARS: usize = 16;

impl DaemonConfig {
    pub fn parse(file: &str, text: &str) -> Result<DaemonConfig, ConfigError> {
        let c: DaemonConfig = parse(file, text)?;
        c.check_api(file)?;
        Ok(c)
    }

    /// The API address, checked: IP:PORT, and loopback unless a token is set. `source` names
    /// where the address came from, for the error.
    pub fn check_api(&self, source: &str) -> Result<std::net::SocketAddr, ConfigError> {
        let addr: std::net::SocketAddr = self.api.parse().map_err(|e| {
            invalid(
                source,
                "api",
                format!("{:?} is not IP:PORT ({e})", self.api),
            )
        })?;
        if !addr.ip().is_loopback() {
            let token = self.token.as_deref().unwrap_or("");
            if token.is_empty() {
                return Err(invalid(
                    source,
                    "api",
                    format!("{addr} is reachable from other machines: set `token` too"),
                ));
            }
            // Guessable from another machine in hours at the rate a daemon answers: a floor,
            // not a measure of randomness.
            let distinct = token
                .chars()
                .collect::<std::collections::HashSet<_>>()
                .len();
            if token.chars().count() < MIN_TOKEN_CHARS || distinct < 8 {
                return Err(invalid(
                    source,
                    "token",
                    format!(
                        "too weak for an API reachable from other machines ({addr}): use at \
                         least {MIN_TOKEN_CHARS} characters, not a word or a repeated one, \
                         for example the output of `openssl rand -hex 16`"
                    ),
                ));
            }
        }
        Ok(addr)
    }

    pub fn read(path: &Path) -> Result<DaemonConfig, ConfigError> {
        let (file, text) = read(path)?;
        DaemonConfig::parse(&file, &text)
    }

    /// The settings a command uses, and where they came from: the file given, else the
    /// default path's file if there is one (see `default_config_path`), else the shipped
    /// defaults. The CLI and the daemon both start here, so they agree on `api`, `token` and
    /// `state_dir`.
    pub fn load(given: Option<&Path>) -> Result<(DaemonConfig, String), ConfigError> {
        if let Some(p) = given {
            return Ok((DaemonConfig::read(p)?, p.display().to_string()));
        }
        // Named on purpose: a file that is not there is an error, not the defaults.
        if let Some(p) = std::env::var_os("BRDFD_CONFIG").filter(|v| !v.is_empty()) {
            let p = PathBuf::from(p);
            return Ok((DaemonConfig::read(&p)?, p.display().to_string()));
        }
        match default_config_path() {
            Some(p) if p.is_file() => Ok((DaemonConfig::read(&p)?, p.display().to_string())),
            _ => Ok((DaemonConfig::embedded(), "the built-in defaults".into())),
        }
    }

    /// The shipped defaults.
    pub fn embedded() -> DaemonConfig {
        DaemonConfig::parse(
            "config/brdfd.toml",
            include_str!("../../../config/brdfd.toml"),
        )
        .expect("the shipped brdfd.toml is checked by tests")
    }
}

impl Rig {
    /// Reads a rig file and checks its values. Whether the capture can run the rig (its
    /// devices in their roles, its calibration) is [`crate::plan::check`]'s question:
    /// `brdfd calibrate radiometry` reads a rig that is not calibrated yet.
    pub fn parse(file: &str, text: &str) -> Result<Rig, ConfigError> {
        let r = Rig::parse_unchecked(file, text)?;
        match r.problems().into_iter().next() {
            Some(e) => Err(e.locate(text)),
            None => Ok(r),
        }
    }

    /// The rig as its TOML reads, before [`Rig::problems`] looks at its values.
    pub fn parse_unchecked(file: &str, text: &str) -> Result<Rig, ConfigError> {
        let mut r: Rig = parse(file, text)?;
        r.file = file.to_string();
        Ok(r)
    }

    /// Every value of the rig that makes no sense, each by its field (not located in the
    /// text: see [`ConfigError::locate`]). Within one field, or one group of fields checked
    /// together, only the first is said.
    pub fn problems(&self) -> Vec<ConfigError> {
        let (r, file) = (self, self.file.as_str());
        let b = &r.brackets;
        let mut found = Vec::new();
        let mut check = |result: Result<(), ConfigError>| found.extend(result.err());
        if b.dslr_shutters.is_empty() {
            check(Err(invalid(
                file,
                "brackets.dslr_shutters",
                "needs at least one exposure",
            )));
        }
        check(check_exposures(
            file,
            "brackets.dslr_shutters",
            &b.dslr_shutters,
        ));
        check(check_exposures(
            file,
            "brackets.theta_shutters",
            &b.theta_shutters,
        ));
        if !(b.dslr_f_number.is_finite() && b.dslr_f_number >= 0.7 && b.dslr_f_number <= 64.0) {
            check(Err(invalid(
                file,
                "brackets.dslr_f_number",
                format!("f/{} is not an aperture", b.dslr_f_number),
            )));
        }
        check(check_fallback_bracket(file, b));
        check(r.calibration.check(file));
        if r.simulation.is_some() && !r.simulated {
            check(Err(invalid(
                file,
                "simulation",
                "is for simulated rigs (`simulated = true`)",
            )));
        }
        let fired_sony = r.simulation.as_ref().is_some_and(|s| {
            s.dslr_body == SimulatedBody::SonyA7m4 && s.shutter == SimulatedPresence::Present
        });
        if fired_sony {
            check(Err(invalid(
                file,
                "simulation.dslr_body",
                "a Sony in PC remote mode cannot be fired from outside here (it lists no card): \
                 leave `shutter` out",
            )));
        }
        let gphoto2 = r
            .simulation
            .as_ref()
            .is_some_and(|s| s.dslr_backend == DslrBackend::Gphoto2);
        if gphoto2 && !cfg!(feature = "gphoto2") {
            check(Err(invalid(
                file,
                "simulation.dslr_backend",
                "gphoto2 needs a brdfd built with the `gphoto2` feature (cargo install --path . \
                 --features gphoto2), and this one was built without",
            )));
        }
        if !r.theta_yaw_deg.is_finite() {
            check(Err(invalid(
                file,
                "theta_yaw_deg",
                "must be a number of degrees",
            )));
        }
        let geometry = r.geometry.check();
        let geometry_ok = geometry.is_ok();
        check(geometry.map_err(|e| invalid(file, geometry_field("geometry", &e), e)));
        // The simulated truths are checked as the geometry with a part replaced: a mistake in
        // the geometry itself would be reported again under their names.
        let truth_camera = r.simulation.as_ref().and_then(|s| s.camera.as_ref());
        if let Some(truth) = truth_camera.filter(|_| geometry_ok) {
            let believed = SceneGeometry {
                camera: truth.clone(),
                ..r.geometry.clone()
            };
            check(
                believed
                    .check()
                    .map_err(|e| invalid(file, "simulation.camera", e)),
            );
            let ((tw, th), (w, h)) = (truth.size(), r.geometry.camera.size());
            // In u128: the sizes may be any the file gives, checked or not.
            if tw as u128 * h as u128 != th as u128 * w as u128 {
                check(Err(invalid(
                    file,
                    "simulation.camera",
                    format!("is {tw}×{th}, and [geometry.camera] {w}×{h}: they are one camera, so of one shape"),
                )));
            }
        }
        if let Some(truth) = r.simulation.as_ref().and_then(|s| s.shape.as_ref()) {
            if geometry_ok {
                check(check_true_shape(file, &r.geometry, truth));
            }
        }
        if let Some(t) = &r.turntable {
            if !(1..=crate::MAX_VIEWS).contains(&t.views) || !t.step_deg.is_finite() {
                check(Err(invalid(
                    file,
                    "turntable",
                    format!(
                        "views must be 1 to {} and step_deg a number",
                        crate::MAX_VIEWS
                    ),
                )));
            }
            // Without a turntable device, the views are turned by hand.
        }
        found
    }

    pub fn read(path: &Path) -> Result<Rig, ConfigError> {
        let (file, text) = read(path)?;
        let mut rig = Rig::parse(&file, &text)?;
        // A mesh or normal map named relative to the rig file is beside it.
        let dir = std::path::absolute(path)
            .ok()
            .and_then(|p| p.parent().map(Path::to_path_buf))
            .unwrap_or_default();
        rig.geometry.resolve_files(&dir);
        if let Some(Shape::Mesh { file, .. }) =
            rig.simulation.as_mut().and_then(|s| s.shape.as_mut())
        {
            if file.is_relative() && !brdfd_core::mesh::is_builtin(file) {
                *file = dir.join(&*file);
            }
        }
        Ok(rig)
    }

    /// The shipped simulated rig, which `capture --simulate` uses.
    pub fn simulated() -> Rig {
        let mut rig = Rig::parse(
            SIMULATED_RIG,
            include_str!("../../../config/rigs/simulated.toml"),
        )
        .expect("the shipped simulated rig is checked by tests");
        rig.shipped = true;
        rig
    }
}

/// The name the shipped simulated rig is read under.
const SIMULATED_RIG: &str = "config/rigs/simulated.toml";

/// The material presets shipped in `config/materials/`, by name.
const PRESETS: [(&str, &str); 5] = [
    ("gold", include_str!("../../../config/materials/gold.toml")),
    (
        "gold-part",
        include_str!("../../../config/materials/gold-part.toml"),
    ),
    (
        "chrome",
        include_str!("../../../config/materials/chrome.toml"),
    ),
    (
        "paint",
        include_str!("../../../config/materials/paint.toml"),
    ),
    (
        "fabric",
        include_str!("../../../config/materials/fabric.toml"),
    ),
];

/// The names of the shipped presets.
pub fn preset_names() -> Vec<&'static str> {
    PRESETS.iter().map(|(n, _)| *n).collect()
}

/// The text of a shipped preset, as stored in a session's manifest.
pub(crate) fn preset_text(name: &str) -> Option<&'static str> {
    PRESETS.iter().find(|(n, _)| *n == name).map(|(_, t)| *t)
}

impl MaterialPreset {
    pub fn parse(file: &str, text: &str) -> Result<MaterialPreset, ConfigError> {
        MaterialPreset::parse_all(file, text).map_err(|mut all| all.remove(0))
    }

    /// The preset, or every mistake in it (at least one), each located in `text`.
    pub fn parse_all(file: &str, text: &str) -> Result<MaterialPreset, Vec<ConfigError>> {
        let m: MaterialPreset = parse(file, text).map_err(|e| vec![e])?;
        let mut found = Vec::new();
        if let PixelCount::Count(n) = m.pixels {
            if n.get() <= m.k {
                found.push(invalid(
                    file,
                    "pixels",
                    format!(
                        "{n} pixels cannot determine K = {} coefficients and the mean",
                        m.k
                    ),
                ));
            }
        }
        if let Some(s) = &m.dslr_shutters {
            found.extend(check_exposures(file, "dslr_shutters", s).err());
        }
        if found.is_empty() {
            Ok(m)
        } else {
            Err(found.into_iter().map(|e| e.locate(text)).collect())
        }
    }

    pub fn read(path: &Path) -> Result<MaterialPreset, ConfigError> {
        let (file, text) = read(path)?;
        MaterialPreset::parse(&file, &text)
    }

    /// A shipped preset by name (after checking the name).
    pub fn embedded(name: &str) -> Result<Option<MaterialPreset>, String> {
        validate_name("material", name)?;
        PRESETS
            .iter()
            .find(|(n, _)| *n == name)
            .map(|(n, text)| {
                MaterialPreset::parse(&format!("config/materials/{n}.toml"), text)
                    .map_err(|e| e.to_string())
            })
            .transpose()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_cannot_escape_the_state_directory() {
        for bad in [
            "",
            "../etc",
            "gold/../../x",
            "Gold",
            "-rf",
            "a b",
            &"x".repeat(65),
        ] {
            assert!(validate_name("material", bad).is_err(), "{bad:?}");
        }
        for good in ["gold", "gold-metallic-paint", "pla-2"] {
            validate_name("material", good).unwrap();
        }
    }

    #[test]
    fn errors_name_the_file_line_and_field() {
        let e = DaemonConfig::parse("b.toml", "state_dir = \"/srv\"\napii = \"127.0.0.1:1\"\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("b.toml: ") && e.contains("line 2") && e.contains("apii"),
            "{e}"
        );
        let e = DaemonConfig::parse("b.toml", "api = \"0.0.0.0:7878\"\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("field `api`") && e.contains("set `token`"),
            "{e}"
        );
        // Issue 40: beyond loopback, a token has a strength floor.
        for weak in ["secret", "aaaaaaaaaaaaaaaaaaaa", "abababababababababab"] {
            let e = DaemonConfig::parse(
                "b.toml",
                &format!("api = \"0.0.0.0:7878\"\ntoken = \"{weak}\"\n"),
            )
            .unwrap_err()
            .to_string();
            assert!(
                e.contains("field `token`") && e.contains("too weak"),
                "{weak}: {e}"
            );
        }
        DaemonConfig::parse(
            "b.toml",
            "api = \"0.0.0.0:7878\"\ntoken = \"3f9c2a7e5b1d8046c7e2\"\n",
        )
        .unwrap();
        // On loopback a short token is the user's choice.
        DaemonConfig::parse("b.toml", "token = \"secret\"\n").unwrap();
        let rig =
            include_str!("../../../config/rigs/bench.toml").replace("usb:04b0:0429", "usb:nikon");
        let e = Rig::parse("r.toml", &rig).unwrap_err().to_string();
        assert!(
            e.contains("r.toml") && e.contains("line") && e.contains("not a hex USB id"),
            "{e}"
        );
        let rig = include_str!("../../../config/rigs/bench.toml").replace("0.004,", "-1.0,");
        let e = Rig::parse("r.toml", &rig).unwrap_err().to_string();
        assert!(e.contains("field `brackets.dslr_shutters[1]`"), "{e}");
        let e = MaterialPreset::parse("m.toml", "simulate_as = \"nickel\"\npixels = 4\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("field `pixels`"), "{e}");
        let e = MaterialPreset::parse(
            "m.toml",
            "simulate_as = \"nickel\"\npixels = 20\nsolve = \"ridge\"\n",
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("m.toml") && e.contains("line 3") && e.contains("least-squares"),
            "{e}"
        );
    }

    #[test]
    fn a_preset_chooses_its_solver() {
        let parse = |extra: &str| {
            MaterialPreset::parse(
                "m.toml",
                &format!("simulate_as = \"nickel\"\npixels = 20\n{extra}"),
            )
            .unwrap()
            .solve
        };
        assert_eq!(parse(""), Solver::Prior);
        assert_eq!(parse("solve = \"least-squares\"\n"), Solver::LeastSquares);
    }

    #[test]
    fn a_preset_chooses_its_colour_model() {
        let parse = |extra: &str| {
            MaterialPreset::parse(
                "m.toml",
                &format!("simulate_as = \"gold-metallic-paint\"\npixels = 20\n{extra}"),
            )
            .map(|p| p.colour)
        };
        assert_eq!(parse("").unwrap(), ColourChoice::Auto);
        assert_eq!(
            parse("colour = \"per-channel\"\n").unwrap(),
            ColourChoice::PerChannel
        );
        assert_eq!(parse("colour = \"joint\"\n").unwrap(), ColourChoice::Joint);
        let e = parse("colour = \"rgb\"\n").unwrap_err().to_string();
        assert!(e.contains("m.toml") && e.contains("colour"), "{e}");
    }
}
