//! Serial devices in their roles: a box that speaks the brdfd rig protocol is a turntable if
//! its `ID?` lists ROT and a shutter if it lists FIRE (one device, both roles, when it lists
//! both); a release cable on a modem line is a shutter; a GRBL G-code controller is a
//! turntable.

use std::time::Duration;

use brdfd_serial::{GrblTurntable, RigController, ShutterCable};

use crate::error::DeviceError;
use crate::roles::{RigDevice, Shutter, Turntable};
use crate::Device;

impl Device for RigController {
    fn identity(&self) -> String {
        format!(
            "{} {} on serial:{}",
            self.identity.name,
            self.identity.version,
            self.port_name()
        )
    }
    fn keep_alive(&mut self) -> Result<(), DeviceError> {
        // A box that does not turn has no position to report: its ID? is the cheap question.
        if self.identity.can_rotate {
            self.position()?;
        } else {
            self.identify()?;
        }
        Ok(())
    }
}

impl RigDevice for RigController {
    fn turntable(&mut self) -> Option<&mut (dyn Turntable + 'static)> {
        self.identity.can_rotate.then_some(self as _)
    }
    fn shutter(&mut self) -> Option<&mut (dyn Shutter + 'static)> {
        self.identity.can_fire.then_some(self as _)
    }
    fn cannot(&self, role: &str) -> String {
        let what = if role == "shutter" { "FIRE" } else { "ROT" };
        format!(
            "{} cannot be the rig's {role}: its ID? does not list {what}",
            Device::identity(self)
        )
    }
}

impl Turntable for RigController {
    fn position(&mut self) -> Result<f64, DeviceError> {
        Ok(RigController::position(self)?)
    }
    fn rotate(&mut self, degrees: f64) -> Result<f64, DeviceError> {
        Ok(RigController::rotate(self, degrees)?)
    }
}

impl Shutter for RigController {
    fn fire(&mut self, hold: Duration) -> Result<(), DeviceError> {
        Ok(RigController::fire(self, hold.as_millis().max(1) as u32)?)
    }
}

impl Device for ShutterCable {
    fn identity(&self) -> String {
        format!("release cable on {:?} of {}", self.line(), self.port_name())
    }
    fn keep_alive(&mut self) -> Result<(), DeviceError> {
        Ok(self.release()?)
    }
}

impl RigDevice for ShutterCable {
    fn shutter(&mut self) -> Option<&mut (dyn Shutter + 'static)> {
        Some(self)
    }
}

impl Shutter for ShutterCable {
    fn fire(&mut self, hold: Duration) -> Result<(), DeviceError> {
        Ok(ShutterCable::fire(self, hold.as_millis().max(1) as u32)?)
    }
}

impl Device for GrblTurntable {
    fn identity(&self) -> String {
        format!(
            "{} ({} axis) on grbl:{}",
            self.identity.banner,
            self.identity.axis,
            self.port_name()
        )
    }
    fn keep_alive(&mut self) -> Result<(), DeviceError> {
        // `?` is GRBL's real-time question: it moves nothing and is answered at once.
        self.status()?;
        Ok(())
    }
}

impl RigDevice for GrblTurntable {
    fn turntable(&mut self) -> Option<&mut (dyn Turntable + 'static)> {
        Some(self)
    }
    fn cannot(&self, role: &str) -> String {
        format!(
            "{} cannot be the rig's {role}: a GRBL controller turns the table only",
            Device::identity(self)
        )
    }
}

impl Turntable for GrblTurntable {
    fn position(&mut self) -> Result<f64, DeviceError> {
        Ok(GrblTurntable::position(self)?)
    }
    fn rotate(&mut self, degrees: f64) -> Result<f64, DeviceError> {
        Ok(GrblTurntable::rotate(self, degrees)?)
    }
}
