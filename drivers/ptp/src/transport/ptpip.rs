//! PTP/IP (CIPA DC-005): two TCP connections to port 15740, one for commands and data, one
//! for events. Every packet starts with a u32 length (including the 8-byte header) and a u32
//! type. The packet codec is public because the simulator's server speaks it too.

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream, ToSocketAddrs};
use std::time::{Duration, Instant};

use crate::container::Message;
use crate::error::{PtpError, Result};
use crate::transport::{Progress, Transport};
use crate::wire::{Reader, Writer};

pub const DEFAULT_PORT: u16 = 15740;
pub const PROTOCOL_VERSION: u32 = 0x0001_0000;
/// The largest packet we accept. Data arrives in packets of tens of kilobytes; anything this
/// big is a corrupt length.
pub const MAX_PACKET: usize = 64 << 20;
/// Longest wait for a TCP connection to the camera, whatever the handshake's timeout is (the
/// handshake may wait for a person to confirm the pairing). A camera on the local network
/// accepts within milliseconds; Linux sends the SYN again after 1 s, so this covers one lost
/// SYN and still answers a dead address within 5 s.
pub const CONNECT_TIMEOUT: Duration = Duration::from_secs(3);
/// Payload bytes per Data packet we send.
pub const DATA_CHUNK: usize = 256 << 10;

pub mod ty {
    pub const INIT_COMMAND_REQUEST: u32 = 1;
    pub const INIT_COMMAND_ACK: u32 = 2;
    pub const INIT_EVENT_REQUEST: u32 = 3;
    pub const INIT_EVENT_ACK: u32 = 4;
    pub const INIT_FAIL: u32 = 5;
    pub const OPERATION_REQUEST: u32 = 6;
    pub const OPERATION_RESPONSE: u32 = 7;
    pub const EVENT: u32 = 8;
    pub const START_DATA: u32 = 9;
    pub const DATA: u32 = 10;
    pub const CANCEL: u32 = 11;
    pub const END_DATA: u32 = 12;
    pub const PROBE_REQUEST: u32 = 13;
    pub const PROBE_RESPONSE: u32 = 14;
}

/// Data phase field of an operation request.
pub mod dataphase {
    pub const NONE_OR_IN: u32 = 1;
    pub const OUT: u32 = 2;
}

pub struct Packet {
    pub ty: u32,
    pub body: Vec<u8>,
}

impl Packet {
    pub fn new(ty: u32, body: Vec<u8>) -> Self {
        Packet { ty, body }
    }

    pub fn to_bytes(&self) -> Vec<u8> {
        let mut w = Writer::new();
        w.u32(8 + self.body.len() as u32)
            .u32(self.ty)
            .bytes(&self.body);
        w.finish()
    }

    /// Code, transaction id and parameters of an OperationRequest (after the data phase
    /// field), OperationResponse or Event.
    pub fn message(&self, skip: usize) -> Result<Message> {
        let what = "PTP/IP operation packet";
        let mut r = Reader::new(&self.body, what);
        r.bytes(skip)?;
        let code = r.u16()?;
        let tid = r.u32()?;
        if !r.remaining().is_multiple_of(4) || r.remaining() / 4 > crate::container::MAX_PARAMS {
            return Err(r.error(format!("{} parameter bytes", r.remaining())));
        }
        let params = (0..r.remaining() / 4)
            .map(|_| r.u32())
            .collect::<Result<_>>()?;
        Ok(Message { code, tid, params })
    }

    pub fn from_message(ty: u32, prefix: Option<u32>, m: &Message) -> Packet {
        let mut w = Writer::new();
        if let Some(p) = prefix {
            w.u32(p);
        }
        w.u16(m.code).u32(m.tid);
        for &p in &m.params {
            w.u32(p);
        }
        Packet::new(ty, w.finish())
    }
}

/// A data phase as packets: StartData with the total length, then Data packets, the last
/// one as EndData.
pub fn data_phase(tid: u32, data: &[u8]) -> Vec<u8> {
    let mut w = Writer::new();
    w.u32(tid).u64(data.len() as u64);
    let mut out = Packet::new(ty::START_DATA, w.finish()).to_bytes();
    let count = data.len().div_ceil(DATA_CHUNK).max(1);
    for i in 0..count {
        let chunk = &data[(i * DATA_CHUNK).min(data.len())..((i + 1) * DATA_CHUNK).min(data.len())];
        let kind = if i + 1 == count {
            ty::END_DATA
        } else {
            ty::DATA
        };
        let mut body = tid.to_le_bytes().to_vec();
        body.extend_from_slice(chunk);
        out.extend(Packet::new(kind, body).to_bytes());
    }
    out
}

pub fn read_packet(r: &mut impl Read) -> Result<Packet> {
    let mut head = [0u8; 8];
    r.read_exact(&mut head)?;
    let len = u32::from_le_bytes(head[..4].try_into().unwrap()) as usize;
    let ty = u32::from_le_bytes(head[4..].try_into().unwrap());
    if !(8..=MAX_PACKET).contains(&len) {
        return Err(PtpError::malformed(
            "PTP/IP packet",
            0,
            format!("length {len} (type {ty})"),
        ));
    }
    let mut body = vec![0u8; len - 8];
    r.read_exact(&mut body)?;
    Ok(Packet { ty, body })
}

/// A stream read against an overall deadline: each read waits at most the time left, so a
/// camera that trickles a byte at a time (each read alone well within a read timeout) cannot
/// stretch a packet, or a transaction, past it.
struct UntilDeadline<'s> {
    stream: &'s TcpStream,
    deadline: Instant,
}

impl Read for UntilDeadline<'_> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let left = self.deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return Err(std::io::Error::new(
                std::io::ErrorKind::TimedOut,
                "the deadline passed",
            ));
        }
        self.stream.set_read_timeout(Some(left))?;
        let mut stream = self.stream;
        stream.read(buf)
    }
}

/// One packet from `stream`, whole by `deadline`.
fn read_packet_by(stream: &TcpStream, deadline: Instant) -> Result<Packet> {
    read_packet(&mut UntilDeadline { stream, deadline })
}

pub fn write_packet(w: &mut impl Write, p: &Packet) -> Result<()> {
    w.write_all(&p.to_bytes())?;
    Ok(())
}

/// Who we say we are in InitCommandRequest. Cameras that pair (Nikon's Wi-Fi bodies)
/// remember the GUID, so keep it stable per installation.
#[derive(Debug, Clone)]
pub struct Initiator {
    pub guid: [u8; 16],
    pub name: String,
}

impl Default for Initiator {
    fn default() -> Self {
        Initiator {
            guid: *b"brdfd-initiator1",
            name: "brdfd".into(),
        }
    }
}

pub struct PtpIpTransport {
    addr: SocketAddr,
    initiator: Initiator,
    connect_timeout: Duration,
    cmd: TcpStream,
    evt: TcpStream,
    /// Event bytes read so far; an event packet may arrive split across polls.
    evt_buf: Vec<u8>,
    pub camera_name: String,
}

impl PtpIpTransport {
    pub fn connect(
        addr: impl ToSocketAddrs,
        initiator: Initiator,
        timeout: Duration,
    ) -> Result<Self> {
        let addr = addr
            .to_socket_addrs()?
            .next()
            .ok_or_else(|| PtpError::Io("PTP/IP address resolves to nothing".into()))?;
        let (cmd, evt, camera_name) = handshake(addr, &initiator, timeout)?;
        Ok(PtpIpTransport {
            addr,
            initiator,
            connect_timeout: timeout,
            cmd,
            evt,
            evt_buf: Vec::new(),
            camera_name,
        })
    }

    /// The next packet on the command stream, whole within `timeout` and by `deadline`.
    fn read_cmd(
        &mut self,
        timeout: Duration,
        deadline: Option<Instant>,
        during: &'static str,
    ) -> Result<Packet> {
        let by = Instant::now() + timeout;
        let by = deadline.map_or(by, |d| d.min(by));
        read_packet_by(&self.cmd, by).map_err(|e| match e {
            PtpError::Io(_) => PtpError::Timeout {
                what: during,
                after: timeout,
            },
            e => e,
        })
    }
}

fn tcp(addr: SocketAddr, timeout: Duration) -> Result<TcpStream> {
    let connect = timeout.min(CONNECT_TIMEOUT);
    let s = TcpStream::connect_timeout(&addr, connect).map_err(|e| PtpError::Connect {
        addr: addr.to_string(),
        reason: match e.kind() {
            std::io::ErrorKind::TimedOut | std::io::ErrorKind::WouldBlock => {
                format!("no answer within {connect:?}")
            }
            _ => e.to_string(),
        },
    })?;
    // Requests are small and each waits for an answer: Nagle would add 40 ms to each.
    s.set_nodelay(true)?;
    s.set_write_timeout(Some(timeout))?;
    Ok(s)
}

fn handshake(
    addr: SocketAddr,
    who: &Initiator,
    timeout: Duration,
) -> Result<(TcpStream, TcpStream, String)> {
    let mut cmd = tcp(addr, timeout)?;
    let mut w = Writer::new();
    w.bytes(&who.guid);
    for u in who.name.encode_utf16() {
        w.u16(u);
    }
    w.u16(0).u32(PROTOCOL_VERSION);
    write_packet(&mut cmd, &Packet::new(ty::INIT_COMMAND_REQUEST, w.finish()))?;
    // A read that fails once the deadline has passed is the handshake's timeout, whatever the
    // socket called it ("Resource temporarily unavailable" is EAGAIN from a read timeout).
    let handshake_step = |step: &'static str, deadline: Instant| {
        move |e: PtpError| match e {
            PtpError::Io(_) if Instant::now() >= deadline => PtpError::Handshake {
                addr: addr.to_string(),
                step,
                after: timeout,
            },
            e => e,
        }
    };
    let deadline = Instant::now() + timeout;
    let ack = read_packet_by(&cmd, deadline)
        .map_err(handshake_step("waiting for InitCommandAck", deadline))
        .map_err(|e| match e {
            // Something listens there, but its first bytes are not a PTP/IP packet: an HTTP
            // server, say, on the wrong port or address.
            PtpError::Malformed { reason, .. } => PtpError::Protocol(format!(
                "{addr} answered, but not as a PTP/IP camera ({reason}): check the address and the port (PTP/IP's is {DEFAULT_PORT}), and that the camera is in PTP/IP (PC connection) mode"
            )),
            e => e,
        })?;
    match ack.ty {
        ty::INIT_COMMAND_ACK => {}
        ty::INIT_FAIL => {
            let reason = Reader::new(&ack.body, "InitFail").u32().unwrap_or(0);
            return Err(PtpError::Protocol(format!(
                "camera at {addr} refused the connection (InitFail reason {reason}); if it asks, confirm the pairing on the camera's screen"
            )));
        }
        t => {
            return Err(PtpError::malformed(
                "InitCommandAck",
                4,
                format!("packet type {t}"),
            ))
        }
    }
    let mut r = Reader::new(&ack.body, "InitCommandAck");
    let conn = r.u32()?;
    r.bytes(16)?;
    let mut units = Vec::new();
    while r.remaining() >= 2 {
        match r.u16()? {
            0 => break,
            u => units.push(u),
        }
    }
    let name = String::from_utf16_lossy(&units);

    let mut evt = tcp(addr, timeout)?;
    let mut w = Writer::new();
    w.u32(conn);
    write_packet(&mut evt, &Packet::new(ty::INIT_EVENT_REQUEST, w.finish()))?;
    let deadline = Instant::now() + timeout;
    let ack = read_packet_by(&evt, deadline)
        .map_err(handshake_step("waiting for InitEventAck", deadline))?;
    if ack.ty != ty::INIT_EVENT_ACK {
        return Err(PtpError::malformed(
            "InitEventAck",
            4,
            format!("packet type {}", ack.ty),
        ));
    }
    Ok((cmd, evt, name))
}

impl Transport for PtpIpTransport {
    fn transact(
        &mut self,
        op: &Message,
        data_out: Option<&[u8]>,
        response_timeout: Duration,
        progress: Progress,
    ) -> Result<(Option<Vec<u8>>, Message)> {
        let phase = if data_out.is_some() {
            dataphase::OUT
        } else {
            dataphase::NONE_OR_IN
        };
        let mut out = Packet::from_message(ty::OPERATION_REQUEST, Some(phase), op).to_bytes();
        if let Some(data) = data_out {
            out.extend(data_phase(op.tid, data));
        }
        self.cmd.write_all(&out)?;

        let mut data: Option<Vec<u8>> = None;
        let mut total = 0u64;
        // Each packet must come whole within the response timeout; once the data phase is
        // announced, the whole transaction must end within the time its size allows
        // (`crate::data_deadline`).
        let mut deadline: Option<Instant> = None;
        loop {
            let p = self.read_cmd(response_timeout, deadline, "camera response")?;
            let tid_of = |p: &Packet| Reader::new(&p.body, "PTP/IP data packet").u32();
            match p.ty {
                ty::START_DATA => {
                    let mut r = Reader::new(&p.body, "StartData");
                    r.u32()?;
                    total = r.u64()?;
                    crate::check_object_size(total, "a PTP/IP data phase (StartData)")?;
                    data = Some(Vec::with_capacity(
                        (total as usize).min(crate::PREALLOCATE_MAX),
                    ));
                    deadline = Some(Instant::now() + crate::data_deadline(response_timeout, total));
                    progress(0, total);
                }
                ty::DATA | ty::END_DATA => {
                    let buf = data.as_mut().ok_or_else(|| {
                        PtpError::Protocol("data packet without StartData".into())
                    })?;
                    if tid_of(&p)? != op.tid {
                        return Err(PtpError::Protocol(
                            "data packet for another transaction".into(),
                        ));
                    }
                    buf.extend_from_slice(&p.body[4..]);
                    if buf.len() as u64 > total {
                        return Err(PtpError::malformed(
                            "PTP/IP data phase",
                            buf.len(),
                            format!("more bytes than the {total} StartData announced"),
                        ));
                    }
                    progress(buf.len() as u64, total);
                    if p.ty == ty::END_DATA && (buf.len() as u64) < total {
                        return Err(PtpError::Protocol(format!(
                            "EndData after {} of {total} bytes",
                            buf.len()
                        )));
                    }
                }
                ty::OPERATION_RESPONSE => {
                    let m = p.message(0)?;
                    if m.tid != op.tid {
                        return Err(PtpError::Protocol(format!(
                            "response for transaction {} while {} was running",
                            m.tid, op.tid
                        )));
                    }
                    return Ok((data, m));
                }
                ty::CANCEL => {
                    return Err(PtpError::Protocol(
                        "camera cancelled the transaction".into(),
                    ))
                }
                t => {
                    return Err(PtpError::malformed(
                        "PTP/IP command stream",
                        4,
                        format!("unexpected packet type {t}"),
                    ))
                }
            }
        }
    }

    fn poll_event(&mut self, timeout: Duration) -> Result<Option<Message>> {
        let deadline = Instant::now() + timeout;
        loop {
            if self.evt_buf.len() >= 8 {
                let len = u32::from_le_bytes(self.evt_buf[..4].try_into().unwrap()) as usize;
                if !(8..=4096).contains(&len) {
                    return Err(PtpError::malformed(
                        "PTP/IP event packet",
                        0,
                        format!("length {len}"),
                    ));
                }
                if self.evt_buf.len() >= len {
                    let p = read_packet(&mut &self.evt_buf[..len])?;
                    self.evt_buf.drain(..len);
                    match p.ty {
                        ty::EVENT => return Ok(Some(p.message(0)?)),
                        // The camera checks that we are alive.
                        ty::PROBE_REQUEST => {
                            write_packet(&mut self.evt, &Packet::new(ty::PROBE_RESPONSE, vec![]))?
                        }
                        _ => {}
                    }
                    continue;
                }
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Ok(None);
            }
            self.evt.set_read_timeout(Some(left))?;
            let mut buf = [0u8; 512];
            match self.evt.read(&mut buf) {
                Ok(0) => {
                    return Err(PtpError::Disconnected {
                        during: "event read",
                    })
                }
                Ok(n) => self.evt_buf.extend_from_slice(&buf[..n]),
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                    ) =>
                {
                    return Ok(None)
                }
                Err(e) => return Err(e.into()),
            }
        }
    }

    fn reset(&mut self) -> Result<()> {
        let _ = self.cmd.shutdown(std::net::Shutdown::Both);
        let _ = self.evt.shutdown(std::net::Shutdown::Both);
        let (cmd, evt, name) = handshake(self.addr, &self.initiator, self.connect_timeout)?;
        self.cmd = cmd;
        self.evt = evt;
        self.evt_buf.clear();
        self.camera_name = name;
        Ok(())
    }

    fn describe(&self) -> String {
        format!("ptpip:{}", self.addr)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::net::TcpListener;

    /// Issue 20, D11: a camera that trickles a packet a byte at a time, each byte well within
    /// any read timeout, is cut off at the packet's deadline, not after the whole packet.
    #[test]
    fn a_trickled_packet_ends_at_its_deadline() {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = listener.local_addr().unwrap();
        let camera = std::thread::spawn(move || {
            let (mut s, _) = listener.accept().unwrap();
            // A 64-byte packet, one byte every 50 ms: 3.2 s in all.
            let packet = Packet::new(ty::OPERATION_RESPONSE, vec![0u8; 56]).to_bytes();
            for b in packet {
                if s.write_all(&[b]).is_err() {
                    return;
                }
                std::thread::sleep(Duration::from_millis(50));
            }
        });
        let stream = TcpStream::connect(addr).unwrap();
        let start = Instant::now();
        let Err(e) = read_packet_by(&stream, start + Duration::from_millis(400)) else {
            panic!("a packet trickled for 3.2 s was read by a 0.4 s deadline");
        };
        let took = start.elapsed();
        assert!(matches!(e, PtpError::Io(_)), "{e}");
        // Cut off near its deadline: far less than the 3.2 s the packet would take.
        assert!(took < Duration::from_secs(2), "{took:?}");
        drop(stream);
        camera.join().unwrap();
    }

    /// Issue 20, D13: a camera that accepts the connection and then says nothing is a
    /// handshake timeout that says what to check, not "Resource temporarily unavailable".
    #[test]
    fn a_silent_camera_is_a_handshake_timeout() {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = listener.local_addr().unwrap();
        let camera = std::thread::spawn(move || {
            let (s, _) = listener.accept().unwrap();
            std::thread::sleep(Duration::from_millis(600));
            drop(s);
        });
        let Err(e) =
            PtpIpTransport::connect(addr, Initiator::default(), Duration::from_millis(300))
        else {
            panic!("a silent camera was connected");
        };
        let text = e.to_string();
        assert!(matches!(e, PtpError::Handshake { .. }), "{text}");
        assert!(
            text.contains("InitCommandAck") && text.contains("PTP/IP (PC connection) mode"),
            "{text}"
        );
        camera.join().unwrap();
    }
}
