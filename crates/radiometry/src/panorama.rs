//! 360° camera files to environment maps: the projection from the file's GPano XMP, the
//! exposure from its EXIF, and the HDR merge of a bracket into linear radiance.
//!
//! The map keeps the camera's own frame: the image centre is the THETA's front. The rig's
//! yaw turns it into the world frame (docs/bench-setup.md, "Conventions"). GPano's pose angles are recorded
//! by the camera after it has already levelled the image (top/bottom correction), so they are
//! reported, not applied.
//!
//! Assumes the camera's JPEG tone curve is sRGB, as for the DSLR; a measured response curve
//! would plug in where [`crate::decode_jpeg`] linearises.

use crate::{decode_jpeg, merge_hdr, Frame, RadiometryError, SATURATED};
use brdfd_core::envmap::EnvMap;

/// What GPano XMP says about a panorama (Google's Photo Sphere XMP metadata).
#[derive(Debug, Clone, PartialEq)]
pub struct GPano {
    pub projection: String,
    pub full_width: u32,
    pub full_height: u32,
    pub cropped_width: u32,
    pub cropped_height: u32,
    pub cropped_left: u32,
    pub cropped_top: u32,
    pub pitch_deg: Option<f64>,
    pub roll_deg: Option<f64>,
}

/// The XMP packet of a JPEG (the APP1 segment with the XMP namespace header), if any.
fn xmp_packet(jpeg: &[u8]) -> Option<&str> {
    const HEADER: &[u8] = b"http://ns.adobe.com/xap/1.0/\0";
    let mut at = 2;
    while at + 4 <= jpeg.len() && jpeg[at] == 0xFF {
        let marker = jpeg[at + 1];
        // Start of scan: no metadata segments after it.
        if marker == 0xDA {
            break;
        }
        let len = u16::from_be_bytes([jpeg[at + 2], jpeg[at + 3]]) as usize;
        let body = jpeg.get(at + 4..at + 2 + len)?;
        if marker == 0xE1 && body.starts_with(HEADER) {
            return std::str::from_utf8(&body[HEADER.len()..]).ok();
        }
        at += 2 + len;
    }
    None
}

/// A GPano field, written as an element (`<GPano:X>v</GPano:X>`, as RICOH writes it) or as an
/// attribute (`GPano:X="v"`, as other cameras do).
fn gpano_field<'a>(xmp: &'a str, name: &str) -> Option<&'a str> {
    let open = format!("<GPano:{name}>");
    if let Some(i) = xmp.find(&open) {
        let rest = &xmp[i + open.len()..];
        return rest.find('<').map(|j| rest[..j].trim());
    }
    let attr = format!("GPano:{name}=\"");
    let i = xmp.find(&attr)?;
    let rest = &xmp[i + attr.len()..];
    rest.find('"').map(|j| rest[..j].trim())
}

/// Reads GPano from a JPEG; None when it has no XMP or no GPano projection.
pub fn read_gpano(jpeg: &[u8]) -> Option<GPano> {
    let xmp = xmp_packet(jpeg)?;
    let num = |n: &str| gpano_field(xmp, n).and_then(|v| v.parse::<u32>().ok());
    let angle = |n: &str| gpano_field(xmp, n).and_then(|v| v.parse::<f64>().ok());
    let full_width = num("FullPanoWidthPixels").unwrap_or(0);
    let full_height = num("FullPanoHeightPixels").unwrap_or(0);
    Some(GPano {
        projection: gpano_field(xmp, "ProjectionType")?.to_string(),
        full_width,
        full_height,
        cropped_width: num("CroppedAreaImageWidthPixels").unwrap_or(full_width),
        cropped_height: num("CroppedAreaImageHeightPixels").unwrap_or(full_height),
        cropped_left: num("CroppedAreaLeftPixels").unwrap_or(0),
        cropped_top: num("CroppedAreaTopPixels").unwrap_or(0),
        pitch_deg: angle("PosePitchDegrees"),
        roll_deg: angle("PoseRollDegrees"),
    })
}

/// Checks that a decoded frame is a full equirectangular panorama. GPano decides where it is
/// present; without it, a 2:1 image is taken as equirectangular (with a warning), since
/// some tools strip XMP.
pub fn check_projection(
    jpeg: &[u8],
    file: &str,
    width: usize,
    height: usize,
) -> Result<(), RadiometryError> {
    let err = |reason: String| RadiometryError::Decode {
        file: file.into(),
        reason,
    };
    match read_gpano(jpeg) {
        Some(g) => {
            if !g.projection.eq_ignore_ascii_case("equirectangular") {
                return Err(err(format!(
                    "GPano:ProjectionType is {:?}; an environment map must be equirectangular",
                    g.projection
                )));
            }
            let full = g.cropped_width == g.full_width
                && g.cropped_height == g.full_height
                && g.cropped_left == 0
                && g.cropped_top == 0;
            if !full {
                return Err(err(format!(
                    "a partial panorama ({}×{} at {},{} of {}×{}); light from the missing part would be taken as black",
                    g.cropped_width, g.cropped_height, g.cropped_left, g.cropped_top, g.full_width, g.full_height
                )));
            }
            if (g.cropped_width as usize, g.cropped_height as usize) != (width, height) {
                tracing::warn!(
                    "{file}: GPano says {}×{}, the image is {width}×{height} (resized after capture?)",
                    g.cropped_width,
                    g.cropped_height
                );
            }
            if let (Some(p), Some(r)) = (g.pitch_deg, g.roll_deg) {
                tracing::debug!("{file}: camera pose pitch {p}°, roll {r}° (already levelled in the image)");
            }
        }
        None if width == 2 * height => {
            tracing::warn!("{file}: no GPano XMP; taking the 2:1 image as equirectangular");
        }
        None => {
            return Err(err(format!(
                "no GPano XMP and a {width}×{height} image is not 2:1, so it is not an equirectangular panorama"
            )))
        }
    }
    Ok(())
}

/// Decodes one panorama frame: linear values, EXIF exposure, projection checked.
pub fn decode_frame(jpeg: &[u8], file: &str) -> Result<Frame, RadiometryError> {
    let frame = decode_jpeg(jpeg, file)?;
    check_projection(jpeg, file, frame.values.width, frame.values.height)?;
    Ok(frame)
}

/// A merged panorama, and how much of it the bracket could not resolve.
pub struct MergedPanorama {
    pub map: EnvMap,
    /// Pixels still clipped (in any channel) in the shortest frame: their radiance is only a
    /// lower bound.
    pub clipped_pixels: usize,
    /// Their share of the map's total light (Σ L·Δω over channels): a lower bound too.
    pub clipped_share: f64,
}

/// Merges a bracket of panorama JPEGs (name, bytes) into a linear map. `gain` is the camera's
/// gain per channel (linear value per unit of radiance per unit of exposure factor, from the
/// rig's calibration); it sets the units. Warns when the shortest frame still clips, since
/// that light is underestimated.
pub fn merge_bracket(
    files: &[(String, Vec<u8>)],
    gain: [f64; 3],
) -> Result<MergedPanorama, RadiometryError> {
    let mut frames = files
        .iter()
        .map(|(name, bytes)| decode_frame(bytes, name))
        .collect::<Result<Vec<_>, _>>()?;
    crate::with_gain(&mut frames, gain);
    let merged = merge_hdr(&frames, 1.0)?;
    let source = match files {
        [(one, _)] => one.clone(),
        _ => format!("{}-frame bracket from {}", files.len(), files[0].0),
    };
    let map = EnvMap::from_pixels(merged.width, merged.height, merged.pixels, &source)?;
    let shortest = frames
        .iter()
        .min_by(|a, b| a.exposure.factor().total_cmp(&b.exposure.factor()))
        .ok_or_else(|| RadiometryError::Merge("no frames".into()))?;
    let (mut clipped_pixels, mut clipped, mut total) = (0, 0.0, 0.0);
    for (y, row) in map.pixels.chunks(map.width).enumerate() {
        let dw = map.pixel_solid_angle(y);
        for (x, p) in row.iter().enumerate() {
            let light = p.iter().map(|&v| v as f64).sum::<f64>() * dw;
            total += light;
            let seen = shortest.values.pixels[y * map.width + x];
            if seen.iter().any(|&v| v >= SATURATED) {
                clipped_pixels += 1;
                clipped += light;
            }
        }
    }
    let clipped_share = if total > 0.0 { clipped / total } else { 0.0 };
    if clipped_pixels > 0 {
        tracing::warn!(
            "{source}: {clipped_pixels} pixels are clipped even in the shortest frame ({:.3} s); they carry at least {:.1}% of the light, which is underestimated. Shorten the shortest exposure, or put a neutral-density filter on the camera",
            shortest.exposure.shutter_s,
            clipped_share * 100.0
        );
    }
    Ok(MergedPanorama {
        map,
        clipped_pixels,
        clipped_share,
    })
}

/// One panorama JPEG (for example a THETA's own photo) as a map in relative units: values
/// divided by the EXIF exposure factor. Highlights that clipped stay clipped.
pub fn load_jpeg(path: &std::path::Path) -> Result<EnvMap, RadiometryError> {
    let name = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|e| RadiometryError::Decode {
        file: name.clone(),
        reason: e.to_string(),
    })?;
    Ok(merge_bracket(&[(name, bytes)], [1.0; 3])?.map)
}

/// Any environment map file: Radiance `.hdr` and OpenEXR through the core, JPEG panoramas
/// through [`load_jpeg`].
pub fn load_envmap(path: &std::path::Path) -> Result<EnvMap, RadiometryError> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    Ok(match ext.as_str() {
        "jpg" | "jpeg" => load_jpeg(path)?,
        _ => EnvMap::load(path)?,
    })
}
