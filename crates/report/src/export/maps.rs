//! The light an export is fitted and checked under: four real HDR panoramas embedded in the
//! binary, so that a bench without the data folder fits its exports the same way.
//!
//! They are the evaluation's CC0 maps (Blender's studio lights, from HDRI Haven: courtyard,
//! interior, sunrise, city; `LICENSE.blender-studiolights` in the reference data), averaged
//! down to 256 × 128 and stored as Radiance RGBE by
//! `regenerate_the_embedded_maps` below. Averaging keeps each region's power, which is what a
//! sphere's render under 512–4,096 compressed lights reads.

use brdfd_core::envmap::EnvMap;
use brdfd_core::{CoreError, Result};

/// Width of the embedded maps (height is half).
pub const WIDTH: usize = 256;

/// Each map's name and bytes.
const MAPS: [(&str, &[u8]); 4] = [
    ("courtyard", include_bytes!("maps/courtyard.hdr")),
    ("interior", include_bytes!("maps/interior.hdr")),
    ("sunrise", include_bytes!("maps/sunrise.hdr")),
    ("city", include_bytes!("maps/city.hdr")),
];

/// The embedded maps, by name.
pub fn reference_maps() -> Result<Vec<(&'static str, EnvMap)>> {
    MAPS.iter()
        .map(|(name, bytes)| {
            let what = format!("the embedded map {name}");
            let img = image::load_from_memory_with_format(bytes, image::ImageFormat::Hdr)
                .map_err(|e| CoreError::format(&what, format!("not a readable HDR: {e}")))?
                .into_rgb32f();
            let (w, h) = (img.width() as usize, img.height() as usize);
            let pixels = img.pixels().map(|p| p.0).collect();
            Ok((*name, EnvMap::from_pixels(w, h, pixels, &what)?))
        })
        .collect()
}

/// The embedded map `name` as its Radiance RGBE file, for a viewer to load.
pub fn reference_map_file(name: &str) -> Option<&'static [u8]> {
    MAPS.iter()
        .find(|(n, _)| *n == name)
        .map(|(_, bytes)| *bytes)
}

/// The embedded maps' names, in order: what a viewer offers beside the capture's light.
pub fn reference_map_names() -> Vec<&'static str> {
    MAPS.iter().map(|(name, _)| *name).collect()
}

/// `pixels` (`width` across) as a Radiance RGBE file; `what` names it in an error.
fn rgbe(pixels: &[[f32; 3]], width: usize, what: &str) -> Result<Vec<u8>> {
    let pixels: Vec<image::Rgb<f32>> = pixels.iter().map(|p| image::Rgb(*p)).collect();
    let mut bytes = Vec::new();
    image::codecs::hdr::HdrEncoder::new(&mut bytes)
        .encode(&pixels, width, pixels.len() / width)
        .map_err(|e| CoreError::format(what, format!("could not encode RGBE: {e}")))?;
    Ok(bytes)
}

/// The widest light map a result holds: a viewer's image-based lighting reads no finer.
const LIGHT_WIDTH: usize = 512;

/// Writes `map`, turned by `yaw` radians into the estimate's world, as Radiance RGBE at most
/// 512 wide: `light.hdr`, the capture's light for a viewer. The yaw is applied by turning the
/// columns, to the nearest column.
pub fn write_light(path: &std::path::Path, map: &EnvMap, yaw: f64) -> Result<()> {
    let map = if map.width > LIGHT_WIDTH {
        map.downsample(LIGHT_WIDTH, LIGHT_WIDTH / 2)
    } else {
        map.clone()
    };
    let (w, h) = (map.width, map.height);
    // Under yaw ψ the map's column u lights the world's column u − ψ/2π (envmap::direction).
    let shift = (yaw / std::f64::consts::TAU * w as f64).round() as isize;
    let turned: Vec<[f32; 3]> = (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            map.pixels[y * w + (x as isize + shift).rem_euclid(w as isize) as usize]
        })
        .collect();
    let bytes = rgbe(&turned, w, &path.display().to_string())?;
    std::fs::write(path, bytes).map_err(|e| CoreError::io(path, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_embedded_maps_load_and_are_lit() {
        let maps = reference_maps().unwrap();
        assert_eq!(maps.len(), 4);
        for (name, m) in maps {
            assert_eq!((m.width, m.height), (WIDTH, WIDTH / 2), "{name}");
            assert!(m.lights(0.0).power().iter().all(|p| *p > 0.0), "{name}");
        }
    }

    #[test]
    fn the_light_file_is_the_map_turned_by_its_yaw() {
        // One bright pixel on the horizon: its light's direction under the yaw is the file's
        // under none (and not the map's under none, a quarter turn away).
        let (w, h) = (64, 32);
        let mut pixels = vec![[0.01f32; 3]; w * h];
        pixels[16 * w + 40] = [5.0; 3];
        let map = EnvMap::from_pixels(w, h, pixels, "test").unwrap();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("light.hdr");
        let yaw = 90f64.to_radians();
        write_light(&path, &map, yaw).unwrap();
        let written = EnvMap::load(&path).unwrap();
        let brightest = |m: &EnvMap, yaw: f64| {
            let set = m.lights(yaw);
            let i = (0..set.len())
                .max_by(|&a, &b| set.radiance[a][0].total_cmp(&set.radiance[b][0]))
                .unwrap();
            set.directions[i]
        };
        let dot = |a: [f32; 3], b: [f32; 3]| -> f32 { (0..3).map(|k| a[k] * b[k]).sum() };
        let (a, b) = (brightest(&map, yaw), brightest(&written, 0.0));
        assert!(dot(a, b) > 0.99, "{a:?} against {b:?}");
        let unturned = brightest(&map, 0.0);
        assert!(dot(unturned, b) < 0.1, "the yaw was not applied: {b:?}");
    }

    /// Writes `maps/*.hdr` from the reference data beside the repository
    /// (`cargo test --release -p brdfd-report --lib export::maps -- --ignored`).
    #[test]
    #[ignore]
    fn regenerate_the_embedded_maps() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        for (name, _) in MAPS {
            let source = root.join(format!("../../../shared/data/envmaps/{name}.hdr"));
            let map = EnvMap::load(&source).unwrap().downsample(WIDTH, WIDTH / 2);
            let bytes = rgbe(&map.pixels, map.width, name).unwrap();
            std::fs::write(root.join(format!("src/export/maps/{name}.hdr")), bytes).unwrap();
        }
    }
}
