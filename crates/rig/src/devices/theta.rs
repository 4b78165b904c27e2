//! A RICOH THETA as the rig's light probe, on either of its links (the THETA Web API over
//! HTTP, or PTP over USB): the driver keeps the link a private matter of [`Theta`].

use brdfd_theta::{BracketPlan, Frame, Theta};

use crate::error::DeviceError;
use crate::roles::{LightProbe, RigDevice};
use crate::Device;

impl Device for Theta {
    fn identity(&self) -> String {
        self.describe()
    }
    fn keep_alive(&mut self) -> Result<(), DeviceError> {
        Ok(Theta::keep_alive(self)?)
    }
}

impl RigDevice for Theta {
    fn light_probe(&mut self) -> Option<&mut (dyn LightProbe + 'static)> {
        Some(self)
    }
}

impl LightProbe for Theta {
    fn prepare(&mut self) -> Result<Vec<String>, DeviceError> {
        Ok(Theta::prepare(self)?)
    }

    fn shoot(
        &mut self,
        plan: &BracketPlan,
        progress: &mut (dyn FnMut(&str, f64) + Send),
    ) -> Result<Vec<Frame>, DeviceError> {
        Ok(self.capture(plan, progress)?)
    }
}
