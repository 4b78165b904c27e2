//! The virtual bench's light as a 360° camera sees it: the environment map, exposed at the
//! shot's settings through a simulated THETA sensor, clipped, and written as a THETA writes
//! its photos (an 8-bit sRGB equirectangular JPEG with EXIF and GPano XMP). The simulated
//! THETA serves these, over HTTP and USB.

use brdfd_sim::{ImageSource, Shot};

use super::camera::{expose_to_jpeg, insert_app1, insert_exif};
use brdfd_core::envmap::EnvMap;

/// Sensor response of the simulated THETA: a pixel value of 1.0 (white) at map radiance 1
/// needs an exposure factor (t·ISO/100/N²) of 1/THETA_SENSOR_GAIN. It is ten times less
/// sensitive than the simulated DSLR (`camera::SENSOR_GAIN`) so that a bare window of the
/// studio map still exposes below white at the THETA's fastest speed (1/25000 s at f/2).
/// The rig calibration's relative scale between the two simulated cameras is therefore
/// SENSOR_GAIN / THETA_SENSOR_GAIN, which the merge undoes by dividing by this gain.
pub const THETA_SENSOR_GAIN: f64 = 100.0;

/// The XMP namespace header of an APP1 segment.
pub const XMP_HEADER: &[u8] = b"http://ns.adobe.com/xap/1.0/\0";

pub struct BenchPanorama {
    env: EnvMap,
    model: String,
}

impl BenchPanorama {
    /// The panorama of `env` at its own resolution. Large maps are downsampled to `max_width`
    /// first (a THETA V writes 5376 × 2688; tests want less).
    pub fn new(env: &EnvMap, max_width: usize, model: &str) -> BenchPanorama {
        let env = if env.width > max_width {
            env.downsample(max_width, max_width / 2)
        } else {
            env.clone()
        };
        BenchPanorama {
            env,
            model: model.into(),
        }
    }

    /// The map the camera photographs, in map units.
    pub fn scene(&self) -> &EnvMap {
        &self.env
    }
}

impl ImageSource for BenchPanorama {
    fn photo(&self, shot: &Shot) -> Result<Vec<u8>, String> {
        let k = (shot.exposure_factor() * THETA_SENSOR_GAIN) as f32;
        let jpeg = expose_to_jpeg(self.env.width, self.env.height, &self.env.pixels, k)?;
        let xmp = gpano_xmp(self.env.width, self.env.height, &self.model);
        let with_xmp = insert_app1(&jpeg, XMP_HEADER, xmp.as_bytes());
        Ok(insert_exif(&with_xmp, "RICOH", &self.model, shot))
    }

    fn dimensions(&self) -> (u32, u32) {
        (self.env.width as u32, self.env.height as u32)
    }
}

/// GPano XMP for a full equirectangular panorama, in the element form RICOH's cameras write.
pub fn gpano_xmp(width: usize, height: usize, model: &str) -> String {
    format!(
        r#"<?xpacket begin="" id="W5M0MpCehiHzreSzNTczkc9d"?>
<x:xmpmeta xmlns:x="adobe:ns:meta/" xmptk="{model} (brdfd simulator)">
  <rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">
    <rdf:Description rdf:about="" xmlns:GPano="http://ns.google.com/photos/1.0/panorama/">
      <GPano:ProjectionType>equirectangular</GPano:ProjectionType>
      <GPano:UsePanoramaViewer>True</GPano:UsePanoramaViewer>
      <GPano:CroppedAreaImageWidthPixels>{width}</GPano:CroppedAreaImageWidthPixels>
      <GPano:CroppedAreaImageHeightPixels>{height}</GPano:CroppedAreaImageHeightPixels>
      <GPano:FullPanoWidthPixels>{width}</GPano:FullPanoWidthPixels>
      <GPano:FullPanoHeightPixels>{height}</GPano:FullPanoHeightPixels>
      <GPano:CroppedAreaLeftPixels>0</GPano:CroppedAreaLeftPixels>
      <GPano:CroppedAreaTopPixels>0</GPano:CroppedAreaTopPixels>
      <GPano:PoseHeadingDegrees>0.0</GPano:PoseHeadingDegrees>
      <GPano:PosePitchDegrees>0.0</GPano:PosePitchDegrees>
      <GPano:PoseRollDegrees>0.0</GPano:PoseRollDegrees>
    </rdf:Description>
  </rdf:RDF>
</x:xmpmeta>
<?xpacket end="r"?>"#
    )
}

/// The GPano this module writes, read back as brdfd reads a THETA's: the reader lives in
/// the radiometry crate, below the bench, so the round trip is checked here.
#[cfg(test)]
mod gpano_read_back {
    use super::*;
    use crate::camera::insert_app1;
    use brdfd_radiometry::panorama::{check_projection, read_gpano};

    #[test]
    fn gpano_is_read_in_element_and_attribute_form() {
        let jpeg = [0xFF, 0xD8, 0xFF, 0xD9];
        let elem = insert_app1(
            &jpeg,
            XMP_HEADER,
            gpano_xmp(1024, 512, "RICOH THETA V").as_bytes(),
        );
        let g = read_gpano(&elem).unwrap();
        assert_eq!(
            (g.projection.as_str(), g.full_width, g.cropped_height),
            ("equirectangular", 1024, 512)
        );
        let attr = r#"<rdf:Description GPano:ProjectionType="cylindrical" GPano:FullPanoWidthPixels="800" GPano:CroppedAreaImageWidthPixels="400"/>"#;
        let g = read_gpano(&insert_app1(&jpeg, XMP_HEADER, attr.as_bytes())).unwrap();
        assert_eq!(
            (g.projection.as_str(), g.full_width, g.cropped_width),
            ("cylindrical", 800, 400)
        );
        assert!(read_gpano(&jpeg).is_none());
        assert!(check_projection(
            &insert_app1(&jpeg, XMP_HEADER, attr.as_bytes()),
            "c.jpg",
            400,
            200
        )
        .unwrap_err()
        .to_string()
        .contains("must be equirectangular"));
        assert!(check_projection(&jpeg, "d.jpg", 300, 200)
            .unwrap_err()
            .to_string()
            .contains("not 2:1"));
    }
}
