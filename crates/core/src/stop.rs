//! A request to stop, seen by the core's long loops.
//!
//! A capture's estimate runs for seconds to minutes; Ctrl-C, SIGTERM and the API's cancel
//! must end it within seconds, not when it finishes. The caller keeps a clone and calls
//! [`Stop::request`]; the core checks at its loops' natural steps (a view's matrix, a pass of
//! rendering columns, a colour model tried, a block of pixels rendered, a position of the
//! pixel selection) and returns [`CoreError::Stopped`].
//! A check is one relaxed atomic load, cheap beside any step it guards.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use crate::error::{CoreError, Result};

/// Shared by whoever may stop the work and the work itself; clones see the same request.
/// The default is a fresh flag that nobody has requested.
#[derive(Clone, Debug, Default)]
pub struct Stop(Arc<AtomicBool>);

impl Stop {
    /// Asks every holder to stop at its next check.
    pub fn request(&self) {
        self.0.store(true, Ordering::SeqCst);
    }

    /// Whether a stop was requested; for loops that cannot return an error where they check
    /// (a parallel loop skips its remaining work, and its caller then calls [`Stop::check`]).
    pub fn requested(&self) -> bool {
        self.0.load(Ordering::Relaxed)
    }

    /// `Err(CoreError::Stopped)` once a stop was requested.
    pub fn check(&self) -> Result<()> {
        if self.requested() {
            Err(CoreError::Stopped)
        } else {
            Ok(())
        }
    }
}
