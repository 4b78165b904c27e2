//! The V4L2 capture path against the simulated camera: format choice, manual settings and
//! what was applied, YUYV and MJPG decoding, exposure acting on the frames, and the faults.

use std::sync::Arc;
use std::time::Duration;

use brdfd_sim::v4l::{SimV4l, V4lFaults};
use brdfd_sim::{ImageSource, Shot};
use brdfd_v4l::{capture, choose_format, FrameSource, PixelFormat, Settings, V4lError};

/// A grey ramp, exposed linearly (value ∝ shutter × ISO), as JPEG.
struct Ramp;

impl ImageSource for Ramp {
    fn photo(&self, s: &Shot) -> Result<Vec<u8>, String> {
        let k = s.shutter_s * s.iso as f64 / 100.0 * 60.0;
        let img = image::RgbImage::from_fn(64, 32, |x, _| {
            let v = ((x as f64 / 63.0) * 200.0 * k).clamp(0.0, 255.0) as u8;
            image::Rgb([v, v, v])
        });
        let mut out = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, 95)
            .encode_image(&img)
            .map_err(|e| e.to_string())?;
        Ok(out)
    }
    fn dimensions(&self) -> (u32, u32) {
        (64, 32)
    }
}

fn mean(data: &[u8]) -> f64 {
    data.iter().map(|&v| v as f64).sum::<f64>() / data.len() as f64
}

#[test]
fn yuyv_is_chosen_and_settings_are_applied_as_the_camera_rounds_them() {
    let mut cam = SimV4l::new(Arc::new(Ramp), "bench webcam");
    assert_eq!(
        choose_format(&cam.formats().unwrap()),
        Some((PixelFormat::Yuyv, 64, 32))
    );
    let settings = Settings {
        exposure_s: Some(1.0 / 60.0),
        gain: Some(100),
        white_balance_k: Some(5003),
    };
    let (applied, frames) = capture(&mut cam, &settings, 4).unwrap();
    // 1/60 s is 166.7 units of 100 µs: the camera keeps 167.
    assert_eq!(applied.exposure_s, Some(0.0167));
    assert_eq!(applied.gain, Some(100));
    assert_eq!(applied.white_balance_k, Some(5000));
    assert!(applied.notes.contains(&"auto exposure off".to_string()));
    assert_eq!(frames.len(), 4);
    assert!(frames
        .iter()
        .all(|f| f.width == 64 && f.height == 32 && f.data.len() == 64 * 32 * 3));
    // Noise makes frames differ; the picture is the same.
    assert_ne!(frames[0].data, frames[1].data);
    assert!((mean(&frames[0].data) - mean(&frames[1].data)).abs() < 1.0);
}

#[test]
fn exposure_scales_the_frames_in_both_formats() {
    for format in [PixelFormat::Yuyv, PixelFormat::Mjpg] {
        let mut cam = SimV4l::new(Arc::new(Ramp), "bench webcam");
        cam.noise_levels = 0.0;
        cam.start(format, 64, 32).unwrap();
        let mut level = |t: f64| {
            cam.apply(&Settings {
                exposure_s: Some(t),
                ..Settings::default()
            })
            .unwrap();
            let raw = cam.next_frame(Duration::from_secs(1)).unwrap();
            assert_eq!(raw.format, format);
            mean(&brdfd_v4l::decode(&raw).unwrap().data)
        };
        let (short, long) = (level(1.0 / 240.0), level(1.0 / 120.0));
        // Twice the exposure, about twice the (linear ramp's) level: within 5% for the
        // codecs' rounding.
        assert!(
            (long / short - 2.0).abs() < 0.1,
            "{format:?}: {short} → {long}"
        );
    }
}

#[test]
fn a_stalled_camera_times_out_and_a_truncated_frame_is_named() {
    let mut cam = SimV4l::new(Arc::new(Ramp), "bench webcam");
    cam.start(PixelFormat::Yuyv, 64, 32).unwrap();
    cam.faults = V4lFaults {
        stall_next: true,
        ..V4lFaults::default()
    };
    let e = cam.next_frame(Duration::from_millis(50)).unwrap_err();
    assert!(matches!(e, V4lError::Timeout { .. }), "{e}");
    assert!(e.to_string().contains("no frame within 50ms"), "{e}");
    // It streams again after the stall.
    cam.next_frame(Duration::from_secs(1)).unwrap();

    cam.faults = V4lFaults {
        truncate_next: Some(1000),
        ..V4lFaults::default()
    };
    let raw = cam.next_frame(Duration::from_secs(1)).unwrap();
    let e = brdfd_v4l::decode(&raw).unwrap_err();
    assert!(e.contains("needs 4096 bytes, the frame has 1000"), "{e}");
}

#[test]
fn a_missing_device_node_is_named() {
    let e = brdfd_v4l::device::V4lCamera::open("/dev/video-brdfd-none")
        .err()
        .unwrap()
        .to_string();
    assert!(
        e.contains("does not exist") && e.contains("brdfd devices"),
        "{e}"
    );
}
