//! Mesh files a rig names (`[geometry.shape] file`): OBJ, STL (ASCII and binary) and PLY, read
//! and checked as a capture reads them. The first byte picks the extension.
#![no_main]
#[path = "allocation_limit.rs"]
mod allocation_limit;
#[path = "input_file.rs"]
mod input_file;

use brdfd_core::mesh::{Mesh, Placement, Units};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Some((&which, rest)) = data.split_first() else {
        return;
    };
    let ext = ["obj", "stl", "ply"][which as usize % 3];
    let path = input_file::write(ext, rest);
    let placement = Placement {
        units: Units::M,
        rotation_deg: [0.0; 3],
        position: [0.0; 3],
    };
    let _ = Mesh::read(&path, &placement);
});
