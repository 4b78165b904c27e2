//! The roles a rig's devices play in a capture: the object camera, the light probe, the
//! turntable and the shutter. The flow asks for a role, never for a device type: a PTP DSLR
//! and a V4L2 webcam are both object cameras, a THETA on HTTP or on USB is a light probe, and
//! a rig-protocol box is a turntable, a shutter, or both. Each role is a trait; what only some
//! devices in a role can do is an optional ability, a method whose default says it cannot
//! (the shape of probe-rs's `DebugProbe`).
//!
//! A device is one [`RigDevice`] on one worker thread, whatever roles it plays; a [`Role`] is
//! the flow's handle on one of them. The implementations for PTP, THETA, V4L2 and serial
//! devices are in [`super::devices`].
//!
//! Not here: opening devices ([`super::devices`]), and turning what cameras send into
//! radiance ([`super::object`]).

use std::marker::PhantomData;
use std::sync::Arc;
use std::time::Duration;

use brdfd_theta::{BracketPlan, Frame};

use super::error::DeviceError;
use super::worker::{Device, Pending, Worker};
use crate::config::DslrFiles;

/// A device of the rig, whatever it is: what its worker needs of it ([`Device`]), and its
/// roles as accessors, `None` for a role it cannot play.
pub trait RigDevice: Device {
    fn object_camera(&mut self) -> Option<&mut (dyn ObjectCamera + 'static)> {
        None
    }
    fn light_probe(&mut self) -> Option<&mut (dyn LightProbe + 'static)> {
        None
    }
    fn turntable(&mut self) -> Option<&mut (dyn Turntable + 'static)> {
        None
    }
    fn shutter(&mut self) -> Option<&mut (dyn Shutter + 'static)> {
        None
    }
    /// Why it cannot be the rig's `role`, when its accessor said so.
    fn cannot(&self, role: &str) -> String {
        format!("{} cannot be the rig's {role}", self.identity())
    }
}

impl Device for Box<dyn RigDevice> {
    fn identity(&self) -> String {
        (**self).identity()
    }
    fn keep_alive(&mut self) -> Result<(), DeviceError> {
        (**self).keep_alive()
    }
}

/// Settings an object camera holds through a bracket. `None` leaves a setting as the camera
/// has it; each camera applies those it has controls for and says what it applied.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CameraSettings {
    pub f_number: Option<f64>,
    pub iso: Option<u32>,
    /// The files a still camera makes per shot.
    pub files: Option<DslrFiles>,
    /// A video camera's sensor gain, in its own units.
    pub gain: Option<i64>,
    /// A video camera's white balance, kelvin.
    pub white_balance_k: Option<i64>,
    /// Frames a video camera averages per exposure.
    pub frames: usize,
}

/// What one exposure gave, and the exposure time the camera applied.
pub struct Exposed {
    pub applied_s: f64,
    pub output: Output,
}

pub enum Output {
    /// A still camera's files as it sent them (RAW, JPEG), in the order it announced them.
    Files(Vec<(String, Vec<u8>)>),
    /// A video camera's frames at one exposure, decoded, to be averaged.
    Frames(Vec<brdfd_v4l::Rgb8Frame>),
}

/// Fires the camera from outside: the rig's shutter, called from the camera's own job.
pub type Fire<'a> = &'a mut dyn FnMut() -> Result<(), DeviceError>;

/// Download progress of one exposure: bytes done, of total.
pub type Bytes<'a> = &'a mut dyn FnMut(u64, u64);

/// The camera that photographs the object, one bracket per view.
pub trait ObjectCamera {
    /// Applies the bracket's fixed settings; a line per setting, as applied, for the
    /// operator.
    fn prepare(&mut self, settings: &CameraSettings) -> Result<Vec<String>, DeviceError>;
    /// One exposure of `seconds`, fired by the camera itself; what it made.
    fn expose(&mut self, seconds: f64, progress: Bytes) -> Result<Exposed, DeviceError>;
    /// Optional: one exposure of `seconds`, fired by `fire` (a trigger box or a release
    /// cable on the camera's remote socket), with the files the camera then reports. `None`
    /// for a camera nothing outside can fire (a webcam streams).
    fn expose_fired_by(
        &mut self,
        _seconds: f64,
        _fire: Fire,
        _progress: Bytes,
    ) -> Option<Result<Exposed, DeviceError>> {
        None
    }
}

/// The 360° camera that measures the light around the object.
pub trait LightProbe {
    /// Sets the camera up for light measurement (manual exposure, fixed white balance,
    /// timers off); a line per setting, as applied.
    fn prepare(&mut self) -> Result<Vec<String>, DeviceError>;
    /// Shoots the plan (snapped to what the camera supports): the frames as the camera sent
    /// them. `progress` gets a phase and the fraction done.
    fn shoot(
        &mut self,
        plan: &BracketPlan,
        progress: &mut (dyn FnMut(&str, f64) + Send),
    ) -> Result<Vec<Frame>, DeviceError>;
}

/// What turns the object between views.
pub trait Turntable {
    /// Where it stands, degrees.
    fn position(&mut self) -> Result<f64, DeviceError>;
    /// Turns by `degrees` (signed); where it stopped.
    fn rotate(&mut self, degrees: f64) -> Result<f64, DeviceError>;
}

/// What fires the DSLR when the capture does not fire it over PTP.
pub trait Shutter {
    /// Presses the release for `hold`, and lets go.
    fn fire(&mut self, hold: Duration) -> Result<(), DeviceError>;
}

/// A device's worker, shared by the roles the device plays.
pub type DeviceWorker = Worker<Box<dyn RigDevice>>;

/// The flow's handle on a role: the worker of the device that plays it.
pub struct Role<R: ?Sized> {
    worker: Arc<DeviceWorker>,
    /// "object camera", "light probe", "turntable", "shutter".
    name: &'static str,
    get: for<'a> fn(&'a mut dyn RigDevice) -> Option<&'a mut R>,
    _role: PhantomData<fn() -> Box<R>>,
}

impl<R: ?Sized> Clone for Role<R> {
    fn clone(&self) -> Self {
        Role {
            worker: self.worker.clone(),
            name: self.name,
            get: self.get,
            _role: PhantomData,
        }
    }
}

impl<R: ?Sized + 'static> Role<R> {
    fn new(
        worker: &Arc<DeviceWorker>,
        name: &'static str,
        get: for<'a> fn(&'a mut dyn RigDevice) -> Option<&'a mut R>,
    ) -> Role<R> {
        Role {
            worker: worker.clone(),
            name,
            get,
            _role: PhantomData,
        }
    }

    /// Runs `f` on the device in this role, on its thread (see [`Worker::submit`]).
    pub(crate) fn submit<T: Send + 'static>(
        &self,
        f: impl FnOnce(&mut R) -> Result<T, DeviceError> + Send + 'static,
    ) -> Pending<T> {
        let (get, name) = (self.get, self.name);
        self.worker.submit(move |d: &mut Box<dyn RigDevice>| {
            let device: &mut dyn RigDevice = d.as_mut();
            let cannot = device.cannot(name);
            match get(device) {
                Some(r) => f(r),
                None => Err(DeviceError::Cannot(cannot)),
            }
        })
    }

    /// `submit`, then `wait`.
    pub fn call<T: Send + 'static>(
        &self,
        f: impl FnOnce(&mut R) -> Result<T, DeviceError> + Send + 'static,
    ) -> Result<T, DeviceError> {
        self.submit(f).wait()
    }

    /// A request the device must answer: an open handle alone says nothing of a camera
    /// that has gone quiet.
    pub(crate) fn ping(&self) -> Result<(), DeviceError> {
        self.worker.call(|d| d.keep_alive())
    }

    pub fn status(&self) -> super::DeviceStatus {
        self.worker.status()
    }
}

pub(crate) fn object_camera(w: &Arc<DeviceWorker>) -> Role<dyn ObjectCamera> {
    Role::new(w, "object camera", |d| d.object_camera())
}

pub fn light_probe(w: &Arc<DeviceWorker>) -> Role<dyn LightProbe> {
    Role::new(w, "light probe", |d| d.light_probe())
}

pub fn turntable(w: &Arc<DeviceWorker>) -> Role<dyn Turntable> {
    Role::new(w, "turntable", |d| d.turntable())
}

pub fn shutter(w: &Arc<DeviceWorker>) -> Role<dyn Shutter> {
    Role::new(w, "shutter", |d| d.shutter())
}
