//! A basis a user passes with --basis: its JSON header and its EXR of vectors. The first two
//! bytes say how long the header is.
#![no_main]
#[path = "allocation_limit.rs"]
mod allocation_limit;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if data.len() < 2 {
        return;
    }
    let n = (u16::from_le_bytes([data[0], data[1]]) as usize).min(data.len() - 2);
    let (json, exr) = data[2..].split_at(n);
    if let Ok(json) = std::str::from_utf8(json) {
        let _ = brdfd_core::basis::Basis::from_parts(json, exr, "fuzz basis");
    }
});
