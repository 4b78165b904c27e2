//! The TOML files a user writes: the daemon's settings, a rig and a material preset.
#![no_main]
#[path = "allocation_limit.rs"]
mod allocation_limit;
use brdfd_rig::config::{DaemonConfig, MaterialPreset, Rig};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let _ = DaemonConfig::parse("fuzz.toml", text);
    let _ = MaterialPreset::parse("fuzz.toml", text);
    if let Ok(rig) = Rig::parse("fuzz.toml", text) {
        let _ = rig.geometry.check();
    }
});
