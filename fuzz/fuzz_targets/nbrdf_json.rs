//! An NBRDF file as `--nbrdf` reads it (`brdfd_core::nbrdf`): the neural-BRDF weights JSON,
//! its matrices checked for their shapes, then each material (the first few) evaluated in a
//! few directions, as the simulator's renderer and the rig's material check use it.
#![no_main]
#[path = "allocation_limit.rs"]
mod allocation_limit;
#[path = "input_file.rs"]
mod input_file;

use brdfd_core::brdf::IsotropicBrdf;
use brdfd_core::nbrdf::NbrdfSet;
use libfuzzer_sys::fuzz_target;

/// Light and view directions (normal +Z): head-on, grazing, mirror and off-mirror pairs, one
/// below the horizon.
const DIRECTIONS: [([f64; 3], [f64; 3]); 5] = [
    ([0.0, 0.0, 1.0], [0.0, 0.0, 1.0]),
    ([0.6, 0.0, 0.8], [-0.6, 0.0, 0.8]),
    ([0.6, 0.0, 0.8], [0.0, 0.6, 0.8]),
    ([0.999, 0.0, 0.0447], [-0.3, 0.5, 0.812]),
    ([0.0, 0.6, -0.8], [0.0, 0.0, 1.0]),
];

fuzz_target!(|data: &[u8]| {
    let path = input_file::write("json", data);
    let Ok(set) = NbrdfSet::read(&path) else {
        return;
    };
    let names = set.names();
    let _ = set.get("nickel");
    for name in names.iter().take(4) {
        let material = set.get(name).expect("a listed material is there");
        for (wi, wo) in DIRECTIONS {
            let rgb = material.eval_dirs(wi, wo);
            // Whatever the weights (NaN, huge), a BRDF value is a number, never below zero.
            assert!(rgb.iter().all(|v| *v >= 0.0), "{name}: {rgb:?}");
        }
        let _ = material.eval_angles(0.1, 0.7, 1.2);
    }
});
