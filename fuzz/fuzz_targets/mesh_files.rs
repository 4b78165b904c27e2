//! Mesh files a rig names (`[geometry.shape] file`): OBJ, STL (ASCII and binary) and PLY, read
//! and checked as a capture reads them. The first byte picks the extension.
#![no_main]
#[path = "allocation_limit.rs"]
mod allocation_limit;
use std::sync::OnceLock;

use brdfd_core::mesh::{Mesh, Placement, Units};
use libfuzzer_sys::fuzz_target;

fn dir() -> &'static tempfile::TempDir {
    static DIR: OnceLock<tempfile::TempDir> = OnceLock::new();
    DIR.get_or_init(|| tempfile::tempdir().expect("a temporary folder"))
}

fuzz_target!(|data: &[u8]| {
    let Some((&which, rest)) = data.split_first() else {
        return;
    };
    let ext = ["obj", "stl", "ply"][which as usize % 3];
    let path = dir().path().join(format!("input.{ext}"));
    std::fs::write(&path, rest).expect("the temporary file is written");
    let placement = Placement {
        units: Units::M,
        rotation_deg: [0.0; 3],
        position: [0.0; 3],
    };
    let _ = Mesh::read(&path, &placement);
});
