//! PTP containers as USB carries them (ISO 15740 annex D): a 12-byte header (length, type,
//! code, transaction id) and then parameters or a data payload. PTP/IP carries the same
//! fields in its own packets (see `transport::ptpip`), so operations, responses and events are
//! transport-neutral values here.

use crate::error::{PtpError, Result};
use crate::wire::{Reader, Writer};

pub const HEADER_LEN: usize = 12;
/// Operations and responses carry at most five parameters.
pub const MAX_PARAMS: usize = 5;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    Command = 1,
    Data = 2,
    Response = 3,
    Event = 4,
}

impl Kind {
    pub fn from_u16(v: u16) -> Option<Kind> {
        Some(match v {
            1 => Kind::Command,
            2 => Kind::Data,
            3 => Kind::Response,
            4 => Kind::Event,
            _ => return None,
        })
    }
}

/// An operation request, a response or an event: a code, a transaction id and parameters.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Message {
    pub code: u16,
    pub tid: u32,
    pub params: Vec<u32>,
}

impl Message {
    pub fn new(code: u16, tid: u32, params: &[u32]) -> Self {
        Message {
            code,
            tid,
            params: params.to_vec(),
        }
    }

    pub fn param(&self, i: usize) -> u32 {
        self.params.get(i).copied().unwrap_or(0)
    }
}

/// A decoded container header.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Header {
    pub length: u32,
    pub kind: Kind,
    pub code: u16,
    pub tid: u32,
}

impl Header {
    pub fn parse(bytes: &[u8]) -> Result<Header> {
        let mut r = Reader::new(bytes, "container header");
        let length = r.u32()?;
        let kind_raw = r.u16()?;
        let code = r.u16()?;
        let tid = r.u32()?;
        let kind = Kind::from_u16(kind_raw).ok_or_else(|| {
            PtpError::malformed(
                "container header",
                4,
                format!("unknown container type {kind_raw}"),
            )
        })?;
        if (length as usize) < HEADER_LEN {
            return Err(PtpError::malformed(
                "container header",
                0,
                format!("length {length} is shorter than the 12-byte header"),
            ));
        }
        Ok(Header {
            length,
            kind,
            code,
            tid,
        })
    }

    pub fn payload_len(&self) -> usize {
        self.length as usize - HEADER_LEN
    }
}

pub fn encode_header(kind: Kind, code: u16, tid: u32, payload_len: usize) -> Vec<u8> {
    let mut w = Writer::new();
    w.u32((HEADER_LEN + payload_len) as u32)
        .u16(kind as u16)
        .u16(code)
        .u32(tid);
    w.finish()
}

/// A command, response or event container: header plus parameters.
pub fn encode_message(kind: Kind, m: &Message) -> Vec<u8> {
    let mut out = encode_header(kind, m.code, m.tid, 4 * m.params.len());
    for p in &m.params {
        out.extend_from_slice(&p.to_le_bytes());
    }
    out
}

/// Parameters after a header. Their count follows from the length; a length that is not
/// header + 4n, or more than five parameters, is malformed.
pub fn decode_message(h: &Header, payload: &[u8]) -> Result<Message> {
    if payload.len() != h.payload_len() {
        return Err(PtpError::malformed(
            "container",
            HEADER_LEN + payload.len(),
            format!(
                "header says {} bytes, got {}",
                h.length,
                HEADER_LEN + payload.len()
            ),
        ));
    }
    if !payload.len().is_multiple_of(4) || payload.len() / 4 > MAX_PARAMS {
        return Err(PtpError::malformed(
            "container",
            HEADER_LEN,
            format!(
                "{} parameter bytes is not 0 to 5 whole parameters",
                payload.len()
            ),
        ));
    }
    let mut r = Reader::new(payload, "container parameters");
    let params = (0..payload.len() / 4)
        .map(|_| r.u32())
        .collect::<Result<_>>()?;
    Ok(Message {
        code: h.code,
        tid: h.tid,
        params,
    })
}

/// Decode one whole container from bytes (a USB transfer or a recording).
pub fn decode(bytes: &[u8]) -> Result<(Header, &[u8])> {
    let h = Header::parse(bytes)?;
    if bytes.len() < h.length as usize {
        return Err(PtpError::malformed(
            "container",
            bytes.len(),
            format!("truncated: header says {} bytes", h.length),
        ));
    }
    Ok((h, &bytes[HEADER_LEN..h.length as usize]))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip() {
        let m = Message::new(0x1002, 0, &[1]);
        let b = encode_message(Kind::Command, &m);
        assert_eq!(b, [16, 0, 0, 0, 1, 0, 2, 0x10, 0, 0, 0, 0, 1, 0, 0, 0]);
        let (h, p) = decode(&b).unwrap();
        assert_eq!(h.kind, Kind::Command);
        assert_eq!(decode_message(&h, p).unwrap(), m);
    }

    #[test]
    fn malformed_containers_report_offsets() {
        let err = |b: &[u8]| match decode(b).and_then(|(h, p)| decode_message(&h, p)) {
            Err(PtpError::Malformed { offset, reason, .. }) => (offset, reason),
            other => panic!("expected malformed, got {other:?}"),
        };
        assert_eq!(err(&[1, 2, 3]).0, 0);
        // unknown type
        assert_eq!(err(&[12, 0, 0, 0, 9, 0, 1, 0x10, 0, 0, 0, 0]).0, 4);
        // length below the header
        assert!(err(&[4, 0, 0, 0, 1, 0, 1, 0x10, 0, 0, 0, 0])
            .1
            .contains("shorter"));
        // length beyond the bytes
        assert!(err(&[20, 0, 0, 0, 3, 0, 1, 0x20, 0, 0, 0, 0])
            .1
            .contains("truncated"));
        // parameter bytes not a multiple of 4
        assert_eq!(err(&[14, 0, 0, 0, 3, 0, 1, 0x20, 0, 0, 0, 0, 1, 2]).0, 12);
    }
}
