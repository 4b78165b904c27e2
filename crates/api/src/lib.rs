//! brdfd's contract with its clients: what the daemon's HTTP API takes and answers, and what
//! the capture flow reports as it goes. The daemon writes these types and the CLI reads them
//! back, so both sides of the wire are one definition; the OpenAPI description is derived
//! from them with the `schema` feature.
//!
//! - [`plan`]: what a capture is asked to do ([`plan::Plan`]), and the limits it is checked
//!   against before any device moves.
//! - [`event`]: what a running capture reports ([`event::Event`]), ending with its
//!   [`event::Summary`].
//! - [`failure`]: why a capture failed, as a code ([`failure::FailureCode`]).
//! - [`session`]: a session's manifest and its states.
//! - [`answers`]: the daemon's answers, and its errors with their codes.
//!
//! This crate sits above the estimation core (for the model, solver and colour choices a
//! plan names) and below everything that runs a capture: it holds no runtime, no HTTP stack
//! and no driver.

pub mod answers;
pub mod event;
pub mod failure;
pub mod plan;
pub mod session;
