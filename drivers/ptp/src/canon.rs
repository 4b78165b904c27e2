//! Canon EOS: the remote-release flow, GetEvent's records, and Canon's exposure codes.
//!
//! An EOS body refuses InitiateCapture ("No Image Capture … Canon EOS Capture" in its
//! DeviceInfo). A host takes it over with SetRemoteMode and SetEventMode, and from then on
//! learns everything through GetEvent: each call returns a list of records (a property's new
//! value, a property's allowed values, a new file, the camera busy or idle), and an empty list
//! once there is nothing new. Properties are set with SetDevicePropValueEx, and the camera
//! answers with a record of the value it applied.
//!
//! A shot is the release pressed half way and fully (RemoteReleaseOn 1, then 2) and let go
//! (RemoteReleaseOff 2, then 1). With the capture destination set to the host, the shot's
//! files wait in the camera's memory, each announced by a RequestObjectTransfer record, read
//! with GetPartialObject and let go with TransferComplete. To the card, an ObjectAddedEx
//! record announces each file.
//!
//! The sequence follows what libgphoto2's `camlibs/ptp2` documents of real bodies and the EOS
//! 60D session log in `shared/data/ptp/device-dumps/`; no code is taken from it.

use std::collections::BTreeMap;
use std::time::Instant;

use crate::camera::Camera;
use crate::capture::{CaptureOptions, CaptureProgress, Captured, Target};
use crate::codes::{event, format, op, prop, vendor};
use crate::dataset::ObjectInfo;
use crate::error::{PtpError, Result};
use crate::exposure::{F_NUMBERS, ISO_SPEEDS, SHUTTER_SECONDS};
use crate::wire::Writer;

/// The capture destination that keeps the shot in the camera's memory for the host.
pub const DESTINATION_HOST: u32 = 4;
/// Bytes per GetPartialObject request of a file held for the host: newer bodies (the EOS R)
/// fail larger reads, libgphoto2 notes, and take 1 MiB.
const HOST_CHUNK: u32 = 1 << 20;
/// GetEvent lists read in one poll at most.
const MAX_POLLS: usize = 64;
/// The camera's status records: busy from the release until the shot's files are written.
pub const STATUS_IDLE: u32 = 0;
pub const STATUS_BUSY: u32 = 1;

/// A file a record announces.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct EosObject {
    pub handle: u32,
    /// 0 for a file held for the host.
    pub storage_id: u32,
    pub format: u16,
    pub size: u32,
    pub parent: u32,
    pub name: String,
}

/// One record of GetEvent's list.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum EosEvent {
    /// A property's current value (PropValueChanged).
    Value { code: u16, value: u32 },
    /// The values a property may be set to now (AvailListChanged).
    Allowed { code: u16, values: Vec<u32> },
    /// A file written to a card (ObjectAddedEx).
    Added(EosObject),
    /// A file held in the camera's memory for the host to read (RequestObjectTransfer).
    Transfer(EosObject),
    /// The camera busy (1) or idle (0) (CameraStatusChanged).
    Status(u32),
    /// A record brdfd does not use, by its code.
    Other(u32),
}

/// Field offsets of the records, from the record's start (its size and code come first).
mod at {
    pub const PROP: usize = 0x08;
    pub const VALUE: usize = 0x0C;
    pub const LIST_TYPE: usize = 0x0C;
    pub const LIST_COUNT: usize = 0x10;
    pub const LIST_VALUES: usize = 0x14;
    pub const ADDED_HANDLE: usize = 0x08;
    pub const ADDED_STORAGE: usize = 0x0C;
    pub const ADDED_FORMAT: usize = 0x10;
    pub const ADDED_SIZE: usize = 0x1C;
    pub const ADDED_PARENT: usize = 0x20;
    pub const ADDED_NAME: usize = 0x28;
    pub const TRANSFER_HANDLE: usize = 0x08;
    pub const TRANSFER_FORMAT: usize = 0x0C;
    pub const TRANSFER_SIZE: usize = 0x14;
    pub const TRANSFER_NAME: usize = 0x1C;
    pub const STATUS: usize = 0x08;
}
/// The list type of an AvailListChanged record whose values are 32-bit integers.
const LIST_OF_INTEGERS: u32 = 3;

struct Record<'a> {
    bytes: &'a [u8],
    /// Where the record starts in the list, for errors.
    offset: usize,
}

impl Record<'_> {
    fn error(&self, reason: impl Into<String>) -> PtpError {
        PtpError::malformed("Canon EOS event list", self.offset, reason.into())
    }
    fn u32(&self, at: usize) -> Result<u32> {
        self.bytes
            .get(at..at + 4)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .ok_or_else(|| self.error(format!("a field at +{at:#x} lies past the record's end")))
    }
    fn u16(&self, at: usize) -> Result<u16> {
        self.bytes
            .get(at..at + 2)
            .map(|b| u16::from_le_bytes([b[0], b[1]]))
            .ok_or_else(|| self.error(format!("a field at +{at:#x} lies past the record's end")))
    }
    /// A NUL-terminated ASCII name (a record without the NUL ends the name at its end).
    fn name(&self, at: usize) -> Result<String> {
        let b = self
            .bytes
            .get(at..)
            .ok_or_else(|| self.error("the file name lies past the record's end"))?;
        let end = b.iter().position(|&c| c == 0).unwrap_or(b.len());
        Ok(String::from_utf8_lossy(&b[..end]).into_owned())
    }
    /// A property code: EOS records carry them in 32 bits.
    fn prop(&self) -> Result<u16> {
        let code = self.u32(at::PROP)?;
        u16::try_from(code).map_err(|_| self.error(format!("property code {code:#x}")))
    }
}

/// Decodes GetEvent's list: records of (size, code, fields), ending with an empty record
/// (size 8, code 0) or at the data's end.
pub fn decode_eos_events(b: &[u8]) -> Result<Vec<EosEvent>> {
    let mut out = Vec::new();
    let mut offset = 0;
    while offset < b.len() {
        let head = Record {
            bytes: &b[offset..],
            offset,
        };
        if head.bytes.len() < 8 {
            return Err(head.error(format!(
                "the list ends {} bytes into a record's 8-byte header",
                head.bytes.len()
            )));
        }
        let (size, code) = (head.u32(0)? as usize, head.u32(4)?);
        if size == 8 && code == 0 {
            break;
        }
        if size < 8 || size > b.len() - offset {
            return Err(head.error(format!(
                "a record of {size} bytes in the {} left",
                b.len() - offset
            )));
        }
        let r = Record {
            bytes: &b[offset..offset + size],
            offset,
        };
        out.push(match code {
            event::CANON_EOS_PROP_VALUE_CHANGED => {
                // Values narrower than 32 bits come in the record's first bytes.
                let mut v = [0u8; 4];
                let data = r.bytes.get(at::VALUE..).unwrap_or_default();
                let n = data.len().min(4);
                v[..n].copy_from_slice(&data[..n]);
                EosEvent::Value {
                    code: r.prop()?,
                    value: u32::from_le_bytes(v),
                }
            }
            event::CANON_EOS_AVAIL_LIST_CHANGED => {
                let count = r.u32(at::LIST_COUNT)? as usize;
                if r.u32(at::LIST_TYPE)? != LIST_OF_INTEGERS {
                    EosEvent::Other(code)
                } else if count > (size - at::LIST_VALUES) / 4 {
                    return Err(r.error(format!("{count} values do not fit in {size} bytes")));
                } else {
                    EosEvent::Allowed {
                        code: r.prop()?,
                        values: (0..count)
                            .map(|i| r.u32(at::LIST_VALUES + 4 * i))
                            .collect::<Result<_>>()?,
                    }
                }
            }
            event::CANON_EOS_OBJECT_ADDED_EX => EosEvent::Added(EosObject {
                handle: r.u32(at::ADDED_HANDLE)?,
                storage_id: r.u32(at::ADDED_STORAGE)?,
                format: r.u16(at::ADDED_FORMAT)?,
                size: r.u32(at::ADDED_SIZE)?,
                parent: r.u32(at::ADDED_PARENT)?,
                name: r.name(at::ADDED_NAME)?,
            }),
            event::CANON_EOS_REQUEST_OBJECT_TRANSFER => EosEvent::Transfer(EosObject {
                handle: r.u32(at::TRANSFER_HANDLE)?,
                storage_id: 0,
                format: r.u16(at::TRANSFER_FORMAT)?,
                size: r.u32(at::TRANSFER_SIZE)?,
                parent: 0,
                name: r.name(at::TRANSFER_NAME)?,
            }),
            event::CANON_EOS_CAMERA_STATUS_CHANGED => EosEvent::Status(r.u32(at::STATUS)?),
            other => EosEvent::Other(other),
        });
        offset += size;
    }
    Ok(out)
}

/// Encodes GetEvent's list, ending with the empty record (the simulated EOS body's side).
pub fn encode_eos_events(events: &[EosEvent]) -> Vec<u8> {
    fn record(out: &mut Vec<u8>, code: u32, mut fields: Vec<u8>) {
        // Records are whole 32-bit words.
        fields.resize(fields.len().next_multiple_of(4), 0);
        out.extend_from_slice(&(8 + fields.len() as u32).to_le_bytes());
        out.extend_from_slice(&code.to_le_bytes());
        out.extend_from_slice(&fields);
    }
    /// The name at its offset in the record (the fields before it zero-padded), with its NUL.
    fn name(w: &mut Writer, at: usize, name: &str) {
        w.buf.resize(at - 8, 0);
        w.bytes(name.as_bytes()).u8(0);
    }
    let mut out = Vec::new();
    for e in events {
        let mut w = Writer::new();
        let code = match e {
            EosEvent::Value { code, value } => {
                w.u32(*code as u32).u32(*value);
                event::CANON_EOS_PROP_VALUE_CHANGED
            }
            EosEvent::Allowed { code, values } => {
                w.u32(*code as u32)
                    .u32(LIST_OF_INTEGERS)
                    .u32(values.len() as u32);
                for v in values {
                    w.u32(*v);
                }
                event::CANON_EOS_AVAIL_LIST_CHANGED
            }
            EosEvent::Added(o) => {
                w.u32(o.handle)
                    .u32(o.storage_id)
                    .u16(o.format)
                    .u16(0)
                    .u32(0)
                    .u32(0)
                    .u32(o.size)
                    .u32(o.parent)
                    .u32(0);
                name(&mut w, at::ADDED_NAME, &o.name);
                event::CANON_EOS_OBJECT_ADDED_EX
            }
            EosEvent::Transfer(o) => {
                w.u32(o.handle).u16(o.format).u16(0).u32(0).u32(o.size);
                name(&mut w, at::TRANSFER_NAME, &o.name);
                event::CANON_EOS_REQUEST_OBJECT_TRANSFER
            }
            EosEvent::Status(s) => {
                w.u32(*s);
                event::CANON_EOS_CAMERA_STATUS_CHANGED
            }
            EosEvent::Other(code) => *code,
        };
        record(&mut out, code, w.finish());
    }
    record(&mut out, 0, Vec::new());
    out
}

/// Canon's exposure codes count eighths of a stop from a reference; a third of a stop is 3
/// eighths (two thirds, 5), and a half stop 4. Returns the stops from `reference`.
fn stops(code: u32, reference: u32) -> f64 {
    let d = code as i64 - reference as i64;
    let frac = match d.rem_euclid(8) {
        3 => 1.0 / 3.0,
        5 => 2.0 / 3.0,
        r => r as f64 / 8.0,
    };
    d.div_euclid(8) as f64 + frac
}

/// The index in a series of whole and third stops of the code `code`, for a series whose
/// first code is `first` (Canon's codes step 3, 5, 8 eighths through each stop).
fn third_index(code: u32, first: u32, len: usize) -> Option<usize> {
    let d = code.checked_sub(first)? as usize;
    let third = match d % 8 {
        0 => 0,
        3 => 1,
        5 => 2,
        _ => return None,
    };
    Some(d / 8 * 3 + third).filter(|&i| i < len)
}

/// The first code of each series: 30 s, f/1.0 and ISO 100.
const FIRST_SHUTTER: u32 = 0x10;
const FIRST_F_NUMBER: u32 = 0x08;
const FIRST_ISO: u32 = 0x48;

/// The code of the `index`th value of a series that starts at `first`.
fn third_code(first: u32, index: usize) -> u32 {
    first + (index / 3 * 8) as u32 + [0, 3, 5][index % 3]
}

/// The codes of the R6's ISO speeds, 100 to 102400 (its dump's list).
pub fn iso_codes() -> impl Iterator<Item = u32> {
    (0..ISO_SPEEDS.len()).map(|i| third_code(FIRST_ISO, i))
}

/// The codes of the shutter speeds from `slowest` to `fastest` seconds, in whole and third
/// stops (a body's list in manual mode).
pub fn shutter_codes(slowest: f64, fastest: f64) -> impl Iterator<Item = u32> {
    SHUTTER_SECONDS
        .iter()
        .enumerate()
        .filter(move |(_, &s)| s <= slowest && s >= fastest)
        .map(|(i, _)| third_code(FIRST_SHUTTER, i))
}

/// The codes of the f-numbers from `widest` to `narrowest` (a lens's range).
pub fn f_number_codes(widest: f64, narrowest: f64) -> impl Iterator<Item = u32> {
    F_NUMBERS
        .iter()
        .enumerate()
        .filter(move |(_, &f)| f >= widest && f <= narrowest)
        .map(|(i, _)| third_code(FIRST_F_NUMBER, i))
}

/// The shutter speed of a code (property 0xD102), in seconds; none for automatic (0) and
/// bulb (0x0C). Codes between the table's (half stops) by their stops from 1 s (0x38).
pub fn shutter_seconds(code: u32) -> Option<f64> {
    match code {
        0 | 0x0C => None,
        c => Some(match third_index(c, FIRST_SHUTTER, SHUTTER_SECONDS.len()) {
            Some(i) => SHUTTER_SECONDS[i],
            None => 2f64.powf(-stops(c, 0x38)),
        }),
    }
}

/// The f-number of a code (property 0xD101); none for automatic (0) and no lens (0xFF).
pub fn f_number(code: u32) -> Option<f64> {
    match code {
        0 | 0xFF => None,
        c => Some(match third_index(c, FIRST_F_NUMBER, F_NUMBERS.len()) {
            Some(i) => F_NUMBERS[i],
            None => 2f64.powf(stops(c, 0x08) / 2.0),
        }),
    }
}

/// The ISO speed of a code (property 0xD103); none for automatic (0).
pub fn iso(code: u32) -> Option<u32> {
    match code {
        0 => None,
        c => Some(match third_index(c, FIRST_ISO, ISO_SPEEDS.len()) {
            Some(i) => ISO_SPEEDS[i],
            None => (100.0 * 2f64.powf(stops(c, 0x48))).round() as u32,
        }),
    }
}

/// What an EOS body has said through GetEvent: its properties' values and allowed values,
/// whether it is busy, and the files it announced and brdfd has not taken yet.
#[derive(Debug, Default)]
pub(crate) struct EosState {
    values: BTreeMap<u16, u32>,
    allowed: BTreeMap<u16, Vec<u32>>,
    busy: bool,
    files: Vec<EosEvent>,
}

impl Camera {
    /// A Canon body that captures through its EOS remote release. Newer bodies report the
    /// Microsoft extension, so the manufacturer counts too.
    pub fn is_canon_eos(&self) -> bool {
        (self.info.vendor_extension_id == vendor::CANON
            || self.info.manufacturer.starts_with("Canon"))
            && self.info.supports(op::CANON_EOS_REMOTE_RELEASE_ON)
    }

    /// Takes the EOS body over, once per session: remote mode, event mode, and the first
    /// records (every property's value and allowed values).
    fn eos_start(&mut self) -> Result<()> {
        if self.eos.is_some() {
            return Ok(());
        }
        self.call(op::CANON_EOS_SET_REMOTE_MODE, &[1])?;
        self.call(op::CANON_EOS_SET_EVENT_MODE, &[1])?;
        self.eos = Some(EosState::default());
        self.eos_poll()
    }

    fn eos_state(&mut self) -> &mut EosState {
        self.eos.get_or_insert_with(Default::default)
    }

    /// GetEvent until the list comes back empty (or for [`MAX_POLLS`] lists: a body that
    /// never runs out of news is read again at the next poll), each record applied to what
    /// brdfd knows.
    fn eos_poll(&mut self) -> Result<()> {
        for _ in 0..MAX_POLLS {
            let records = decode_eos_events(&self.data_in(op::CANON_EOS_GET_EVENT, &[])?)?;
            if records.is_empty() {
                return Ok(());
            }
            let state = self.eos_state();
            for r in records {
                match r {
                    EosEvent::Value { code, value } => {
                        state.values.insert(code, value);
                    }
                    EosEvent::Allowed { code, values } => {
                        state.allowed.insert(code, values);
                    }
                    EosEvent::Status(s) => state.busy = s == STATUS_BUSY,
                    EosEvent::Added(_) | EosEvent::Transfer(_) => state.files.push(r),
                    EosEvent::Other(code) => tracing::trace!("EOS record {code:#06x} skipped"),
                }
            }
        }
        Ok(())
    }

    /// Sets an EOS property with SetDevicePropValueEx and returns the value the camera
    /// reports afterwards.
    fn eos_set(&mut self, code: u16, value: u32) -> Result<u32> {
        if self.eos_state().values.get(&code) == Some(&value) {
            return Ok(value);
        }
        let data = Writer::new().u32(12).u32(code as u32).u32(value).finish();
        self.data_out(op::CANON_EOS_SET_DEVICE_PROP_VALUE_EX, &[], &data)?;
        self.eos_poll()?;
        self.eos_state()
            .values
            .get(&code)
            .copied()
            .ok_or_else(|| PtpError::Protocol(format!("the camera never reported {code:#06x}")))
    }

    /// Sets an EOS exposure property to the allowed value nearest to `want`, by the value
    /// each code stands for; returns that value as applied.
    pub(crate) fn eos_set_nearest(
        &mut self,
        code: u16,
        value_of: fn(u32) -> Option<f64>,
        want: f64,
    ) -> Result<f64> {
        self.eos_start()?;
        let allowed = self.eos_state().allowed.get(&code).cloned();
        let best = allowed
            .unwrap_or_default()
            .into_iter()
            .filter_map(|c| value_of(c).map(|v| (c, (v / want).ln().abs())))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(c, _)| c)
            .ok_or_else(|| {
                PtpError::Protocol(format!(
                    "property {code:#06x} offers no settable values (on an EOS body, exposure \
                     is set from the computer only in manual mode: turn the mode dial to M)"
                ))
            })?;
        let applied = self.eos_set(code, best)?;
        value_of(applied).ok_or_else(|| {
            PtpError::Protocol(format!("property {code:#06x} read back as {applied:#x}"))
        })
    }

    /// The capture destination for `target`: the host, or the card value the camera offers.
    fn eos_destination(&mut self, target: Target) -> Result<()> {
        let state = self.eos_state();
        let want = match target {
            Target::Sdram => DESTINATION_HOST,
            Target::Card => {
                let card = state
                    .allowed
                    .get(&prop::CANON_EOS_CAPTURE_DESTINATION)
                    .and_then(|v| v.iter().copied().find(|&v| v != DESTINATION_HOST));
                match (card, state.values.get(&prop::CANON_EOS_CAPTURE_DESTINATION)) {
                    (Some(c), _) => c,
                    (None, Some(&c)) if c != DESTINATION_HOST => c,
                    _ => {
                        return Err(PtpError::Protocol(
                            "the camera offers no card to capture to: check that one is in".into(),
                        ))
                    }
                }
            }
        };
        let was = state
            .values
            .get(&prop::CANON_EOS_CAPTURE_DESTINATION)
            .copied();
        if was != Some(want) {
            self.eos_set(prop::CANON_EOS_CAPTURE_DESTINATION, want)?;
            if want == DESTINATION_HOST {
                // The host says how much room it has for the files (in the camera's units):
                // without it the body may refuse to shoot for lack of space.
                self.call(op::CANON_EOS_PC_HDD_CAPACITY, &[0x0FFF_FFFF, 0x1000, 1])?;
            }
        }
        Ok(())
    }

    /// Reads the records waiting and drops the files they announce (shots taken before).
    pub(crate) fn eos_set_events_aside(&mut self) -> Result<()> {
        self.eos_start()?;
        self.eos_poll()?;
        for f in std::mem::take(&mut self.eos_state().files) {
            tracing::debug!("EOS file set aside: {f:?}");
        }
        Ok(())
    }

    /// The EOS remote release: every file of one shot, downloaded. The shot is whole once
    /// the camera has announced a file and reports itself idle (and, when brdfd set the image
    /// format, has announced as many files as it makes).
    pub(crate) fn capture_canon_eos(
        &mut self,
        opts: &CaptureOptions,
        progress: CaptureProgress,
    ) -> Result<Vec<Captured>> {
        self.eos_start()?;
        self.eos_destination(opts.target)?;
        self.eos_set_events_aside()?;
        progress("exposure", 0, 0);
        // Half way (focus; skipped by a lens set to manual focus), fully, and let go.
        self.call(op::CANON_EOS_REMOTE_RELEASE_ON, &[1, 0])?;
        self.call(op::CANON_EOS_REMOTE_RELEASE_ON, &[2, 0])?;
        self.call(op::CANON_EOS_REMOTE_RELEASE_OFF, &[2])?;
        self.call(op::CANON_EOS_REMOTE_RELEASE_OFF, &[1])?;
        let start = Instant::now();
        let mut files = Vec::new();
        loop {
            self.eos_poll()?;
            for announced in std::mem::take(&mut self.eos_state().files) {
                match announced {
                    EosEvent::Transfer(o) => files.push(self.eos_transfer(o, progress)?),
                    EosEvent::Added(o) if o.format != format::ASSOCIATION => {
                        let info = self.object_info(o.handle)?;
                        files.push(self.fetch(o.handle, info, opts, progress)?);
                    }
                    _ => {}
                }
            }
            let enough = self.files_per_shot.is_none_or(|n| files.len() >= n);
            if !files.is_empty() && enough && !self.eos_state().busy {
                return Ok(files);
            }
            if start.elapsed() > self.timeouts.capture {
                if files.is_empty() {
                    return Err(PtpError::Timeout {
                        what: "capture",
                        after: self.timeouts.capture,
                    });
                }
                tracing::warn!(
                    "the camera stayed busy for {:?} after announcing {} file(s)",
                    self.timeouts.capture,
                    files.len()
                );
                return Ok(files);
            }
            std::thread::sleep(self.timeouts.poll);
        }
    }

    /// Reads a file the camera holds for the host, then lets it go (TransferComplete).
    fn eos_transfer(&mut self, o: EosObject, progress: CaptureProgress) -> Result<Captured> {
        progress("download", 0, o.size as u64);
        let data = self.download_in_chunks(o.handle, o.size as u64, HOST_CHUNK, &mut |d, t| {
            progress("download", d, t)
        })?;
        self.call(op::CANON_EOS_TRANSFER_COMPLETE, &[o.handle])?;
        let info = ObjectInfo {
            storage_id: 0,
            format: o.format,
            compressed_size: o.size,
            parent: o.parent,
            filename: o.name,
            ..Default::default()
        };
        Ok(Captured {
            handle: o.handle,
            info,
            data,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Vec<EosEvent> {
        vec![
            EosEvent::Value {
                code: prop::CANON_EOS_SHUTTER_SPEED,
                value: 0x68,
            },
            EosEvent::Allowed {
                code: prop::CANON_EOS_CAPTURE_DESTINATION,
                values: vec![1, 5, 4],
            },
            EosEvent::Status(STATUS_BUSY),
            EosEvent::Transfer(EosObject {
                handle: 0x9000_0001,
                storage_id: 0,
                format: format::EXIF_JPEG,
                size: 123_456,
                parent: 0,
                name: "IMG_0001.JPG".into(),
            }),
            EosEvent::Added(EosObject {
                handle: 0x2B00_0002,
                storage_id: 0x0001_0001,
                format: format::CANON_CR3,
                size: 25_000_000,
                parent: 0x2B00_0001,
                name: "IMG_0001.CR3".into(),
            }),
            EosEvent::Status(STATUS_IDLE),
        ]
    }

    #[test]
    fn records_round_trip_and_end_at_the_empty_record() {
        let bytes = encode_eos_events(&sample());
        assert_eq!(decode_eos_events(&bytes).unwrap(), sample());
        // Nothing new is the empty record alone.
        assert_eq!(encode_eos_events(&[]), [8, 0, 0, 0, 0, 0, 0, 0]);
        assert!(decode_eos_events(&encode_eos_events(&[]))
            .unwrap()
            .is_empty());
    }

    #[test]
    fn a_cut_or_lying_list_is_an_error_with_its_offset() {
        let bytes = encode_eos_events(&sample());
        // Cut inside the second record's header, and inside its fields.
        let e = decode_eos_events(&bytes[..20]).unwrap_err().to_string();
        assert!(e.contains("byte 16: the list ends 4 bytes into"), "{e}");
        let e = decode_eos_events(&bytes[..30]).unwrap_err().to_string();
        assert!(e.contains("byte 16: a record of"), "{e}");
        // A record claiming fewer bytes than its header.
        let mut lying = bytes.clone();
        lying[0] = 4;
        let e = decode_eos_events(&lying).unwrap_err().to_string();
        assert!(e.contains("a record of 4 bytes"), "{e}");
        // A list whose count runs past its record.
        let mut long = encode_eos_events(&sample()[1..2]);
        long[16] = 200;
        let e = decode_eos_events(&long).unwrap_err().to_string();
        assert!(e.contains("200 values do not fit"), "{e}");
    }

    #[test]
    fn exposure_codes_read_as_the_camera_shows_them() {
        assert_eq!(shutter_seconds(0x68), Some(1.0 / 60.0));
        assert_eq!(shutter_seconds(0x38), Some(1.0));
        assert_eq!(shutter_seconds(0x0C), None, "bulb");
        // A half stop from 1/60 s, between the table's thirds.
        let half = shutter_seconds(0x6C).unwrap();
        assert!((half - 2f64.powf(-6.5)).abs() < 1e-12, "{half}");
        assert_eq!(f_number(0x30), Some(5.6));
        assert_eq!(f_number(0x50), Some(22.0));
        assert_eq!(iso(0x48), Some(100));
        assert_eq!(iso(0x65), Some(1250));
        assert_eq!(iso(0), None, "automatic");
        let codes: Vec<u32> = shutter_codes(30.0, 1.0 / 8000.0).collect();
        assert_eq!((codes[0], codes[codes.len() - 1]), (0x10, 0xA0));
        for code in codes {
            // The nominal values are within a sixth of a stop of the codes' own stops.
            let s = shutter_seconds(code).unwrap();
            let true_s = 2f64.powf(-stops(code, 0x38));
            assert!(
                (s / true_s).log2().abs() < 1.0 / 6.0,
                "{code:#x}: {s} vs {true_s}"
            );
        }
        let isos: Vec<u32> = iso_codes().collect();
        assert_eq!(
            (isos[0], isos[30], iso(isos[29])),
            (0x48, 0x98, Some(80000))
        );
        assert_eq!(
            f_number_codes(4.0, 22.0).collect::<Vec<_>>()[..2],
            [0x28, 0x2B]
        );
    }
}
