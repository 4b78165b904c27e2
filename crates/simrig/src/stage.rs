//! The simulated rig's stage ([`brdfd_rig::simulation::Stage`]): the virtual bench. It tabulates the
//! material the plan names on the rig's object, shows each view to the simulated cameras,
//! and judges the estimate against the material: its projection on the basis, and its
//! relight error under light the estimate was not fitted to. Its work is the devices' time in
//! the session's phases: a real bench does none of it.

use std::sync::Arc;

use brdfd_core::basis::Basis;
use brdfd_core::bivariate::Bivariate;
use brdfd_core::envmap::EnvMap;
use brdfd_core::estimate::Estimate;
use brdfd_core::geometry::SceneGeometry;
use brdfd_core::merl::MerlBrdf;
use brdfd_core::nbrdf::NbrdfSet;
use brdfd_core::solve::Colour;

use brdfd_bench::{RelightTruth, VirtualBench, HELD_OUT_YAW_DEG};
use brdfd_rig::config::MaterialPreset;
use brdfd_rig::error::{Result, RigError, StepExt};
use brdfd_rig::flow::{Context, Phases};
use brdfd_rig::settings::CaptureSettings;
use brdfd_rig::simulation::{Judgement, Stage};
use brdfd_rig::turning::turned;
use brdfd_rig::Plan;

use super::simulators::Simulators;
use super::truth_scene;

/// The virtual bench, once the sample is placed, and the truth the estimate is relit against,
/// rendered in the background once the first view is in front of the camera.
pub(super) struct SimulatedStage {
    rig: Arc<Simulators>,
    bench: Option<VirtualBench>,
    relight_truth: Option<Joined<brdfd_core::Result<RelightTruth>>>,
}

impl SimulatedStage {
    /// The stage of the simulated rig `rig`, with nothing placed on it yet.
    pub(super) fn new(rig: Arc<Simulators>) -> SimulatedStage {
        SimulatedStage {
            rig,
            bench: None,
            relight_truth: None,
        }
    }

    fn bench(&self) -> Result<&VirtualBench> {
        self.bench
            .as_ref()
            .step("the simulated bench has no sample: it is placed before anything is shot")
    }
}

impl Stage for SimulatedStage {
    /// Tabulating the material is the simulator's work: a real bench has the object.
    fn place(
        &mut self,
        cx: &Context,
        s: &CaptureSettings,
        basis: &Basis,
        phases: &mut Phases,
    ) -> Result<()> {
        let rig = &self.rig;
        let p = phases.start("simulated bench: place the sample", 1);
        // The bench photographs the object where it truly stands; the estimate uses where the
        // rig says it is.
        let scene = truth_scene(cx.rig, &s.scene);
        let mut bench = simulated_bench(&s.plan, s.preset.as_ref(), &scene, s.yaw, basis)?;
        bench.stop = cx.cancel.stop();
        rig.show_light(&bench);
        phases.end_as_device(p);
        let (w, h) = s.scene.camera.size();
        cx.say(format!(
            "simulated rig: {} on {}; DSLR: simulated {} on {}, {w}×{h}",
            bench.material_name,
            s.scene
                .shape
                .as_ref()
                .map_or("the normal map's object".to_string(), |s| s.describe()),
            rig.dslr_model(),
            cx.devices
                .dslr
                .as_ref()
                .map_or("none".into(), |d| d.status().selector),
        ));
        self.bench = Some(bench);
        Ok(())
    }

    fn light_note(&self, measured: &EnvMap) -> Option<String> {
        Some(report_panorama(measured, self.bench.as_ref()?))
    }

    /// The simulated turntable only reports angles: the object turns here.
    fn show(&mut self, _: &Context, deg: f64) -> Result<()> {
        let bench = self.bench()?;
        self.rig.show_object(&turned_bench(bench, deg))?;
        // The truth the estimate is relit against needs no estimate: it renders while the
        // camera's modelled exposures wait and the estimate runs. (Not before the scene's own
        // render: two renders at once only slow each other.)
        if self.relight_truth.is_none() {
            let b = bench.clone();
            self.relight_truth = Some(Joined(Some(std::thread::spawn(move || b.relight_truth()))));
        }
        Ok(())
    }

    fn judge(
        &mut self,
        cx: &Context,
        basis: &Basis,
        est: &Estimate,
        phases: &mut Phases,
    ) -> Result<Judgement> {
        // The true material on the estimate's grid: the report overlays it, and a basis
        // estimate is compared with its projection.
        let reduced = Bivariate::reduce(&*self.bench()?.material, basis.header.grid);
        let coefficients = self.compare_with_truth(cx, basis, est, &reduced, phases);
        let relight = self.relight_against_truth(est, phases)?;
        Ok(Judgement {
            coefficients,
            relight: Some((
                relight,
                format!("the bench's map turned {HELD_OUT_YAW_DEG}°"),
            )),
            brdf: Some(reduced),
        })
    }
}

impl SimulatedStage {
    /// The basis model's estimate beside the simulated material's own projection onto the
    /// basis, its best answer (an analytic fit has no such reference). Comparing with it is
    /// the simulator's business, so its time is the devices'.
    fn compare_with_truth(
        &self,
        cx: &Context,
        basis: &Basis,
        est: &Estimate,
        reduced: &Bivariate,
        phases: &mut Phases,
    ) -> Option<Vec<f64>> {
        let basis_outcome = est.outcome.basis()?;
        let p = phases.start("compare with the ground truth (simulator)", 1);
        let truth = match basis_outcome.colour {
            Colour::Joint => basis.project(reduced),
            Colour::PerChannel => basis.project_channels(reduced),
        };
        phases.end_as_device(p);
        cx.say(brdfd_report::results::coefficient_lines(
            "ground truth projected on the basis",
            &est.names,
            &truth,
        ));
        Some(truth)
    }

    /// How far the estimate is from the simulated material under light it was not fitted to.
    fn relight_against_truth(&mut self, est: &Estimate, phases: &mut Phases) -> Result<f64> {
        let p = phases.start("relight against the ground truth (simulator)", 1);
        let truth = match self.relight_truth.take() {
            Some(mut render) => render
                .join()
                .ok_or_else(|| RigError::invalid("rendering the relight truth panicked"))??,
            // Every view was already on disk (a resumed session): render it now.
            None => self.bench()?.relight_truth()?,
        };
        let error = truth.error_of(est);
        phases.end_as_device(p);
        Ok(error)
    }
}

/// A thread the stage started, joined when dropped: a capture that ends early (an error, a
/// cancel) does not leave it running into the next one.
struct Joined<T>(Option<std::thread::JoinHandle<T>>);

impl<T> Joined<T> {
    /// Its result; `None` if it panicked.
    fn join(&mut self) -> Option<T> {
        self.0.take()?.join().ok()
    }
}

impl<T> Drop for Joined<T> {
    fn drop(&mut self) {
        if let Some(h) = self.0.take() {
            let _ = h.join();
        }
    }
}

/// The simulated bench for a plan: the material (preset, MERL name, alias or NBRDF file) on
/// the rig's object, under the plan's light.
fn simulated_bench(
    plan: &Plan,
    preset: Option<&MaterialPreset>,
    scene: &SceneGeometry,
    yaw: f64,
    basis: &Basis,
) -> Result<VirtualBench> {
    let simulate_as = preset.map_or(plan.material.as_str(), |p| p.simulate_as.as_str());
    let mut bench = VirtualBench::embedded(simulate_as, plan.size).or_else(|e| {
        // Not an embedded material: the NBRDF file may have it.
        let Some(path) = &plan.nbrdf else {
            return Err(e);
        };
        let set = NbrdfSet::read(path)?;
        let name = brdfd_bench::resolve_material(simulate_as);
        let mut b = VirtualBench::embedded("gold", plan.size)?;
        b.material = Arc::new(MerlBrdf::tabulate(set.get(name)?));
        b.material_name = name.to_string();
        Ok::<_, brdfd_core::CoreError>(b)
    })?;
    if plan.in_span {
        let projected = basis.project(&Bivariate::reduce(&*bench.material, basis.header.grid));
        bench.material = Arc::new(basis.reconstruct(&projected).to_merl());
        bench.material_name = format!("{} (its projection onto the basis)", bench.material_name);
    }
    bench.geometry = scene.clone();
    bench.yaw = yaw;
    bench.cache = brdfd_bench::cache::RenderCache::user();
    if let Some(p) = &plan.env {
        bench.env = brdfd_radiometry::panorama::load_envmap(p)?;
    }
    Ok(bench)
}

/// How far the measured map is from the bench's own (total light, per channel).
fn report_panorama(map: &EnvMap, bench: &VirtualBench) -> String {
    // Total light is independent of the map's resolution (the downsample preserves Σ L·Δω),
    // so the bench's own map is the reference as it is.
    let (measured, truth) = (map.lights(0.0).power(), bench.env.lights(0.0).power());
    format!(
        "  panorama merged to {}×{}; total light vs the bench's map: {:+.2}% {:+.2}% {:+.2}% (R G B)",
        map.width,
        map.height,
        (measured[0] / truth[0] - 1.0) * 100.0,
        (measured[1] / truth[1] - 1.0) * 100.0,
        (measured[2] / truth[2] - 1.0) * 100.0,
    )
}

/// The bench with its sample turned `deg` on the (simulated) turntable.
fn turned_bench(bench: &VirtualBench, deg: f64) -> VirtualBench {
    let (geometry, yaw) = turned(&bench.geometry, bench.yaw, deg);
    VirtualBench {
        geometry,
        yaw,
        ..bench.clone()
    }
}
