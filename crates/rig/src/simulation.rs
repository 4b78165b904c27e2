//! The seam between the rig and its simulator. A simulated rig's devices are simulators that
//! speak the real protocols on loopback, and its stage is a virtual bench that renders what
//! they photograph. Both live in a crate above this one (`brdfd-simrig`), so that nothing
//! here imports the simulator's renderer: the rig opens the simulators' devices through the
//! code that opens hardware, and asks the bench for what a real bench's hands would do
//! ([`Stage`]).
//!
//! A program that offers the simulated rig provides its [`Simulator`] once, at start
//! ([`provide`]), as a program sets its logger: the rig asks for it only when a rig file says
//! `simulated = true`, and a program without one refuses such a rig in words.

use std::sync::OnceLock;

use brdfd_core::geometry::SceneGeometry;

use crate::config::Rig;
use crate::devices::Planned;
use crate::error::{refuse, Result};
use crate::flow::Context;
use crate::pose::OnBench;
use crate::Plan;

pub use crate::stage::{Judgement, Stage};

/// What starts a simulated rig.
pub trait Simulator: Send + Sync {
    /// Starts the simulators the rig's `[simulation]` table names, with nothing in front of
    /// the cameras.
    fn start(&self, rig: &Rig) -> Result<Box<dyn SimulatedRig>>;

    /// Refuses a plan whose scene the simulator cannot show: a material it cannot render, or
    /// a light map (the plan's `env`) it cannot read. Checked before a session exists, so
    /// that a typo leaves nothing behind (a session that failed on it would fail the same
    /// way on every resume).
    fn check_scene(&self, plan: &Plan) -> Result<()>;
}

/// A simulated rig, started: its devices, the time they spent, and the bench in front of them.
pub trait SimulatedRig: Send + Sync {
    /// The simulators as the rig's devices: each opened by the code that opens hardware,
    /// through the selector a bench would give it.
    fn devices(&self) -> Vec<Planned>;

    /// Seconds the simulated devices have spent on their own work so far (rendering scenes,
    /// the cameras' modelled exposures): the simulated world's time, not brdfd's.
    fn device_seconds(&self) -> f64;

    /// A capture's stage: the virtual bench with the plan's material on it.
    fn stage(&self) -> Box<dyn Stage>;

    /// Puts a Lambertian target of `albedo` where `scene` (as the rig believes it) stands,
    /// under the studio light: what a light calibration photographs.
    fn show_target(&self, cx: &Context, scene: &SceneGeometry, albedo: [f64; 3]) -> Result<()>;

    /// Puts `on_bench` in front of the cameras, turned `turn_deg` on the turntable, under the
    /// studio light: what a pose calibration photographs.
    fn show_for_pose(&self, cx: &Context, on_bench: OnBench, turn_deg: f64) -> Result<()>;
}

static SIMULATOR: OnceLock<Box<dyn Simulator>> = OnceLock::new();

/// Gives the rig its simulator, for the whole program; a second call changes nothing.
pub fn provide(simulator: Box<dyn Simulator>) {
    let _ = SIMULATOR.set(simulator);
}

/// The program's simulator, for a rig file that says `simulated = true`.
pub(crate) fn simulator() -> Result<&'static dyn Simulator> {
    match SIMULATOR.get() {
        Some(s) => Ok(s.as_ref()),
        None => refuse!(
            "this program has no simulated rig: the rig file says `simulated = true`; run it with brdfd, or name real devices"
        ),
    }
}
