//! The simulated rig: a Nikon D5100 (or a Canon EOS R6) over PTP/IP, a RICOH THETA V over the THETA Web API (or
//! PTP over an in-memory USB pipe), a turntable with a shutter line on a pseudo-terminal, and
//! a V4L2 webcam, all speaking the real protocols. The rig's workers open them through the
//! same code as hardware; only the scene in front of the cameras is set from here (the
//! operator placing the sample), and the trigger box's shutter line is wired to the DSLR's
//! remote socket when `[simulation] shutter` says so.

use std::sync::Arc;
use std::time::{Duration, Instant};

use brdfd_ptp::transport::usb::UsbTransport;
use brdfd_ptp::{Camera, Timeouts};
use brdfd_sim::grbl::{GrblConfig, GrblPeer};
use brdfd_sim::ptp::{ptpip::Server, Profile, Responder, SharedResponder};
use brdfd_sim::serial::{PeerConfig, SerialPeer, Wire};
use brdfd_sim::theta::{OscServer, ThetaConfig};
use brdfd_sim::{Stage, Timed};
use brdfd_theta::Theta;

use brdfd_bench::camera::BenchCamera;
use brdfd_bench::panorama::BenchPanorama;
use brdfd_bench::raw_file::{RawDamage, RawFormat};
use brdfd_bench::VirtualBench;
use brdfd_rig::config::{
    DslrBackend, Rig, SimulatedBody, SimulatedLink, SimulatedPresence, SimulatedRaw,
    SimulatedRawDamage, SimulatedTurntable,
};
use brdfd_rig::devices::{video::VideoCamera, Planned};
use brdfd_rig::error::{Result, RigError};
use brdfd_rig::plan::{self, SIMULATED_WEBCAM};
use brdfd_rig::roles::RigDevice;
use brdfd_rig::selector::Selector;
use brdfd_sim::v4l::SimV4l;

/// Time the simulated THETA takes per frame. A real THETA V takes about a second; the
/// simulation keeps a delay so that the client's polling runs as it would, but a short one.
pub const SIM_THETA_SHOT_TIME: Duration = Duration::from_millis(20);

/// Largest panorama the simulated THETA serves (a real THETA V writes 5376 × 2688).
const SIM_THETA_WIDTH: usize = 1024;

/// How the simulated THETA is reached.
enum ThetaLink {
    Http(OscServer),
    /// The THETA V's USB profile behind an in-memory pipe, plugged in at each open.
    Usb(SharedResponder),
}

pub(crate) struct Simulators {
    /// Whether the rig has the simulated V4L2 webcam.
    fallback: bool,
    /// The RAW files the DSLR writes (`[simulation] dslr_raw`), and how it damages them.
    raw: RawFormat,
    raw_damage: Option<RawDamage>,
    dslr_scene: Arc<Stage>,
    dslr_time: Arc<Timed>,
    /// The DSLR's make and model, as its photos' EXIF names them, and as people do.
    dslr_names: (&'static str, &'static str, &'static str),
    dslr_backend: DslrBackend,
    dslr: SharedResponder,
    theta_scene: Arc<Stage>,
    theta_time: Arc<Timed>,
    /// Seconds spent rendering scenes: the simulated world's time, not brdfd's.
    render_nanos: std::sync::atomic::AtomicU64,
    ptpip: Server,
    theta: ThetaLink,
    /// The box on the pseudo-terminal, and the roles it plays (turntable, shutter), if any.
    serial: Option<(SerialPeer, Vec<&'static str>)>,
    /// Our own handle on the pseudo-terminal keeps it open while no client has it.
    _serial_end: Option<serialport::TTYPort>,
    /// A GRBL controller turning the table, and our handle on its pseudo-terminal.
    grbl: Option<(GrblPeer, serialport::TTYPort)>,
}

impl Simulators {
    /// Starts the simulators the rig's `[simulation]` table names, with nothing in front of
    /// the cameras.
    pub(crate) fn start(rig: &Rig) -> Result<Simulators> {
        let simulation = rig.simulation.clone().unwrap_or_default();
        let dslr_scene = Arc::new(Stage::new((256, 256)));
        let dslr_time = Arc::new(Timed::new(dslr_scene.clone()));
        let (body, dslr_names) = match simulation.dslr_body {
            SimulatedBody::NikonD5100 => (
                Profile::NikonD5100,
                ("NIKON CORPORATION", "NIKON D5100", "Nikon D5100"),
            ),
            SimulatedBody::CanonEosR6 => (
                Profile::CanonEosR6,
                ("Canon", "Canon EOS R6", "Canon EOS R6"),
            ),
            SimulatedBody::SonyA7m4 => (Profile::SonyA7M4, ("SONY", "ILCE-7M4", "Sony a7 IV")),
        };
        let dslr = Responder::new(body, dslr_time.clone()).shared();
        lock(&dslr).faults.power_off_after_captures = simulation.dslr_powers_off_after;
        lock(&dslr).faults.same_file_names = simulation.dslr_reuses_file_names;
        let ptpip = Server::start("127.0.0.1:0", dslr.clone())?;
        // An absent DSLR is one that is off: the server closes every connection at once.
        // (A port nobody listens on could be taken by another program meanwhile.)
        lock(&dslr).powered_off = simulation.dslr == SimulatedPresence::Absent;
        let theta_scene = Arc::new(Stage::new((
            SIM_THETA_WIDTH as u32,
            SIM_THETA_WIDTH as u32 / 2,
        )));
        let theta_time = Arc::new(Timed::new(theta_scene.clone()));
        let theta = match simulation.theta {
            SimulatedLink::Http => ThetaLink::Http(OscServer::start(
                "127.0.0.1:0",
                theta_time.clone(),
                ThetaConfig {
                    shot_time: SIM_THETA_SHOT_TIME,
                    ..ThetaConfig::default()
                },
            )?),
            SimulatedLink::Usb => {
                ThetaLink::Usb(Responder::new(Profile::ThetaV, theta_time.clone()).shared())
            }
        };
        let mut roles = Vec::new();
        if simulation.turntable == SimulatedTurntable::Present {
            roles.push(plan::TURNTABLE);
        }
        let grbl = if simulation.turntable == SimulatedTurntable::Grbl {
            // A desktop turntable's rate: 15 turns a minute ($113=5400).
            let (peer, end) = GrblPeer::start(GrblConfig {
                rate_per_s: 90.0,
                ..GrblConfig::default()
            })?;
            Some((peer, end))
        } else {
            None
        };
        if simulation.shutter == SimulatedPresence::Present {
            roles.push(plan::SHUTTER);
        }
        let (serial, end) = if roles.is_empty() {
            (None, None)
        } else {
            let shutter_wired_to = roles.contains(&plan::SHUTTER).then(|| {
                let camera = dslr.clone();
                Wire(Arc::new(move |_ms| {
                    lock(&camera).press_release();
                }))
            });
            let (peer, end) = SerialPeer::start(PeerConfig {
                name: if roles.contains(&plan::TURNTABLE) {
                    "brdfd-sim-turntable".into()
                } else {
                    "brdfd-sim-trigger".into()
                },
                can_rotate: roles.contains(&plan::TURNTABLE),
                can_fire: true,
                shutter_wired_to,
                ..PeerConfig::default()
            })?;
            (Some((peer, roles)), Some(end))
        };
        Ok(Simulators {
            fallback: rig.devices.fallback_camera.is_some(),
            raw: match simulation.dslr_raw {
                None | Some(SimulatedRaw::Nef) => RawFormat::Nef,
                Some(SimulatedRaw::Dng) => RawFormat::Dng,
                Some(SimulatedRaw::Dng12) => RawFormat::Dng12,
            },
            raw_damage: simulation.dslr_raw_damage.map(|d| match d {
                SimulatedRawDamage::Oversized => RawDamage::Oversized,
                SimulatedRawDamage::IfdLoop => RawDamage::IfdLoop,
            }),
            dslr_scene,
            dslr_time,
            dslr_names,
            dslr_backend: simulation.dslr_backend,
            dslr,
            theta_scene,
            theta_time,
            render_nanos: Default::default(),
            ptpip,
            theta,
            serial,
            _serial_end: end,
            grbl,
        })
    }

    /// The simulated DSLR's model, as it names itself.
    pub(crate) fn dslr_model(&self) -> &'static str {
        self.dslr_names.2
    }

    /// The simulators as the rig's devices: each opened by the code that opens hardware,
    /// through the selector a bench would give it.
    pub(crate) fn devices(&self) -> Vec<Planned> {
        let addr = self.ptpip.addr;
        let dslr = match self.dslr_backend {
            DslrBackend::Brdfd => Selector::PtpIp(addr.to_string()),
            // libgphoto2's PTP/IP port is HOST:COMMANDPORT:EVENTPORT; the simulator takes
            // both on one.
            DslrBackend::Gphoto2 => Selector::Gphoto(Some(format!("ptpip:{addr}:{}", addr.port()))),
        };
        let mut v = vec![Planned::from_selector(plan::DSLR, dslr, true)];
        v.push(match &self.theta {
            ThetaLink::Http(osc) => {
                Planned::from_selector(plan::THETA, Selector::Osc(osc.url()), true)
            }
            ThetaLink::Usb(responder) => {
                let responder = responder.clone();
                Planned {
                    fields: vec![plan::THETA],
                    selector: "usb:05ca:0368 (simulated, in-memory)".into(),
                    open: Box::new(move || {
                        let pipe = brdfd_sim::ptp::usb::plug(responder.clone());
                        let camera =
                            Camera::open(Box::new(UsbTransport::new(pipe)), Timeouts::default())?;
                        Ok(Box::new(Theta::from_ptp(camera)?) as Box<dyn RigDevice>)
                    }),
                }
            }
        });
        if self.fallback {
            let scene: Arc<dyn brdfd_sim::ImageSource> = self.dslr_time.clone();
            v.push(Planned {
                fields: vec![plan::FALLBACK],
                selector: format!("v4l:{SIMULATED_WEBCAM}"),
                open: Box::new(move || {
                    Ok(Box::new(VideoCamera::new(Box::new(SimV4l::new(
                        scene.clone(),
                        "simulated webcam",
                    )))) as Box<dyn RigDevice>)
                }),
            });
        }
        if let Some((peer, _)) = &self.grbl {
            let grbl = Selector::Grbl {
                axis: 'A',
                path: peer.path.clone(),
            };
            v.push(Planned::from_selector(plan::TURNTABLE, grbl, true));
        }
        if let Some((peer, roles)) = &self.serial {
            let mut p = Planned::from_selector(roles[0], Selector::Serial(peer.path.clone()), true);
            p.fields = roles.clone();
            v.push(p);
        }
        v
    }

    /// Puts the bench's light in front of the THETA.
    pub(crate) fn show_light(&self, bench: &VirtualBench) {
        let t = Instant::now();
        self.theta_scene.show(Arc::new(BenchPanorama::new(
            &bench.env,
            SIM_THETA_WIDTH,
            "RICOH THETA V",
        )));
        self.add_render(t);
    }

    /// Puts the object in front of the DSLR as it stands now (after the turntable moved it),
    /// rendered at once, as a real scene simply exists.
    pub(crate) fn show_object(&self, bench: &VirtualBench) -> Result<()> {
        let t = Instant::now();
        let (make, model, _) = self.dslr_names;
        let camera = BenchCamera::new(bench.clone(), make, model)
            .with_raw(self.raw)
            .with_raw_damage(self.raw_damage);
        camera
            .prepare()
            .map_err(|e| RigError::invalid(format!("rendering the simulated scene: {e}")))?;
        self.dslr_scene.show(Arc::new(camera));
        self.add_render(t);
        Ok(())
    }

    /// Puts a scene rendered elsewhere in front of the DSLR (the pose board), as `camera`
    /// sees it.
    pub(crate) fn show_radiance(
        &self,
        radiance: brdfd_core::raster::Raster,
        camera: &brdfd_core::geometry::Camera,
    ) {
        let (make, model, _) = self.dslr_names;
        let camera = BenchCamera::of_radiance(radiance, camera, make, model)
            .with_raw(self.raw)
            .with_raw_damage(self.raw_damage);
        self.dslr_scene.show(Arc::new(camera));
    }

    fn add_render(&self, since: Instant) {
        self.render_nanos.fetch_add(
            since.elapsed().as_nanos() as u64,
            std::sync::atomic::Ordering::Relaxed,
        );
    }

    /// Seconds the simulated devices have spent on their own work so far: rendering scenes,
    /// making frames, the DSLR's modelled exposure and processing, and the THETA's modelled
    /// shot time per frame.
    pub(crate) fn device_seconds(&self) -> f64 {
        let dslr_busy = self.dslr.lock().map_or(0.0, |r| r.busy_seconds());
        let theta_shots = match &self.theta {
            ThetaLink::Http(osc) => SIM_THETA_SHOT_TIME.as_secs_f64() * osc.shots() as f64,
            ThetaLink::Usb(r) => r.lock().map_or(0.0, |r| r.busy_seconds()),
        };
        self.render_nanos.load(std::sync::atomic::Ordering::Relaxed) as f64 * 1e-9
            + self.dslr_time.seconds()
            + dslr_busy
            + self.theta_time.seconds()
            + theta_shots
    }
}

/// The simulated camera's state, even if a thread panicked holding it (its state is plain
/// data, valid between operations).
fn lock(r: &SharedResponder) -> std::sync::MutexGuard<'_, Responder> {
    r.lock().unwrap_or_else(|p| p.into_inner())
}
