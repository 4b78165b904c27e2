//! brdfd: BRDF acquisition with simple devices, after Hirasawa et al., "BRDF Estimation with
//! Simple Measurement and Data-driven Model".
//!
//! # Layout
//! - `brdfd-core` (`crates/core`, its own crate): the estimation core (BRDF sources, bivariate
//!   reduction, PCA basis, environment maps, geometry, rendering matrix, pixel selection, solve,
//!   the models). No async, no drivers, no HTTP (`tests/layers.rs` checks its dependencies).
//! - `brdfd-eval` (`crates/eval`): relighting under maps an estimate never saw, through the one
//!   estimate pipeline, and the paper's protocol. See docs/architecture.md for the layers.
//! - [`bench`](mod@bench): the virtual bench: renders what a camera on a simulated rig would see.
//! - [`radiometry`]: camera files to linear radiance (EXIF exposure, HDR merge).
//! - [`panorama`]: 360° camera files to environment maps (GPano projection, bracket merge).
//! - [`pose`]: the object camera's pose and focal length from a photo of a printed board.
//! - [`config`]: the daemon, rig and material files, validated.
//! - [`session`]: sessions on disk (manifest state machine, raw files with sha256, atomic
//!   writes).
//! - [`selector`]: the strings that name devices (`usb:04b0:0429`, `osc:http://...`, ...).
//! - `brdfd-report` (`crates/report`), re-exported: [`results`], the files an estimate leaves
//!   behind; [`export`], the estimate as a glTF material and an OpenPBR `.mtlx`, fitted to how
//!   it relights; [`html`], its `report.html`; [`compare`], its photo-against-estimate picture;
//!   [`summary`], the judged lines it is reported in.
//! - [`rig`]: the devices on their worker threads, and the capture flow.
//! - [`daemon`]: `brdfd serve`: the devices kept open, one capture at a time, the HTTP API.
//! - `drivers/` (workspace crates, as they land): device protocols and their simulators.

pub use brdfd_bench as bench;
pub mod config;
pub mod daemon;
/// The camera's pose from a printed board, and an object's placement from its silhouettes:
/// its own crate, re-exported where the library's modules have always found it.
pub use brdfd_pose as pose;
/// Camera files to linear values: its own crate, re-exported where the library's modules
/// have always found it.
pub use brdfd_radiometry as radiometry;
/// 360° camera files to environment maps: in the radiometry crate, re-exported where the
/// library's modules have always found it.
pub use brdfd_radiometry::panorama;
/// What an estimate is written as for people and renderers: its own crate, re-exported where
/// the library's modules have always found it (the report itself is now `html`).
pub use brdfd_report::{compare, export, flags, html, results, summary};
pub mod rig;
pub mod selector;
pub mod session;
