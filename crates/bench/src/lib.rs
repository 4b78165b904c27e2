//! The virtual bench: a known material on a known shape under a known light, rendered the way
//! the rig's cameras would see it. The device simulators serve these images, and tests and
//! `brdfd capture --simulate` use them, so a user without hardware runs the whole flow.
//!
//! A crate of its own, above the core, pose (the printed board) and the report (its reference
//! lights). The capture flow does not import it: the simulated rig's devices and stage do, as
//! do the simulated calibration and pose photos and the checks of a simulated plan.
//!
//! Defaults are embedded so the binary needs no data folder: the NBRDF fits of the 10
//! evaluation test materials (derived data, see `test_materials.json` for provenance) and a
//! procedural studio environment written for this project.

pub mod board_photo;
pub mod cache;
pub mod camera;
pub mod object_photo;
pub mod panorama;
pub mod raw_file;
pub mod tiff;

use std::sync::Arc;

use brdfd_core::bivariate::Bivariate;
use brdfd_core::bounce;
use brdfd_core::brdf::{tangent_frame, IsotropicBrdf};
use brdfd_core::envmap::{EnvMap, LightSet};
use brdfd_core::geometry::{Camera, PixelGeometry, SceneGeometry, Shape};
use brdfd_core::merl::MerlBrdf;
use brdfd_core::nbrdf::NbrdfSet;
use brdfd_core::raster::Raster;
use brdfd_core::render::{render_bivariate, render_merl_until};
use brdfd_core::stop::Stop;
use brdfd_core::Result;

use cache::{Key, RenderCache};

/// Why a photo of a printed board or of an object on one could not be rendered.
#[derive(Debug, thiserror::Error)]
pub enum PhotoError {
    /// The board's file does not describe a board that can be drawn.
    #[error(transparent)]
    Board(#[from] brdfd_pose::PoseError),
    /// The camera, the map or the mesh (the core's own error).
    #[error(transparent)]
    Scene(#[from] brdfd_core::CoreError),
}

/// Short names a bench operator types, mapped to MERL names.
const ALIASES: [(&str, &str); 6] = [
    ("gold", "gold-metallic-paint"),
    ("chrome", "chrome-steel"),
    ("plastic", "red-specular-plastic"),
    ("paint", "white-paint"),
    ("fabric", "blue-fabric"),
    ("latex", "green-latex"),
];

/// Lights used to render simulated photos: finer than the estimate's default, so the
/// estimate's own compression counts as error, as it would with a real camera.
pub const PHOTO_LIGHTS: usize = 8_192;

pub fn embedded_materials() -> NbrdfSet {
    NbrdfSet::from_json(
        include_str!("test_materials.json"),
        "embedded test materials",
    )
    .expect("embedded materials are checked by tests")
}

/// The short names, as "alias (MERL name)".
pub fn aliases() -> Vec<String> {
    ALIASES.iter().map(|(a, m)| format!("{a} ({m})")).collect()
}

/// The short names alone.
pub fn alias_names() -> impl Iterator<Item = &'static str> {
    ALIASES.iter().map(|(a, _)| *a)
}

/// MERL name for a material name or alias.
pub fn resolve_material(name: &str) -> &str {
    ALIASES
        .iter()
        .find(|(a, _)| *a == name)
        .map_or(name, |(_, m)| m)
}

// The procedural studio and daylight are the reports' reference lights; the bench lights its
// scenes with the studio by default.
pub use brdfd_report::lights::{daylight_envmap, reference_maps, studio_envmap};

/// The simulated rig's geometry: an orthographic camera on a unit sphere.
pub fn default_geometry(size: usize) -> SceneGeometry {
    SceneGeometry {
        camera: Camera::eval_orthographic(size),
        shape: Some(Shape::unit_sphere()),
        normal_map: None,
    }
}

/// A material under a light, seen by a camera.
#[derive(Clone)]
pub struct VirtualBench {
    pub material_name: String,
    /// Shared: a turned bench is a clone, and the table is 35 MB.
    pub material: Arc<MerlBrdf>,
    pub env: EnvMap,
    /// Yaw of the panorama in the world, radians.
    pub yaw: f64,
    pub geometry: SceneGeometry,
    /// Where renders are kept between runs; none by default.
    pub cache: Option<RenderCache>,
    /// Ends a render early: a capture's cancel, so that it need not wait for the scene.
    pub stop: Stop,
}

impl VirtualBench {
    /// A bench with an embedded test material (name or alias) under the studio map.
    pub fn embedded(material: &str, size: usize) -> Result<VirtualBench> {
        let set = embedded_materials();
        let name = resolve_material(material);
        let fit = set.get(name)?;
        Ok(VirtualBench {
            material_name: name.to_string(),
            material: Arc::new(MerlBrdf::tabulate(fit)),
            env: studio_envmap(512),
            yaw: 0.0,
            geometry: default_geometry(size),
            cache: None,
            stop: Stop::default(),
        })
    }

    pub fn pixels(&self) -> Result<PixelGeometry> {
        let (w, h) = self.geometry.camera.size();
        self.geometry.pixels(w, h)
    }

    /// Keeps this bench's renders in `cache` between runs.
    pub fn with_cache(mut self, cache: Option<RenderCache>) -> VirtualBench {
        self.cache = cache;
        self
    }

    /// The linear radiance the object camera records (before any camera response): a
    /// concave mesh with the light it throws on itself (two bounces, [`brdfd_core::bounce`]).
    pub fn photo(&self) -> Result<Raster> {
        // The label is part of the render cache's key: photos cached with one bounce are
        // not these.
        self.cached("photo with two bounces", self.yaw, &self.geometry, || {
            let lights: LightSet = self.env.compressed(PHOTO_LIGHTS, self.yaw);
            let pixels = self.pixels()?;
            let mut photo = render_merl_until(&pixels, &lights, &self.material, &self.stop)?;
            let material = &*self.material;
            bounce::add_to_until(
                &mut photo,
                &pixels,
                &lights,
                &self.stop,
                tangent_frame,
                |wi, wo| material.eval_dirs(wi, wo),
            )?;
            Ok(photo)
        })
    }

    /// `render()`, or its image from the cache if this bench has one. The key holds what the
    /// render reads of the bench: the material, the map turned by `yaw`, and `geometry`.
    fn cached(
        &self,
        what: &str,
        yaw: f64,
        geometry: &SceneGeometry,
        render: impl FnOnce() -> Result<Raster>,
    ) -> Result<Raster> {
        // Without every part of the key, no cache: a wrong hit would be a wrong picture.
        let (Some(cache), Some(mut key), Ok(geometry_json)) =
            (&self.cache, Key::new(what), serde_json::to_string(geometry))
        else {
            return render();
        };
        key.add_f64s(self.material.values())
            .add(&(self.env.width as u64).to_le_bytes())
            .add_f32s(self.env.pixels.iter().flatten().copied())
            .add_f64s(&[yaw])
            .add(&(PHOTO_LIGHTS as u64).to_le_bytes())
            .add(geometry_json.as_bytes());
        // The map's or the mesh's file is read by the render: its size and time stand for its
        // content (a shipped mesh is the binary's own).
        let mesh = match &geometry.shape {
            Some(Shape::Mesh { file, .. }) if !brdfd_core::mesh::is_builtin(file) => Some(file),
            _ => None,
        };
        for path in geometry.normal_map.iter().chain(mesh) {
            let m = std::fs::metadata(path).ok();
            key.add(format!("{:?}", m.map(|m| (m.len(), m.modified().ok()))).as_bytes());
        }
        cache.get_or_render(&key, render)
    }

    /// How far `estimate` is from the bench's material under light it was not fitted to:
    /// the relative RMSE, over a sphere of [`RELIGHT_SIZE`]², between the estimate and the
    /// truth (the full table), both rendered under the bench's map turned [`HELD_OUT_YAW_DEG`]
    /// about the vertical, so that its bright regions light the object from other sides.
    pub fn relight_error(&self, estimate: &Bivariate) -> Result<f64> {
        Ok(self.relight_truth()?.error(estimate))
    }

    /// The truth of [`VirtualBench::relight_error`]: the material under the held-out light,
    /// with the sphere and lights it was rendered with, which the estimate is rendered with.
    pub fn relight_truth(&self) -> Result<RelightTruth> {
        let (sphere, lights, yaw) = self.held_out()?;
        let image = self.cached(
            "relight truth",
            yaw,
            &default_geometry(RELIGHT_SIZE),
            || render_merl_until(&sphere, &lights, &self.material, &self.stop),
        )?;
        Ok(RelightTruth {
            sphere,
            lights,
            image,
        })
    }

    /// The sphere and the light of the relight check, and the light's yaw.
    fn held_out(&self) -> Result<(PixelGeometry, LightSet, f64)> {
        let sphere = PixelGeometry::rasterize(
            &Camera::eval_orthographic(RELIGHT_SIZE),
            &Shape::unit_sphere(),
        )?;
        let yaw = self.yaw + HELD_OUT_YAW_DEG.to_radians();
        Ok((sphere, self.env.compressed(PHOTO_LIGHTS, yaw), yaw))
    }
}

/// The bench's material under the held-out light ([`VirtualBench::relight_truth`]), kept
/// with the sphere and the lights it was rendered with: the estimate's render needs them
/// too, and they cost a pass over the map to make again.
pub struct RelightTruth {
    sphere: PixelGeometry,
    lights: LightSet,
    pub image: Raster,
}

impl RelightTruth {
    /// [`VirtualBench::relight_error`] of `estimate` against this truth.
    pub fn error(&self, estimate: &Bivariate) -> f64 {
        render_bivariate(&self.sphere, &self.lights, estimate).relative_rmse(&self.image)
    }

    /// The same of what an estimate relights with: the anisotropic lobe it chose, if any,
    /// else its BRDF.
    pub fn error_of(&self, estimate: &brdfd_core::estimate::Estimate) -> f64 {
        match estimate.chosen_lobe() {
            Some(lobe) => brdfd_core::render::render_anisotropic(&self.sphere, &self.lights, lobe)
                .relative_rmse(&self.image),
            None => self.error(&estimate.brdf),
        }
    }
}

/// The turn of the bench's map under which [`VirtualBench::relight_error`] relights.
pub const HELD_OUT_YAW_DEG: f64 = 120.0;
/// Sphere size of [`VirtualBench::relight_error`]'s renders.
pub const RELIGHT_SIZE: usize = 128;
