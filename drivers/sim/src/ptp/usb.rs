//! The simulated camera behind the in-memory USB pipe: the device side of annex D framing.

use std::thread;

use brdfd_ptp::container::{self, Header, Kind, HEADER_LEN};
use brdfd_ptp::transport::memory::{self, DevicePipe, FromDevice, HostPipe, ToDevice};
use brdfd_ptp::transport::usb::{class_request, PipeError};

use super::{Reply, Responder, SharedResponder, WireFault};

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
    let mut buf: Vec<u8> = Vec::new();
    let mut pending_op: Option<brdfd_ptp::container::Message> = None;
    while let Ok(msg) = dev.from_host.recv() {
        match msg {
            ToDevice::Control {
                request,
                data: _,
                reply,
            } => {
                let answer = match request {
                    class_request::DEVICE_RESET => {
                        responder.lock().unwrap().reset();
                        buf.clear();
                        pending_op = None;
                        Vec::new()
                    }
                    // Length 4, code OK.
                    class_request::GET_DEVICE_STATUS => vec![4, 0, 0x01, 0x20],
                    class_request::CANCEL => {
                        buf.clear();
                        pending_op = None;
                        Vec::new()
                    }
                    _ => {
                        let _ = reply.send(Err(PipeError::Stall));
                        continue;
                    }
                };
                let _ = reply.send(Ok(answer));
            }
            ToDevice::ClearHalt(_) => {}
            ToDevice::Bulk(bytes) => {
                buf.extend_from_slice(&bytes);
                // Whole containers only; a zero-length packet adds nothing.
                while buf.len() >= HEADER_LEN {
                    let h = match Header::parse(&buf[..HEADER_LEN]) {
                        Ok(h) => h,
                        Err(e) => {
                            tracing::warn!("simulated camera: bad container from host: {e}");
                            buf.clear();
                            break;
                        }
                    };
                    if buf.len() < h.length as usize {
                        break;
                    }
                    let c: Vec<u8> = buf.drain(..h.length as usize).collect();
                    let payload = &c[HEADER_LEN..];
                    let reply = match (h.kind, pending_op.take()) {
                        (Kind::Command, _) => {
                            let Ok(m) = container::decode_message(&h, payload) else {
                                continue;
                            };
                            if Responder::expects_data_out(m.code) {
                                pending_op = Some(m);
                                continue;
                            }
                            (responder.lock().unwrap().handle(&m, None), m)
                        }
                        (Kind::Data, Some(m)) => {
                            (responder.lock().unwrap().handle(&m, Some(payload)), m)
                        }
                        _ => continue,
                    };
                    if !send_reply(&dev, reply.0, reply.1.code) {
                        return;
                    }
                }
            }
        }
    }
}

/// Sends data phase, response and events; false when the host is gone.
fn send_reply(dev: &DevicePipe, r: Reply, code: u16) -> bool {
    if let Some(d) = r.delay {
        thread::sleep(d);
    }
    let tid = r.response.tid;
    let send = |t: Vec<u8>| dev.bulk_in.send(FromDevice::Transfer(t)).is_ok();
    match r.fault {
        Some(WireFault::Silence) => return true,
        Some(WireFault::HaltBulkIn) => {
            let _ = dev.bulk_in.send(FromDevice::Fail(PipeError::Stall));
        }
        _ => {}
    }
    if let Some(data) = &r.data {
        let mut c = container::encode_header(Kind::Data, code, tid, data.len());
        c.extend_from_slice(data);
        let limit = match r.fault {
            Some(WireFault::DropAfter(n)) => Some(HEADER_LEN + n),
            _ => None,
        };
        let end = limit.unwrap_or(c.len()).min(c.len());
        for chunk in c[..end].chunks(TRANSFER) {
            if !send(chunk.to_vec()) {
                return false;
            }
        }
        if limit.is_some() {
            // The camera dropped off the bus mid-transfer.
            let _ = dev
                .bulk_in
                .send(FromDevice::Fail(PipeError::Other("LIBUSB_ERROR_IO".into())));
            return true;
        }
        if c.len().is_multiple_of(MAX_PACKET) && !send(Vec::new()) {
            return false;
        }
    }
    let mut resp = container::encode_message(Kind::Response, &r.response);
    if r.fault == Some(WireFault::CorruptResponse) {
        resp[..4].copy_from_slice(&7u32.to_le_bytes());
    }
    if !send(resp) {
        return false;
    }
    for e in &r.events {
        let _ = dev
            .interrupt
            .send(FromDevice::Transfer(container::encode_message(
                Kind::Event,
                e,
            )));
    }
    true
}
