//! The object on the virtual bench as the object camera sees it for its silhouette: the raw
//! print (a grey Lambertian surface, unshadowed) lit by the bench's light, on white card; or
//! the card alone. The card is what a bench lays down for it: a grey print's faces turned from
//! the light are as dark as a grey bench, and a face turned down (lit by nothing but the
//! floor) as dark as black cloth, and a mask against either loses them; against white card a
//! print of half its albedo differs everywhere but in a face lit 1.8 times as brightly as the card.
//! Each pixel averages 4 × 4 rays, and the photo is spoiled as the board's is ([`Spoil`]).

use super::board_photo::{photograph, Spoil};
use crate::pose::board::PAPER;
use brdfd_core::brdf::{cross, dot, normalize, scale, sub, Vec3};
use brdfd_core::bvh::Bvh;
use brdfd_core::envmap::EnvMap;
use brdfd_core::geometry::Camera;
use brdfd_core::mesh::Mesh;
use brdfd_core::raster::Raster;

/// Lights the print's irradiance is summed over: it is smooth in the normal.
const LIGHTS: usize = 256;
/// A grey print's albedo.
const PRINT: f64 = 0.5;
/// White card's albedo.
const CARD: f64 = 0.9;

/// `mesh` (or the empty bench, for `None`) photographed by `camera` under `env` turned by
/// `yaw`: linear radiance in the bench's unit, and white paper's facing up (what the noise is
/// relative to, and what an exposure is set by).
pub fn render(
    mesh: Option<&Mesh>,
    camera: &Camera,
    env: &EnvMap,
    yaw: f64,
    spoil: Spoil,
) -> anyhow::Result<(Raster, [f32; 3])> {
    let lights = env.compressed(LIGHTS, yaw);
    let irradiance = |n: Vec3| lights.irradiance_facing(n);
    let radiance_of =
        |albedo: f64, e: [f64; 3]| e.map(|e| (albedo / std::f64::consts::PI * e) as f32);
    let paper = radiance_of(PAPER, irradiance([0.0, 1.0, 0.0]));
    let bench = radiance_of(CARD, irradiance([0.0, 1.0, 0.0]));
    let bvh = mesh.map(Bvh::build);
    let radiance = |o: Vec3, d: Vec3| {
        let (Some(bvh), Some(mesh)) = (&bvh, mesh) else {
            return bench;
        };
        match bvh.closest(o, d, 0.0, f64::INFINITY) {
            Some(hit) => {
                let [a, b, c] = mesh.corners(hit.triangle);
                let mut n = normalize(cross(sub(b, a), sub(c, a)));
                if dot(n, d) > 0.0 {
                    n = scale(n, -1.0);
                }
                radiance_of(PRINT, irradiance(n))
            }
            None => bench,
        }
    };
    Ok((photograph(camera, radiance, spoil, paper)?, paper))
}
