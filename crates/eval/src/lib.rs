//! Evaluations that measure the estimate from outside the core: they run the same estimate
//! pipeline as `brdfd estimate` and compare its output with ground truth.
//!
//! - [`relight`]: the headline measure, relighting under maps the estimate never saw.
//! - [`paper`]: the paper's own protocol for the basis model (BRDF and image error against
//!   pixel count, Fig. 5 and Fig. 6). For speed it selects once per lighting and solves every
//!   material on the shared selection, so it calls the pipeline's steps (`chosen_rows`, the
//!   solvers) rather than the whole `estimate`.
//! - [`figures`]: their figures as SVG, with axes, labels and legends.

pub mod figures;
pub mod paper;
pub mod relight;

/// Where a long run stands, for the caller to show (runs take 5 to 25 minutes; a library
/// never prints). One is sent as each item of a stage begins.
#[derive(Debug, Clone, Copy)]
pub struct Progress<'a> {
    /// The stage, in words: "paper's protocol under grace", "leave-one-out", ...
    pub stage: &'a str,
    /// The item begun, usually a material.
    pub item: &'a str,
    /// Its number in the stage, from 1.
    pub index: usize,
    /// Items in the stage.
    pub total: usize,
}

/// What a run is told its progress through.
pub type OnProgress<'a> = &'a dyn Fn(Progress);
