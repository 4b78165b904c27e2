//! PTP datasets: DeviceInfo, StorageInfo, ObjectInfo, DevicePropDesc and property values, and
//! the Nikon GetEvent list. Each decodes with bounds checks and encodes (the simulator needs
//! both directions, and round trips keep the two honest).

use crate::codes::datatype as dt;
use crate::error::Result;
use crate::wire::{Reader, Writer};

#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct DeviceInfo {
    pub standard_version: u16,
    pub vendor_extension_id: u32,
    pub vendor_extension_version: u16,
    pub vendor_extension_desc: String,
    pub functional_mode: u16,
    pub operations: Vec<u16>,
    pub events: Vec<u16>,
    pub properties: Vec<u16>,
    pub capture_formats: Vec<u16>,
    pub image_formats: Vec<u16>,
    pub manufacturer: String,
    pub model: String,
    pub device_version: String,
    pub serial_number: String,
}

impl DeviceInfo {
    pub fn decode(b: &[u8]) -> Result<Self> {
        let mut r = Reader::new(b, "DeviceInfo");
        Ok(DeviceInfo {
            standard_version: r.u16()?,
            vendor_extension_id: r.u32()?,
            vendor_extension_version: r.u16()?,
            vendor_extension_desc: r.string()?,
            functional_mode: r.u16()?,
            operations: r.u16_array()?,
            events: r.u16_array()?,
            properties: r.u16_array()?,
            capture_formats: r.u16_array()?,
            image_formats: r.u16_array()?,
            manufacturer: r.string()?,
            model: r.string()?,
            device_version: r.string()?,
            serial_number: r.string()?,
        })
    }

    pub fn encode(&self) -> Vec<u8> {
        let mut w = Writer::new();
        w.u16(self.standard_version)
            .u32(self.vendor_extension_id)
            .u16(self.vendor_extension_version)
            .string(&self.vendor_extension_desc)
            .u16(self.functional_mode)
            .u16_array(&self.operations)
            .u16_array(&self.events)
            .u16_array(&self.properties)
            .u16_array(&self.capture_formats)
            .u16_array(&self.image_formats)
            .string(&self.manufacturer)
            .string(&self.model)
            .string(&self.device_version)
            .string(&self.serial_number);
        w.finish()
    }

    pub fn supports(&self, op: u16) -> bool {
        self.operations.contains(&op)
    }
}

#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct StorageInfo {
    pub storage_type: u16,
    pub filesystem_type: u16,
    pub access_capability: u16,
    pub max_capacity: u64,
    pub free_space_bytes: u64,
    pub free_space_images: u32,
    pub description: String,
    pub volume_label: String,
}

impl StorageInfo {
    pub fn decode(b: &[u8]) -> Result<Self> {
        let mut r = Reader::new(b, "StorageInfo");
        Ok(StorageInfo {
            storage_type: r.u16()?,
            filesystem_type: r.u16()?,
            access_capability: r.u16()?,
            max_capacity: r.u64()?,
            free_space_bytes: r.u64()?,
            free_space_images: r.u32()?,
            description: r.string()?,
            volume_label: r.string()?,
        })
    }

    pub fn encode(&self) -> Vec<u8> {
        let mut w = Writer::new();
        w.u16(self.storage_type)
            .u16(self.filesystem_type)
            .u16(self.access_capability)
            .u64(self.max_capacity)
            .u64(self.free_space_bytes)
            .u32(self.free_space_images)
            .string(&self.description)
            .string(&self.volume_label);
        w.finish()
    }
}

#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct ObjectInfo {
    pub storage_id: u32,
    pub format: u16,
    pub protection: u16,
    /// 32 bits on the wire: files of 4 GiB and more report 0xFFFFFFFF.
    pub compressed_size: u32,
    pub thumb_format: u16,
    pub thumb_size: u32,
    pub thumb_width: u32,
    pub thumb_height: u32,
    pub width: u32,
    pub height: u32,
    pub bit_depth: u32,
    pub parent: u32,
    pub association_type: u16,
    pub association_desc: u32,
    pub sequence_number: u32,
    pub filename: String,
    pub capture_date: String,
    pub modification_date: String,
    pub keywords: String,
}

impl ObjectInfo {
    pub fn decode(b: &[u8]) -> Result<Self> {
        let mut r = Reader::new(b, "ObjectInfo");
        Ok(ObjectInfo {
            storage_id: r.u32()?,
            format: r.u16()?,
            protection: r.u16()?,
            compressed_size: r.u32()?,
            thumb_format: r.u16()?,
            thumb_size: r.u32()?,
            thumb_width: r.u32()?,
            thumb_height: r.u32()?,
            width: r.u32()?,
            height: r.u32()?,
            bit_depth: r.u32()?,
            parent: r.u32()?,
            association_type: r.u16()?,
            association_desc: r.u32()?,
            sequence_number: r.u32()?,
            filename: r.string()?,
            capture_date: r.string()?,
            modification_date: r.string()?,
            // Some cameras end the dataset before Keywords.
            keywords: if r.remaining() > 0 {
                r.string()?
            } else {
                String::new()
            },
        })
    }

    pub fn encode(&self) -> Vec<u8> {
        let mut w = Writer::new();
        w.u32(self.storage_id)
            .u16(self.format)
            .u16(self.protection)
            .u32(self.compressed_size)
            .u16(self.thumb_format)
            .u32(self.thumb_size)
            .u32(self.thumb_width)
            .u32(self.thumb_height)
            .u32(self.width)
            .u32(self.height)
            .u32(self.bit_depth)
            .u32(self.parent)
            .u16(self.association_type)
            .u32(self.association_desc)
            .u32(self.sequence_number)
            .string(&self.filename)
            .string(&self.capture_date)
            .string(&self.modification_date)
            .string(&self.keywords);
        w.finish()
    }
}

/// A property value, in the width its datatype gives.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Value {
    Int(i64),
    UInt(u64),
    Str(String),
    Array(Vec<i64>),
}

impl Value {
    pub fn as_i64(&self) -> Option<i64> {
        match self {
            Value::Int(v) => Some(*v),
            Value::UInt(v) => i64::try_from(*v).ok(),
            _ => None,
        }
    }

    pub fn decode(r: &mut Reader, datatype: u16) -> Result<Value> {
        Ok(match datatype {
            dt::INT8 => Value::Int(r.u8()? as i8 as i64),
            dt::UINT8 => Value::UInt(r.u8()? as u64),
            dt::INT16 => Value::Int(r.u16()? as i16 as i64),
            dt::UINT16 => Value::UInt(r.u16()? as u64),
            dt::INT32 => Value::Int(r.u32()? as i32 as i64),
            dt::UINT32 => Value::UInt(r.u32()? as u64),
            dt::INT64 => Value::Int(r.u64()? as i64),
            dt::UINT64 => Value::UInt(r.u64()?),
            dt::STRING => Value::Str(r.string()?),
            t if t & dt::ARRAY_FLAG != 0 && (t & !dt::ARRAY_FLAG) <= dt::UINT64 => {
                let elem = t & !dt::ARRAY_FLAG;
                let width = element_width(elem);
                let at = r.offset();
                let n = r.u32()? as usize;
                if n.saturating_mul(width) > r.remaining() {
                    return Err(crate::error::PtpError::malformed(
                        "property value",
                        at,
                        format!("array of {n} does not fit"),
                    ));
                }
                let mut v = Vec::with_capacity(n);
                for _ in 0..n {
                    v.push(Value::decode(r, elem)?.as_i64().unwrap_or(i64::MAX));
                }
                Value::Array(v)
            }
            t => return Err(r.error(format!("unknown datatype {t:#06x}"))),
        })
    }

    pub fn encode(&self, w: &mut Writer, datatype: u16) {
        let int = |v: &Value| match v {
            Value::Int(i) => *i as u64,
            Value::UInt(u) => *u,
            _ => 0,
        };
        match datatype {
            dt::INT8 | dt::UINT8 => {
                w.u8(int(self) as u8);
            }
            dt::INT16 | dt::UINT16 => {
                w.u16(int(self) as u16);
            }
            dt::INT32 | dt::UINT32 => {
                w.u32(int(self) as u32);
            }
            dt::INT64 | dt::UINT64 => {
                w.u64(int(self));
            }
            dt::STRING => {
                w.string(match self {
                    Value::Str(s) => s,
                    _ => "",
                });
            }
            t => {
                let elem = t & !dt::ARRAY_FLAG;
                let items = match self {
                    Value::Array(v) => v.clone(),
                    _ => vec![],
                };
                w.u32(items.len() as u32);
                for i in items {
                    Value::Int(i).encode(w, elem);
                }
            }
        }
    }

    /// The value alone, as SetDevicePropValue sends it and GetDevicePropValue returns it.
    pub fn to_bytes(&self, datatype: u16) -> Vec<u8> {
        let mut w = Writer::new();
        self.encode(&mut w, datatype);
        w.finish()
    }

    pub fn from_bytes(b: &[u8], datatype: u16) -> Result<Value> {
        Value::decode(&mut Reader::new(b, "property value"), datatype)
    }
}

fn element_width(datatype: u16) -> usize {
    match datatype {
        dt::INT8 | dt::UINT8 => 1,
        dt::INT16 | dt::UINT16 => 2,
        dt::INT32 | dt::UINT32 => 4,
        _ => 8,
    }
}

#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Form {
    None,
    Range { min: Value, max: Value, step: Value },
    Enum(Vec<Value>),
}

#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DevicePropDesc {
    pub code: u16,
    pub datatype: u16,
    pub writable: bool,
    pub factory_default: Value,
    pub current: Value,
    pub form: Form,
}

impl DevicePropDesc {
    pub fn decode(b: &[u8]) -> Result<Self> {
        let mut r = Reader::new(b, "DevicePropDesc");
        let code = r.u16()?;
        let datatype = r.u16()?;
        let writable = r.u8()? == 1;
        DevicePropDesc::decode_values(&mut r, code, datatype, writable)
    }

    /// A descriptor's values and form, after its header: the part every vendor's descriptors
    /// share (Sony's header has a byte more).
    pub fn decode_values(r: &mut Reader, code: u16, datatype: u16, writable: bool) -> Result<Self> {
        let factory_default = Value::decode(r, datatype)?;
        let current = Value::decode(r, datatype)?;
        let form = match r.u8()? {
            0 => Form::None,
            1 => Form::Range {
                min: Value::decode(r, datatype)?,
                max: Value::decode(r, datatype)?,
                step: Value::decode(r, datatype)?,
            },
            2 => {
                let n = r.u16()? as usize;
                let mut v = Vec::with_capacity(n.min(r.remaining()));
                for _ in 0..n {
                    v.push(Value::decode(r, datatype)?);
                }
                Form::Enum(v)
            }
            f => return Err(r.error(format!("unknown form flag {f}"))),
        };
        Ok(DevicePropDesc {
            code,
            datatype,
            writable,
            factory_default,
            current,
            form,
        })
    }

    pub fn encode(&self) -> Vec<u8> {
        let mut w = Writer::new();
        w.u16(self.code).u16(self.datatype).u8(self.writable as u8);
        self.encode_values(&mut w);
        w.finish()
    }

    /// [`DevicePropDesc::decode_values`]'s inverse.
    pub fn encode_values(&self, w: &mut Writer) {
        self.factory_default.encode(w, self.datatype);
        self.current.encode(w, self.datatype);
        match &self.form {
            Form::None => {
                w.u8(0);
            }
            Form::Range { min, max, step } => {
                w.u8(1);
                min.encode(w, self.datatype);
                max.encode(w, self.datatype);
                step.encode(w, self.datatype);
            }
            Form::Enum(v) => {
                w.u8(2).u16(v.len() as u16);
                for x in v {
                    x.encode(w, self.datatype);
                }
            }
        }
    }

    /// The allowed integer values, for enumerations and ranges (ranges are expanded, so keep
    /// them to the small ones cameras use for exposure).
    pub fn allowed(&self) -> Vec<i64> {
        match &self.form {
            Form::Enum(v) => v.iter().filter_map(Value::as_i64).collect(),
            Form::Range { min, max, step } => {
                let (a, b, s) = (
                    min.as_i64().unwrap_or(0),
                    max.as_i64().unwrap_or(0),
                    step.as_i64().unwrap_or(1).max(1),
                );
                // In i128: a camera's range can span all of i64 (issue 40: `b - a` overflowed).
                let steps = ((b as i128 - a as i128) / s as i128).min(100_000);
                (0..=steps)
                    .map(|i| (a as i128 + i * s as i128) as i64)
                    .collect()
            }
            Form::None => self.current.as_i64().into_iter().collect(),
        }
    }
}

/// One entry of Nikon's GetEvent (0x90C7) list: a u16 count, then (u16 code, u32 param).
pub fn decode_nikon_events(b: &[u8]) -> Result<Vec<(u16, u32)>> {
    let mut r = Reader::new(b, "Nikon event list");
    let n = r.u16()? as usize;
    if n * 6 > r.remaining() {
        return Err(r.error(format!("{n} events do not fit in {} bytes", r.remaining())));
    }
    (0..n).map(|_| Ok((r.u16()?, r.u32()?))).collect()
}

pub fn encode_nikon_events(events: &[(u16, u32)]) -> Vec<u8> {
    let mut w = Writer::new();
    w.u16(events.len() as u16);
    for &(c, p) in events {
        w.u16(c).u32(p);
    }
    w.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn datasets_round_trip() {
        let di = DeviceInfo {
            standard_version: 100,
            vendor_extension_id: 0xA,
            vendor_extension_desc: "microsoft.com: 1.0".into(),
            operations: vec![0x1001, 0x90C0],
            model: "D5100".into(),
            ..Default::default()
        };
        assert_eq!(DeviceInfo::decode(&di.encode()).unwrap(), di);
        let oi = ObjectInfo {
            storage_id: 0x10001,
            format: 0x3801,
            compressed_size: 1234,
            filename: "DSC_0001.JPG".into(),
            ..Default::default()
        };
        assert_eq!(ObjectInfo::decode(&oi.encode()).unwrap(), oi);
        let pd = DevicePropDesc {
            code: 0x500D,
            datatype: dt::UINT32,
            writable: true,
            factory_default: Value::UInt(100),
            current: Value::UInt(250),
            form: Form::Enum(vec![Value::UInt(100), Value::UInt(250)]),
        };
        assert_eq!(DevicePropDesc::decode(&pd.encode()).unwrap(), pd);
        let ev = vec![(0xC101, 0xFFFF0001)];
        assert_eq!(decode_nikon_events(&encode_nikon_events(&ev)).unwrap(), ev);
    }

    #[test]
    fn a_range_over_all_of_i64_lists_its_first_values_without_overflow() {
        let pd = DevicePropDesc {
            code: 0x500D,
            datatype: dt::INT64,
            writable: true,
            factory_default: Value::Int(0),
            current: Value::Int(0),
            form: Form::Range {
                min: Value::Int(i64::MIN),
                max: Value::Int(i64::MAX),
                step: Value::Int(1),
            },
        };
        let v = pd.allowed();
        assert_eq!((v.len(), v[0], v[1]), (100_001, i64::MIN, i64::MIN + 1));
    }

    #[test]
    fn hostile_counts_and_truncation_are_errors_with_offsets() {
        let mut b = DeviceInfo::default().encode();
        // operations count claims a billion entries
        b[11..15].copy_from_slice(&1_000_000_000u32.to_le_bytes());
        let e = DeviceInfo::decode(&b).unwrap_err().to_string();
        assert!(e.contains("DeviceInfo at byte 11"), "{e}");
        let oi = ObjectInfo {
            filename: "A.JPG".into(),
            ..Default::default()
        }
        .encode();
        let e = ObjectInfo::decode(&oi[..55]).unwrap_err().to_string();
        assert!(e.contains("ObjectInfo at byte"), "{e}");
        assert!(decode_nikon_events(&[5, 0, 1, 2]).is_err());
    }
}
