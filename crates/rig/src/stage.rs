//! The hands on the bench: what puts the sample in front of the cameras, turns it for each
//! view, and judges the estimate against what it knows of the truth. The capture flow asks
//! them through [`Stage`] and has no other knowledge of what stands on the bench.
//!
//! - On a real bench ([`Hands`]) the operator has placed the object and the turntable turns
//!   it, so there is nothing to do and no truth to judge by.
//! - On the simulated rig the stage is the virtual bench (`brdfd-simrig`, through
//!   [`crate::simulation`]): it renders the material the plan names, shows each view to the
//!   simulated cameras, and relights the estimate against the material.

use brdfd_core::basis::Basis;
use brdfd_core::bivariate::Bivariate;
use brdfd_core::envmap::EnvMap;
use brdfd_core::estimate::Estimate;

use super::flow::{Context, Phases};
use super::settings::CaptureSettings;
use crate::error::Result;

/// The bench's hands, as the capture flow asks for them: what puts the sample in front of the
/// cameras, turns it for each view, and judges the estimate against what it knows of the
/// truth. A real bench's do nothing and know no truth; the simulated rig's are its virtual
/// bench ([`crate::simulation`]).
pub trait Stage {
    /// Puts the sample on the bench before anything is shot.
    fn place(
        &mut self,
        cx: &Context,
        s: &CaptureSettings,
        basis: &Basis,
        phases: &mut Phases,
    ) -> Result<()>;

    /// A line on the measured light against the light the stage knows is there, if it knows.
    fn light_note(&self, measured: &EnvMap) -> Option<String>;

    /// Shows the sample turned to `deg` to the object camera, before its view is shot (the
    /// turntable has already turned to it).
    fn show(&mut self, cx: &Context, deg: f64) -> Result<()>;

    /// What the stage knows of the truth, set beside the estimate.
    fn judge(
        &mut self,
        cx: &Context,
        basis: &Basis,
        est: &Estimate,
        phases: &mut Phases,
    ) -> Result<Judgement>;
}

/// The estimate judged against the truth, where the stage knows it.
#[derive(Default)]
pub struct Judgement {
    /// The truth projected on the basis, beside a basis estimate's coefficients.
    pub coefficients: Option<Vec<f64>>,
    /// The estimate's relight error against the truth, and the light it was relit under.
    pub relight: Option<(f64, String)>,
    /// The true BRDF, which the report overlays on the estimate's slices.
    pub brdf: Option<Bivariate>,
}

/// A real bench: the operator placed the object, and the turntable turns it.
pub(super) struct Hands;

impl Stage for Hands {
    fn place(&mut self, _: &Context, _: &CaptureSettings, _: &Basis, _: &mut Phases) -> Result<()> {
        Ok(())
    }

    fn light_note(&self, _: &EnvMap) -> Option<String> {
        None
    }

    fn show(&mut self, _: &Context, _: f64) -> Result<()> {
        Ok(())
    }

    fn judge(&mut self, _: &Context, _: &Basis, _: &Estimate, _: &mut Phases) -> Result<Judgement> {
        Ok(Judgement::default())
    }
}

/// The stage of the rig `cx` runs on: the simulated rig's virtual bench, or a real bench's
/// hands. The one place the flow's composition looks at which rig it has.
pub(super) fn of(cx: &Context) -> Box<dyn Stage> {
    match &cx.devices.sim {
        Some(sim) => sim.stage(),
        None => Box::new(Hands),
    }
}
