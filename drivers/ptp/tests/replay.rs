//! A real Nikon D5500 talking PTP over USB (`shared/data/ptp/nikon-d5500-capture.pcapng`,
//! USBPcap): our codec must read every container it sent, and our capture flow, run against
//! the recording, must issue requests the camera answered and download the same image.

use std::collections::VecDeque;
use std::path::PathBuf;
use std::time::Duration;

use brdfd_ptp::codes::op;
use brdfd_ptp::container::{self, Kind};
use brdfd_ptp::dataset::{decode_nikon_events, DeviceInfo, DevicePropDesc, ObjectInfo, Value};
use brdfd_ptp::transport::usb::{BulkPipe, Endpoint, PipeError, UsbTransport};
use brdfd_ptp::{Camera, CaptureOptions, Timeouts};

fn recording() -> Option<Vec<u8>> {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/ptp/nikon-d5500-capture.pcapng");
    match std::fs::read(&p) {
        Ok(b) => Some(b),
        Err(_) => {
            eprintln!(
                "skipping: shared/data/ptp/nikon-d5500-capture.pcapng is missing (CI has it)"
            );
            None
        }
    }
}

/// Bulk transfers from a USBPcap pcapng: (endpoint address, payload), in capture order.
fn bulk_transfers(pcap: &[u8]) -> Vec<(u8, Vec<u8>)> {
    let u32_at = |o: usize| u32::from_le_bytes(pcap[o..o + 4].try_into().unwrap());
    let mut out = Vec::new();
    let mut off = 0;
    while off + 12 <= pcap.len() {
        let (ty, len) = (u32_at(off), u32_at(off + 4) as usize);
        assert!(
            len >= 12 && off + len <= pcap.len(),
            "pcapng block at {off}"
        );
        if ty == 1 {
            let link = u16::from_le_bytes([pcap[off + 8], pcap[off + 9]]);
            assert_eq!(link, 249, "USBPcap link type");
        }
        if ty == 6 {
            let cap = u32_at(off + 20) as usize;
            let pkt = &pcap[off + 28..off + 28 + cap];
            let header_len = u16::from_le_bytes([pkt[0], pkt[1]]) as usize;
            let (endpoint, transfer) = (pkt[21], pkt[22]);
            if transfer == 3 && pkt.len() > header_len {
                out.push((endpoint, pkt[header_len..].to_vec()));
            }
        }
        off += len;
    }
    out
}

/// One recorded transaction: the host's command and data containers, and the device's
/// bulk-in transfers.
struct Recorded {
    command: container::Message,
    host_data: Option<Vec<u8>>,
    device: Vec<Vec<u8>>,
}

fn transactions(pcap: &[u8]) -> Vec<Recorded> {
    let mut out: Vec<Recorded> = Vec::new();
    for (ep, t) in bulk_transfers(pcap) {
        if ep & 0x80 == 0 {
            let (h, p) = container::decode(&t).expect("host container");
            match h.kind {
                Kind::Command => out.push(Recorded {
                    command: container::decode_message(&h, p).unwrap(),
                    host_data: None,
                    device: Vec::new(),
                }),
                Kind::Data => out.last_mut().unwrap().host_data = Some(p.to_vec()),
                k => panic!("host sent {k:?}"),
            }
        } else if let Some(last) = out.last_mut() {
            last.device.push(t);
        }
    }
    out
}

/// The device side of a transaction, as containers (data phases reassembled).
fn containers(device: &[Vec<u8>]) -> Vec<(container::Header, Vec<u8>)> {
    let bytes: Vec<u8> = device.concat();
    let mut out = Vec::new();
    let mut at = 0;
    while at < bytes.len() {
        let (h, p) = container::decode(&bytes[at..]).expect("device container");
        out.push((h, p.to_vec()));
        at += h.length as usize;
    }
    out
}

#[test]
fn every_recorded_container_decodes() {
    let Some(pcap) = recording() else { return };
    let tx = transactions(&pcap);
    assert!(tx.len() > 30, "{} transactions", tx.len());
    let mut seen = std::collections::BTreeSet::new();
    for t in &tx {
        let c = containers(&t.device);
        let (resp_h, resp_p) = c.last().unwrap();
        assert_eq!(resp_h.kind, Kind::Response);
        assert_eq!(resp_h.tid, t.command.tid);
        container::decode_message(resp_h, resp_p).unwrap();
        let ok = resp_h.code == brdfd_ptp::codes::rc::OK;
        // A failed request may still carry an empty data phase (GetObjectInfo of an empty
        // SDRAM slot does): only decode data the camera vouched for.
        let data = c
            .iter()
            .find(|(h, _)| h.kind == Kind::Data && ok)
            .map(|(_, p)| p.as_slice());
        seen.insert(t.command.code);
        match (t.command.code, data) {
            (op::GET_DEVICE_INFO, Some(d)) => {
                let di = DeviceInfo::decode(d).unwrap();
                assert_eq!(di.manufacturer, "Nikon Corporation");
                assert_eq!(di.model, "D5500");
                // Newer Nikons announce the MTP extension, not Nikon's 0xA.
                assert_eq!(di.vendor_extension_id, 0x6);
                assert!(di.supports(op::NIKON_INITIATE_CAPTURE_REC_IN_SDRAM));
                assert!(di.supports(op::NIKON_GET_EVENT) && di.supports(op::NIKON_DEVICE_READY));
            }
            (op::GET_DEVICE_PROP_DESC, Some(d)) => {
                let desc = DevicePropDesc::decode(d).unwrap();
                assert_eq!(desc.code as u32, t.command.param(0));
                assert!(!desc.allowed().is_empty());
            }
            (op::GET_OBJECT_INFO, Some(d)) => {
                let oi = ObjectInfo::decode(d).unwrap();
                assert_eq!(oi.compressed_size, 1_325_002);
                assert!(oi.filename.ends_with(".JPG"), "{}", oi.filename);
            }
            (op::GET_OBJECT, Some(d)) => {
                assert_eq!(d.len(), 1_325_002);
                assert_eq!(&d[..2], [0xFF, 0xD8]);
            }
            (op::NIKON_GET_EVENT, Some(d)) => {
                decode_nikon_events(d).unwrap();
            }
            (op::SET_DEVICE_PROP_VALUE, None) => {
                // Our encoding of the value the host sent is byte-identical.
                let sent = t.host_data.as_ref().unwrap();
                let v = Value::from_bytes(sent, brdfd_ptp::codes::datatype::UINT16).unwrap();
                assert_eq!(v.to_bytes(brdfd_ptp::codes::datatype::UINT16), *sent);
            }
            _ => {}
        }
    }
    for code in [
        op::OPEN_SESSION,
        op::GET_DEVICE_INFO,
        op::NIKON_INITIATE_CAPTURE_REC_IN_SDRAM,
        op::NIKON_DEVICE_READY,
        op::GET_OBJECT,
    ] {
        assert!(seen.contains(&code), "{code:#06x} in the recording");
    }
}

/// Plays the camera's side of the recording. Each command we send must match (code and
/// parameters) a later recorded command; the camera's recorded answer is replayed with our
/// transaction id. Requests the camera never answered fail the test.
struct ReplayPipe {
    tx: Vec<Recorded>,
    cursor: usize,
    out: VecDeque<Vec<u8>>,
    sent: Vec<u8>,
    issued: std::sync::Arc<std::sync::Mutex<Vec<u16>>>,
}

impl BulkPipe for ReplayPipe {
    fn max_packet(&self) -> usize {
        512
    }
    fn write(&mut self, data: &[u8], _: Duration) -> Result<usize, PipeError> {
        self.sent.extend_from_slice(data);
        while let Ok((h, p)) = container::decode(&self.sent) {
            let len = h.length as usize;
            if h.kind == Kind::Command {
                let m = container::decode_message(&h, p).unwrap();
                let found = self.tx[self.cursor..]
                    .iter()
                    .position(|t| t.command.code == m.code && t.command.params == m.params)
                    .unwrap_or_else(|| {
                        panic!("the camera never answered {:#06x} {:x?}", m.code, m.params)
                    });
                let t = &self.tx[self.cursor + found];
                self.cursor += found + 1;
                self.issued.lock().unwrap().push(m.code);
                // Rewrite the transaction id in each container header of the answer.
                let mut bytes = t.device.concat();
                let mut at = 0;
                while at < bytes.len() {
                    let l = u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap()) as usize;
                    bytes[at + 8..at + 12].copy_from_slice(&m.tid.to_le_bytes());
                    at += l;
                }
                let mut at = 0;
                for d in &t.device {
                    self.out.push_back(bytes[at..at + d.len()].to_vec());
                    at += d.len();
                }
            }
            self.sent.drain(..len);
        }
        Ok(data.len())
    }
    fn read(&mut self, ep: Endpoint, buf: &mut [u8], _: Duration) -> Result<usize, PipeError> {
        if ep == Endpoint::Interrupt {
            return Err(PipeError::Timeout);
        }
        let t = self.out.pop_front().ok_or(PipeError::Timeout)?;
        assert!(t.len() <= buf.len());
        buf[..t.len()].copy_from_slice(&t);
        Ok(t.len())
    }
    fn clear_halt(&mut self, _: Endpoint) -> Result<(), PipeError> {
        Ok(())
    }
    fn class_request(&mut self, _: u8, _: &[u8], _: usize) -> Result<Vec<u8>, PipeError> {
        Ok(vec![4, 0, 1, 0x20])
    }
    fn describe(&self) -> String {
        "replay of a Nikon D5500".into()
    }
}

#[test]
fn nikon_capture_flow_replays_against_a_real_d5500() {
    let Some(pcap) = recording() else { return };
    let pipe = ReplayPipe {
        tx: transactions(&pcap),
        cursor: 0,
        out: VecDeque::new(),
        sent: Vec::new(),
        issued: Default::default(),
    };
    let issued = pipe.issued.clone();
    let t = Timeouts {
        poll: Duration::ZERO,
        ..Timeouts::default()
    };
    let mut cam = Camera::open(Box::new(UsbTransport::new(pipe)), t).unwrap();
    assert!(cam.is_nikon());
    let shot = cam
        .capture(&CaptureOptions::default(), &mut |_, _, _| {})
        .unwrap();
    assert_eq!(
        shot.handle, 0x2B00_0001,
        "the handle from ObjectAddedInSdram"
    );
    assert_eq!(shot.data.len(), 1_325_002);
    assert_eq!(
        &shot.data[shot.data.len() - 2..],
        [0xFF, 0xD9],
        "the whole JPEG"
    );
    let mut want = vec![
        op::OPEN_SESSION,
        op::GET_DEVICE_INFO,
        op::NIKON_INITIATE_CAPTURE_REC_IN_SDRAM,
    ];
    want.extend([op::NIKON_GET_EVENT; 7]);
    want.extend([op::NIKON_DEVICE_READY, op::GET_OBJECT_INFO, op::GET_OBJECT]);
    assert_eq!(*issued.lock().unwrap(), want);
}
