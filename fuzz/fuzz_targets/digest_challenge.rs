//! A THETA's `WWW-Authenticate` Digest challenge, as bytes off the network.
#![no_main]
#[path = "allocation_limit.rs"]
mod allocation_limit;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = brdfd_theta::http::parse_challenge(data);
});
