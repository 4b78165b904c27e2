//! The object on the virtual bench as the object camera sees it for its silhouette: the raw
//! print (a grey Lambertian surface, unshadowed) lit by the bench's light, on white card; or
//! the card alone. The card is what a bench lays down for it: a grey print's faces turned from
//! the light are as dark as a grey bench, and a face turned down (lit by nothing but the
//! floor) as dark as black cloth, and a mask against either loses them; against white card a
//! print of half its albedo differs everywhere but in a face lit 1.8 times as brightly as the card.
//! Each pixel averages 4 × 4 rays, and the photo is spoiled as the board's is ([`Spoil`]).

use super::board_photo::{photograph, Spoil};
use brdfd_core::brdf::{cross, dot, normalize, scale, sub, Vec3};
use brdfd_core::bvh::Bvh;
use brdfd_core::envmap::EnvMap;
use brdfd_core::geometry::Camera;
use brdfd_core::mesh::Mesh;
use brdfd_core::raster::Raster;
use brdfd_pose::board::PAPER;

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
) -> Result<(Raster, [f32; 3]), crate::PhotoError> {
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

#[cfg(test)]
mod tests {
    use super::*;
    use brdfd_core::geometry::{Pose, Shape};
    use brdfd_pose::silhouette::{refine, Mask, Offset, View};

    fn camera() -> Camera {
        Camera::Pinhole {
            width: 640,
            height: 424,
            fx: 2400.0,
            fy: 2400.0,
            cx: 320.0,
            cy: 212.0,
            pose: Pose {
                position: [0.0, 0.25, 1.2],
                look_at: [0.0, 0.0, 0.0],
                up: [0.0, 1.0, 0.0],
            },
        }
    }

    fn block() -> (Shape, Mesh) {
        let shape = Shape::Mesh {
            file: "builtin:grooved-block.obj".into(),
            units: brdfd_core::mesh::Units::Mm,
            rotation_deg: [-25.0, 0.0, 0.0],
            position: [0.0; 3],
        };
        let mesh = shape.mesh().unwrap().unwrap();
        (shape, mesh)
    }

    /// 8-bit sRGB grey, white paper facing up at 90% of the range.
    fn grey(r: &brdfd_core::raster::Raster, paper: [f32; 3]) -> image::GrayImage {
        let white = 0.2126 * paper[0] + 0.7152 * paper[1] + 0.0722 * paper[2];
        image::GrayImage::from_fn(r.width as u32, r.height as u32, |x, y| {
            let p = r.get(x as usize, y as usize);
            let lum = (0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2]) / white * 0.9;
            image::Luma([
                (brdfd_core::raster::linear_to_srgb(lum.clamp(0.0, 1.0)) * 255.0).round() as u8,
            ])
        })
    }

    /// The grooved block photographed at three turntable views, placed a few millimetres off
    /// and turned, against the empty bench: the search finds the offset from the photos'
    /// masks, blurred and noisy and in 8 bits as a camera's JPEG is.
    #[test]
    fn the_print_s_photos_give_its_offset() {
        let camera = camera();
        let (shape, believed) = block();
        let (lo, hi) = believed.bounds();
        let truth = Offset {
            shift: [0.00273, 0.00041, -0.00338],
            turn_deg: 1.73,
            pivot: [0, 1, 2].map(|i| (lo[i] + hi[i]) / 2.0),
        };
        let there = truth.placed(&shape).mesh().unwrap().unwrap();
        let env = crate::studio_envmap(256);
        let views: Vec<View> = [0.0f64, 30.0, -30.0]
            .iter()
            .enumerate()
            .map(|(i, &turn)| {
                let seen = camera.turned_about_y(-turn.to_radians());
                let yaw = -turn.to_radians();
                let spoil = |seed| Spoil {
                    seed,
                    ..Default::default()
                };
                let (empty, paper) = render(None, &seen, &env, yaw, spoil(2 * i as u64)).unwrap();
                let (object, _) =
                    render(Some(&there), &seen, &env, yaw, spoil(2 * i as u64 + 1)).unwrap();
                let mask =
                    Mask::from_photos(&grey(&empty, paper), &grey(&object, paper), "view").unwrap();
                View {
                    camera: camera.clone(),
                    turn_deg: turn,
                    mask,
                }
            })
            .collect();
        let found = refine(&believed, &views).unwrap();
        let o = found.offset;
        let miss = (0..3)
            .map(|i| (o.shift[i] - truth.shift[i]).powi(2))
            .sum::<f64>()
            .sqrt();
        assert!(miss < 2e-4, "{:.3} mm off: {o:?}", miss * 1e3);
        assert!((o.turn_deg - truth.turn_deg).abs() < 0.1, "{o:?}");
    }
}
