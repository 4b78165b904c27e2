//! Is the light where the map says it is? A panorama whose north is set wrong (its yaw), or an
//! object placed turned from where the rig file says, lights every pixel from the wrong side.
//! The estimate then fits a BRDF to the wrong light: its misfit grows, and nothing in it says
//! why, since a material that reflected the light differently could as well be to blame.
//!
//! The evidence is a comparison of one model fitted under the map as given and under the map
//! turned about the vertical: Lambert plus one isotropic GGX lobe, its weights solved for each
//! turn ([`crate::anisotropy`]'s fit, on the same pixels). A material reflects a turned room no
//! better than the real one; when a turn re-renders the photo much closer, the light was
//! turned. Turns are tried every [`COARSE_STEP_DEG`] up to [`MAX_TURN_DEG`] each way, then
//! refined to a quarter of that step.
//!
//! A turned pose moves the object's normals with its view, which a turned map does not do
//! exactly; its photo still fits best under the map turned by about the pose's error about
//! the vertical, and the flag names both causes. Tilts about other axes are not searched.

use serde::Serialize;

use super::anisotropy::{isotropic_fit, merged, ViewSamples};
use super::brdf::rot_y;
use super::envmap::LightSet;
use super::stop::Stop;

/// Turns tried first, in degrees, each way, up to [`MAX_TURN_DEG`], which the refinement does
/// not pass either.
pub const COARSE_STEP_DEG: f64 = 5.0;
pub const MAX_TURN_DEG: f64 = 30.0;
/// Halvings of the step about the best coarse turn.
const REFINE_ROUNDS: usize = 2;
/// The best turn's misfit, over the misfit with the map as given, at or below which the photo
/// says the light is turned.
pub const ASKS_BELOW: f64 = 0.8;

/// The fit under the map as given, and under the turn that fits best.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Registration {
    /// ‖prediction − photo‖ / ‖photo‖ of Lambert plus the best isotropic GGX lobe, under the
    /// map as given.
    pub misfit: f64,
    /// The further turn of the map about +Y (degrees, right-handed, as `--yaw` turns it) that
    /// re-renders the photo closest; 0 when none does better.
    pub turn_deg: f64,
    /// The fit's misfit under that turn.
    pub turned_misfit: f64,
    /// Pixels compared.
    pub pixels: usize,
}

impl Registration {
    /// The best turn's misfit over the unturned one (1 when no turn is better).
    pub fn ratio(&self) -> f64 {
        if self.misfit > 0.0 {
            self.turned_misfit / self.misfit
        } else {
            1.0
        }
    }

    /// Whether the photo says the light is turned: a turn fits much closer ([`ASKS_BELOW`]).
    pub fn asks(&self) -> bool {
        self.turn_deg != 0.0 && self.ratio() <= ASKS_BELOW
    }
}

/// The comparison on the views' pixels; `None` with too few pixels, no light, or when the
/// estimate is asked to stop.
pub fn check(views: &[ViewSamples], stop: &Stop) -> Option<Registration> {
    // The lights are merged once and then turned: merged again after each turn, the cells'
    // grid would move against the light and change the misfit by itself.
    let merged: Vec<LightSet> = views.iter().map(|v| merged(v.lights)).collect();
    let misfit_at = |deg: f64| -> Option<f64> {
        let lights: Vec<LightSet> = merged.iter().map(|l| turned(l, deg)).collect();
        let turned: Vec<ViewSamples> = views
            .iter()
            .zip(&lights)
            .map(|(v, lights)| ViewSamples { lights, ..*v })
            .collect();
        isotropic_fit(&turned).map(|(_, m, _)| m)
    };
    let (_, misfit, pixels) = {
        let given: Vec<ViewSamples> = views
            .iter()
            .zip(&merged)
            .map(|(v, lights)| ViewSamples { lights, ..*v })
            .collect();
        isotropic_fit(&given)?
    };
    let mut best = (0.0, misfit);
    let consider = |deg: f64, best: &mut (f64, f64)| -> Option<()> {
        if stop.requested() {
            return None;
        }
        if let Some(m) = misfit_at(deg) {
            if m < best.1 {
                *best = (deg, m);
            }
        }
        Some(())
    };
    let steps = (MAX_TURN_DEG / COARSE_STEP_DEG).round() as i32;
    for k in (-steps..=steps).filter(|k| *k != 0) {
        consider(k as f64 * COARSE_STEP_DEG, &mut best)?;
    }
    let mut step = COARSE_STEP_DEG / 2.0;
    for _ in 0..REFINE_ROUNDS {
        let centre = best.0;
        let tries = [centre - step, centre + step];
        for deg in tries
            .into_iter()
            .filter(|d| *d != 0.0 && d.abs() <= MAX_TURN_DEG)
        {
            consider(deg, &mut best)?;
        }
        step /= 2.0;
    }
    Some(Registration {
        misfit,
        turn_deg: best.0,
        turned_misfit: best.1,
        pixels,
    })
}

/// The lights turned a further `deg` about +Y, right-handed (as a map's yaw turns it); the map
/// they were made from is left out, since nothing here reads it.
fn turned(lights: &LightSet, deg: f64) -> LightSet {
    LightSet {
        directions: lights
            .directions
            .iter()
            .map(|d| rot_y(d.map(f64::from), deg.to_radians()).map(|c| c as f32))
            .collect(),
        radiance: lights.radiance.clone(),
        solid_angle: lights.solid_angle.clone(),
        spread: lights.spread.clone(),
        map: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::normalize;
    use crate::geometry::GeomPixel;

    /// A room of point lights with one bright window and a dim sky, so that a highlight
    /// shows where the window is.
    fn room(count: usize) -> LightSet {
        let window = normalize([0.5, 0.6, 0.6]);
        let mut set = LightSet::default();
        for d in crate::brdf::fibonacci_sphere(count) {
            let y = d[1];
            let cos = d[0] * window[0] + d[1] * window[1] + d[2] * window[2];
            let bright = 30.0 * (-(1.0 - cos) / 0.01).exp() + 0.3 + 0.2 * y.max(0.0);
            set.directions.push(d.map(|x| x as f32));
            set.radiance.push([bright as f32; 3]);
            set.solid_angle
                .push((4.0 * std::f64::consts::PI / count as f64) as f32);
            set.spread.push(0.0);
        }
        set
    }

    /// A sphere seen straight on, and its photo: Lambert (0.3) plus a GGX lobe (α 0.15,
    /// weight 0.6) under `lights`, written out from its definition.
    fn sphere_photo(lights: &LightSet) -> (Vec<GeomPixel>, Vec<[f64; 3]>) {
        let lobe = crate::anisotropic::AnisotropicLobe {
            diffuse: [0.3; 3],
            specular: [0.6; 3],
            axis: [1.0, 0.0, 0.0],
            alpha_t: 0.15,
            alpha_b: 0.15,
        };
        let mut pixels = Vec::new();
        let n = 48;
        for y in 0..n {
            for x in 0..n {
                let u = (x as f64 + 0.5) / n as f64 * 2.0 - 1.0;
                let v = 1.0 - (y as f64 + 0.5) / n as f64 * 2.0;
                if u * u + v * v < 0.95 {
                    pixels.push(GeomPixel {
                        x: x as u32,
                        y: y as u32,
                        normal: [u, v, (1.0 - u * u - v * v).sqrt()].map(|c| c as f32),
                        view: [0.0, 0.0, 1.0],
                        shadow: None,
                    });
                }
            }
        }
        let photo = crate::anisotropy::render_lobe(&pixels, lights, &lobe);
        (pixels, photo)
    }

    #[test]
    fn a_photo_taken_under_a_turned_room_asks_for_the_turn() {
        let lights = room(4096);
        // The photo was lit by the room turned 12° further than the lights say.
        let (pixels, photo) = sphere_photo(&turned(&lights, 12.0));
        let views = [ViewSamples {
            pixels: &pixels,
            observed: &photo,
            lights: &lights,
        }];
        let r = check(&views, &Stop::default()).expect("enough pixels");
        assert!(r.asks(), "{r:?}");
        assert!((r.turn_deg - 12.0).abs() <= 1.25, "{r:?}");
        // Under the room as it was, nothing asks.
        let views = [ViewSamples {
            pixels: &pixels,
            observed: &photo,
            lights: &turned(&lights, 12.0),
        }];
        let r = check(&views, &Stop::default()).expect("enough pixels");
        assert!(!r.asks(), "{r:?}");
    }

    #[test]
    fn turning_lights_is_turning_the_map_by_its_yaw() {
        // A map whose pixels all differ, as lights at yaw 20° and then turned a further 12°,
        // against the same map's lights at yaw 32° (crate::envmap's convention).
        let (w, h) = (16, 8);
        let pixels = (0..w * h).map(|i| [i as f32, 1.0, 2.0]).collect();
        let map = crate::envmap::EnvMap::from_pixels(w, h, pixels, "test").unwrap();
        let at = |yaw_deg: f64| map.lights(yaw_deg.to_radians());
        let (turned, direct) = (turned(&at(20.0), 12.0), at(32.0));
        assert_eq!(turned.radiance, direct.radiance);
        for (a, b) in turned.directions.iter().zip(&direct.directions) {
            assert!((0..3).all(|k| (a[k] - b[k]).abs() < 1e-5), "{a:?} {b:?}");
        }
    }
}
