//! A network camera that answers brdfd's PTP/IP client with whatever the fuzzer says: after
//! a valid handshake, the bytes are the camera's side of the command connection. The client
//! opens a session, reads DeviceInfo, lists storage, reads an ObjectInfo and downloads the
//! object with a size the input also gives, as `brdfd ptp capture` would. Device-declared
//! lengths (StartData, ObjectInfo) must not drive huge allocations (`allocation_limit.rs`).
#![no_main]
#[path = "allocation_limit.rs"]
mod allocation_limit;
use std::io::Write;
use std::net::TcpListener;
use std::time::{Duration, Instant};

use brdfd_ptp::transport::ptpip::{ty, Initiator, Packet, PtpIpTransport};
use brdfd_ptp::{Camera, Timeouts};
use libfuzzer_sys::fuzz_target;

fn ack(kind: u32) -> Vec<u8> {
    let mut body = Vec::new();
    if kind == ty::INIT_COMMAND_ACK {
        body.extend(1u32.to_le_bytes()); // connection number
        body.extend([7u8; 16]); // the camera's GUID
        body.extend("fuzz\0".encode_utf16().flat_map(u16::to_le_bytes));
        body.extend(0x0001_0000u32.to_le_bytes());
    } else {
        body.extend(1u32.to_le_bytes());
    }
    Packet::new(kind, body).to_bytes()
}

fuzz_target!(|data: &[u8]| {
    if data.len() < 8 {
        return;
    }
    let size = u64::from_le_bytes(data[..8].try_into().unwrap());
    let camera_says = data[8..].to_vec();
    let listener = TcpListener::bind("127.0.0.1:0").expect("a loopback port");
    let addr = listener.local_addr().unwrap();
    listener.set_nonblocking(true).unwrap();
    let peer = std::thread::spawn(move || {
        // The command connection, then the event connection, if the client gets that far.
        let mut streams: Vec<std::net::TcpStream> = Vec::new();
        let deadline = Instant::now() + Duration::from_millis(500);
        while streams.len() < 2 && Instant::now() < deadline {
            match listener.accept() {
                Ok((mut s, _)) => {
                    s.set_nonblocking(false).unwrap();
                    let _ = s.set_write_timeout(Some(Duration::from_secs(2)));
                    if streams.is_empty() {
                        let _ = s.write_all(&ack(ty::INIT_COMMAND_ACK));
                    } else {
                        let _ = s.write_all(&ack(ty::INIT_EVENT_ACK));
                        // The session's bytes once the client has both connections: a large
                        // input cannot hold up the handshake.
                        let _ = streams[0].write_all(&camera_says);
                    }
                    streams.push(s);
                }
                Err(_) => std::thread::sleep(Duration::from_micros(200)),
            }
        }
        // The camera has said everything: half-close, so that the client reads its bytes and
        // then EOF, and drain what the client sends until it hangs up (closing with unread
        // data would reset the connection and discard the bytes in flight).
        for s in &mut streams {
            let _ = s.shutdown(std::net::Shutdown::Write);
            let _ = s.set_read_timeout(Some(Duration::from_secs(2)));
        }
        for mut s in streams {
            let _ = std::io::copy(&mut s, &mut std::io::sink());
        }
    });
    let timeouts = Timeouts {
        command: Duration::from_millis(300),
        data: Duration::from_millis(300),
        capture: Duration::from_millis(300),
        busy: Duration::from_millis(100),
        poll: Duration::from_millis(1),
    };
    let link = PtpIpTransport::connect(addr, Initiator::default(), Duration::from_millis(300));
    if let Ok(link) = link {
        if let Ok(mut camera) = Camera::open(Box::new(link), timeouts) {
            let _ = camera.storage_ids();
            let _ = camera.object_info(1);
            let _ = camera.download(1, size, &mut |_, _| {});
        }
    }
    peer.join().unwrap();
});
