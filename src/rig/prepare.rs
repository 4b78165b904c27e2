//! What a capture works out while its camera shoots: the parts of the estimate and of the
//! exports that need the light and the first view's turn, not the photo. A bracket leaves the
//! cores idle for a second on the simulated bench and for several on a real camera; done
//! then, this work is out of the wait for the results.
//!
//! Both parts are guesses checked later. The estimate's renders take the view's candidates to
//! be every object pixel (no pixel clipped or unmeasured): an estimate whose candidates turn
//! out to be others renders its own ([`Shared::prepare`]). The exports' renders are for the
//! first view's turn, which the results check ([`Prepared::is_for`]).

use std::sync::Arc;
use std::thread::JoinHandle;

use brdfd_core::basis::Basis;
use brdfd_core::envmap::{EnvMap, CHOSEN_LIGHTS, DEFAULT_LIGHTS};
use brdfd_core::estimate::{EstimateOptions, Shared};
use brdfd_core::geometry::SceneGeometry;

use crate::export::Prepared;

/// The work under way, on a thread of its own.
pub(super) struct Preparing {
    exports: JoinHandle<Option<Prepared>>,
    shared: Arc<Shared>,
}

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
        let exports = std::thread::spawn(move || {
            let (exports, estimate) = rayon::join(
                || Prepared::new(Some((&env, yaw)), basis.header.grid),
                || {
                    if !single_view {
                        return Ok(());
                    }
                    let (w, h) = scene.camera.size();
                    let pixels = scene.pixels(w, h)?;
                    let (lights, _) = env.estimate_lights(DEFAULT_LIGHTS, CHOSEN_LIGHTS, yaw);
                    for_estimate.prepare(&basis, &[(&pixels, &lights)], &options)
                },
            );
            // Either failing costs only time: the results make their own.
            if let Err(e) = estimate {
                tracing::warn!("preparing the estimate's renders: {e}");
            }
            exports
                .inspect_err(|e| tracing::warn!("preparing the exports: {e}"))
                .ok()
        });
        Preparing { exports, shared }
    }

    /// Waits for the work; what of it failed is left to the steps that need it.
    pub(super) fn finish(self) -> Ready {
        let exports = self.exports.join().unwrap_or_else(|_| {
            tracing::warn!("preparing the exports and the estimate panicked");
            None
        });
        Ready {
            exports,
            shared: self.shared,
        }
    }
}
