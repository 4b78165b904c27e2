//! The light an export is fitted and checked under: four real HDR panoramas embedded in the
//! binary, so that a bench without the data folder fits its exports the same way.
//!
//! They are the evaluation's CC0 maps (Blender's studio lights, from HDRI Haven: courtyard,
//! interior, sunrise, city; `LICENSE.blender-studiolights` in the reference data), averaged
//! down to 256 × 128 and stored as Radiance RGBE by
//! `regenerate_the_embedded_maps` below. Averaging keeps each region's power, which is what a
//! sphere's render under 1,024–4,096 compressed lights reads.

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

    /// Writes `maps/*.hdr` from the reference data beside the repository
    /// (`cargo test --release --lib export::maps -- --ignored`).
    #[test]
    #[ignore]
    fn regenerate_the_embedded_maps() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        for (name, _) in MAPS {
            let source = root.join(format!("../shared/data/envmaps/{name}.hdr"));
            let map = EnvMap::load(&source).unwrap().downsample(WIDTH, WIDTH / 2);
            let out =
                std::fs::File::create(root.join(format!("src/export/maps/{name}.hdr"))).unwrap();
            let pixels: Vec<image::Rgb<f32>> = map.pixels.iter().map(|p| image::Rgb(*p)).collect();
            image::codecs::hdr::HdrEncoder::new(std::io::BufWriter::new(out))
                .encode(&pixels, map.width, map.height)
                .unwrap();
        }
    }
}
