//! A PTP/IP stream as a camera on the network sends it: packets read one after another until
//! the bytes run out or one is malformed, each decoded as the client would.
#![no_main]
#[path = "allocation_limit.rs"]
mod allocation_limit;
use brdfd_ptp::transport::ptpip::read_packet;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let mut stream = std::io::Cursor::new(data);
    while let Ok(packet) = read_packet(&mut stream) {
        for skip in [0, 4] {
            let _ = packet.message(skip);
        }
    }
});
