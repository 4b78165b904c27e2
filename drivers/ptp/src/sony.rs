//! Sony Alpha: the SDIO connection, the properties read all at once, the shutter button
//! pressed from the computer, and the shot waiting in the camera's memory.
//!
//! A Sony body in PC remote mode refuses InitiateCapture ("No Image Capture … Sony Capture"
//! in its DeviceInfo) and lists no storage. A host connects in three steps (SDIOConnect 1, 2,
//! 3), with GetExtDeviceInfo between them naming the protocol version and Sony's properties
//! and controls. GetAllExtDevicePropInfo returns every property's descriptor in one list
//! (Sony's descriptors carry a byte more than PTP's: whether the property is enabled now).
//! Values are set with SetExtDevicePropValue, and buttons pressed (2) and let go (1) with
//! ControlDevice. After the shutter button's full press the camera holds the shot in its
//! memory at handle 0xFFFFC001, says so with ObjectAdded (0xC201) and with the property
//! "objects in memory" (0xD215) at 0x8000 plus the number of files, and gives one file per
//! GetObject on that handle until none are left.
//!
//! The sequence follows what libgphoto2's `camlibs/ptp2` documents of real bodies; no code is
//! taken from it.

use std::collections::BTreeMap;
use std::time::Instant;

use crate::camera::Camera;
use crate::capture::{CaptureOptions, CaptureProgress, Captured};
use crate::codes::{op, prop, vendor};
use crate::dataset::{DevicePropDesc, Form, Value};
use crate::error::{PtpError, Result};
use crate::exposure::{F_NUMBERS, ISO_SPEEDS, SHUTTER_SECONDS};
use crate::wire::{Reader, Writer};

/// Where a Sony body holds the shot for the computer.
pub const MEMORY_HANDLE: u32 = 0xFFFF_C001;
/// The protocol version a host asks for (3.00); a body answers with the one it speaks.
pub const PROTOCOL_3: u16 = 0x012C;
/// "Objects in memory" at or above this: the shot is ready; the low bits count its files.
pub const IN_MEMORY_READY: i64 = 0x8000;
/// Notches an exposure property may be moved in one setting: 30 s to 1/8000 s is 54.
const MAX_NOTCHES: usize = 64;
/// How long a notch may take to show in the body's value (libgphoto2 allows about a second).
const NOTCH_SETTLE: std::time::Duration = std::time::Duration::from_secs(1);
const NOTCH_POLL: std::time::Duration = std::time::Duration::from_millis(100);
/// ISO value meaning automatic.
pub const ISO_AUTO: u32 = 0x00FF_FFFF;
const PRESSED: u16 = 2;
const LET_GO: u16 = 1;
/// Files one shot leaves in memory at most (RAW + JPEG makes two): a camera that reports more
/// after this many were read is not emptying its memory.
const MAX_FILES_IN_MEMORY: usize = 8;
/// PriorityMode: the computer's settings win over the body's dials.
const PRIORITY_APPLICATION: i64 = 1;

/// A Sony descriptor: PTP's, with whether the property is enabled now.
#[derive(Debug, Clone, PartialEq)]
pub struct SonyProp {
    pub desc: DevicePropDesc,
    /// 1 enabled, 0 greyed out, 2 shown only.
    pub enabled: u8,
}

/// Decodes GetAllExtDevicePropInfo's list: a count (and a zero word), then the descriptors.
pub fn decode_sony_props(b: &[u8]) -> Result<Vec<SonyProp>> {
    let mut r = Reader::new(b, "Sony property list");
    let n = r.u64()? as usize;
    // Each descriptor takes at least its header and two one-byte values.
    if n > r.remaining() / 8 {
        return Err(r.error(format!(
            "{n} properties do not fit in {} bytes",
            r.remaining()
        )));
    }
    (0..n)
        .map(|_| {
            let code = r.u16()?;
            let datatype = r.u16()?;
            let writable = r.u8()? == 1;
            let enabled = r.u8()?;
            let desc = DevicePropDesc::decode_values(&mut r, code, datatype, writable)?;
            Ok(SonyProp { desc, enabled })
        })
        .collect()
}

/// Encodes the list (the simulated body's side).
pub fn encode_sony_props(props: &[SonyProp]) -> Vec<u8> {
    let mut w = Writer::new();
    w.u64(props.len() as u64);
    for p in props {
        let d = &p.desc;
        w.u16(d.code)
            .u16(d.datatype)
            .u8(d.writable as u8)
            .u8(p.enabled);
        d.encode_values(&mut w);
    }
    w.finish()
}

/// Sony's shutter speed: numerator in the high 16 bits, denominator in the low (1/60 s is
/// 0x0001003C, 2.5 s 0x0019000A). Zero means bulb.
pub fn shutter_seconds(v: i64) -> Option<f64> {
    let (n, d) = ((v >> 16) & 0xFFFF, v & 0xFFFF);
    (n > 0 && d > 0).then(|| n as f64 / d as f64)
}

/// The code of a nominal shutter speed: whole seconds over 1, tenths over 10 from 0.3 s to
/// 2.5 s, and 1/N below.
pub fn shutter_code(seconds: f64) -> i64 {
    let (n, d) = if seconds >= 1.0 && seconds.fract() == 0.0 {
        (seconds as i64, 1)
    } else if seconds >= 0.3 {
        ((seconds * 10.0).round() as i64, 10)
    } else {
        (1, (1.0 / seconds).round() as i64)
    };
    (n << 16) | d
}

/// What a Sony body has told brdfd: its protocol version and its properties.
#[derive(Debug, Default)]
pub(crate) struct SonyState {
    /// The control protocol the body answered with (300: 3.00).
    version: u16,
    props: BTreeMap<u16, SonyProp>,
}

impl Camera {
    /// A Sony body that speaks the SDIO control protocol. Over PTP/IP some report the MTP
    /// extension, so the manufacturer counts too.
    pub fn is_sony(&self) -> bool {
        (self.info.vendor_extension_id == vendor::SONY
            || self.info.manufacturer.starts_with("Sony"))
            && self.info.supports(op::SONY_SDIO_CONNECT)
    }

    /// Connects to the body, once per session, and reads its properties. The computer's
    /// settings are given priority over the body's dials where it offers the choice.
    fn sony_start(&mut self) -> Result<()> {
        if self.sony.is_some() {
            return Ok(());
        }
        self.call(op::SONY_SDIO_CONNECT, &[1, 0, 0])?;
        self.call(op::SONY_SDIO_CONNECT, &[2, 0, 0])?;
        let info = self.data_in(op::SONY_SDIO_GET_EXT_DEVICE_INFO, &[PROTOCOL_3 as u32, 1])?;
        let version = Reader::new(&info, "Sony ExtDeviceInfo").u16()?;
        tracing::info!(
            "Sony control protocol {}.{:02}",
            version / 100,
            version % 100
        );
        self.call(op::SONY_SDIO_CONNECT, &[3, 0, 0])?;
        self.sony = Some(SonyState {
            version,
            ..SonyState::default()
        });
        self.sony_read_props()?;
        if self.sony_prop(prop::SONY_PRIORITY_MODE).is_some() {
            let v = Value::Int(PRIORITY_APPLICATION);
            if let Err(e) = self.sony_set(prop::SONY_PRIORITY_MODE, &v) {
                tracing::warn!("the camera keeps its own settings first: {e}");
            }
        }
        Ok(())
    }

    fn sony_read_props(&mut self) -> Result<()> {
        let props =
            decode_sony_props(&self.data_in(op::SONY_SDIO_GET_ALL_EXT_DEVICE_PROP_INFO, &[])?)?;
        let state = self.sony.get_or_insert_with(Default::default);
        state.props = props.into_iter().map(|p| (p.desc.code, p)).collect();
        Ok(())
    }

    fn sony_prop(&self, code: u16) -> Option<&SonyProp> {
        self.sony.as_ref()?.props.get(&code)
    }

    fn sony_value(&self, code: u16) -> Option<i64> {
        self.sony_prop(code)?.desc.current.as_i64()
    }

    /// Sets a property and returns what the camera reports afterwards.
    fn sony_set(&mut self, code: u16, v: &Value) -> Result<Value> {
        let desc = self
            .sony_prop(code)
            .map(|p| p.desc.clone())
            .ok_or_else(|| PtpError::Protocol(format!("the camera has no property {code:#06x}")))?;
        self.data_out(
            op::SONY_SDIO_SET_EXT_DEVICE_PROP_VALUE,
            &[code as u32],
            &v.to_bytes(desc.datatype),
        )?;
        self.sony_read_props()?;
        Ok(self
            .sony_prop(code)
            .map_or(v.clone(), |p| p.desc.current.clone()))
    }

    /// Sets an exposure property to the value nearest to `want` among `nominal` (the values
    /// the property allows, when it lists them; the nominal ones within its range when it
    /// gives a range), by `value_of`; returns the value applied.
    pub(crate) fn sony_set_nearest(
        &mut self,
        code: u16,
        nominal: &[i64],
        value_of: fn(i64) -> Option<f64>,
        plus_is_larger: bool,
        want: f64,
    ) -> Result<f64> {
        self.sony_start()?;
        let p = self
            .sony_prop(code)
            .cloned()
            .ok_or_else(|| PtpError::Protocol(format!("the camera has no property {code:#06x}")))?;
        if !p.desc.writable || p.enabled != 1 {
            return Err(PtpError::Protocol(format!(
                "property {code:#06x} is not settable now (on a Sony, exposure is set from the \
                 computer in manual mode, with the priority given to the computer: turn the mode \
                 dial to M)"
            )));
        }
        let candidates: Vec<i64> = match &p.desc.form {
            Form::Enum(v) if !v.is_empty() => v.iter().filter_map(Value::as_i64).collect(),
            Form::Range { min, max, .. } => {
                let (lo, hi) = (min.as_i64().unwrap_or(0), max.as_i64().unwrap_or(0));
                let within = |v: f64| {
                    let (a, b) = (value_of(lo), value_of(hi));
                    matches!((a, b), (Some(a), Some(b)) if v >= a.min(b) && v <= a.max(b))
                };
                nominal
                    .iter()
                    .copied()
                    .filter(|&c| value_of(c).is_some_and(within))
                    .collect()
            }
            _ => nominal.to_vec(),
        };
        let best = candidates
            .into_iter()
            .filter_map(|c| value_of(c).map(|v| (c, (v / want).ln().abs())))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(c, _)| c)
            .ok_or_else(|| PtpError::Protocol(format!("property {code:#06x} offers no values")))?;
        let absolute = self.sony.as_ref().is_some_and(|s| s.version >= PROTOCOL_3);
        let applied = if absolute {
            self.sony_set(code, &Value::Int(best))?
        } else {
            self.sony_step_to(code, best, value_of, plus_is_larger)?
        };
        applied.as_i64().and_then(value_of).ok_or_else(|| {
            PtpError::Protocol(format!("property {code:#06x} read back as {applied:?}"))
        })
    }

    pub(crate) fn sony_set_shutter(&mut self, seconds: f64) -> Result<f64> {
        let nominal: Vec<i64> = SHUTTER_SECONDS.iter().map(|&s| shutter_code(s)).collect();
        // A notch up is a shorter time.
        self.sony_set_nearest(
            prop::SONY_SHUTTER_SPEED,
            &nominal,
            shutter_seconds,
            false,
            seconds,
        )
    }

    pub(crate) fn sony_set_f_number(&mut self, f: f64) -> Result<f64> {
        let nominal: Vec<i64> = F_NUMBERS
            .iter()
            .map(|f| (f * 100.0).round() as i64)
            .collect();
        let value_of = |v: i64| (v > 0).then_some(v as f64 / 100.0);
        self.sony_set_nearest(prop::F_NUMBER, &nominal, value_of, true, f)
    }

    pub(crate) fn sony_set_iso(&mut self, iso: u32) -> Result<u32> {
        let nominal: Vec<i64> = ISO_SPEEDS.iter().map(|&i| i as i64).collect();
        // The high byte carries flags (multi-frame noise reduction); automatic is 0xFFFFFF.
        let value_of = |v: i64| {
            let v = v & ISO_AUTO as i64;
            (v > 0 && v != ISO_AUTO as i64).then_some(v as f64)
        };
        let applied =
            self.sony_set_nearest(prop::SONY_ISO, &nominal, value_of, true, iso as f64)?;
        Ok(applied as u32)
    }

    /// Moves a property to `target` a notch at a time, as a body below protocol 3.00 takes
    /// its exposure (ControlDevice with +1 or -1; +1 is a larger value when `plus_is_larger`).
    /// It stops at the target, or at the first notch past it (the body offers nothing between),
    /// and fails if a notch moves nothing within [`NOTCH_SETTLE`] or the target is not reached
    /// in [`MAX_NOTCHES`]. Returns the value the body reports.
    fn sony_step_to(
        &mut self,
        code: u16,
        target: i64,
        value_of: fn(i64) -> Option<f64>,
        plus_is_larger: bool,
    ) -> Result<Value> {
        let unreadable = |v: i64| PtpError::Protocol(format!("property {code:#06x} reads {v:#x}"));
        let goal = value_of(target).ok_or_else(|| unreadable(target))?;
        let reached = |v: i64| v == target || value_of(v).is_some_and(|v| v == goal);
        let mut settled = false;
        for _ in 0..MAX_NOTCHES {
            let now = self.sony_value(code).unwrap_or(0);
            if reached(now) {
                settled = true;
                break;
            }
            let at = value_of(now);
            let up = match at {
                Some(at) => (goal > at) == plus_is_larger,
                // A value that is not a number (automatic ISO) sits at one end of the body's
                // list: the numbers are a notch up from its first half, down from its second.
                None => self
                    .sony_prop(code)
                    .is_none_or(|p| listed_early(&p.desc.form, now)),
            };
            self.data_out(
                op::SONY_SDIO_CONTROL_DEVICE,
                &[code as u32],
                &[if up { 0x01 } else { 0xFF }],
            )?;
            // A body applies a notch a moment after it is asked: its value is read until it
            // moves, for a while.
            let asked = std::time::Instant::now();
            let moved = loop {
                self.sony_read_props()?;
                let moved = self.sony_value(code).unwrap_or(0);
                if moved != now || asked.elapsed() >= NOTCH_SETTLE {
                    break moved;
                }
                std::thread::sleep(NOTCH_POLL);
            };
            if moved == now {
                return Err(PtpError::Protocol(format!(
                    "property {code:#06x} did not move from {now:#x} toward {target:#x}"
                )));
            }
            // Past the target: the body offers nothing between.
            if value_of(moved)
                .zip(at)
                .is_some_and(|(m, at)| (m - goal) * (at - goal) < 0.0)
            {
                settled = true;
                break;
            }
        }
        if !settled && !reached(self.sony_value(code).unwrap_or(0)) {
            return Err(PtpError::Protocol(format!(
                "property {code:#06x} did not reach {target:#x} in {MAX_NOTCHES} notches"
            )));
        }
        Ok(self
            .sony_prop(code)
            .map_or(Value::Int(target), |p| p.desc.current.clone()))
    }

    fn sony_button(&mut self, code: u16, state: u16) -> Result<()> {
        let data = Writer::new().u16(state).finish();
        self.data_out(op::SONY_SDIO_CONTROL_DEVICE, &[code as u32], &data)
    }

    /// The files waiting in the camera's memory, by its "objects in memory" property.
    fn sony_files_waiting(&mut self) -> Result<usize> {
        self.sony_read_props()?;
        let v = self.sony_value(prop::SONY_OBJECT_IN_MEMORY).unwrap_or(0);
        Ok(if v >= IN_MEMORY_READY {
            (v - IN_MEMORY_READY).max(1) as usize
        } else {
            0
        })
    }

    /// The shutter button pressed from the computer: every file of one shot, downloaded from
    /// the camera's memory. Files left there by an earlier shot are read and dropped first,
    /// so that they are not taken for this one's.
    pub(crate) fn capture_sony(
        &mut self,
        opts: &CaptureOptions,
        progress: CaptureProgress,
    ) -> Result<Vec<Captured>> {
        self.sony_start()?;
        for _ in 0..MAX_FILES_IN_MEMORY {
            if self.sony_files_waiting()? == 0 {
                break;
            }
            let info = self.object_info(MEMORY_HANDLE)?;
            tracing::warn!("{} was left in the camera's memory: dropped", info.filename);
            self.download(MEMORY_HANDLE, info.compressed_size as u64, &mut |_, _| {})?;
        }
        while let Some(e) = self.next_event(std::time::Duration::from_millis(1))? {
            tracing::debug!("event {:#06x} set aside", e.code);
        }
        progress("exposure", 0, 0);
        self.sony_button(prop::SONY_SHUTTER_HALF_RELEASE, PRESSED)?;
        self.sony_button(prop::SONY_SHUTTER_RELEASE, PRESSED)?;
        self.sony_button(prop::SONY_SHUTTER_RELEASE, LET_GO)?;
        self.sony_button(prop::SONY_SHUTTER_HALF_RELEASE, LET_GO)?;
        // The shot is ready when the camera says so, by event or by its property (it may
        // send no event); reading the handle before that can crash a body's firmware.
        let start = Instant::now();
        loop {
            if let Some(e) = self.next_event(self.timeouts.poll)? {
                tracing::debug!("event {:#06x} while waiting for the shot", e.code);
            }
            if self.sony_files_waiting()? > 0 {
                break;
            }
            if start.elapsed() > self.timeouts.capture {
                return Err(PtpError::Timeout {
                    what: "capture",
                    after: self.timeouts.capture,
                });
            }
        }
        let mut files = Vec::new();
        while self.sony_files_waiting()? > 0 {
            if files.len() >= MAX_FILES_IN_MEMORY {
                return Err(PtpError::Protocol(format!(
                    "the camera still reports files in its memory after {} of this shot were read",
                    files.len()
                )));
            }
            let info = self.object_info(MEMORY_HANDLE)?;
            // The camera's memory keeps no copy once read: nothing to delete.
            let no_delete = CaptureOptions {
                delete_after: false,
                ..opts.clone()
            };
            files.push(self.fetch(MEMORY_HANDLE, info, &no_delete, progress)?);
        }
        Ok(files)
    }
}

/// Whether `value` sits in the first half of a listed property's values (or the property is
/// not listed, or does not list it): a notch up leads away from the list's start.
fn listed_early(form: &Form, value: i64) -> bool {
    match form {
        Form::Enum(listed) => listed
            .iter()
            .position(|v| v.as_i64() == Some(value))
            .is_none_or(|i| i < listed.len() / 2),
        _ => true,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shutter_codes_are_sony_s_fractions() {
        assert_eq!(shutter_code(1.0 / 60.0), 0x0001_003C);
        assert_eq!(shutter_code(0.5), 0x0005_000A);
        assert_eq!(shutter_code(2.5), 0x0019_000A);
        assert_eq!(
            shutter_code(1.0 / 8000.0),
            73_536,
            "the a7 IV's fastest, in its dump"
        );
        assert_eq!(shutter_code(30.0), 1_966_081, "its slowest");
        for s in SHUTTER_SECONDS {
            let back = shutter_seconds(shutter_code(s)).unwrap();
            assert!((back / s - 1.0).abs() < 0.02, "{s}: {back}");
        }
        assert_eq!(shutter_seconds(0), None, "bulb");
    }

    #[test]
    fn the_property_list_round_trips_and_refuses_a_lying_count() {
        let props = vec![
            SonyProp {
                desc: DevicePropDesc {
                    code: prop::SONY_SHUTTER_SPEED,
                    datatype: crate::codes::datatype::UINT32,
                    writable: true,
                    factory_default: Value::UInt(327_690),
                    current: Value::UInt(327_690),
                    form: Form::Range {
                        min: Value::UInt(73_536),
                        max: Value::UInt(1_966_081),
                        step: Value::UInt(1),
                    },
                },
                enabled: 1,
            },
            SonyProp {
                desc: DevicePropDesc {
                    code: prop::SONY_CAPTURE_TARGET,
                    datatype: crate::codes::datatype::UINT16,
                    writable: true,
                    factory_default: Value::UInt(1),
                    current: Value::UInt(1),
                    form: Form::Enum(vec![Value::UInt(1), Value::UInt(17), Value::UInt(16)]),
                },
                enabled: 2,
            },
        ];
        let bytes = encode_sony_props(&props);
        assert_eq!(decode_sony_props(&bytes).unwrap(), props);
        let mut lying = bytes.clone();
        lying[0] = 0xFF;
        lying[1] = 0xFF;
        let e = decode_sony_props(&lying).unwrap_err().to_string();
        assert!(e.contains("65535 properties do not fit"), "{e}");
        let e = decode_sony_props(&bytes[..bytes.len() - 3])
            .unwrap_err()
            .to_string();
        assert!(e.contains("Sony property list"), "{e}");
    }
}
