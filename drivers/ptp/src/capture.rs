//! Capture flows: the generic still-image path and Nikon's (Canon's EOS flow is in
//! [`crate::canon`]), exposure settings, and exposure-bracketed series for HDR.

use std::time::{Duration, Instant};

use crate::camera::Camera;
use crate::codes::{event, format, op, prop, rc, vendor};
use crate::dataset::{decode_nikon_events, ObjectInfo, Value};
use crate::error::{PtpError, Result};

/// Nikon's handle for the image held in SDRAM when no card write was asked for.
pub const NIKON_SDRAM_HANDLE: u32 = 0xFFFF_0001;
/// How long the card's listing must stay the same before a shot fired from outside is taken
/// to be whole, when brdfd did not set how many files a shot makes. A RAW + JPEG body lists
/// its second file within a few hundred milliseconds of the first.
pub const FIRED_SHOT_SETTLE: Duration = Duration::from_secs(2);
/// How often the card is listed while waiting for a shot fired from outside.
const FIRED_SHOT_POLL: Duration = Duration::from_millis(50);
/// Exposure time units of property 0x500D: 1/10000 s. This value means bulb.
const EXPOSURE_TIME_BULB: i64 = 0xFFFF_FFFF;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Target {
    /// Keep the image in the camera's RAM and download it (Nikon, and Canon EOS with the
    /// capture destination set to the computer; others use Card).
    #[default]
    Sdram,
    Card,
}

#[derive(Debug, Clone, Default)]
pub struct CaptureOptions {
    pub target: Target,
    /// Delete the file from the card after the download.
    pub delete_after: bool,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ImageFormat {
    Jpeg,
    Raw,
    RawJpeg,
}

/// What a setter applied, in physical units.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Exposure {
    pub shutter_s: Option<f64>,
    pub f_number: Option<f64>,
    pub iso: Option<u32>,
}

#[derive(Debug, Clone)]
pub struct Captured {
    pub handle: u32,
    pub info: ObjectInfo,
    pub data: Vec<u8>,
}

/// Progress of a capture: a phase name and bytes done of total (0 of 0 for phases that are
/// not downloads).
pub type CaptureProgress<'a> = &'a mut dyn FnMut(&str, u64, u64);

impl Camera {
    /// Nikon bodies since about 2014 report the Microsoft (MTP) extension id 6, not Nikon's
    /// 0xA (the D5500 recording does), so the manufacturer counts too.
    pub fn is_nikon(&self) -> bool {
        (self.info.vendor_extension_id == vendor::NIKON
            || self.info.manufacturer.starts_with("Nikon"))
            && (self.info.supports(op::NIKON_INITIATE_CAPTURE_REC_IN_SDRAM)
                || self.info.supports(op::NIKON_INITIATE_CAPTURE_REC_IN_MEDIA))
    }

    /// What a camera without InitiateCapture lacks, and what to do: Canon PowerShots and Sony's
    /// older and QX bodies capture through their vendor's own flows, which brdfd does not
    /// speak yet.
    fn missing_capture(&self) -> String {
        let maker = &self.info.manufacturer;
        let canon = self.info.vendor_extension_id == vendor::CANON || maker.starts_with("Canon");
        let flow = if canon {
            Some("Canon's PowerShot release control")
        } else if maker.starts_with("Sony") {
            Some("an older Sony protocol than SDIO control")
        } else {
            None
        };
        match flow {
            Some(flow) => format!(
                "remote capture (InitiateCapture): {} {} captures through {flow}, which brdfd \
                 does not speak yet (docs/devices.md lists the cameras it drives)",
                maker.trim_end_matches('.'),
                self.info.model
            ),
            None => "remote capture (InitiateCapture)".into(),
        }
    }

    /// Triggers one exposure and downloads its first file: for cameras set to make one file
    /// per shot (the THETA, a JPEG-only DSLR). [`Camera::capture_all`] keeps every file.
    pub fn capture(
        &mut self,
        opts: &CaptureOptions,
        progress: CaptureProgress,
    ) -> Result<Captured> {
        let mut files = self.capture_all(opts, progress)?;
        Ok(files.swap_remove(0))
    }

    /// Triggers one exposure and downloads every file it makes (a RAW + JPEG shot makes
    /// two), in the order the camera announces them. Folders the camera announces (a new
    /// 101NIKON) are not files. Never empty.
    pub fn capture_all(
        &mut self,
        opts: &CaptureOptions,
        progress: CaptureProgress,
    ) -> Result<Vec<Captured>> {
        if self.is_canon_eos() {
            return self.capture_canon_eos(opts, progress);
        }
        if self.is_sony() {
            return self.capture_sony(opts, progress);
        }
        let nikon = self.is_nikon();
        let handles = if nikon {
            self.trigger_nikon(opts.target, progress)?
        } else if self.info.supports(op::INITIATE_CAPTURE) {
            self.trigger_generic(progress)?
        } else {
            return Err(PtpError::Unsupported(self.missing_capture()));
        };
        let mut files = Vec::new();
        for handle in handles {
            self.fetch_new(handle, opts, progress, &mut files)?;
        }
        if nikon && opts.target == Target::Sdram {
            self.fetch_rest_of_sdram_shot(opts, progress, &mut files)?;
        }
        if files.is_empty() {
            return Err(PtpError::Protocol(
                "the camera announced no file for the shot (only folders)".into(),
            ));
        }
        Ok(files)
    }

    /// Fires the camera from outside (a trigger box or a release cable on its remote
    /// socket, through `fire`) and downloads every file the shot makes.
    ///
    /// A shot the camera did not initiate goes to its card, and the card's listing is what
    /// every PTP camera keeps: the shot's files are the objects listed after `fire` and not
    /// before. (Some bodies also send ObjectAdded for it, others do not; the events are
    /// read and set aside so that they are not taken for a later shot's.) The shot is whole
    /// when it has as many files as the camera was set to make, or, when brdfd did not set
    /// it, once the listing has not grown for [`FIRED_SHOT_SETTLE`].
    pub fn capture_fired(
        &mut self,
        fire: &mut dyn FnMut() -> Result<()>,
        opts: &CaptureOptions,
        progress: CaptureProgress,
    ) -> Result<Vec<Captured>> {
        if self.is_sony() {
            // In PC remote mode a Sony lists no card: a shot fired from outside is not found
            // the way this flow finds it.
            return Err(PtpError::Unsupported(
                "a shot fired from outside on a Sony in PC remote mode (it lists no card);                  let brdfd fire it over USB or PTP/IP instead"
                    .into(),
            ));
        }
        let before = self.card_objects()?;
        self.set_events_aside()?;
        progress("exposure", 0, 0);
        fire()?;
        let start = Instant::now();
        let mut shot: Vec<u32> = Vec::new();
        let mut grew = start;
        // A card holds thousands of files: each is looked up, not searched for.
        let mut seen: std::collections::HashSet<u32> = before.into_iter().collect();
        loop {
            for h in self.card_objects()? {
                if !seen.insert(h) {
                    continue;
                }
                // A folder made for the shot (a new 101NIKON) is not one of its files.
                if self.object_info(h)?.format != format::ASSOCIATION {
                    shot.push(h);
                    grew = Instant::now();
                }
            }
            let whole = match self.files_per_shot {
                Some(n) => shot.len() >= n,
                None => !shot.is_empty() && grew.elapsed() >= FIRED_SHOT_SETTLE,
            };
            if whole {
                break;
            }
            if start.elapsed() > self.timeouts.capture {
                if shot.is_empty() {
                    return Err(PtpError::Protocol(format!(
                        "no new file on the camera's card within {:?} of the shutter firing: check that a card is in, and that the release is plugged into the camera's remote socket",
                        self.timeouts.capture
                    )));
                }
                tracing::warn!(
                    "the camera was set to make {:?} files per shot and listed {} within {:?}",
                    self.files_per_shot,
                    shot.len(),
                    self.timeouts.capture
                );
                break;
            }
            std::thread::sleep(FIRED_SHOT_POLL);
        }
        if self.is_nikon() {
            self.wait_device_ready(start)?;
        }
        let mut files = Vec::new();
        for h in shot {
            self.fetch_new(h, opts, progress, &mut files)?;
        }
        self.set_events_aside()?;
        Ok(files)
    }

    /// Every object on the camera's cards.
    fn card_objects(&mut self) -> Result<Vec<u32>> {
        let mut all = Vec::new();
        for id in self.storage_ids()? {
            all.extend(self.object_handles(id)?);
        }
        Ok(all)
    }

    /// Reads the events waiting (Nikon's GetEvent queue, or the event channel), so that an
    /// ObjectAdded of a shot fired from outside is not taken for the next shot's.
    fn set_events_aside(&mut self) -> Result<()> {
        if self.is_canon_eos() {
            return self.eos_set_events_aside();
        }
        if self.is_nikon() {
            let mut ignored = Vec::new();
            return self.nikon_added(Target::Sdram, &mut ignored);
        }
        // Not zero: libusb reads a zero timeout as no timeout.
        while let Some(e) = self.next_event(Duration::from_millis(1))? {
            tracing::debug!("event {:#06x} set aside", e.code);
        }
        Ok(())
    }

    /// Downloads the object at `handle` into `files` unless it is a folder or a file
    /// already there. Returns whether it did.
    fn fetch_new(
        &mut self,
        handle: u32,
        opts: &CaptureOptions,
        progress: CaptureProgress,
        files: &mut Vec<Captured>,
    ) -> Result<bool> {
        let info = self.object_info(handle)?;
        let seen = files.iter().any(|f| f.info.filename == info.filename);
        if info.format == format::ASSOCIATION || seen {
            return Ok(false);
        }
        files.push(self.fetch(handle, info, opts, progress)?);
        Ok(true)
    }

    /// Downloads one object whose ObjectInfo is known, deleting it after if asked.
    pub(crate) fn fetch(
        &mut self,
        handle: u32,
        info: ObjectInfo,
        opts: &CaptureOptions,
        progress: CaptureProgress,
    ) -> Result<Captured> {
        progress("download", 0, info.compressed_size as u64);
        let data = self.download(handle, info.compressed_size as u64, &mut |d, t| {
            progress("download", d, t)
        })?;
        if data.len() != info.compressed_size as usize && info.compressed_size != u32::MAX {
            return Err(PtpError::Protocol(format!(
                "downloaded {} bytes of {} ({})",
                data.len(),
                info.compressed_size,
                info.filename
            )));
        }
        if opts.delete_after && handle != NIKON_SDRAM_HANDLE {
            self.delete_object(handle)?;
        }
        Ok(Captured { handle, info, data })
    }

    /// A Nikon shooting RAW + JPEG to SDRAM holds the shot's files one at a time: the next
    /// comes once the one before has been read (or deleted), on the same handle or announced
    /// by another ObjectAddedInSdram. So, when brdfd set the camera to two files per shot,
    /// the handle is asked again and events are polled until both are in. A camera left as it
    /// was set on its body is taken to make one file, as the recording of a real D5500
    /// (JPEG, one file, nothing asked after the download) shows.
    fn fetch_rest_of_sdram_shot(
        &mut self,
        opts: &CaptureOptions,
        progress: CaptureProgress,
        files: &mut Vec<Captured>,
    ) -> Result<()> {
        let want = self.files_per_shot.unwrap_or(1);
        let start = Instant::now();
        while let Some(last) = files.last().map(|f| f.handle) {
            if files.len() >= want {
                return Ok(());
            }
            match self.object_info(last) {
                Ok(info) if files.iter().any(|f| f.info.filename == info.filename) => {
                    // Still the file just read: this camera frees it when it is deleted. If
                    // it refuses, the next file may still be announced by an event.
                    if let Err(e) = self.delete_object(last) {
                        tracing::debug!("deleting {} from SDRAM: {e}", info.filename);
                    }
                }
                Ok(_) => {
                    self.fetch_new(last, opts, progress, files)?;
                    continue;
                }
                Err(PtpError::Response {
                    code: rc::INVALID_OBJECT_HANDLE,
                    ..
                }) => {}
                Err(e) => return Err(e),
            }
            let mut announced = Vec::new();
            self.nikon_added(Target::Sdram, &mut announced)?;
            let mut got = false;
            for h in announced {
                got |= self.fetch_new(h, opts, progress, files)?;
            }
            if !got {
                if start.elapsed() > self.timeouts.capture {
                    tracing::warn!(
                        "the camera was set to make {want} files per shot and gave {} within {:?}",
                        files.len(),
                        self.timeouts.capture
                    );
                    return Ok(());
                }
                std::thread::sleep(self.timeouts.poll);
            }
        }
        Ok(())
    }

    /// InitiateCapture, then an ObjectAdded per file and CaptureComplete, in any order.
    fn trigger_generic(&mut self, progress: CaptureProgress) -> Result<Vec<u32>> {
        progress("exposure", 0, 0);
        self.call_with(
            op::INITIATE_CAPTURE,
            &[0, 0],
            None,
            self.timeouts.capture,
            &mut |_, _| {},
        )?;
        let start = Instant::now();
        let (mut added, mut complete) = (Vec::new(), false);
        while added.is_empty() || !complete {
            let left = self.timeouts.capture.saturating_sub(start.elapsed());
            if left.is_zero() {
                return Err(PtpError::Timeout {
                    what: if added.is_empty() {
                        "capture"
                    } else {
                        "capture complete"
                    },
                    after: self.timeouts.capture,
                });
            }
            match self.next_event(left.min(Duration::from_millis(500)))? {
                Some(e) if e.code == event::OBJECT_ADDED && !added.contains(&e.param(0)) => {
                    added.push(e.param(0));
                }
                Some(e) if e.code == event::OBJECT_ADDED => {}
                Some(e) if e.code == event::CAPTURE_COMPLETE => complete = true,
                Some(e) if e.code == event::STORE_FULL => {
                    return Err(PtpError::Protocol("the camera's card is full".into()))
                }
                Some(e) => tracing::debug!("event {:#06x} while waiting for capture", e.code),
                None => {}
            }
        }
        Ok(added)
    }

    /// Nikon: InitiateCaptureRecInSdram or RecInMedia, GetEvent polling until the object
    /// appears, then DeviceReady polling through busy replies. This order is what a real
    /// D5500 shows in `shared/data/ptp/nikon-d5500-capture.pcapng`. To the card, every
    /// ObjectAdded seen until the camera is ready again is a file of the shot; in SDRAM the
    /// files come one after another on one handle ([`Camera::fetch_sdram`]).
    fn trigger_nikon(&mut self, target: Target, progress: CaptureProgress) -> Result<Vec<u32>> {
        progress("exposure", 0, 0);
        let (code, params): (u16, &[u32]) = match target {
            Target::Sdram => (op::NIKON_INITIATE_CAPTURE_REC_IN_SDRAM, &[0xFFFF_FFFF]),
            Target::Card => (op::NIKON_INITIATE_CAPTURE_REC_IN_MEDIA, &[0xFFFF_FFFF, 0]),
        };
        self.call_with(code, params, None, self.timeouts.capture, &mut |_, _| {})?;
        let start = Instant::now();
        let mut handles = Vec::new();
        while handles.is_empty() {
            if start.elapsed() > self.timeouts.capture {
                return Err(PtpError::Timeout {
                    what: "capture",
                    after: self.timeouts.capture,
                });
            }
            self.nikon_added(target, &mut handles)?;
            if handles.is_empty() {
                std::thread::sleep(self.timeouts.poll);
            }
        }
        self.wait_device_ready(start)?;
        if target == Target::Card {
            self.nikon_added(target, &mut handles)?;
        }
        Ok(handles)
    }

    /// One GetEvent poll: adds the handles of new objects to `handles`.
    fn nikon_added(&mut self, target: Target, handles: &mut Vec<u32>) -> Result<()> {
        let events = decode_nikon_events(&self.data_in(op::NIKON_GET_EVENT, &[])?)?;
        for (code, param) in events {
            let handle = match code {
                // A parameter of 0 means the SDRAM handle.
                event::NIKON_OBJECT_ADDED_IN_SDRAM if param == 0 => NIKON_SDRAM_HANDLE,
                event::NIKON_OBJECT_ADDED_IN_SDRAM => param,
                event::OBJECT_ADDED if target == Target::Card => param,
                event::STORE_FULL => {
                    return Err(PtpError::Protocol("the camera's card is full".into()))
                }
                _ => continue,
            };
            if !handles.contains(&handle) {
                handles.push(handle);
            }
        }
        Ok(())
    }

    fn wait_device_ready(&mut self, start: Instant) -> Result<()> {
        loop {
            let (_, r) = self.transact(
                op::NIKON_DEVICE_READY,
                &[],
                None,
                self.timeouts.command,
                &mut |_, _| {},
            )?;
            match r.code {
                rc::OK => return Ok(()),
                rc::DEVICE_BUSY if start.elapsed() < self.timeouts.capture => {
                    std::thread::sleep(self.timeouts.poll)
                }
                rc::DEVICE_BUSY => {
                    return Err(PtpError::Timeout {
                        what: "capture",
                        after: self.timeouts.capture,
                    })
                }
                c => {
                    return Err(PtpError::Response {
                        op: op::NIKON_DEVICE_READY,
                        code: c,
                    })
                }
            }
        }
    }

    /// Sets an integer property to the allowed value nearest to `want` (by `distance`),
    /// returning what the camera applied.
    fn set_nearest(&mut self, code: u16, distance: impl Fn(i64) -> f64) -> Result<i64> {
        let desc = self.prop_desc(code)?;
        let best = desc
            .allowed()
            .into_iter()
            .filter(|&v| v != EXPOSURE_TIME_BULB || code != prop::EXPOSURE_TIME)
            .min_by(|a, b| distance(*a).total_cmp(&distance(*b)))
            .ok_or_else(|| PtpError::Protocol(format!("property {code:#06x} offers no values")))?;
        let applied = self.set_prop(&desc, &Value::Int(best))?;
        applied.as_i64().ok_or_else(|| {
            PtpError::Protocol(format!("property {code:#06x} read back as {applied:?}"))
        })
    }

    /// Shutter speed in seconds; returns the speed applied.
    pub fn set_shutter(&mut self, seconds: f64) -> Result<f64> {
        if self.is_sony() {
            return self.sony_set_shutter(seconds);
        }
        if self.is_canon_eos() {
            let code = prop::CANON_EOS_SHUTTER_SPEED;
            return self.eos_set_nearest(code, crate::canon::shutter_seconds, seconds);
        }
        let v = self.set_nearest(prop::EXPOSURE_TIME, |v| {
            ((v as f64 / 1e4) / seconds).ln().abs()
        })?;
        Ok(v as f64 / 1e4)
    }

    /// Aperture as an f-number; returns the f-number applied.
    pub fn set_f_number(&mut self, f: f64) -> Result<f64> {
        if self.is_sony() {
            return self.sony_set_f_number(f);
        }
        if self.is_canon_eos() {
            return self.eos_set_nearest(prop::CANON_EOS_APERTURE, crate::canon::f_number, f);
        }
        let v = self.set_nearest(prop::F_NUMBER, |v| ((v as f64 / 100.0) / f).ln().abs())?;
        Ok(v as f64 / 100.0)
    }

    pub fn set_iso(&mut self, iso: u32) -> Result<u32> {
        if self.is_sony() {
            return self.sony_set_iso(iso);
        }
        if self.is_canon_eos() {
            let iso_of = |c| crate::canon::iso(c).map(f64::from);
            let applied = self.eos_set_nearest(prop::CANON_EOS_ISO_SPEED, iso_of, iso as f64)?;
            return Ok(applied as u32);
        }
        let v = self.set_nearest(prop::EXPOSURE_INDEX, |v| (v as f64 / iso as f64).ln().abs())?;
        Ok(v as u32)
    }

    /// JPEG or RAW through the compression setting. Nikon's values: 0-2 JPEG basic to fine,
    /// 4 RAW, 5-7 RAW + JPEG; other vendors keep JPEG qualities only.
    pub fn set_format(&mut self, f: ImageFormat) -> Result<ImageFormat> {
        if self.is_canon_eos() || self.is_sony() {
            // An EOS body's image format (0xD120) is a list of file descriptions of its own,
            // and a Sony's compression setting has values of its own; brdfd writes neither yet.
            return Err(PtpError::Unsupported(format!(
                "setting the image format ({f:?}) of a {} from the computer",
                if self.is_sony() { "Sony" } else { "Canon EOS" }
            )));
        }
        let want = match f {
            ImageFormat::Jpeg => 2,
            ImageFormat::Raw => 4,
            ImageFormat::RawJpeg => 7,
        };
        let desc = self.prop_desc(prop::COMPRESSION_SETTING)?;
        if !desc.allowed().contains(&want) {
            return Err(PtpError::Unsupported(format!("image format {f:?}")));
        }
        let got = self
            .set_prop(&desc, &Value::Int(want))?
            .as_i64()
            .unwrap_or(-1);
        let applied = match got {
            0..=3 => ImageFormat::Jpeg,
            4 => ImageFormat::Raw,
            _ => ImageFormat::RawJpeg,
        };
        self.files_per_shot = Some(if applied == ImageFormat::RawJpeg {
            2
        } else {
            1
        });
        Ok(applied)
    }

    /// Exposure: sets what is given, returns what the camera applied.
    pub fn set_exposure(&mut self, want: &Exposure) -> Result<Exposure> {
        Ok(Exposure {
            shutter_s: want.shutter_s.map(|s| self.set_shutter(s)).transpose()?,
            f_number: want.f_number.map(|f| self.set_f_number(f)).transpose()?,
            iso: want.iso.map(|i| self.set_iso(i)).transpose()?,
        })
    }

    /// An exposure bracket: one capture per shutter speed, each with the speed applied.
    pub fn bracket(
        &mut self,
        shutters_s: &[f64],
        opts: &CaptureOptions,
        progress: CaptureProgress,
    ) -> Result<Vec<(f64, Vec<Captured>)>> {
        let mut out = Vec::with_capacity(shutters_s.len());
        for (i, &s) in shutters_s.iter().enumerate() {
            let applied = self.set_shutter(s)?;
            tracing::info!(
                "bracket {}/{}: asked {s} s, camera applied {applied} s",
                i + 1,
                shutters_s.len()
            );
            let files = self.capture_all(opts, &mut |phase, d, t| progress(phase, d, t))?;
            out.push((applied, files));
        }
        Ok(out)
    }
}
