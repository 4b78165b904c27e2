//! A small TIFF writer for the files the simulated cameras make: the EXIF block of a JPEG,
//! and the NEF and DNG RAW files, which are TIFF structures (with sub-IFDs and, for NEF, a
//! maker note that is a TIFF of its own).

use std::collections::BTreeMap;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ByteOrder {
    /// "II": Intel, as DNG and JPEG EXIF usually are.
    Little,
    /// "MM": Motorola, as Nikon writes NEF.
    Big,
}

/// A tag's value, by TIFF field type.
#[derive(Debug, Clone)]
pub enum Value {
    Byte(Vec<u8>),
    /// Written with its terminating NUL.
    Ascii(String),
    Short(Vec<u16>),
    Long(Vec<u32>),
    Rational(Vec<(u32, u32)>),
    SRational(Vec<(i32, i32)>),
    Undefined(Vec<u8>),
    /// Offsets (LONG) to these IFDs, written after this one: SubIFDs, the Exif IFD.
    Ifds(Vec<Ifd>),
    /// An offset (LONG) to these bytes: StripOffsets, with StripByteCounts beside it.
    Data(Vec<u8>),
}

impl Value {
    /// TIFF field type, and the count.
    fn kind(&self) -> (u16, usize) {
        match self {
            Value::Byte(v) => (1, v.len()),
            Value::Ascii(s) => (2, s.len() + 1),
            Value::Short(v) => (3, v.len()),
            Value::Long(v) => (4, v.len()),
            Value::Ifds(v) => (4, v.len()),
            Value::Data(_) => (4, 1),
            Value::Rational(v) => (5, v.len()),
            Value::Undefined(v) => (7, v.len()),
            Value::SRational(v) => (10, v.len()),
        }
    }
}

/// One image file directory: tags in ascending order, as TIFF requires.
#[derive(Debug, Clone, Default)]
pub struct Ifd(BTreeMap<u16, Value>);

impl Ifd {
    pub fn new() -> Ifd {
        Ifd::default()
    }

    pub fn set(&mut self, tag: u16, value: Value) -> &mut Ifd {
        self.0.insert(tag, value);
        self
    }

    /// The image data as one strip: StripOffsets, RowsPerStrip and StripByteCounts.
    pub fn strip(&mut self, rows: u32, data: Vec<u8>) -> &mut Ifd {
        let n = data.len() as u32;
        self.set(0x0111, Value::Data(data))
            .set(0x0116, Value::Long(vec![rows]))
            .set(0x0117, Value::Long(vec![n]))
    }
}

struct Out {
    order: ByteOrder,
    bytes: Vec<u8>,
}

impl Out {
    fn u16(&mut self, v: u16) {
        self.bytes.extend_from_slice(&match self.order {
            ByteOrder::Little => v.to_le_bytes(),
            ByteOrder::Big => v.to_be_bytes(),
        });
    }
    fn u32(&mut self, v: u32) {
        self.bytes.extend_from_slice(&match self.order {
            ByteOrder::Little => v.to_le_bytes(),
            ByteOrder::Big => v.to_be_bytes(),
        });
    }
    fn patch_u32(&mut self, at: usize, v: u32) {
        let b = match self.order {
            ByteOrder::Little => v.to_le_bytes(),
            ByteOrder::Big => v.to_be_bytes(),
        };
        self.bytes[at..at + 4].copy_from_slice(&b);
    }
    /// A value's bytes in the file's order (not for Ifds and Data, which are offsets).
    fn encode(&self, v: &Value) -> Vec<u8> {
        let mut o = Out {
            order: self.order,
            bytes: Vec::new(),
        };
        match v {
            Value::Byte(b) | Value::Undefined(b) => o.bytes.extend_from_slice(b),
            Value::Ascii(s) => {
                o.bytes.extend_from_slice(s.as_bytes());
                o.bytes.push(0);
            }
            Value::Short(v) => v.iter().for_each(|&x| o.u16(x)),
            Value::Long(v) => v.iter().for_each(|&x| o.u32(x)),
            Value::Rational(v) => v.iter().for_each(|&(n, d)| {
                o.u32(n);
                o.u32(d)
            }),
            Value::SRational(v) => v.iter().for_each(|&(n, d)| {
                o.u32(n as u32);
                o.u32(d as u32)
            }),
            Value::Ifds(_) | Value::Data(_) => unreachable!("offsets are written by write_ifd"),
        }
        o.bytes
    }
    fn align(&mut self) {
        if self.bytes.len() % 2 == 1 {
            self.bytes.push(0);
        }
    }
}

/// A whole TIFF structure: header, then `ifd0` and everything it points to. Offsets count
/// from the header, so a maker note or an EXIF block can be written the same way.
pub fn write(order: ByteOrder, ifd0: &Ifd) -> Vec<u8> {
    let mut out = Out {
        order,
        bytes: match order {
            ByteOrder::Little => b"II".to_vec(),
            ByteOrder::Big => b"MM".to_vec(),
        },
    };
    out.u16(42);
    out.u32(8);
    write_ifd(&mut out, ifd0);
    out.bytes
}

/// Writes an IFD at the current end, then its out-of-line values, sub-IFDs and data.
/// Returns the IFD's offset.
fn write_ifd(out: &mut Out, ifd: &Ifd) -> u32 {
    out.align();
    let start = out.bytes.len();
    out.u16(ifd.0.len() as u16);
    // Where each entry's value or offset goes, to patch once the target is written.
    let mut pending = Vec::new();
    for (&tag, value) in &ifd.0 {
        let (ty, count) = value.kind();
        out.u16(tag);
        out.u16(ty);
        out.u32(count as u32);
        let slot = out.bytes.len();
        match value {
            Value::Ifds(_) | Value::Data(_) => {
                out.u32(0);
                pending.push((slot, value));
            }
            _ => {
                let bytes = out.encode(value);
                if bytes.len() <= 4 {
                    let mut b = bytes;
                    b.resize(4, 0);
                    out.bytes.extend_from_slice(&b);
                } else {
                    out.u32(0);
                    pending.push((slot, value));
                }
            }
        }
    }
    out.u32(0); // no next IFD
    for (slot, value) in pending {
        match value {
            Value::Ifds(ifds) => {
                let offsets: Vec<u32> = ifds.iter().map(|i| write_ifd(out, i)).collect();
                if let [one] = offsets[..] {
                    out.patch_u32(slot, one);
                } else {
                    out.align();
                    let at = out.bytes.len() as u32;
                    offsets.iter().for_each(|&o| out.u32(o));
                    out.patch_u32(slot, at);
                }
            }
            Value::Data(data) => {
                out.align();
                let at = out.bytes.len() as u32;
                out.bytes.extend_from_slice(data);
                out.patch_u32(slot, at);
            }
            _ => {
                out.align();
                let at = out.bytes.len() as u32;
                let bytes = out.encode(value);
                out.bytes.extend_from_slice(&bytes);
                out.patch_u32(slot, at);
            }
        }
    }
    start as u32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn big_endian_tiff_with_a_sub_ifd_and_a_strip_reads_back() {
        let mut exif = Ifd::new();
        exif.set(0x829A, Value::Rational(vec![(1, 250)]));
        let mut ifd = Ifd::new();
        ifd.set(0x010F, Value::Ascii("NIKON CORPORATION".into()))
            .set(0x8769, Value::Ifds(vec![exif]))
            .strip(1, vec![1, 2, 3]);
        let t = write(ByteOrder::Big, &ifd);
        let r = exif::Reader::new().read_raw(t).unwrap();
        let make = r.get_field(exif::Tag::Make, exif::In::PRIMARY).unwrap();
        assert_eq!(make.display_value().to_string(), "\"NIKON CORPORATION\"");
        let t = r
            .get_field(exif::Tag::ExposureTime, exif::In::PRIMARY)
            .unwrap();
        assert_eq!(t.display_value().to_string(), "1/250");
        let offset = r
            .get_field(exif::Tag::StripOffsets, exif::In::PRIMARY)
            .unwrap();
        let offset = offset.value.get_uint(0).unwrap() as usize;
        assert_eq!(&r.buf()[offset..offset + 3], &[1, 2, 3]);
    }
}
