//! Evaluations that measure the estimate from outside the core: they run the same estimate
//! pipeline as `brdfd estimate` and compare its output with ground truth.
//!
//! - [`relight`]: the headline measure, relighting under maps the estimate never saw.
//!
//! The paper's own protocol (BRDF and image error against pixel count) is still
//! [`crate::core::eval`].

pub mod relight;
