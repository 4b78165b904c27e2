//! The simulated Sony a7 IV's own side: the SDIO connection, its properties as one list of
//! Sony descriptors, values set with SetExtDevicePropValue, and the shutter buttons. The
//! properties and their values are the a7 IV's dump's
//! (`shared/data/ptp/device-dumps/sony-a7m4.txt`), but for the exposure program, which is
//! manual here (a measurement), where the dump was taken in aperture priority, and the ISO
//! list, which the dump left empty (automatic ISO): here the body's 100 to 51200.

use std::collections::BTreeMap;

use brdfd_ptp::codes::{datatype as dt, prop, rc};
use brdfd_ptp::dataset::{DevicePropDesc, Form, Value};
use brdfd_ptp::exposure::{F_NUMBERS, ISO_SPEEDS, SHUTTER_SECONDS};
use brdfd_ptp::sony::{self, SonyProp, IN_MEMORY_READY, ISO_AUTO, PROTOCOL_3};
use brdfd_ptp::wire::Writer;

const INVALID_DEVICE_PROP_VALUE: u16 = 0x201C;
const EXPOSURE_PROGRAM_MANUAL: u64 = 1;
const FOCUS_MANUAL: u64 = 1;

pub struct SonyBody {
    /// The last SDIOConnect phase done (3: connected).
    phase: u32,
    props: BTreeMap<u16, SonyProp>,
    /// The newest control protocol the body speaks: 3.00 for the a7 IV; 2.00 to rehearse an
    /// older body. Below 3.00 a host moves the exposure in notches (ControlDevice), as
    /// libgphoto2 2.5 does, and may then set the value it reached, which the body takes too.
    pub max_protocol: u16,
}

fn sony_prop(code: u16, datatype: u16, current: u64, form: Form) -> SonyProp {
    SonyProp {
        desc: DevicePropDesc {
            code,
            datatype,
            writable: true,
            factory_default: Value::UInt(current),
            current: Value::UInt(current),
            form,
        },
        enabled: 1,
    }
}

fn list(values: &[u64]) -> Form {
    Form::Enum(values.iter().map(|&v| Value::UInt(v)).collect())
}

fn range(min: u64, max: u64, step: u64) -> Form {
    Form::Range {
        min: Value::UInt(min),
        max: Value::UInt(max),
        step: Value::UInt(step),
    }
}

impl Default for SonyBody {
    fn default() -> Self {
        let isos: Vec<u64> = std::iter::once(ISO_AUTO as u64)
            .chain(
                ISO_SPEEDS
                    .iter()
                    .map(|&i| i as u64)
                    .filter(|&i| i <= 51_200),
            )
            .collect();
        let mut in_memory = sony_prop(
            prop::SONY_OBJECT_IN_MEMORY,
            dt::UINT16,
            0,
            range(0, 65535, 1),
        );
        in_memory.desc.writable = false;
        let props = [
            sony_prop(
                prop::COMPRESSION_SETTING,
                dt::UINT8,
                20,
                list(&[16, 20, 19, 18, 17, 4, 3, 2, 1]),
            ),
            sony_prop(prop::F_NUMBER, dt::UINT16, 800, range(560, 3200, 1)),
            sony_prop(prop::FOCUS_MODE, dt::UINT16, FOCUS_MANUAL, list(&[])),
            sony_prop(
                prop::EXPOSURE_PROGRAM_MODE,
                dt::UINT16,
                EXPOSURE_PROGRAM_MANUAL,
                list(&[]),
            ),
            sony_prop(
                prop::SONY_SHUTTER_SPEED,
                dt::UINT32,
                0x0001_003C,
                range(73_536, 1_966_081, 1),
            ),
            sony_prop(prop::SONY_FOCUS_FOUND, dt::UINT8, 1, list(&[])),
            in_memory,
            sony_prop(
                prop::SONY_ISO,
                dt::UINT32,
                100,
                Form::Enum(isos.into_iter().map(Value::UInt).collect()),
            ),
            sony_prop(prop::SONY_CAPTURE_TARGET, dt::UINT16, 1, list(&[1, 17, 16])),
            sony_prop(prop::SONY_PRIORITY_MODE, dt::UINT8, 0, list(&[0, 1])),
        ];
        SonyBody {
            phase: 0,
            props: props.into_iter().map(|p| (p.desc.code, p)).collect(),
            max_protocol: PROTOCOL_3,
        }
    }
}

/// The values an exposure property moves through a notch at a time, in the order +1 moves:
/// the a7 IV's third stops within its ranges; ISO's are its property's list, in the order the
/// body lists them (empty here).
fn notches(code: u16) -> Option<Vec<i64>> {
    Some(match code {
        prop::F_NUMBER => F_NUMBERS
            .iter()
            .map(|f| (f * 100.0).round() as i64)
            .filter(|f| (560..=3200).contains(f))
            .collect(),
        prop::SONY_SHUTTER_SPEED => SHUTTER_SECONDS
            .iter()
            .map(|&s| sony::shutter_code(s))
            .collect(),
        // ISO moves through the list the body's property gives, in its order.
        prop::SONY_ISO => Vec::new(),
        _ => return None,
    })
}

impl SonyBody {
    /// SDIOConnect: phases 1, 2 and 3, in order.
    pub fn connect(&mut self, phase: u32) -> u16 {
        if phase == 1 || phase == self.phase + 1 {
            self.phase = phase;
            rc::OK
        } else {
            rc::INVALID_PARAMETER
        }
    }

    /// GetExtDeviceInfo: the protocol version (the one asked for, up to 3.00, which the a7 IV
    /// speaks), the properties, and the buttons.
    pub fn ext_device_info(&self, asked: u32) -> Vec<u8> {
        let codes: Vec<u16> = self.props.keys().copied().collect();
        Writer::new()
            .u16(asked.min(u32::from(self.max_protocol)) as u16)
            .u16_array(&codes)
            .u16_array(&[prop::SONY_SHUTTER_HALF_RELEASE, prop::SONY_SHUTTER_RELEASE])
            .finish()
    }

    /// GetAllExtDevicePropInfo, with `files` waiting in memory (none while exposing).
    pub fn all_props(&mut self, files: usize) -> Vec<u8> {
        let in_memory = if files > 0 {
            IN_MEMORY_READY as u64 + files as u64
        } else {
            0
        };
        if let Some(p) = self.props.get_mut(&prop::SONY_OBJECT_IN_MEMORY) {
            p.desc.current = Value::UInt(in_memory);
        }
        let props: Vec<SonyProp> = self.props.values().cloned().collect();
        sony::encode_sony_props(&props)
    }

    /// SetExtDevicePropValue, checked against the property's form.
    pub fn set(&mut self, code: u16, data: &[u8]) -> u16 {
        if self.phase < 3 {
            return rc::ACCESS_DENIED;
        }
        let Some(p) = self.props.get_mut(&code) else {
            return rc::DEVICE_PROP_NOT_SUPPORTED;
        };
        if !p.desc.writable {
            return rc::ACCESS_DENIED;
        }
        let Ok(v) = Value::from_bytes(data, p.desc.datatype) else {
            return INVALID_DEVICE_PROP_VALUE;
        };
        let seconds = |v: &Value| v.as_i64().and_then(sony::shutter_seconds);
        let ok = match (&p.desc.form, v.as_i64()) {
            (Form::Enum(values), _) if !values.is_empty() => values.contains(&v),
            // A shutter speed's range is of times: its codes are fractions, not a scale.
            (Form::Range { min, max, .. }, _) if code == prop::SONY_SHUTTER_SPEED => {
                match (seconds(min), seconds(max), seconds(&v)) {
                    (Some(a), Some(b), Some(s)) => s >= a.min(b) && s <= a.max(b),
                    _ => false,
                }
            }
            (Form::Range { min, max, .. }, Some(x)) => {
                (min.as_i64().unwrap_or(0)..=max.as_i64().unwrap_or(0)).contains(&x)
            }
            _ => true,
        };
        if !ok {
            return INVALID_DEVICE_PROP_VALUE;
        }
        p.desc.current = v;
        rc::OK
    }

    /// ControlDevice on an exposure property: `data`'s first byte, a signed count of notches
    /// (+1 a larger f-number or ISO, or a shorter time; 0xFF one back), moves it along its
    /// values, stopping at either end. `None` for a property that does not move so.
    pub fn step(&mut self, code: u16, data: &[u8]) -> Option<u16> {
        let values = notches(code)?;
        let Some(&n) = data.first() else {
            return Some(INVALID_DEVICE_PROP_VALUE);
        };
        let p = self.props.get_mut(&code)?;
        let values: Vec<i64> = match &p.desc.form {
            Form::Enum(listed) if values.is_empty() => {
                listed.iter().filter_map(Value::as_i64).collect()
            }
            _ => values,
        };
        if values.is_empty() {
            return Some(INVALID_DEVICE_PROP_VALUE);
        }
        let current = p.desc.current.as_i64().unwrap_or(0);
        let at = values.iter().position(|&v| v == current).unwrap_or(0) as i64;
        let to = (at + i64::from(n as i8)).clamp(0, values.len() as i64 - 1);
        p.desc.current = Value::UInt(values[to as usize] as u64);
        Some(rc::OK)
    }

    /// Lists automatic ISO last instead of first, and sets it: a body whose notch out of
    /// automatic goes down, not up.
    pub fn list_auto_iso_last(&mut self) {
        if let Some(p) = self.props.get_mut(&prop::SONY_ISO) {
            if let Form::Enum(listed) = &mut p.desc.form {
                listed.rotate_left(1);
            }
            p.desc.current = Value::UInt(ISO_AUTO as u64);
        }
    }

    pub fn connected(&self) -> bool {
        self.phase >= 3
    }

    /// A session's end: the connection is to be made again.
    pub fn end_session(&mut self) {
        self.phase = 0;
    }

    fn value(&self, code: u16) -> i64 {
        self.props
            .get(&code)
            .and_then(|p| p.desc.current.as_i64())
            .unwrap_or(0)
    }

    /// The current exposure: seconds, f-number, ISO (automatic reads as 100).
    pub fn exposure(&self) -> (f64, f64, u32) {
        let iso = self.value(prop::SONY_ISO) & ISO_AUTO as i64;
        (
            sony::shutter_seconds(self.value(prop::SONY_SHUTTER_SPEED)).unwrap_or(1.0 / 60.0),
            self.value(prop::F_NUMBER) as f64 / 100.0,
            if iso == ISO_AUTO as i64 {
                100
            } else {
                iso as u32
            },
        )
    }
}
