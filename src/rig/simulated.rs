//! The simulated rig: a Nikon D5100 over PTP/IP, a RICOH THETA V over the THETA Web API and a
//! turntable on a pseudo-terminal, all on loopback and all speaking the real protocols. The
//! rig's workers reach them through ordinary selectors, exactly as they reach hardware; only
//! the scene in front of the cameras is set from here (the operator placing the sample).

use std::sync::Arc;
use std::time::{Duration, Instant};

use brdfd_sim::ptp::{ptpip::Server, Profile, Responder, SharedResponder};
use brdfd_sim::serial::SerialPeer;
use brdfd_sim::theta::{OscServer, ThetaConfig};
use brdfd_sim::{Stage, Timed};

use crate::bench::camera::BenchCamera;
use crate::bench::panorama::BenchPanorama;
use crate::bench::raw_file::RawFormat;
use crate::bench::VirtualBench;
use crate::config::{RigDevices, SimulatedPresence, Simulation};
use crate::rig::worker::Opener;
use crate::rig::VideoCamera;
use crate::selector::Selector;
use brdfd_sim::v4l::SimV4l;

/// Time the simulated THETA takes per frame. A real THETA V takes about a second; the
/// simulation keeps a delay so that the client's polling runs as it would, but a short one.
pub const SIM_THETA_SHOT_TIME: Duration = Duration::from_millis(20);

/// The simulated rig's fallback camera: `fallback_camera = "v4l:simulated"`.
pub const SIMULATED_WEBCAM: &str = "simulated";

/// Largest panorama the simulated THETA serves (a real THETA V writes 5376 × 2688).
const SIM_THETA_WIDTH: usize = 1024;

pub struct SimulatedRig {
    /// Whether the rig has the simulated V4L2 webcam.
    fallback: bool,
    /// Whether the rig has its simulated turntable (`[simulation] turntable`).
    turntable_present: bool,
    /// The RAW files the DSLR writes (`[simulation] dslr_raw`).
    raw: RawFormat,
    dslr_scene: Arc<Stage>,
    dslr_time: Arc<Timed>,
    dslr: SharedResponder,
    theta_scene: Arc<Stage>,
    theta_time: Arc<Timed>,
    /// Seconds spent rendering scenes: the simulated world's time, not brdfd's.
    render_nanos: std::sync::atomic::AtomicU64,
    ptpip: Server,
    osc: OscServer,
    turntable: SerialPeer,
    /// Our own handle on the pseudo-terminal keeps it open while no client has it.
    _turntable_end: serialport::TTYPort,
}

impl SimulatedRig {
    /// Starts the simulators on loopback, with nothing in front of the cameras: the DSLR
    /// as `simulation` says, and the webcam if `fallback`.
    pub fn start(simulation: Simulation, fallback: bool) -> anyhow::Result<SimulatedRig> {
        let dslr_scene = Arc::new(Stage::new((256, 256)));
        let dslr_time = Arc::new(Timed::new(dslr_scene.clone()));
        let dslr = Responder::new(Profile::NikonD5100, dslr_time.clone()).shared();
        dslr.lock().unwrap().faults.power_off_after_captures = simulation.dslr_powers_off_after;
        let ptpip = Server::start("127.0.0.1:0", dslr.clone())?;
        // An absent DSLR is one that is off: the server closes every connection at once.
        // (A port nobody listens on could be taken by another program meanwhile.)
        dslr.lock().unwrap().powered_off = simulation.dslr == SimulatedPresence::Absent;
        let theta_scene = Arc::new(Stage::new((
            SIM_THETA_WIDTH as u32,
            SIM_THETA_WIDTH as u32 / 2,
        )));
        let theta_time = Arc::new(Timed::new(theta_scene.clone()));
        let osc = OscServer::start(
            "127.0.0.1:0",
            theta_time.clone(),
            ThetaConfig {
                shot_time: SIM_THETA_SHOT_TIME,
                ..ThetaConfig::default()
            },
        )?;
        let (turntable, end) = SerialPeer::start(Default::default())?;
        Ok(SimulatedRig {
            fallback,
            turntable_present: simulation.turntable == SimulatedPresence::Present,
            raw: simulation.dslr_raw.unwrap_or(RawFormat::Nef),
            dslr_scene,
            dslr_time,
            dslr,
            theta_scene,
            theta_time,
            render_nanos: Default::default(),
            ptpip,
            osc,
            turntable,
            _turntable_end: end,
        })
    }

    /// Where the rig's workers find the simulators.
    pub fn selectors(&self) -> RigDevices {
        RigDevices {
            dslr: Some(Selector::PtpIp(self.ptpip.addr.to_string())),
            theta: Some(Selector::Osc(self.osc.url())),
            fallback_camera: self
                .fallback
                .then(|| Selector::V4l(SIMULATED_WEBCAM.into())),
            turntable: self
                .turntable_present
                .then(|| Selector::Serial(self.turntable.path.clone())),
        }
    }

    /// Opens the simulated webcam: a V4L2 camera beside the DSLR, seeing what it sees.
    pub fn fallback_opener(&self) -> Opener<VideoCamera> {
        let scene: Arc<dyn brdfd_sim::ImageSource> = self.dslr_time.clone();
        Box::new(move || {
            Ok(VideoCamera(Box::new(SimV4l::new(
                scene.clone(),
                "simulated webcam",
            ))))
        })
    }

    /// Puts the bench's light in front of the THETA.
    pub fn show_light(&self, bench: &VirtualBench) {
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
    pub fn show_object(&self, bench: &VirtualBench) -> anyhow::Result<()> {
        let t = Instant::now();
        let camera =
            BenchCamera::new(bench.clone(), "NIKON CORPORATION", "NIKON D5100").with_raw(self.raw);
        camera
            .prepare()
            .map_err(|e| anyhow::anyhow!("rendering the simulated scene: {e}"))?;
        self.dslr_scene.show(Arc::new(camera));
        self.add_render(t);
        Ok(())
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
    pub fn device_seconds(&self) -> f64 {
        let dslr_busy = self.dslr.lock().map_or(0.0, |r| r.busy_seconds());
        self.render_nanos.load(std::sync::atomic::Ordering::Relaxed) as f64 * 1e-9
            + self.dslr_time.seconds()
            + dslr_busy
            + self.theta_time.seconds()
            + SIM_THETA_SHOT_TIME.as_secs_f64() * self.osc.shots() as f64
    }
}
