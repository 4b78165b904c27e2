//! Simulated devices that speak the real protocols, for tests and for users without
//! hardware. Their pictures come from an [`ImageSource`] that the estimation side provides
//! (the virtual bench renderer in `brdfd_bench`), so a simulated capture is a physically
//! rendered image of a known material.

pub mod grbl;
pub mod ptp;
pub mod serial;
pub mod theta;
pub mod v4l;

/// The exposure a simulated camera shoots with, from its current property values.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Shot {
    pub shutter_s: f64,
    pub f_number: f64,
    pub iso: u32,
    pub raw: bool,
    /// 1 for the first picture of the simulator's life, then 2, 3, ...
    pub sequence: u32,
}

impl Shot {
    /// Exposure relative to 1 s, f/1, ISO 100: what scales scene radiance to sensor values.
    pub fn exposure_factor(&self) -> f64 {
        self.shutter_s * self.iso as f64 / 100.0 / (self.f_number * self.f_number)
    }
}

/// Where a simulated camera's pictures come from.
pub trait ImageSource: Send + Sync {
    /// The file the camera would write for this shot (a JPEG with EXIF, usually).
    fn photo(&self, shot: &Shot) -> Result<Vec<u8>, String>;
    /// The RAW file of this shot and its extension ("NEF", "DNG"), for a camera set to RAW
    /// or RAW + JPEG. `None`: this source makes no RAW files, and the camera writes its
    /// JPEG alone.
    fn raw(&self, _shot: &Shot) -> Result<Option<(&'static str, Vec<u8>)>, String> {
        Ok(None)
    }
    /// Pixel size, for ObjectInfo.
    fn dimensions(&self) -> (u32, u32);
    /// Whether a shot can be taken now; a camera whose source is not ready answers a capture
    /// with DeviceBusy.
    fn ready(&self) -> bool {
        true
    }
}

/// A file of a fixed size with JPEG markers and deterministic filler, for transfer tests and
/// benchmarks where the picture's content does not matter.
pub struct SizedPayload {
    pub bytes: usize,
}

impl ImageSource for SizedPayload {
    fn photo(&self, shot: &Shot) -> Result<Vec<u8>, String> {
        let n = self.bytes.max(4);
        let mut v: Vec<u8> = (0..n)
            .map(|i| {
                (i as u32)
                    .wrapping_mul(2_654_435_761)
                    .wrapping_add(shot.sequence) as u8
                    >> 1
            })
            .collect();
        v[..2].copy_from_slice(&[0xFF, 0xD8]);
        v[n - 2..].copy_from_slice(&[0xFF, 0xD9]);
        Ok(v)
    }
    fn dimensions(&self) -> (u32, u32) {
        (6000, 4000)
    }
}

/// An image source that adds up the time spent making pictures: the simulated device's own
/// work, which a benchmark of brdfd leaves out of brdfd's overhead.
pub struct Timed {
    inner: std::sync::Arc<dyn ImageSource>,
    nanos: std::sync::atomic::AtomicU64,
}

impl Timed {
    pub fn new(inner: std::sync::Arc<dyn ImageSource>) -> Timed {
        Timed {
            inner,
            nanos: Default::default(),
        }
    }

    /// Seconds spent in `photo` so far.
    pub fn seconds(&self) -> f64 {
        self.nanos.load(std::sync::atomic::Ordering::Relaxed) as f64 * 1e-9
    }
}

impl Timed {
    fn timed<T>(&self, f: impl FnOnce() -> T) -> T {
        let t = std::time::Instant::now();
        let r = f();
        self.nanos.fetch_add(
            t.elapsed().as_nanos() as u64,
            std::sync::atomic::Ordering::Relaxed,
        );
        r
    }
}

impl ImageSource for Timed {
    fn photo(&self, shot: &Shot) -> Result<Vec<u8>, String> {
        self.timed(|| self.inner.photo(shot))
    }
    fn raw(&self, shot: &Shot) -> Result<Option<(&'static str, Vec<u8>)>, String> {
        self.timed(|| self.inner.raw(shot))
    }
    fn dimensions(&self) -> (u32, u32) {
        self.inner.dimensions()
    }
}

/// What stands in front of a simulated camera. The camera keeps running while the scene is
/// changed from outside, as an operator puts a new sample on the bench or a turntable turns.
pub struct Stage {
    scene: std::sync::RwLock<Option<std::sync::Arc<dyn ImageSource>>>,
    /// Reported while nothing is on the stage.
    empty_dimensions: (u32, u32),
}

impl Stage {
    pub fn new(empty_dimensions: (u32, u32)) -> Stage {
        Stage {
            scene: std::sync::RwLock::new(None),
            empty_dimensions,
        }
    }

    pub fn show(&self, scene: std::sync::Arc<dyn ImageSource>) {
        *self.scene.write().expect("stage lock") = Some(scene);
    }

    fn current(&self) -> Option<std::sync::Arc<dyn ImageSource>> {
        self.scene.read().expect("stage lock").clone()
    }
}

impl ImageSource for Stage {
    fn photo(&self, shot: &Shot) -> Result<Vec<u8>, String> {
        match self.current() {
            Some(s) => s.photo(shot),
            None => Err(
                "the simulated bench is empty: no scene was placed in front of the camera".into(),
            ),
        }
    }
    fn raw(&self, shot: &Shot) -> Result<Option<(&'static str, Vec<u8>)>, String> {
        match self.current() {
            Some(s) => s.raw(shot),
            None => Ok(None),
        }
    }
    fn dimensions(&self) -> (u32, u32) {
        self.current()
            .map_or(self.empty_dimensions, |s| s.dimensions())
    }
}
