//! Geometry from the command line: a TOML file, a normal map, or a built-in shape seen by the
//! evaluation's orthographic camera.

use std::path::PathBuf;

use anyhow::Context;
use brdfd_core::geometry::{Camera, SceneGeometry, Shape};

#[derive(clap::Args, Clone)]
pub struct GeometryArgs {
    /// Geometry file (TOML: [camera] and [shape], or normal_map).
    #[arg(long, conflicts_with_all = ["shape", "normal_map"])]
    pub geometry: Option<PathBuf>,
    /// Built-in shape under an orthographic camera looking down −Z that spans 2 world units.
    #[arg(long, value_parser = ["sphere", "plane", "corrugated"])]
    pub shape: Option<String>,
    /// World-frame normal map (EXR, RGB = normal); the camera is the orthographic default.
    #[arg(long)]
    pub normal_map: Option<PathBuf>,
}

impl GeometryArgs {
    /// The geometry given; an error that lists the choices if none was. An estimate made on
    /// an assumed shape would be wrong without a word, so nothing is assumed.
    pub fn scene(&self) -> anyhow::Result<SceneGeometry> {
        if self.geometry.is_none() && self.shape.is_none() && self.normal_map.is_none() {
            anyhow::bail!(
                "no geometry given: the estimate needs the object's shape. Give one of --geometry FILE (a TOML [camera] and [shape], or normal_map), --normal-map FILE.exr, or --shape sphere|plane|corrugated (a built-in shape under the default orthographic camera)"
            );
        }
        self.scene_or_sphere()
    }

    /// The geometry given, or the unit sphere (for renders, where a sphere is the usual
    /// preview).
    pub fn scene_or_sphere(&self) -> anyhow::Result<SceneGeometry> {
        if let Some(path) = &self.geometry {
            return SceneGeometry::read(path)
                .with_context(|| format!("reading geometry {}", path.display()));
        }
        let camera = Camera::eval_orthographic(256);
        if let Some(nm) = &self.normal_map {
            return Ok(SceneGeometry {
                camera,
                shape: None,
                normal_map: Some(nm.clone()),
            });
        }
        let shape = match self.shape.as_deref().unwrap_or("sphere") {
            "plane" => Shape::Plane {
                center: [0.0; 3],
                normal: [0.0, 0.5, 1.0],
                half_size: 0.9,
            },
            "corrugated" => Shape::Corrugated {
                center: [0.0; 3],
                half_size: 0.9,
                amplitude: 0.12,
                period: 0.6,
                tilt_deg: 25.0,
            },
            _ => Shape::unit_sphere(),
        };
        Ok(SceneGeometry {
            camera,
            shape: Some(shape),
            normal_map: None,
        })
    }
}
