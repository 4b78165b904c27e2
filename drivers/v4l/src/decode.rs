//! Raw V4L2 frames to 8-bit RGB: YUYV (4:2:2, BT.601 limited range, as UVC cameras send it)
//! and MJPG (a JPEG per frame).

use crate::{PixelFormat, RawFrame};

/// An 8-bit RGB frame, row-major, 3 bytes a pixel, still in the camera's (sRGB) encoding.
#[derive(Debug, Clone, PartialEq)]
pub struct Rgb8Frame {
    pub width: u32,
    pub height: u32,
    pub data: Vec<u8>,
}

/// Decodes a frame; the error says what was wrong with it.
pub fn decode(frame: &RawFrame) -> Result<Rgb8Frame, String> {
    match frame.format {
        PixelFormat::Yuyv => yuyv_to_rgb(frame),
        PixelFormat::Mjpg => {
            let img = image::load_from_memory_with_format(&frame.data, image::ImageFormat::Jpeg)
                .map_err(|e| format!("MJPG: {e}"))?
                .to_rgb8();
            if (img.width(), img.height()) != (frame.width, frame.height) {
                return Err(format!(
                    "MJPG frame is {}×{}, the stream {}×{}",
                    img.width(),
                    img.height(),
                    frame.width,
                    frame.height
                ));
            }
            Ok(Rgb8Frame {
                width: img.width(),
                height: img.height(),
                data: img.into_raw(),
            })
        }
    }
}

/// YUYV: Y0 U Y1 V for each pair of pixels. BT.601 with video range (Y 16..235, chroma
/// 16..240), which is what UVC specifies unless the device says otherwise.
fn yuyv_to_rgb(frame: &RawFrame) -> Result<Rgb8Frame, String> {
    let (w, h) = (frame.width as usize, frame.height as usize);
    if w % 2 != 0 {
        return Err(format!("YUYV needs an even width, got {w}"));
    }
    let need = w * h * 2;
    if frame.data.len() < need {
        return Err(format!(
            "YUYV {w}×{h} needs {need} bytes, the frame has {} (truncated: bytesused too small)",
            frame.data.len()
        ));
    }
    let mut out = Vec::with_capacity(w * h * 3);
    for q in frame.data[..need].chunks_exact(4) {
        let (u, v) = (q[1] as f32 - 128.0, q[3] as f32 - 128.0);
        for y in [q[0], q[2]] {
            let c = (y as f32 - 16.0) * 1.164_383;
            let rgb = [
                c + 1.596_027 * v,
                c - 0.391_762 * u - 0.812_968 * v,
                c + 2.017_232 * u,
            ];
            out.extend(rgb.map(|x| x.round().clamp(0.0, 255.0) as u8));
        }
    }
    Ok(Rgb8Frame {
        width: frame.width,
        height: frame.height,
        data: out,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn yuyv(bytes: Vec<u8>, w: u32, h: u32) -> RawFrame {
        RawFrame {
            format: PixelFormat::Yuyv,
            width: w,
            height: h,
            sequence: 7,
            data: bytes,
        }
    }

    #[test]
    fn yuyv_video_range_maps_to_full_rgb() {
        // Black (16,128,128), white (235,128,128); then pure red in BT.601: Y 81, U 90, V 240.
        let f = decode(&yuyv(vec![16, 128, 235, 128, 81, 90, 81, 240], 4, 1)).unwrap();
        assert_eq!(&f.data[..6], &[0, 0, 0, 255, 255, 255]);
        let red = &f.data[6..9];
        // Within 2 levels: the standard's coefficients are rounded to 3 places.
        assert!(red[0] >= 253 && red[1] <= 2 && red[2] <= 2, "{red:?}");
    }

    #[test]
    fn truncated_yuyv_is_named() {
        let e = decode(&yuyv(vec![16; 10], 4, 2)).unwrap_err();
        assert!(e.contains("needs 16 bytes, the frame has 10"), "{e}");
    }
}
