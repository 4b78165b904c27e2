//! A USB camera that answers brdfd's PTP client with whatever the fuzzer says: the bytes are
//! the camera's bulk-in transfers, framed by brdfd's USB transport (annex D containers, data
//! phases over several transfers, zero-length packets, a response in the data phase's
//! transfer, a halted endpoint). The client opens a session, reads DeviceInfo, lists
//! storage, reads an ObjectInfo and downloads the object with a size the input also gives,
//! as `brdfd ptp capture` would; a download that fails on the link resets the camera, opens
//! a new session and tries again. Mirrors `ptpip_camera`, over USB.
//!
//! The input: the object's size (u64, little-endian), then transfers, each a u16
//! little-endian length and that many bytes; length 0xFFFF is the camera halting bulk-in.
//! The camera is a `BulkPipe` of its own rather than the tests' in-memory pipe
//! (`transport::memory`), which needs a device thread: no thread, no channel, and each
//! execution takes microseconds. OpenSession is the harness's to answer (OK, as the
//! handshake is in `ptpip_camera`): the engine sleeps 200 ms on a busy OpenSession, and the
//! recovery's new session then needs no bytes of the input.
#![no_main]
#[path = "allocation_limit.rs"]
mod allocation_limit;

use std::collections::VecDeque;
use std::time::Duration;

use brdfd_ptp::codes::{op, rc};
use brdfd_ptp::container::{self, Header, Kind, Message, HEADER_LEN};
use brdfd_ptp::transport::usb::{class_request, BulkPipe, Endpoint, PipeError, UsbTransport};
use brdfd_ptp::{Camera, Timeouts};
use libfuzzer_sys::fuzz_target;

/// The transfer length that stands for a halted bulk-in endpoint.
const STALL: u16 = 0xFFFF;

enum Transfer {
    Bytes(Vec<u8>),
    Stall,
}

struct FuzzCamera {
    /// The harness's answers (OpenSession), sent before the input's next transfer.
    ours: VecDeque<Vec<u8>>,
    /// The input's transfers, in order.
    theirs: VecDeque<Transfer>,
}

fn transfers(mut input: &[u8]) -> VecDeque<Transfer> {
    let mut out = VecDeque::new();
    while input.len() >= 2 {
        let len = u16::from_le_bytes([input[0], input[1]]);
        input = &input[2..];
        if len == STALL {
            out.push_back(Transfer::Stall);
            continue;
        }
        let (transfer, rest) = input.split_at((len as usize).min(input.len()));
        out.push_back(Transfer::Bytes(transfer.to_vec()));
        input = rest;
    }
    out
}

impl BulkPipe for FuzzCamera {
    fn max_packet(&self) -> usize {
        512
    }

    fn write(&mut self, data: &[u8], _: Duration) -> Result<usize, PipeError> {
        // The transport writes each command container in one transfer.
        if let Ok(h) = Header::parse(&data[..data.len().min(HEADER_LEN)]) {
            if h.kind == Kind::Command && h.code == op::OPEN_SESSION {
                let ok = Message::new(rc::OK, h.tid, &[]);
                self.ours
                    .push_back(container::encode_message(Kind::Response, &ok));
            }
        }
        Ok(data.len())
    }

    fn read(&mut self, ep: Endpoint, buf: &mut [u8], _: Duration) -> Result<usize, PipeError> {
        if ep == Endpoint::Interrupt {
            return Err(PipeError::Timeout);
        }
        let transfer = match self.ours.pop_front() {
            Some(t) => t,
            None => match self.theirs.pop_front() {
                Some(Transfer::Bytes(t)) => t,
                Some(Transfer::Stall) => return Err(PipeError::Stall),
                // Nothing more to say: the camera is silent, and the read times out at once.
                None => return Err(PipeError::Timeout),
            },
        };
        // The transport reads a megabyte at a time; a transfer is at most 64 KiB.
        let n = transfer.len().min(buf.len());
        buf[..n].copy_from_slice(&transfer[..n]);
        Ok(n)
    }

    fn clear_halt(&mut self, _: Endpoint) -> Result<(), PipeError> {
        Ok(())
    }

    fn class_request(&mut self, request: u8, _: &[u8], _: usize) -> Result<Vec<u8>, PipeError> {
        // A camera that resets at once and is ready after it: Get Device Status answers OK
        // (a busy one would cost the transport 50 ms a poll).
        Ok(match request {
            class_request::GET_DEVICE_STATUS => vec![4, 0, 0x01, 0x20],
            _ => Vec::new(),
        })
    }

    fn describe(&self) -> String {
        "usb:fuzz".into()
    }
}

fuzz_target!(|data: &[u8]| {
    if data.len() < 8 {
        return;
    }
    let size = u64::from_le_bytes(data[..8].try_into().unwrap());
    let camera = FuzzCamera {
        ours: VecDeque::new(),
        theirs: transfers(&data[8..]),
    };
    // No read waits (a silent camera times out at once); no busy retries, whose backoff
    // sleeps 20 ms and more.
    let timeouts = Timeouts {
        command: Duration::from_millis(300),
        data: Duration::from_millis(300),
        capture: Duration::from_millis(300),
        busy: Duration::ZERO,
        poll: Duration::from_millis(1),
    };
    if let Ok(mut camera) = Camera::open(Box::new(UsbTransport::new(camera)), timeouts) {
        let _ = camera.storage_ids();
        let _ = camera.object_info(1);
        let _ = camera.download(1, size, &mut |_, _| {});
    }
});
