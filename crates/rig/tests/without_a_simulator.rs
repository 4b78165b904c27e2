//! A program built on the rig that provides no simulator (`brdfd_rig::simulation::provide`)
//! refuses a simulated rig in words, before anything starts. Its own process: the rig's unit
//! tests provide one.

use std::time::Duration;

use brdfd_rig::config::Rig;
use brdfd_rig::error::said;
use brdfd_rig::settings::CaptureSettings;
use brdfd_rig::{Devices, Plan};

#[test]
fn a_simulated_rig_is_refused_by_a_program_without_a_simulator() {
    let rig = Rig::simulated();
    let refused = |words: String| {
        assert!(
            words.contains("this program has no simulated rig")
                && words.contains("simulated = true"),
            "{words}"
        );
    };
    let Err(e) = Devices::start(&rig, Duration::from_secs(1)) else {
        panic!("a simulated rig started without a simulator");
    };
    refused(said(&e));
    let plan: Plan = serde_json::from_value(serde_json::json!({ "material": "gold" })).unwrap();
    let Err(e) = CaptureSettings::resolve(&plan, &rig) else {
        panic!("a simulated capture's settings resolved without a simulator");
    };
    refused(said(&e));
}
