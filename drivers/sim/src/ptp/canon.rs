//! The simulated Canon EOS R6's own side: remote and event modes, its exposure properties
//! reported as GetEvent records and set with SetDevicePropValueEx, and the records a shot
//! makes. The values are the R6's dump's (`shared/data/ptp/device-dumps/canon-eos-r6.txt`):
//! its ISO list, its capture destinations, its free-shot count; the shutter list is the
//! body's in manual mode (the dump was taken in an automatic one) and the apertures are a
//! 24-105 mm f/4 lens's.

use std::collections::BTreeMap;

use brdfd_ptp::canon::{self, EosEvent, EosObject, DESTINATION_HOST, STATUS_BUSY, STATUS_IDLE};
use brdfd_ptp::codes::{prop, rc};

const INVALID_DEVICE_PROP_VALUE: u16 = 0x201C;
const FOCUS_MODE: u16 = 0xD108;
/// Manual focus: the lens's switch at MF, as on a measurement bench.
const FOCUS_MANUAL: u32 = 3;

pub struct EosBody {
    remote: bool,
    events_on: bool,
    values: BTreeMap<u16, u32>,
    allowed: BTreeMap<u16, Vec<u32>>,
    /// Records waiting for GetEvent.
    queue: Vec<EosEvent>,
    /// A shot's records, held until its exposure and processing are over.
    after_shot: Vec<EosEvent>,
}

impl Default for EosBody {
    fn default() -> Self {
        // Automatic ISO, then the list; bulb, then 30 s to 1/8000 s.
        let isos = std::iter::once(0).chain(canon::iso_codes()).collect();
        let shutters = std::iter::once(0x0C)
            .chain(canon::shutter_codes(30.0, 1.0 / 8000.0))
            .collect();
        let values = BTreeMap::from([
            (prop::CANON_EOS_APERTURE, 0x30),
            (prop::CANON_EOS_SHUTTER_SPEED, 0x68),
            (prop::CANON_EOS_ISO_SPEED, 0x48),
            (FOCUS_MODE, FOCUS_MANUAL),
            (prop::CANON_EOS_AVAILABLE_SHOTS, 0x71C),
            (prop::CANON_EOS_CAPTURE_DESTINATION, 1),
            (prop::CANON_EOS_EVF_OUTPUT_DEVICE, 1),
        ]);
        let allowed = BTreeMap::from([
            (
                prop::CANON_EOS_APERTURE,
                canon::f_number_codes(4.0, 22.0).collect(),
            ),
            (prop::CANON_EOS_SHUTTER_SPEED, shutters),
            (prop::CANON_EOS_ISO_SPEED, isos),
            (
                prop::CANON_EOS_CAPTURE_DESTINATION,
                vec![1, 5, DESTINATION_HOST],
            ),
        ]);
        EosBody {
            remote: false,
            events_on: false,
            values,
            allowed,
            queue: Vec::new(),
            after_shot: Vec::new(),
        }
    }
}

impl EosBody {
    /// A session's end (closed, reset or dropped): the body leaves remote and event modes;
    /// its settings stay.
    pub fn end_session(&mut self) {
        self.remote = false;
        self.events_on = false;
        self.queue.clear();
        self.after_shot.clear();
    }

    pub fn set_remote_mode(&mut self, mode: u32) {
        self.remote = mode != 0;
    }

    /// Event mode on: the first GetEvent reports every property's value, then the values
    /// each may take (values first, so a host knows a property before its list).
    pub fn set_event_mode(&mut self, mode: u32) {
        let on = mode != 0;
        if on && !self.events_on {
            let values = self
                .values
                .iter()
                .map(|(&code, &value)| EosEvent::Value { code, value });
            let allowed = self
                .allowed
                .iter()
                .map(|(&code, values)| EosEvent::Allowed {
                    code,
                    values: values.clone(),
                });
            self.queue.extend(values.chain(allowed).collect::<Vec<_>>());
        }
        self.events_on = on;
    }

    /// GetEvent's list: what is waiting, with a shot's records once `exposing` is over.
    pub fn get_event(&mut self, exposing: bool) -> Vec<u8> {
        if !exposing {
            self.queue.append(&mut self.after_shot);
        }
        if !self.events_on {
            return canon::encode_eos_events(&[]);
        }
        canon::encode_eos_events(&std::mem::take(&mut self.queue))
    }

    /// SetDevicePropValueEx: (size, code, value), checked against the property's list.
    pub fn set_value(&mut self, data: &[u8]) -> u16 {
        let word = |i: usize| {
            data.get(4 * i..4 * i + 4)
                .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        };
        let (Some(size), Some(code), Some(value)) = (word(0), word(1), word(2)) else {
            return rc::INVALID_PARAMETER;
        };
        let Ok(code) = u16::try_from(code) else {
            return rc::INVALID_PARAMETER;
        };
        if size as usize != data.len() || !self.values.contains_key(&code) {
            return rc::INVALID_PARAMETER;
        }
        if self.allowed.get(&code).is_some_and(|v| !v.contains(&value)) {
            return INVALID_DEVICE_PROP_VALUE;
        }
        self.values.insert(code, value);
        self.queue.push(EosEvent::Value { code, value });
        rc::OK
    }

    pub fn value(&self, code: u16) -> u32 {
        self.values.get(&code).copied().unwrap_or(0)
    }

    /// Whether the release is the host's: a body not in remote mode ignores it.
    pub fn in_remote_mode(&self) -> bool {
        self.remote
    }

    /// Whether the shot's files stay in the camera for the host.
    pub fn to_host(&self) -> bool {
        self.value(prop::CANON_EOS_CAPTURE_DESTINATION) == DESTINATION_HOST
    }

    /// The records of a shot: busy now; its files and idle once it is processed.
    pub fn shot(&mut self, files: Vec<EosObject>) {
        self.queue.push(EosEvent::Status(STATUS_BUSY));
        for f in files {
            self.after_shot.push(if f.storage_id == 0 {
                EosEvent::Transfer(f)
            } else {
                EosEvent::Added(f)
            });
        }
        self.after_shot.push(EosEvent::Status(STATUS_IDLE));
    }

    /// The current exposure: seconds, f-number, ISO.
    pub fn exposure(&self) -> (f64, f64, u32) {
        (
            canon::shutter_seconds(self.value(prop::CANON_EOS_SHUTTER_SPEED)).unwrap_or(1.0 / 60.0),
            canon::f_number(self.value(prop::CANON_EOS_APERTURE)).unwrap_or(5.6),
            canon::iso(self.value(prop::CANON_EOS_ISO_SPEED)).unwrap_or(100),
        )
    }
}
