//! A camera's RAW file as brdfd checks its TIFF structure before the decoder sees it (issue
//! 40): IFD chains, sizes, strips. The check must end, without a panic or a large allocation,
//! on any bytes. rawler itself is not fuzzed here: it panics on damaged files (which brdfd
//! catches), and runs in a child process bounded in memory and time (crates/radiometry).
#![no_main]
#[path = "allocation_limit.rs"]
mod allocation_limit;

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = brdfd_radiometry::tiff::check(data);
});
