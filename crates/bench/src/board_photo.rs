//! The printed pose board on the virtual bench, as the object camera sees it: a flat
//! Lambertian card of the board's pattern (paper and ink), lit by the bench's light, in front
//! of a dim bench. Each pixel averages 4 × 4 rays; the lens's blur and the sensor's noise are
//! added to the radiance, and the camera's 8-bit files quantise it.

use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use rayon::prelude::*;

use brdfd_core::brdf::{add, dot, scale, sub, Vec3};
use brdfd_core::envmap::EnvMap;
use brdfd_core::geometry::Camera;
use brdfd_core::raster::Raster;
use brdfd_pose::board::{Board, PAPER};

/// Rays per pixel, each way.
const SUPERSAMPLE: usize = 4;
/// Lights the board's irradiance is summed over (it is flat and alone: no shadows).
const LIGHTS: usize = 4_096;
/// The bench behind the board, as a share of the paper's radiance.
const BACKGROUND: f32 = 0.2;

/// How the photo is spoiled, as a real one is.
#[derive(Debug, Clone, Copy)]
pub struct Spoil {
    /// The lens's blur: a Gaussian of this σ, pixels.
    pub blur_px: f64,
    /// Sensor noise: a Gaussian of this σ, relative to the paper's radiance.
    pub noise: f64,
    pub seed: u64,
}

impl Default for Spoil {
    /// A slightly soft lens, and noise of about 2 of 255 on the paper.
    fn default() -> Self {
        Spoil {
            blur_px: 0.7,
            noise: 0.01,
            seed: 1,
        }
    }
}

/// The board photographed by `camera` under `env` turned by `yaw`: linear radiance in the
/// bench's unit (as [`super::VirtualBench::photo`]).
pub fn render(
    board: &Board,
    camera: &Camera,
    env: &EnvMap,
    yaw: f64,
    spoil: Spoil,
) -> Result<Raster, crate::PhotoError> {
    let pattern = board.pattern()?;
    let normal = board.normal();
    let centre = board.world([board.size_mm().0 / 2.0, board.size_mm().1 / 2.0]);
    // The board's in-plane axes in the world, per millimetre of the pattern (x across, y down).
    let origin = board.world([0.0, 0.0]);
    let across = sub(board.world([1.0, 0.0]), origin);
    let down = sub(board.world([0.0, 1.0]), origin);
    let mm_per_m2 = 1.0 / dot(across, across);
    let lights = env.compressed(LIGHTS, yaw);
    let irradiance = lights.irradiance_facing(normal);
    let radiance_of = |albedo: f64| irradiance.map(|e| (albedo / std::f64::consts::PI * e) as f32);
    let paper = radiance_of(PAPER);
    let background = paper.map(|p| p * BACKGROUND);
    photograph(
        camera,
        |o, d| {
            let facing = dot(d, normal);
            let t = dot(sub(centre, o), normal) / facing;
            let value = if facing < 0.0 && t > 0.0 {
                let rel = sub(add(o, scale(d, t)), origin);
                let (mx, my) = (dot(rel, across) * mm_per_m2, dot(rel, down) * mm_per_m2);
                pattern.at(mx, my).map(radiance_of)
            } else {
                None
            };
            value.unwrap_or(background)
        },
        spoil,
        paper,
    )
}

/// What `camera` sees where `radiance` says what each ray from `o` along `d` meets: each
/// pixel the mean of 4 × 4 rays, then spoiled (`reference`: what the noise is relative to).
pub fn photograph(
    camera: &Camera,
    radiance: impl Fn(Vec3, Vec3) -> [f32; 3] + Sync,
    spoil: Spoil,
    reference: [f32; 3],
) -> Result<Raster, crate::PhotoError> {
    let (w, h) = camera.size();
    camera.ray_through(0.5, 0.5)?;
    let mut pixels = vec![[0.0f32; 3]; w * h];
    pixels.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, out) in row.iter_mut().enumerate() {
            let mut sum = [0.0f32; 3];
            for sy in 0..SUPERSAMPLE {
                for sx in 0..SUPERSAMPLE {
                    let u = x as f64 + (sx as f64 + 0.5) / SUPERSAMPLE as f64;
                    let v = y as f64 + (sy as f64 + 0.5) / SUPERSAMPLE as f64;
                    let Ok((o, d)) = camera.ray_through(u, v) else {
                        continue;
                    };
                    let value = radiance(o, d);
                    for c in 0..3 {
                        sum[c] += value[c];
                    }
                }
            }
            let n = (SUPERSAMPLE * SUPERSAMPLE) as f32;
            *out = sum.map(|s| s / n);
        }
    });
    let mut raster = Raster {
        width: w,
        height: h,
        pixels,
    };
    spoil.apply(&mut raster, reference);
    Ok(raster)
}

impl Spoil {
    /// Blurs the radiance, then adds the noise, relative to `reference` (the paper's).
    pub fn apply(&self, raster: &mut Raster, reference: [f32; 3]) {
        blur(raster, self.blur_px);
        let mut rng = rand::rngs::StdRng::seed_from_u64(self.seed);
        if self.noise > 0.0 {
            let normal = Normal::new(0.0, self.noise).expect("a positive σ");
            for p in &mut raster.pixels {
                for c in 0..3 {
                    p[c] = (p[c] + reference[c] * normal.sample(&mut rng) as f32).max(0.0);
                }
            }
        }
    }
}

/// A separable Gaussian blur of σ pixels (none at 0), the image's edge repeated beyond it.
fn blur(r: &mut Raster, sigma: f64) {
    if sigma <= 0.0 {
        return;
    }
    let reach = (3.0 * sigma).ceil() as isize;
    let kernel: Vec<f32> = (-reach..=reach)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp() as f32)
        .collect();
    let total: f32 = kernel.iter().sum();
    let kernel: Vec<f32> = kernel.iter().map(|k| k / total).collect();
    let (w, h) = (r.width as isize, r.height as isize);
    let pass = |src: &[[f32; 3]], along_x: bool| -> Vec<[f32; 3]> {
        (0..w * h)
            .into_par_iter()
            .map(|i| {
                let (x, y) = (i % w, i / w);
                let mut acc = [0.0f32; 3];
                for (k, weight) in kernel.iter().enumerate() {
                    let o = k as isize - reach;
                    let (sx, sy) = if along_x {
                        ((x + o).clamp(0, w - 1), y)
                    } else {
                        (x, (y + o).clamp(0, h - 1))
                    };
                    let p = src[(sy * w + sx) as usize];
                    for c in 0..3 {
                        acc[c] += weight * p[c];
                    }
                }
                acc
            })
            .collect()
    };
    let across = pass(&r.pixels, true);
    r.pixels = pass(&across, false);
}
