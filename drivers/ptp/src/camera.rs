//! The transaction engine: transaction ids, sessions, busy retries, named timeouts and
//! recovery of a wedged link. Everything above it (capture flows, property setters) is
//! written against [`Camera`].

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use crate::codes::{op, rc};
use crate::container::Message;
use crate::dataset::{DeviceInfo, DevicePropDesc, ObjectInfo, StorageInfo, Value};
use crate::error::{PtpError, Result};
use crate::transport::Transport;

/// Every wait the engine makes, by name. Error messages name the one that ran out.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Timeouts {
    /// An ordinary operation's response.
    pub command: Duration,
    /// Each read of a data phase (the phase as a whole may take longer).
    pub data: Duration,
    /// From triggering a capture to the new object's event.
    pub capture: Duration,
    /// How long DeviceBusy replies are retried before giving up.
    pub busy: Duration,
    /// Interval between event and DeviceReady polls. gphoto2 polls a D5500 about every 6 ms
    /// (`shared/data/ptp/nikon-d5500-capture.pcapng`); 10 ms keeps the link as quiet while
    /// adding at most 10 ms to each wait.
    pub poll: Duration,
}

impl Default for Timeouts {
    fn default() -> Self {
        Timeouts {
            command: Duration::from_secs(5),
            data: Duration::from_secs(10),
            capture: Duration::from_secs(60),
            busy: Duration::from_secs(15),
            poll: Duration::from_millis(10),
        }
    }
}

/// Attempts of a download before its error is final (each after a reset and a new session).
const DOWNLOAD_ATTEMPTS: usize = 3;
/// Storages a camera may list (card slots and internal memory).
const MAX_STORAGES: usize = 64;
/// Bytes per GetPartialObject request for large files.
pub const PARTIAL_CHUNK: u32 = 4 << 20;

pub struct Camera {
    link: Box<dyn Transport>,
    next_tid: u32,
    session_id: u32,
    pub timeouts: Timeouts,
    pub info: DeviceInfo,
    /// Events read while waiting for something else.
    pub(crate) events: VecDeque<Message>,
    /// Files per shot, if brdfd set the camera's image format ([`Camera::set_format`]): two
    /// for RAW + JPEG.
    pub(crate) files_per_shot: Option<usize>,
    /// A Canon EOS body's properties and announced files, once brdfd has taken it over.
    pub(crate) eos: Option<crate::canon::EosState>,
    /// A Sony body's properties, once brdfd has connected to it.
    pub(crate) sony: Option<crate::sony::SonyState>,
}

impl Camera {
    /// Opens a session and reads DeviceInfo.
    pub fn open(link: Box<dyn Transport>, timeouts: Timeouts) -> Result<Camera> {
        let mut cam = Camera {
            link,
            next_tid: 0,
            session_id: 1,
            timeouts,
            info: DeviceInfo::default(),
            events: VecDeque::new(),
            files_per_shot: None,
            eos: None,
            sony: None,
        };
        cam.open_session()?;
        cam.info = DeviceInfo::decode(&cam.data_in(op::GET_DEVICE_INFO, &[])?)?;
        tracing::info!(
            model = %cam.info.model,
            vendor = cam.info.vendor_extension_id,
            link = %cam.link.describe(),
            "camera open"
        );
        Ok(cam)
    }

    pub fn describe(&self) -> String {
        format!(
            "{} {} on {}",
            self.info.manufacturer,
            self.info.model,
            self.link.describe()
        )
    }

    /// OpenSession, accepting SessionAlreadyOpen (a previous process left it open). A camera
    /// that does not answer is reset and asked once more.
    fn open_session(&mut self) -> Result<()> {
        for attempt in 0..2 {
            self.next_tid = 0;
            let m = Message::new(op::OPEN_SESSION, 0, &[self.session_id]);
            match self
                .link
                .transact(&m, None, self.timeouts.command, &mut |_, _| {})
            {
                Ok((_, r)) if r.code == rc::OK || r.code == rc::SESSION_ALREADY_OPEN => {
                    self.next_tid = 1;
                    return Ok(());
                }
                Ok((_, r)) if r.code == rc::DEVICE_BUSY => {
                    std::thread::sleep(Duration::from_millis(200));
                }
                Ok((_, r)) => {
                    return Err(PtpError::Response {
                        op: op::OPEN_SESSION,
                        code: r.code,
                    })
                }
                Err(e) if attempt == 0 && e.is_link_failure() => {
                    tracing::warn!("OpenSession failed ({e}); resetting the camera and retrying");
                    if let Err(reset) = self.link.reset() {
                        return Err(e.and_recovery(reset));
                    }
                }
                Err(e) => return Err(e),
            }
        }
        Err(PtpError::Protocol("camera would not open a session".into()))
    }

    /// Resets the link and opens a new session: the recovery after an I/O error.
    pub fn recover(&mut self) -> Result<()> {
        tracing::warn!(
            "resetting {} and reopening the session",
            self.link.describe()
        );
        self.link.reset()?;
        self.open_session()
    }

    fn tid(&mut self) -> u32 {
        let t = self.next_tid;
        // 0 is reserved for OpenSession; 0xFFFFFFFF is not a valid id.
        self.next_tid = if t >= 0xFFFF_FFFE { 1 } else { t + 1 };
        t
    }

    /// One transaction, whatever the response code.
    pub fn transact(
        &mut self,
        code: u16,
        params: &[u32],
        data_out: Option<&[u8]>,
        timeout: Duration,
        progress: &mut dyn FnMut(u64, u64),
    ) -> Result<(Option<Vec<u8>>, Message)> {
        let m = Message::new(code, self.tid(), params);
        self.link.transact(&m, data_out, timeout, progress)
    }

    /// A transaction that must answer OK; DeviceBusy is retried with backoff for up to
    /// `timeouts.busy`.
    pub fn call_with(
        &mut self,
        code: u16,
        params: &[u32],
        data_out: Option<&[u8]>,
        timeout: Duration,
        progress: &mut dyn FnMut(u64, u64),
    ) -> Result<(Option<Vec<u8>>, Message)> {
        let start = Instant::now();
        let mut wait = Duration::from_millis(20);
        loop {
            let (data, resp) = self.transact(code, params, data_out, timeout, progress)?;
            match resp.code {
                rc::OK => return Ok((data, resp)),
                rc::DEVICE_BUSY if start.elapsed() < self.timeouts.busy => {
                    tracing::debug!("{code:#06x}: camera busy, retrying in {wait:?}");
                    std::thread::sleep(wait);
                    wait = (wait * 2).min(Duration::from_millis(500));
                }
                rc::DEVICE_BUSY => {
                    return Err(PtpError::Timeout {
                        what: "busy",
                        after: self.timeouts.busy,
                    })
                }
                c => return Err(PtpError::Response { op: code, code: c }),
            }
        }
    }

    pub fn call(&mut self, code: u16, params: &[u32]) -> Result<Message> {
        let t = self.timeouts.command;
        Ok(self.call_with(code, params, None, t, &mut |_, _| {})?.1)
    }

    /// A transaction with a device-to-host data phase; returns the data.
    pub fn data_in(&mut self, code: u16, params: &[u32]) -> Result<Vec<u8>> {
        let t = self.timeouts.data;
        self.call_with(code, params, None, t, &mut |_, _| {})?
            .0
            .ok_or_else(|| PtpError::Protocol(format!("{code:#06x} returned no data")))
    }

    pub fn data_out(&mut self, code: u16, params: &[u32], data: &[u8]) -> Result<()> {
        let t = self.timeouts.command;
        self.call_with(code, params, Some(data), t, &mut |_, _| {})
            .map(|_| ())
    }

    /// The next event from the camera, waiting up to `timeout`.
    pub fn next_event(&mut self, timeout: Duration) -> Result<Option<Message>> {
        if let Some(e) = self.events.pop_front() {
            return Ok(Some(e));
        }
        self.link.poll_event(timeout)
    }

    pub fn storage_ids(&mut self) -> Result<Vec<u32>> {
        let b = self.data_in(op::GET_STORAGE_IDS, &[])?;
        let ids = crate::wire::Reader::new(&b, "StorageIDs").u32_array()?;
        // A camera has a card slot or two, and its memory: a list of thousands is not one.
        if ids.len() > MAX_STORAGES {
            return Err(PtpError::malformed(
                "StorageIDs",
                0,
                format!("{} storages, more than {MAX_STORAGES}", ids.len()),
            ));
        }
        Ok(ids)
    }

    pub fn storage_info(&mut self, id: u32) -> Result<StorageInfo> {
        StorageInfo::decode(&self.data_in(op::GET_STORAGE_INFO, &[id])?)
    }

    pub fn object_info(&mut self, handle: u32) -> Result<ObjectInfo> {
        ObjectInfo::decode(&self.data_in(op::GET_OBJECT_INFO, &[handle])?)
    }

    pub fn object_handles(&mut self, storage: u32) -> Result<Vec<u32>> {
        let b = self.data_in(op::GET_OBJECT_HANDLES, &[storage, 0, 0])?;
        crate::wire::Reader::new(&b, "ObjectHandles").u32_array()
    }

    pub fn delete_object(&mut self, handle: u32) -> Result<()> {
        self.call(op::DELETE_OBJECT, &[handle, 0]).map(|_| ())
    }

    pub fn prop_desc(&mut self, code: u16) -> Result<DevicePropDesc> {
        DevicePropDesc::decode(&self.data_in(op::GET_DEVICE_PROP_DESC, &[code as u32])?)
    }

    pub fn prop_value(&mut self, code: u16, datatype: u16) -> Result<Value> {
        Value::from_bytes(
            &self.data_in(op::GET_DEVICE_PROP_VALUE, &[code as u32])?,
            datatype,
        )
    }

    /// Sets a property and returns the value the camera reports afterwards, which is what
    /// was applied (cameras round, clamp, or ignore values in the wrong mode).
    pub fn set_prop(&mut self, desc: &DevicePropDesc, v: &Value) -> Result<Value> {
        if !desc.writable {
            return Err(PtpError::Protocol(format!(
                "property {:#06x} is read-only on this camera right now (on DSLRs, exposure settings are writable only in manual mode: turn the mode dial to M)",
                desc.code
            )));
        }
        self.data_out(
            op::SET_DEVICE_PROP_VALUE,
            &[desc.code as u32],
            &v.to_bytes(desc.datatype),
        )?;
        self.prop_value(desc.code, desc.datatype)
    }

    /// Downloads an object, in GetPartialObject chunks when the camera supports it and the
    /// file is large, with progress. An I/O failure resets the camera, reopens the session
    /// and resumes (or restarts) the download.
    pub fn download(
        &mut self,
        handle: u32,
        size: u64,
        progress: &mut dyn FnMut(u64, u64),
    ) -> Result<Vec<u8>> {
        let partial = self.info.supports(op::GET_PARTIAL_OBJECT) && size > PARTIAL_CHUNK as u64;
        let chunk = partial.then_some(PARTIAL_CHUNK);
        self.download_with(handle, size, chunk, progress)
    }

    /// Downloads an object in GetPartialObject requests of `chunk` bytes whatever its size:
    /// the way a Canon EOS body gives the files it holds for the host.
    pub fn download_in_chunks(
        &mut self,
        handle: u32,
        size: u64,
        chunk: u32,
        progress: &mut dyn FnMut(u64, u64),
    ) -> Result<Vec<u8>> {
        self.download_with(handle, size, Some(chunk.max(1)), progress)
    }

    /// [`Camera::download`], whole (GetObject) or in chunks of the size given.
    fn download_with(
        &mut self,
        handle: u32,
        size: u64,
        chunk: Option<u32>,
        progress: &mut dyn FnMut(u64, u64),
    ) -> Result<Vec<u8>> {
        // Refused before any transfer, however it would be fetched (whole, or in chunks each
        // within the data-phase limit).
        crate::check_object_size(size, &format!("the object info of {handle:#010x}"))?;
        let mut out = Vec::with_capacity((size as usize).min(crate::PREALLOCATE_MAX));
        let mut attempt = 0;
        loop {
            let r = if let Some(chunk) = chunk {
                self.download_partial(handle, size, chunk, &mut out, progress)
            } else {
                let t = self.timeouts.data;
                self.call_with(op::GET_OBJECT, &[handle], None, t, progress)
                    .and_then(|(d, _)| {
                        d.ok_or_else(|| PtpError::Protocol("GetObject returned no data".into()))
                    })
                    .map(|d| out = d)
            };
            match r {
                Ok(()) => return Ok(out),
                Err(e) if e.is_link_failure() && attempt + 1 < DOWNLOAD_ATTEMPTS => {
                    attempt += 1;
                    tracing::warn!(
                        "download of {handle:#010x} failed ({e}); recovering (attempt {attempt})"
                    );
                    if let Err(reset) = self.recover() {
                        return Err(e.and_recovery(reset));
                    }
                }
                Err(e) => return Err(e),
            }
        }
    }

    fn download_partial(
        &mut self,
        handle: u32,
        size: u64,
        chunk: u32,
        out: &mut Vec<u8>,
        progress: &mut dyn FnMut(u64, u64),
    ) -> Result<()> {
        // Each chunk is a data phase with its own deadline; the whole attempt has one too, so
        // a camera that answers each request with a byte cannot hold the download for hours.
        let whole = crate::data_deadline(self.timeouts.data, size - out.len() as u64);
        let deadline = std::time::Instant::now() + whole;
        while (out.len() as u64) < size {
            if std::time::Instant::now() > deadline {
                return Err(PtpError::Timeout {
                    what: "data",
                    after: whole,
                });
            }
            let offset = out.len() as u64;
            let n = chunk.min((size - offset) as u32);
            let t = self.timeouts.data;
            let (data, _) = self.call_with(
                op::GET_PARTIAL_OBJECT,
                &[handle, offset as u32, n],
                None,
                t,
                &mut |done, _| progress(offset + done, size),
            )?;
            let data =
                data.ok_or_else(|| PtpError::Protocol("GetPartialObject returned no data".into()))?;
            if data.is_empty() {
                return Err(PtpError::Protocol(format!(
                    "camera returned no bytes at offset {offset} of {size}"
                )));
            }
            out.extend_from_slice(&data[..data.len().min((size - offset) as usize)]);
        }
        progress(size, size);
        Ok(())
    }

    pub fn close(mut self) -> Result<()> {
        self.call(op::CLOSE_SESSION, &[]).map(|_| ())
    }
}
