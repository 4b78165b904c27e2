//! A camera's JPEG as the HDR merges read it: the DSLR's (EXIF exposure, then the pixels) and
//! the THETA's (its pose too).
#![no_main]
#[path = "allocation_limit.rs"]
mod allocation_limit;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = brdfd_radiometry::decode_jpeg(data, "fuzz.jpg");
    let _ = brdfd_radiometry::panorama::decode_frame(data, "fuzz.jpg");
});
