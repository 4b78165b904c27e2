//! A USB PTP container as a camera sends it: header, then parameters or data.
#![no_main]
#[path = "allocation_limit.rs"]
mod allocation_limit;
use brdfd_ptp::container;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok((header, payload)) = container::decode(data) {
        let _ = container::decode_message(&header, payload);
    }
});
