//! The simulated camera behind the in-memory USB pipe: the device side of annex D framing.

use std::thread;

use brdfd_ptp::container::{self, Header, Kind, HEADER_LEN};
use brdfd_ptp::transport::memory::{self, DevicePipe, FromDevice, HostPipe, ToDevice};
use brdfd_ptp::transport::usb::{class_request, PipeError};

use super::{Reply, SharedResponder, WireFault};

/// Bytes per simulated bulk-in transfer (a data phase spans several, as on a real bus).
const TRANSFER: usize = 256 << 10;
pub const MAX_PACKET: usize = 512;

/// Plugs a simulated camera in: returns the host end of its pipe. The device thread ends
/// when the host end is dropped.
pub fn plug(responder: SharedResponder) -> HostPipe {
    let (host, device) = memory::pair(MAX_PACKET);
    thread::Builder::new()
        .name("sim-ptp-usb".into())
        .spawn(move || serve(device, responder))
        .expect("spawn simulator thread");
    host
}

fn serve(dev: DevicePipe, responder: SharedResponder) {
    let mut framing = Framing::default();
    while let Ok(msg) = dev.from_host.recv() {
        match msg {
            ToDevice::Control {
                request,
                data: _,
                reply,
            } => {
                let answer = framing.class_request(request, &responder);
                let _ = reply.send(answer.ok_or(PipeError::Stall));
            }
            ToDevice::ClearHalt(_) => {}
            ToDevice::Bulk(bytes) => {
                if !framing.bulk_out(&bytes, &responder, &dev) {
                    return;
                }
            }
        }
    }
}

/// Where the device side of the framing sends: the in-memory pipe's channels, or
/// FunctionFS's endpoint files ([`super::functionfs`]).
pub(crate) trait Endpoints {
    /// One bulk-in transfer; false when the host is gone.
    fn bulk_in(&self, transfer: Vec<u8>) -> bool;
    /// A failed bulk-in, for the injected wire faults: a stall (a real bus halts the
    /// endpoint), or the camera dropping off the bus (a real bus ignores it: unbind the
    /// gadget instead).
    fn fail_bulk_in(&self, e: PipeError);
    /// One transfer on the interrupt endpoint (an event).
    fn interrupt_in(&self, transfer: Vec<u8>);
}

impl Endpoints for DevicePipe {
    fn bulk_in(&self, transfer: Vec<u8>) -> bool {
        self.bulk_in.send(FromDevice::Transfer(transfer)).is_ok()
    }

    fn fail_bulk_in(&self, e: PipeError) {
        let _ = self.bulk_in.send(FromDevice::Fail(e));
    }

    fn interrupt_in(&self, transfer: Vec<u8>) {
        let _ = self.interrupt.send(FromDevice::Transfer(transfer));
    }
}

/// The device side of annex D: containers reassembled from bulk-out, answered by the
/// responder, the answers sent on bulk-in and the events on the interrupt endpoint; and the
/// class requests on the control endpoint.
#[derive(Default)]
pub(crate) struct Framing {
    buf: Vec<u8>,
    /// An operation whose data phase is still to come from the host.
    pending_op: Option<brdfd_ptp::container::Message>,
}

impl Framing {
    /// A class request (annex D.5): its answer (empty for none), or `None` to stall.
    pub fn class_request(&mut self, request: u8, responder: &SharedResponder) -> Option<Vec<u8>> {
        match request {
            class_request::DEVICE_RESET => {
                responder.lock().unwrap().reset();
                self.buf.clear();
                self.pending_op = None;
                Some(Vec::new())
            }
            // Length 4, code OK.
            class_request::GET_DEVICE_STATUS => Some(vec![4, 0, 0x01, 0x20]),
            class_request::CANCEL => {
                self.buf.clear();
                self.pending_op = None;
                Some(Vec::new())
            }
            _ => None,
        }
    }

    /// Bytes the host sent on bulk-out; false when the host is gone.
    pub fn bulk_out(
        &mut self,
        bytes: &[u8],
        responder: &SharedResponder,
        ep: &impl Endpoints,
    ) -> bool {
        self.buf.extend_from_slice(bytes);
        // Whole containers only; a zero-length packet adds nothing.
        while self.buf.len() >= HEADER_LEN {
            let h = match Header::parse(&self.buf[..HEADER_LEN]) {
                Ok(h) => h,
                Err(e) => {
                    tracing::warn!("simulated camera: bad container from host: {e}");
                    self.buf.clear();
                    break;
                }
            };
            if self.buf.len() < h.length as usize {
                break;
            }
            let c: Vec<u8> = self.buf.drain(..h.length as usize).collect();
            let payload = &c[HEADER_LEN..];
            let reply = match (h.kind, self.pending_op.take()) {
                (Kind::Command, _) => {
                    let Ok(m) = container::decode_message(&h, payload) else {
                        continue;
                    };
                    if responder.lock().unwrap().expects_data_out(m.code) {
                        self.pending_op = Some(m);
                        continue;
                    }
                    (responder.lock().unwrap().handle(&m, None), m)
                }
                (Kind::Data, Some(m)) => (responder.lock().unwrap().handle(&m, Some(payload)), m),
                _ => continue,
            };
            if !send_reply(ep, reply.0, reply.1.code) {
                return false;
            }
        }
        true
    }
}

/// Sends data phase, response and events; false when the host is gone.
fn send_reply(ep: &impl Endpoints, r: Reply, code: u16) -> bool {
    if let Some(d) = r.delay {
        thread::sleep(d);
    }
    let tid = r.response.tid;
    match r.fault {
        Some(WireFault::Silence) => return true,
        Some(WireFault::Hangup) => {
            ep.fail_bulk_in(PipeError::Gone);
            return true;
        }
        _ => {}
    }
    if let Some(data) = &r.data {
        let mut c = container::encode_header(Kind::Data, code, tid, data.len());
        c.extend_from_slice(data);
        // Where the transfer ends early, and how: the camera drops off the bus, or halts
        // the endpoint and abandons the transaction (no response follows either way).
        let cut = match r.fault {
            Some(WireFault::DropAfter(n)) => Some((n, PipeError::Other("LIBUSB_ERROR_IO".into()))),
            Some(WireFault::HaltBulkIn(n)) => Some((n, PipeError::Stall)),
            _ => None,
        };
        let end = cut
            .as_ref()
            .map_or(c.len(), |(n, _)| HEADER_LEN + n)
            .min(c.len());
        for chunk in c[..end].chunks(TRANSFER) {
            if !ep.bulk_in(chunk.to_vec()) {
                return false;
            }
        }
        if let Some((_, e)) = cut {
            ep.fail_bulk_in(e);
            return true;
        }
        if c.len().is_multiple_of(MAX_PACKET) && !ep.bulk_in(Vec::new()) {
            return false;
        }
    }
    let mut resp = container::encode_message(Kind::Response, &r.response);
    if r.fault == Some(WireFault::CorruptResponse) {
        resp[..4].copy_from_slice(&7u32.to_le_bytes());
    }
    if !ep.bulk_in(resp) {
        return false;
    }
    for e in &r.events {
        ep.interrupt_in(container::encode_message(Kind::Event, e));
    }
    true
}
