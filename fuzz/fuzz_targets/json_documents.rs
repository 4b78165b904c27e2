//! JSON from outside: a capture plan as a client POSTs it, a session manifest and a result's
//! `coefficients.json` read back from disk, and the THETA's answers (`/osc/info`, `/osc/state`, command results).
#![no_main]
#[path = "allocation_limit.rs"]
mod allocation_limit;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(plan) = serde_json::from_slice::<brdfd_rig::Plan>(data) {
        let _ = plan.validate();
    }
    let _ = serde_json::from_slice::<brdfd_rig::session::Manifest>(data);
    if let Ok(result) = serde_json::from_slice::<brdfd_report::results::StoredResult>(data) {
        let _ = result.coefficient_values();
        let _ = result.chosen_lobe();
        // A split's triangles, as `brdfd render --coefficients` paints them.
        if let Some(m) = &result.materials {
            if let Some(t) = &m.triangles {
                let _ = brdfd_report::materials::painted(t, m.parts.len());
            }
        }
    }
    let _ = serde_json::from_slice::<brdfd_theta::osc::Info>(data);
    let _ = serde_json::from_slice::<brdfd_theta::osc::StateResponse>(data);
    if let Ok(command) = serde_json::from_slice::<brdfd_theta::osc::Command>(data) {
        let _ = command.file_urls();
        let _ = command.options();
    }
});
