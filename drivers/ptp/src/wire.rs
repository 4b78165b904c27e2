//! Little-endian readers and writers for PTP datasets, with bounds checks that report the
//! byte offset of the problem. Nothing here panics on short or hostile input.

use crate::error::{PtpError, Result};

pub struct Reader<'a> {
    buf: &'a [u8],
    pos: usize,
    what: &'static str,
}

impl<'a> Reader<'a> {
    pub fn new(buf: &'a [u8], what: &'static str) -> Self {
        Reader { buf, pos: 0, what }
    }

    pub fn offset(&self) -> usize {
        self.pos
    }

    pub fn remaining(&self) -> usize {
        self.buf.len() - self.pos
    }

    pub fn error(&self, reason: impl Into<String>) -> PtpError {
        PtpError::malformed(self.what, self.pos, reason)
    }

    pub fn bytes(&mut self, n: usize) -> Result<&'a [u8]> {
        if n > self.remaining() {
            return Err(self.error(format!(
                "needs {n} more bytes, only {} left",
                self.remaining()
            )));
        }
        let s = &self.buf[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    pub fn u8(&mut self) -> Result<u8> {
        Ok(self.bytes(1)?[0])
    }
    pub fn u16(&mut self) -> Result<u16> {
        Ok(u16::from_le_bytes(self.bytes(2)?.try_into().unwrap()))
    }
    pub fn u32(&mut self) -> Result<u32> {
        Ok(u32::from_le_bytes(self.bytes(4)?.try_into().unwrap()))
    }
    pub fn u64(&mut self) -> Result<u64> {
        Ok(u64::from_le_bytes(self.bytes(8)?.try_into().unwrap()))
    }

    /// A count-prefixed array. The count is checked against the bytes left before anything
    /// is allocated, so a hostile count cannot exhaust memory.
    fn count(&mut self, elem: usize) -> Result<usize> {
        let at = self.pos;
        let n = self.u32()? as usize;
        if n.saturating_mul(elem) > self.remaining() {
            return Err(PtpError::malformed(
                self.what,
                at,
                format!(
                    "array of {n} elements does not fit in {} bytes",
                    self.remaining()
                ),
            ));
        }
        Ok(n)
    }

    pub fn u16_array(&mut self) -> Result<Vec<u16>> {
        let n = self.count(2)?;
        (0..n).map(|_| self.u16()).collect()
    }
    pub fn u32_array(&mut self) -> Result<Vec<u32>> {
        let n = self.count(4)?;
        (0..n).map(|_| self.u32()).collect()
    }

    /// A PTP string: a length byte counting UCS-2 units including the terminating NUL, then
    /// the units. Length 0 is the empty string.
    pub fn string(&mut self) -> Result<String> {
        let at = self.pos;
        let n = self.u8()? as usize;
        if n == 0 {
            return Ok(String::new());
        }
        let raw = self.bytes(n * 2)?;
        let units: Vec<u16> = raw
            .chunks_exact(2)
            .map(|c| u16::from_le_bytes([c[0], c[1]]))
            .take_while(|&u| u != 0)
            .collect();
        String::from_utf16(&units)
            .map_err(|_| PtpError::malformed(self.what, at, "string is not valid UCS-2"))
    }
}

#[derive(Default)]
pub struct Writer {
    pub buf: Vec<u8>,
}

impl Writer {
    pub fn new() -> Self {
        Writer::default()
    }
    pub fn u8(&mut self, v: u8) -> &mut Self {
        self.buf.push(v);
        self
    }
    pub fn u16(&mut self, v: u16) -> &mut Self {
        self.buf.extend_from_slice(&v.to_le_bytes());
        self
    }
    pub fn u32(&mut self, v: u32) -> &mut Self {
        self.buf.extend_from_slice(&v.to_le_bytes());
        self
    }
    pub fn u64(&mut self, v: u64) -> &mut Self {
        self.buf.extend_from_slice(&v.to_le_bytes());
        self
    }
    pub fn bytes(&mut self, v: &[u8]) -> &mut Self {
        self.buf.extend_from_slice(v);
        self
    }
    pub fn u16_array(&mut self, v: &[u16]) -> &mut Self {
        self.u32(v.len() as u32);
        for &x in v {
            self.u16(x);
        }
        self
    }
    pub fn u32_array(&mut self, v: &[u32]) -> &mut Self {
        self.u32(v.len() as u32);
        for &x in v {
            self.u32(x);
        }
        self
    }
    /// PTP strings hold at most 254 units plus the NUL; longer text is cut.
    pub fn string(&mut self, s: &str) -> &mut Self {
        if s.is_empty() {
            return self.u8(0);
        }
        let units: Vec<u16> = s.encode_utf16().take(254).collect();
        self.u8(units.len() as u8 + 1);
        for u in units {
            self.u16(u);
        }
        self.u16(0)
    }
    pub fn finish(&mut self) -> Vec<u8> {
        std::mem::take(&mut self.buf)
    }
}
