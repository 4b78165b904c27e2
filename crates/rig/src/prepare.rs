//! What a capture works out while its camera shoots: the parts of the estimate and of the
//! exports that need the light and the first view's turn, not the photo. A bracket leaves the
//! cores idle for a second on the simulated bench and for several on a real camera; done
//! then, this work is out of the wait for the results.
//!
//! Both parts are guesses checked later. The estimate's renders take the view's candidates to
//! be every object pixel (no pixel clipped or unmeasured): an estimate whose candidates turn
//! out to be others renders its own ([`Shared::prepare`]). That includes a RAW bracket's,
//! whose demosaiced merge leaves the object's outline out: there the estimate's part is work
//! lost. The exports' renders are for the capture's map at the first view's turn, which the
//! results check ([`Prepared::is_for`]).

use std::sync::mpsc::{channel, Receiver};
use std::sync::Arc;
use std::thread::JoinHandle;

use brdfd_core::basis::Basis;
use brdfd_core::envmap::{EnvMap, LightSet, CHOSEN_LIGHTS, DEFAULT_LIGHTS};
use brdfd_core::estimate::{EstimateOptions, Shared};
use brdfd_core::geometry::SceneGeometry;
use brdfd_core::CoreError;

use brdfd_report::export::Prepared;

/// The work under way, on a thread of its own. Dropped unfinished (the capture failed or
/// was cancelled), it waits for the thread: nothing of a capture outlives it, and the
/// estimate's part stops with the capture's cancel.
pub(super) struct Preparing {
    thread: Option<JoinHandle<Option<Prepared>>>,
    shared: Arc<Shared>,
    /// The first view's lights, sent as soon as they are made: the view's merge needs the
    /// same ones, and making them again took about 45 ms of the wait for the results.
    lights: Option<(f64, Receiver<ViewLights>)>,
}

/// A view's lights for the estimate: for every candidate, and for the chosen pixels.
pub(super) type ViewLights = (LightSet, Option<LightSet>);

/// The work done: the exports' renders if they could be made, and what the estimate shares.
pub(super) struct Ready {
    pub exports: Option<Prepared>,
    pub shared: Arc<Shared>,
}

impl Preparing {
    /// Starts on the light `env` and the first view, `scene` seen with the map turned `yaw`
    /// (radians). The estimate's part only for a single view: with more, its candidates are
    /// shared between views not yet turned to.
    pub(super) fn start(
        env: &EnvMap,
        (scene, yaw): (&SceneGeometry, f64),
        basis: &Basis,
        options: &EstimateOptions,
        single_view: bool,
    ) -> Preparing {
        let shared = Arc::new(Shared::default());
        let (env, scene, basis, options) =
            (env.clone(), scene.clone(), basis.clone(), options.clone());
        let for_estimate = shared.clone();
        let (send, lights_made) = channel();
        let work = move || {
            // The estimate's lights first: then the map itself can go to the exports' part.
            let lights = single_view.then(|| {
                let lights = env.estimate_lights(DEFAULT_LIGHTS, CHOSEN_LIGHTS, yaw);
                // Nobody waiting (the capture ended) is no error.
                let _ = send.send(lights.clone());
                lights.0
            });
            let grid = basis.header.grid;
            let (exports, estimate) = rayon::join(
                move || Prepared::new(Some((env, yaw)), grid),
                || {
                    let Some(lights) = lights else {
                        return Ok(());
                    };
                    let (w, h) = scene.camera.size();
                    let pixels = scene.pixels(w, h)?;
                    for_estimate.prepare(&basis, &[(&pixels, &lights)], &options)
                },
            );
            // Either failing costs only time: the steps that need them make their own.
            if let Err(e) = &estimate {
                warn_unless_stopped("the estimate's", e);
            }
            if let Err(e) = &exports {
                warn_unless_stopped("the exports'", e);
            }
            exports.ok()
        };
        let thread = std::thread::Builder::new()
            .name("brdfd-prepare".into())
            .spawn(work)
            .inspect_err(|e| tracing::warn!("no thread to prepare renders on: {e}"))
            .ok();
        Preparing {
            thread,
            shared,
            lights: single_view.then_some((yaw, lights_made)),
        }
    }

    /// The first view's lights if it is seen with the map turned `yaw` (radians), as the
    /// thread made them, waiting for them if they are not made yet; `None` if they were made
    /// for another turn, taken already, or never made (the thread failed).
    pub(super) fn take_lights(&mut self, yaw: f64) -> Option<ViewLights> {
        let (made_for, made) = self.lights.take()?;
        (made_for == yaw).then(|| made.recv().ok()).flatten()
    }

    /// Waits for the work; what of it failed is left to the steps that need it.
    pub(super) fn finish(mut self) -> Ready {
        Ready {
            exports: self.join(),
            shared: self.shared.clone(),
        }
    }

    fn join(&mut self) -> Option<Prepared> {
        self.thread.take()?.join().unwrap_or_else(|panic| {
            let what = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_default();
            tracing::warn!("preparing the estimate's and exports' renders panicked: {what}");
            None
        })
    }
}

impl Drop for Preparing {
    fn drop(&mut self) {
        self.join();
    }
}

/// A cancelled capture's stop is no news; anything else is logged.
fn warn_unless_stopped(whose: &str, e: &CoreError) {
    if !matches!(e, CoreError::Stopped) {
        tracing::warn!("preparing {whose} renders: {e}");
    }
}
