//! The procedural lights every report relights its estimate under, and the simulated bench's
//! default light: a studio of soft lights and a daylight with one hard sun. Radiance in
//! arbitrary linear units.

use brdfd_core::envmap::EnvMap;

fn unit(v: [f64; 3]) -> [f64; 3] {
    brdfd_core::brdf::normalize(v)
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
