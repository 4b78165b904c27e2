//! Flags that name an assumption of brdfd's model which the photo says is broken, from the
//! structure of what the estimate leaves unexplained: a poor estimate must never look like
//! a good one, and "poor fit" alone does not say what to do about it.
//!
//! **Several materials.** One BRDF fitted to a part of two colours is a compromise: the photo
//! is redder than the estimate in one region and bluer in the other, while one material's
//! colour, changing with the angles, is what the models hold.
//!
//! **Interreflection.** brdfd lights each pixel with the map's light that the
//! part lets through, and nothing else; a concave part's grooves and inner faces also
//! receive what its own surface reflects. Those faces are the ones the part shades from
//! part of the room, and the more of it the part hides, the more of the part they see: among
//! faces turned the same way, the more shaded are brighter against the estimate. The
//! estimate takes the bounced light for the material's own, and its albedo comes out too
//! bright. On a convex part no face is shaded by the part, and nothing is flagged.
//!
//! **Anisotropy.** A brushed or machined metal, or a print's layer lines, stretch the
//! highlights across a grain, which the isotropic models cannot follow. The estimate
//! ([`brdfd_core::anisotropy`]) compares Lambert with one isotropic GGX lobe against Lambert
//! with one anisotropic lobe along a grain it searches for: when the anisotropic lobe
//! re-renders the photo much closer, the grain is there. The flag says whether the estimate
//! relights with that lobe, and what stays isotropic.
//!
//! **Misregistration.** A panorama whose north is set wrong, or a pose turned from the
//! object's, lights the estimate from the wrong side. The estimate
//! ([`brdfd_core::registration`]) refits Lambert and one isotropic lobe with the light turned
//! about the vertical, when its fit is not good; a turn that re-renders the photo much closer
//! is flagged, and the other flags, which read residuals under the wrong light, are not.
//!
//! Measured on brdfd's own Mitsuba set (`scripts/mitsuba-scenes.py`, docs/evaluation.md)
//! and the simulated presets: each scene that breaks an assumption is flagged for it, and no
//! scene within the model is flagged.

use std::collections::HashMap;

use serde::Serialize;

use crate::compare::luminance;
use crate::visibility::Visibility;
use brdfd_core::anisotropy::{Anisotropy, ASKS_BELOW};
use brdfd_core::estimate::{Estimate, Rerendered};
use brdfd_core::materials::colour_departure;
use brdfd_core::registration::{Registration, ASKS_BELOW as REGISTRATION_ASKS_BELOW};

/// A face is shaded when it sees less than this share of the light above its horizon: the
/// part hides more than a fifth of it (by irradiance, [`brdfd_core::render::visible_fraction`]).
const SHADED_BELOW: f32 = 0.8;
/// Shaded faces this much brighter against the estimate than faces turned the same way that
/// see the whole room are flagged. On the set's grooved parts, rendered with their bounces:
/// 1.69 (a plastic) and 2.37 (gold); rendered with direct light only: 0.99 and 0.92; the
/// simulated gold part (direct light): 0.78.
const BRIGHTER: f64 = 1.10;
/// Shaded pixels needed, at least, and as a share of the pixels compared: a few shaded
/// pixels at a silhouette's crease are not a concave part.
const MIN_SHADED: usize = 200;
const MIN_SHADED_SHARE: f64 = 0.02;

/// Which assumption a flag says is broken.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Reason {
    /// The part lights itself: light reflected by its own surface reaches its concave faces.
    Interreflection,
    /// The part carries materials of different colours: one BRDF fitted to all of it is
    /// none of them.
    SeveralMaterials,
    /// The surface has a grain: its highlights are stretched across one direction, which no
    /// isotropic model holds.
    Anisotropy,
    /// The light is turned from where the map and the pose put it.
    Misregistration,
}

/// A broken assumption, the figure that shows it, and what it means for the estimate.
#[derive(Clone, Debug, Serialize)]
pub struct Flag {
    pub reason: Reason,
    /// The measure (for interreflection: how much brighter, relative to the estimate, the
    /// shaded faces are than the open ones; for several materials: how far the photo's
    /// colour departs from the estimate's; for anisotropy: the anisotropic lobe's misfit
    /// over the isotropic one's).
    pub figure: f64,
    /// The evidence and what it means, in words.
    pub text: String,
}

impl Reason {
    /// The reason's code, as `coefficients.json` and the API write it.
    pub fn name(self) -> &'static str {
        match self {
            Reason::Interreflection => "interreflection",
            Reason::SeveralMaterials => "several_materials",
            Reason::Anisotropy => "anisotropy",
            Reason::Misregistration => "misregistration",
        }
    }
}

/// The flags an estimate's residuals raise. `visibility` is the first view's (none for a
/// shape that hides nothing from itself).
pub fn of(estimate: &Estimate, visibility: Option<&Visibility>) -> Vec<Flag> {
    // Under light turned from where it was, every residual reads the wrong light: the other
    // flags would name the material for what the map's yaw or the pose did.
    if let Some(turned) = estimate.registration.as_ref().and_then(misregistration) {
        return vec![turned];
    }
    let bounce =
        visibility.and_then(|v| interreflection(&estimate.rerender, v, estimate.bounce.is_some()));
    bounce
        .into_iter()
        .chain(several_materials(&estimate.rerender, visibility))
        .chain(estimate.anisotropy.as_ref().and_then(anisotropy))
        .collect()
}

/// Whether the photo fits much closer with the light turned about the vertical
/// ([`Registration::asks`]).
fn misregistration(r: &Registration) -> Option<Flag> {
    r.asks().then(|| Flag {
        reason: Reason::Misregistration,
        figure: r.ratio(),
        text: format!(
            "misregistration: the photo fits much closer with the light turned a further {:+.1}° about the vertical: Lambert with one GGX lobe re-renders it to {:.3} there, and to {:.3} as the map was given (flagged at {:.0}% of it or less). Add {:+.1}° to the map's yaw (--yaw, or theta_yaw_deg in the rig file), or, if the map's north is right, turn the object's pose by {:+.1}° about the vertical; the estimate was fitted to the wrong light, and its other figures say nothing of the material",
            r.turn_deg,
            r.turned_misfit,
            r.misfit,
            100.0 * REGISTRATION_ASKS_BELOW,
            r.turn_deg,
            -r.turn_deg,
        ),
    })
}

/// Whether an anisotropic lobe re-renders the photo much closer than any isotropic one
/// ([`Anisotropy::asks`]).
fn anisotropy(a: &Anisotropy) -> Option<Flag> {
    let figure = a.misfit_ratio();
    let consequence = if a.chosen {
        "The estimate relights with this lobe (coefficients.json's `anisotropy.lobe`, `brdfd render`, the glTF's KHR_materials_anisotropy and the .mtlx); the MERL-layout tables and the report's BRDF plots are isotropic, as the layout is, and are too sharp across the grain and too blurred along it"
    } else {
        "The estimate's own model re-renders the photo closer still, and is kept; it is isotropic, and is too sharp across the grain and too blurred along it"
    };
    a.asks().then(|| Flag {
        reason: Reason::Anisotropy,
        figure,
        text: format!(
            "anisotropy: the highlights are stretched across a grain; Lambert with an anisotropic GGX lobe (α {:.3} along the grain, {:.3} across it) re-renders the photo to {:.3}, where the best isotropic lobe gives {:.3} (flagged at {:.0}% of it or less); the grain runs along ({:.2}, {:.2}, {:.2}) in the object's frame. {consequence}",
            a.alpha_along,
            a.alpha_across,
            a.anisotropic_misfit,
            a.isotropic_misfit,
            100.0 * ASKS_BELOW,
            a.grain[0],
            a.grain[1],
            a.grain[2],
        ),
    })
}

/// Normals within a cell this wide (about 6°, in each of the unit normal's coordinates) face
/// the same way: a misfit that depends on the way a face turns is the same across the cell,
/// and only the light the part hides from it differs.
const NORMAL_CELL: f32 = 0.1;
/// A cell's pixels split into the more and the less shaded half must differ by at least
/// this much of their light hidden to say anything.
const MIN_CONTRAST: f64 = 0.05;
/// Pixels a cell needs in each half: a cell of a pixel or two at a shadow's edge would set
/// the slope by its noise.
const MIN_HALF: usize = 4;

/// Whether, among faces turned the same way, those the part hides more of the room from are
/// brighter against the estimate: the bounce light grows with the part a face sees of
/// itself. Comparing faces turned the same way keeps out a misfit that depends on the way a
/// face turns (a groove's walls face other parts of the map than the top does).
/// With `bounce_taken_out`, the estimate rendered its bounces back ([`brdfd_core::bounce`]):
/// what is left is more light than two bounces carry.
fn interreflection(
    rerender: &[Rerendered],
    visibility: &Visibility,
    bounce_taken_out: bool,
) -> Option<Flag> {
    // Per cell of normals: (hidden share, observed, predicted) of each pixel.
    let mut cells: HashMap<[i32; 3], Vec<(f64, f64, f64)>> = HashMap::new();
    let (mut shaded, mut shaded_hidden, mut compared) = (0usize, 0.0, 0usize);
    for r in rerender.iter().filter(|r| r.view == 0) {
        let Some((seen, normal)) = visibility.at(r.x as usize, r.y as usize) else {
            continue;
        };
        let hidden = f64::from(1.0 - seen);
        compared += 1;
        if seen < SHADED_BELOW {
            shaded += 1;
            shaded_hidden += hidden;
        }
        let cell = normal.map(|c| (c / NORMAL_CELL).round() as i32);
        cells.entry(cell).or_default().push((
            hidden,
            f64::from(luminance(r.observed)),
            f64::from(luminance(r.predicted)),
        ));
    }
    if shaded < MIN_SHADED || (shaded as f64) < MIN_SHADED_SHARE * compared as f64 {
        return None;
    }
    // Σ weight · ln(brightness of the more shaded half / the less), and Σ weight · the
    // difference in their hidden share: their quotient is the slope of ln(photo / estimate)
    // against the share of light hidden, within cells.
    let (mut rise, mut run, mut contributing) = (0.0, 0.0, 0usize);
    for pixels in cells.values_mut() {
        pixels.sort_by(|a, b| a.0.total_cmp(&b.0));
        let (less, more) = pixels.split_at(pixels.len() / 2);
        let sums = |half: &[(f64, f64, f64)]| {
            half.iter()
                .fold((0.0, 0.0, 0.0), |s, p| (s.0 + p.0, s.1 + p.1, s.2 + p.2))
        };
        let (l, m) = (sums(less), sums(more));
        if less.len() < MIN_HALF || !(l.2 > 0.0 && m.2 > 0.0 && l.1 > 0.0 && m.1 > 0.0) {
            continue;
        }
        let contrast = m.0 / more.len() as f64 - l.0 / less.len() as f64;
        if contrast < MIN_CONTRAST {
            continue;
        }
        let weight = pixels.len() as f64;
        rise += weight * ((m.1 / m.2) / (l.1 / l.2)).ln();
        run += weight * contrast;
        contributing += pixels.len();
    }
    // The slope is judged on as many pixels as the shaded faces are counted by.
    if run <= 0.0 || contributing < MIN_SHADED {
        return None;
    }
    // The photo against the estimate on the shaded faces, at their mean share hidden,
    // relative to a face that sees the whole room.
    let figure = (rise / run * shaded_hidden / shaded as f64).exp();
    (figure >= BRIGHTER).then(|| Flag {
        reason: Reason::Interreflection,
        figure,
        text: format!(
            "interreflection: the faces the part shades from part of the room ({:.0}% of its pixels) are {:.0}% brighter, against the estimate, than faces turned the same way that see all of it would be (flagged from {:.0}%); {}, so it is too bright (a map or pose that does not line up with the photo, or a black level or flare in it, can look the same)",
            100.0 * shaded as f64 / compared as f64,
            100.0 * (figure - 1.0),
            100.0 * (BRIGHTER - 1.0),
            if bounce_taken_out {
                "the part seems to light itself more than the two bounces the estimate takes out, and the estimate takes the rest for the material's own"
            } else {
                "the part seems to light itself, and the estimate, fitted with that light left in (--no-bounce), takes it for the material's own"
            }
        ),
    })
}

/// Blocks the first view's candidates are gathered into, about: each block's colour is the
/// mean of its pixels', so that the photo's noise averages out (6 × 6 pixels on the set's
/// dome, about 240 pixels across).
const COLOUR_BLOCKS: f64 = 1500.0;
/// Candidates a block needs, at least, for its colour to count.
const BLOCK_PIXELS: usize = 4;
/// Blocks needed, at least, to judge.
const MIN_BLOCKS: usize = 50;
/// The photo's colour departing from the estimate's by this much, RMS over the blocks (in
/// ln of red's and blue's shares of the light, about a uniform cast), is flagged. One
/// material's estimate departs by 0.02–0.03 on the set's domes and by 0.02–0.09 on the
/// simulated presets; brushed aluminium, one material outside the model, by 0.14; the gold
/// grooves' open faces, still lit by the gold around them, by 0.20; a blue plastic with a
/// gold stripe, by 0.69. The estimate splits a part into two materials by the same threshold,
/// on its own figure over smaller neighbourhoods of every view ([`brdfd_core::materials`]).
const COLOUR_DEPARTS: f64 = brdfd_core::materials::DEPARTS_FROM;

/// A block's sums of the photo and the estimate per channel, and its candidates.
#[derive(Default)]
struct Block {
    observed: [f64; 3],
    predicted: [f64; 3],
    pixels: usize,
}

/// Whether the photo's colour departs from the estimate's by region: one BRDF is a compromise
/// between the colours of several materials, redder than the one and bluer than the other,
/// while a material's own colour changing with the angles (a paint's white highlight) is what
/// the models hold. A cast over the whole photo (the map's white balance) is not a material's,
/// and is left out. Materials of one colour and different gloss are not seen by this.
fn several_materials(rerender: &[Rerendered], visibility: Option<&Visibility>) -> Option<Flag> {
    // Light bounced between a concave part's walls takes their colour again at each bounce:
    // the shaded faces are left out, so that one saturated material is not several.
    let open = |r: &Rerendered| {
        visibility
            .and_then(|v| v.at(r.x as usize, r.y as usize))
            .is_none_or(|(seen, _)| seen >= SHADED_BELOW)
    };
    let first: Vec<&Rerendered> = rerender.iter().filter(|r| r.view == 0 && open(r)).collect();
    if first.is_empty() {
        return None;
    }
    let (x0, x1) = first
        .iter()
        .fold((u32::MAX, 0), |(a, b), r| (a.min(r.x), b.max(r.x)));
    let (y0, y1) = first
        .iter()
        .fold((u32::MAX, 0), |(a, b), r| (a.min(r.y), b.max(r.y)));
    let area = f64::from(x1 - x0 + 1) * f64::from(y1 - y0 + 1);
    let side = ((area / COLOUR_BLOCKS).sqrt().round() as u32).max(2);
    let mut blocks: HashMap<(u32, u32), Block> = HashMap::new();
    for r in &first {
        let b = blocks.entry((r.x / side, r.y / side)).or_default();
        for c in 0..3 {
            b.observed[c] += f64::from(r.observed[c]);
            b.predicted[c] += f64::from(r.predicted[c]);
        }
        b.pixels += 1;
    }
    // The photo's share of red and of blue in the block's light against the estimate's (ln),
    // and the block's weight (the estimate's light).
    let departs: Vec<([f64; 2], f64)> = blocks
        .values()
        .filter(|b| b.pixels >= BLOCK_PIXELS)
        .filter_map(|b| {
            let d = colour_departure(&b.observed, &b.predicted)?;
            Some((d, b.predicted.iter().sum::<f64>()))
        })
        .collect();
    if departs.len() < MIN_BLOCKS {
        return None;
    }
    let total: f64 = departs.iter().map(|d| d.1).sum();
    let mean = [0, 1].map(|k| departs.iter().map(|d| d.0[k] * d.1).sum::<f64>() / total);
    let figure = (departs
        .iter()
        .map(|(d, w)| w * ((d[0] - mean[0]).powi(2) + (d[1] - mean[1]).powi(2)))
        .sum::<f64>()
        / total)
        .sqrt();
    (figure >= COLOUR_DEPARTS).then(|| Flag {
        reason: Reason::SeveralMaterials,
        figure,
        text: format!(
            "several materials: the photo's colour departs from the estimate's by {figure:.2} from place to place (RMS of ln colour shares; flagged from {COLOUR_DEPARTS}; single materials measured up to 0.2, a concave gold part's walls lighting each other); the part seems to carry materials of different colours, and one BRDF fitted to all of it is none of them",
        ),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use brdfd_core::raster::Raster;

    /// A 40 × 40 image of faces turned one way (`normal` of each column), the part hiding
    /// `hidden(x)` of each column's light, and a photo `gain(x)` times the estimate.
    fn part(
        normal: impl Fn(usize) -> [f32; 3],
        hidden: impl Fn(usize) -> f32,
        gain: impl Fn(usize) -> f32,
    ) -> Vec<Flag> {
        let mut fraction = Raster::black(40, 40);
        let mut normals = vec![None; 40 * 40];
        let mut rerender = Vec::new();
        for y in 0..40 {
            for x in 0..40 {
                fraction.set(x, y, [1.0 - hidden(x); 3]);
                normals[y * 40 + x] = Some(normal(x));
                let predicted = [0.2, 0.3, 0.1];
                rerender.push(Rerendered {
                    view: 0,
                    x: x as u32,
                    y: y as u32,
                    predicted,
                    observed: predicted.map(|v| v * gain(x)),
                });
            }
        }
        let visibility = Visibility::new(fraction, normals, 1);
        interreflection(&rerender, &visibility, false)
            .into_iter()
            .collect()
    }

    /// A groove's wall: turned one way, hiding from none to half of its light, brighter
    /// against the estimate by `k` per share hidden.
    fn wall(k: f32) -> Vec<Flag> {
        let hidden = |x: usize| 0.5 * x as f32 / 39.0;
        part(|_| [0.0, 0.0, 1.0], hidden, |x| 1.0 + k * hidden(x))
    }

    #[test]
    fn shaded_faces_brighter_than_the_estimate_are_flagged_as_interreflection() {
        let f = wall(1.0);
        assert_eq!(f.len(), 1);
        assert_eq!(f[0].reason, Reason::Interreflection);
        // At the shaded columns' mean share hidden (0.35), 1.35 times as bright as with
        // none hidden; the slope of ln between the halves comes out a little under it.
        assert!((f[0].figure - 1.33).abs() < 0.03, "{}", f[0].figure);
        assert!(f[0].text.contains("interreflection"), "{}", f[0].text);
    }

    #[test]
    fn shaded_faces_that_the_estimate_explains_are_not_flagged() {
        assert!(wall(0.0).is_empty());
        assert!(wall(0.2).is_empty());
        // Darker than the estimate where more is hidden is not light from the part.
        assert!(wall(-1.0).is_empty());
    }

    #[test]
    fn a_misfit_that_follows_the_way_a_face_turns_is_not_interreflection() {
        // The shaded half faces another way, and the estimate misses it by 30% however much
        // the part hides from it.
        let f = part(
            |x| {
                if x < 20 {
                    [0.8, 0.0, 0.6]
                } else {
                    [0.0, 0.0, 1.0]
                }
            },
            |x| if x < 20 { 0.5 } else { 0.0 },
            |x| if x < 20 { 1.3 } else { 1.0 },
        );
        assert!(f.is_empty(), "{f:?}");
    }

    fn several_materials_of(rerender: &[Rerendered]) -> Option<Flag> {
        several_materials(rerender, None)
    }

    /// A 60 × 60 part whose photo is `left` and `right` times the estimate per channel in
    /// its two halves, with a little noise.
    fn two_halves(left: [f32; 3], right: [f32; 3]) -> Vec<Rerendered> {
        let mut out = Vec::new();
        for y in 0..60u32 {
            for x in 0..60u32 {
                let gain = if x < 30 { left } else { right };
                let noise = 1.0 + 0.05 * (((x * 7919 + y * 104729) % 101) as f32 / 50.0 - 1.0);
                let predicted = [0.3, 0.25, 0.2];
                out.push(Rerendered {
                    view: 0,
                    x,
                    y,
                    predicted,
                    observed: std::array::from_fn(|c| predicted[c] * gain[c] * noise),
                });
            }
        }
        out
    }

    #[test]
    fn a_photo_redder_than_the_estimate_here_and_bluer_there_is_flagged_as_several_materials() {
        let f = several_materials_of(&two_halves([1.5, 1.0, 0.7], [0.7, 1.0, 1.4])).unwrap();
        assert_eq!(f.reason, Reason::SeveralMaterials);
        // Each half's shares of red and blue against the estimate's, about their mean: half
        // the difference between the halves, in each share.
        let p = [0.3, 0.25, 0.2];
        let shares = |g: [f64; 3]| {
            let o: Vec<f64> = (0..3).map(|c| p[c] * g[c]).collect();
            let (so, sp) = (o.iter().sum::<f64>(), p.iter().sum::<f64>());
            [0, 2].map(|c| (o[c] / so).ln() - (p[c] / sp).ln())
        };
        let (l, r) = (shares([1.5, 1.0, 0.7]), shares([0.7, 1.0, 1.4]));
        let expected = (((l[0] - r[0]) / 2.0).powi(2) + ((l[1] - r[1]) / 2.0).powi(2)).sqrt();
        assert!(
            (f.figure - expected).abs() < 0.02,
            "{} against {expected}",
            f.figure
        );
    }

    #[test]
    fn a_saturated_material_with_next_to_no_green_is_one_material() {
        // A deep red: its green is noise, which ratios to green would have made a colour.
        let mut red = two_halves([1.0; 3], [1.0; 3]);
        for (i, r) in red.iter_mut().enumerate() {
            r.predicted = [0.5, 0.001, 0.01];
            let noise = 1.0 + 0.9 * ((i * 37 % 11) as f32 / 5.0 - 1.0);
            r.observed = [0.5, 0.001 * noise, 0.01];
        }
        assert!(several_materials_of(&red).is_none());
    }

    #[test]
    fn each_reason_is_written_by_the_name_the_api_gives_it() {
        for reason in [
            Reason::Interreflection,
            Reason::SeveralMaterials,
            Reason::Anisotropy,
            Reason::Misregistration,
        ] {
            let json = serde_json::to_value(reason).unwrap();
            assert_eq!(json, reason.name());
        }
    }

    fn compared(isotropic: f64, anisotropic: f64, along: f64, across: f64) -> Anisotropy {
        Anisotropy {
            isotropic_misfit: isotropic,
            isotropic_alpha: 0.15,
            anisotropic_misfit: anisotropic,
            axis: [1.0, 0.0, 0.0],
            smooth_along_axis: true,
            grain: [1.0, 0.0, 0.0],
            alpha_along: along,
            alpha_across: across,
            pixels: 1000,
            lobe: brdfd_core::anisotropic::AnisotropicLobe {
                diffuse: [0.0; 3],
                specular: [1.0; 3],
                axis: [1.0, 0.0, 0.0],
                alpha_t: along,
                alpha_b: across,
            },
            chosen: false,
        }
    }

    #[test]
    fn a_much_closer_turn_is_misregistration_and_no_turn_or_a_little_closer_one_is_not() {
        let turned = |turn_deg: f64, turned_misfit: f64| Registration {
            misfit: 0.3,
            turn_deg,
            turned_misfit,
            pixels: 1000,
        };
        let flag = misregistration(&turned(-10.0, 0.15)).expect("flagged");
        assert_eq!(flag.reason, Reason::Misregistration);
        assert!((flag.figure - 0.5).abs() < 1e-12, "{}", flag.figure);
        assert!(
            flag.text.contains("Add -10.0° to the map's yaw"),
            "{}",
            flag.text
        );
        assert!(flag.text.contains("pose by +10.0°"), "{}", flag.text);
        // At the threshold, and just above it.
        assert!(misregistration(&turned(5.0, 0.24)).is_some());
        assert!(misregistration(&turned(5.0, 0.2403)).is_none());
        // No turn fits better.
        assert!(misregistration(&turned(0.0, 0.3)).is_none());
    }

    #[test]
    fn a_much_closer_stretched_lobe_is_anisotropy_and_a_little_closer_or_round_one_is_not() {
        let flag = anisotropy(&compared(0.2, 0.06, 0.06, 0.24)).expect("flagged");
        assert_eq!(flag.reason, Reason::Anisotropy);
        assert!((flag.figure - 0.3).abs() < 1e-12, "{}", flag.figure);
        assert!(
            flag.text.contains("0.060 along the grain, 0.240 across"),
            "{}",
            flag.text
        );
        // At the threshold, and just above it.
        assert!(anisotropy(&compared(0.2, 0.15, 0.06, 0.24)).is_some());
        assert!(anisotropy(&compared(0.2, 0.152, 0.06, 0.24)).is_none());
        // Much closer, but as rough both ways: a better lobe, not a grain.
        assert!(anisotropy(&compared(0.2, 0.06, 0.15, 0.2)).is_none());
        // A black photo's comparison says nothing.
        assert!(anisotropy(&compared(0.0, 0.0, 0.06, 0.24)).is_none());
    }

    #[test]
    fn a_cast_over_the_whole_photo_or_brightness_alone_is_not_several_materials() {
        // The map's white balance: the same cast everywhere.
        assert!(several_materials_of(&two_halves([1.3, 1.0, 0.8], [1.3, 1.0, 0.8])).is_none());
        // Brighter in one half, the same colour: not a colour of its own.
        assert!(several_materials_of(&two_halves([1.4, 1.4, 1.4], [0.8, 0.8, 0.8])).is_none());
    }
}
