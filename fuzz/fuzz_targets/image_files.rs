//! Files a user hands `brdfd estimate`: an environment map or a photo as OpenEXR or Radiance
//! HDR, and a MERL table. The first byte picks the extension the reader is given.
#![no_main]
#[path = "allocation_limit.rs"]
mod allocation_limit;
#[path = "input_file.rs"]
mod input_file;

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Some((&which, rest)) = data.split_first() else {
        return;
    };
    let _ = brdfd_core::merl::MerlBrdf::from_bytes(rest, "fuzz.binary");
    let ext = if which % 2 == 0 { "exr" } else { "hdr" };
    let path = input_file::write(ext, rest);
    let _ = brdfd_core::envmap::EnvMap::load(&path);
    let _ = brdfd_core::raster::Raster::read_with_white(&path);
});
