//! The virtual bench: a known material on a known shape under a known light, rendered the way
//! the rig's cameras would see it. The device simulators serve these images, and tests and
//! `brdfd capture --simulate` use them, so a user without hardware runs the whole flow.
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

use brdfd_core::bivariate::Bivariate;
use brdfd_core::envmap::{EnvMap, LightSet};
use brdfd_core::geometry::{Camera, PixelGeometry, SceneGeometry, Shape};
use brdfd_core::merl::MerlBrdf;
use brdfd_core::nbrdf::NbrdfSet;
use brdfd_core::raster::Raster;
use brdfd_core::render::{render_bivariate, render_merl_until};
use brdfd_core::stop::Stop;
use brdfd_core::Result;

use cache::{Key, RenderCache};

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

/// MERL name for a material name or alias.
pub fn resolve_material(name: &str) -> &str {
    ALIASES
        .iter()
        .find(|(a, _)| *a == name)
        .map_or(name, |(_, m)| m)
}

/// A procedural studio: sky gradient, warm floor, a large soft key light front-right, a cooler
/// fill light left and a small bright window behind. Asymmetric on purpose, so orientation
/// errors show. Radiance in arbitrary linear units.
pub fn studio_envmap(width: usize) -> EnvMap {
    let lights: [([f64; 3], f64, [f32; 3]); 3] = [
        // direction, angular radius (rad), radiance
        (unit([0.6, 0.55, 0.55]), 0.30, [40.0, 38.0, 34.0]),
        (unit([-0.8, 0.3, -0.3]), 0.45, [6.0, 7.0, 9.0]),
        (unit([0.1, 0.35, -0.95]), 0.08, [300.0, 300.0, 280.0]),
    ];
    procedural_map(width, "procedural studio", |d| {
        let mut l = if d[1] > 0.0 {
            let t = d[1] as f32;
            [0.6 + 0.2 * t, 0.7 + 0.3 * t, 0.9 + 0.6 * t]
        } else {
            [0.35, 0.28, 0.2]
        };
        for (dir, radius, rad) in &lights {
            let cos = d.iter().zip(dir).map(|(a, b)| a * b).sum::<f64>();
            if cos > radius.cos() {
                for c in 0..3 {
                    l[c] += rad[c];
                }
            }
        }
        l
    })
}

/// An equirectangular map `width` × `width / 2` whose pixels are `radiance` of their centre's
/// direction.
fn procedural_map(width: usize, name: &str, radiance: impl Fn([f64; 3]) -> [f32; 3]) -> EnvMap {
    let height = width / 2;
    let mut pixels = Vec::with_capacity(width * height);
    for y in 0..height {
        for x in 0..width {
            pixels.push(radiance(brdfd_core::envmap::direction(
                (x as f64 + 0.5) / width as f64,
                (y as f64 + 0.5) / height as f64,
                0.0,
            )));
        }
    }
    EnvMap::from_pixels(width, height, pixels, name).expect("procedural map is finite")
}

/// A procedural daylight: a blue sky brightening towards the horizon, a small sun 35° up
/// over the left shoulder of a camera looking down −z, and grey ground. The second reference
/// light (after [`studio_envmap`]) that reports relight every estimate under: one hard light,
/// where the studio has soft ones. Radiance in arbitrary linear units.
pub fn daylight_envmap(width: usize) -> EnvMap {
    let sun = unit([-0.45, 0.57, 0.68]);
    // About 1.7°: larger than the real sun, so that a coarse map holds it.
    let sun_radius = 0.03f64;
    procedural_map(width, "procedural daylight", |d| {
        let cos = d.iter().zip(&sun).map(|(a, b)| a * b).sum::<f64>();
        if cos > sun_radius.cos() {
            [3000.0, 2900.0, 2600.0]
        } else if d[1] > 0.0 {
            let t = (1.0 - d[1] as f32).powi(3);
            [0.25 + 0.65 * t, 0.45 + 0.5 * t, 1.0 + 0.1 * t]
        } else {
            [0.22, 0.21, 0.19]
        }
    })
}

/// The reference lights every report relights its estimate under, by name.
pub fn reference_maps() -> [(&'static str, EnvMap); 2] {
    [
        ("studio", studio_envmap(512)),
        ("daylight", daylight_envmap(512)),
    ]
}

fn unit(v: [f64; 3]) -> [f64; 3] {
    brdfd_core::brdf::normalize(v)
}

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
    pub material: MerlBrdf,
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
            material: MerlBrdf::tabulate(fit),
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

    /// The linear radiance the object camera records (before any camera response).
    pub fn photo(&self) -> Result<Raster> {
        self.cached("photo", self.yaw, &self.geometry, || {
            let lights: LightSet = self.env.compressed(PHOTO_LIGHTS, self.yaw);
            render_merl_until(&self.pixels()?, &lights, &self.material, &self.stop)
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
        self.relight_error_with(&self.relight_truth()?, estimate)
    }

    /// The truth of [`VirtualBench::relight_error`]: the material under the held-out light.
    pub fn relight_truth(&self) -> Result<Raster> {
        let (sphere, lights, yaw) = self.held_out()?;
        self.cached(
            "relight truth",
            yaw,
            &default_geometry(RELIGHT_SIZE),
            || render_merl_until(&sphere, &lights, &self.material, &self.stop),
        )
    }

    /// [`VirtualBench::relight_error`] against a truth rendered beforehand.
    pub fn relight_error_with(&self, truth: &Raster, estimate: &Bivariate) -> Result<f64> {
        let (sphere, lights, _) = self.held_out()?;
        Ok(render_bivariate(&sphere, &lights, estimate).relative_rmse(truth))
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

/// The turn of the bench's map under which [`VirtualBench::relight_error`] relights.
pub const HELD_OUT_YAW_DEG: f64 = 120.0;
/// Sphere size of [`VirtualBench::relight_error`]'s renders.
pub const RELIGHT_SIZE: usize = 128;
