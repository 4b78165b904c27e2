//! The estimation core: the paper's method (Hirasawa et al.) from BRDF data to coefficients.
//! Synchronous and free of device code: it imports neither tokio nor any driver.
//!
//! Data flow: [`merl`]/[`nbrdf`] sources → [`bivariate`] reduction → [`basis`] (PCA) →
//! [`render`] builds A from [`geometry`] and [`envmap`] lights → [`select`] picks pixels →
//! [`solve`] gives the coefficients; [`analytic`] and [`hybrid`] are the other models. [`estimate`] runs the chain;
//! `brdfd-eval`, a crate above this one, measures it from outside. A real part's shape is a [`mesh`], cast per
//! pixel through a [`bvh`]; what it hides of its own lights is [`visibility`], and the light
//! it throws on itself is [`bounce`].

pub mod analytic;
pub mod anisotropic;
pub mod anisotropy;
pub mod basis;
pub mod bivariate;
pub mod bounce;
pub mod brdf;
pub mod bvh;
pub mod envmap;
pub mod error;
pub mod estimate;
pub mod geometry;
pub mod hybrid;
pub mod materials;
pub mod merl;
pub mod mesh;
pub mod nbrdf;
pub mod nnls;
pub mod raster;
pub mod registration;
pub mod render;
pub mod select;
pub mod sharp;
pub mod solve;
pub mod stop;
pub mod uncertainty;
pub mod visibility;

pub use error::{CoreError, Result};
