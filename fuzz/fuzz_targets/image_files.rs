//! Files a user hands `brdfd estimate`: an environment map or a photo as OpenEXR or Radiance
//! HDR, and a MERL table. The first byte picks the extension the reader is given.
#![no_main]
#[path = "allocation_limit.rs"]
mod allocation_limit;
use std::sync::OnceLock;

use libfuzzer_sys::fuzz_target;

fn dir() -> &'static tempfile::TempDir {
    static DIR: OnceLock<tempfile::TempDir> = OnceLock::new();
    DIR.get_or_init(|| tempfile::tempdir().expect("a temporary folder"))
}

fuzz_target!(|data: &[u8]| {
    let Some((&which, rest)) = data.split_first() else {
        return;
    };
    let _ = brdfd_core::merl::MerlBrdf::from_bytes(rest, "fuzz.binary");
    let ext = if which % 2 == 0 { "exr" } else { "hdr" };
    let path = dir().path().join(format!("input.{ext}"));
    std::fs::write(&path, rest).expect("the temporary file is written");
    let _ = brdfd_core::envmap::EnvMap::load(&path);
    let _ = brdfd_core::raster::Raster::read_with_white(&path);
});
