//! PTP over USB (still image class 6/1/1, ISO 15740 annex D). The container framing is
//! written against [`BulkPipe`], so the in-memory pipe of the tests runs it too; [`RusbPipe`]
//! is the real device through libusb.

use std::time::{Duration, Instant};

use crate::container::{self, Header, Kind, Message, HEADER_LEN};
use crate::error::{PtpError, Result};
use crate::transport::{Progress, Transport};

#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PipeError {
    Timeout,
    /// The endpoint halted (STALL): on bulk-in, the camera abandoned the transaction.
    Stall,
    /// The device is gone.
    Gone,
    Other(String),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Endpoint {
    BulkIn,
    BulkOut,
    Interrupt,
}

/// Still image class requests (annex D.5).
pub mod class_request {
    pub const CANCEL: u8 = 0x64;
    pub const DEVICE_RESET: u8 = 0x66;
    pub const GET_DEVICE_STATUS: u8 = 0x67;
}

/// The USB operations PTP needs, on one claimed still-image interface.
pub trait BulkPipe: Send {
    fn max_packet(&self) -> usize;
    fn write(&mut self, data: &[u8], timeout: Duration) -> Result<usize, PipeError>;
    /// Reads one transfer from the bulk-in or interrupt endpoint.
    fn read(&mut self, ep: Endpoint, buf: &mut [u8], timeout: Duration)
        -> Result<usize, PipeError>;
    fn clear_halt(&mut self, ep: Endpoint) -> Result<(), PipeError>;
    /// A class-specific control request to the interface. Requests with `data_in` > 0 read
    /// that many bytes back.
    fn class_request(
        &mut self,
        request: u8,
        data_out: &[u8],
        data_in: usize,
    ) -> Result<Vec<u8>, PipeError>;
    fn describe(&self) -> String;
}

fn pipe_err(e: PipeError, during: &'static str, after: Duration) -> PtpError {
    match e {
        PipeError::Timeout => PtpError::Timeout {
            what: during,
            after,
        },
        PipeError::Gone => PtpError::Disconnected { during },
        PipeError::Stall => PtpError::Io(format!("endpoint stalled during {during}")),
        PipeError::Other(s) => PtpError::Io(format!("{s} during {during}")),
    }
}

/// Bytes read per bulk transfer: large transfers keep downloads fast; a multiple of every
/// max packet size.
const READ_CHUNK: usize = 1 << 20;

pub struct UsbTransport<P: BulkPipe> {
    pipe: P,
    /// Bytes of the next container already read (a device may send a response straight
    /// after a data phase in the same transfer).
    pending: Vec<u8>,
    /// One read buffer for the link's life: most transactions move a few bytes, and a fresh
    /// megabyte per read would cost more than the transfer.
    buf: Vec<u8>,
}

impl<P: BulkPipe> UsbTransport<P> {
    pub fn new(pipe: P) -> Self {
        UsbTransport {
            pipe,
            pending: Vec::new(),
            buf: vec![0u8; READ_CHUNK],
        }
    }

    pub fn pipe_mut(&mut self) -> &mut P {
        &mut self.pipe
    }

    /// Writes a whole transfer; ends it with a zero-length packet when it fills its last
    /// packet exactly, or the device would wait for more. A stall is cleared and the write
    /// retried once.
    fn write_transfer(&mut self, data: &[u8], timeout: Duration) -> Result<()> {
        let mut retried = false;
        loop {
            match self.write_all(data, timeout) {
                Err(PipeError::Stall) if !retried => {
                    retried = true;
                    tracing::warn!("bulk-out stalled; clearing the halt and retrying once");
                    self.pipe
                        .clear_halt(Endpoint::BulkOut)
                        .map_err(|e| pipe_err(e, "clear halt", timeout))?;
                }
                r => return r.map_err(|e| pipe_err(e, "command or data write", timeout)),
            }
        }
    }

    fn write_all(&mut self, data: &[u8], timeout: Duration) -> Result<(), PipeError> {
        let mut sent = 0;
        while sent < data.len() {
            sent += self.pipe.write(&data[sent..], timeout)?;
        }
        if data.len().is_multiple_of(self.pipe.max_packet()) {
            self.pipe.write(&[], timeout)?;
        }
        Ok(())
    }

    /// Reads at least `want` bytes into `pending`, skipping zero-length packets.
    fn fill(&mut self, want: usize, timeout: Duration, during: &'static str) -> Result<()> {
        let start = Instant::now();
        while self.pending.len() < want {
            let left = timeout.saturating_sub(start.elapsed());
            if left.is_zero() {
                return Err(PtpError::Timeout {
                    what: during,
                    after: timeout,
                });
            }
            let n = self.read_bulk_in(left, timeout, during)?;
            self.pending.extend_from_slice(&self.buf[..n]);
        }
        Ok(())
    }

    /// One bulk-in read into `buf`. A stall means the camera abandoned the transaction
    /// (still-image class, 7.2): the halt is cleared so that the next transaction can run,
    /// and the transaction fails, for the caller to recover (a download resets the camera
    /// and resumes). Waiting for more data after a stall would only time out. `wait` is
    /// what is left of `timeout`, the phase's timeout that an error names.
    fn read_bulk_in(
        &mut self,
        wait: Duration,
        timeout: Duration,
        during: &'static str,
    ) -> Result<usize> {
        match self.pipe.read(Endpoint::BulkIn, &mut self.buf, wait) {
            Ok(n) => Ok(n),
            Err(PipeError::Stall) => {
                tracing::warn!("bulk-in stalled during {during}; clearing the halt");
                self.pending.clear();
                self.pipe
                    .clear_halt(Endpoint::BulkIn)
                    .map_err(|e| pipe_err(e, "clear halt", timeout))?;
                Err(PtpError::Stalled { during })
            }
            Err(e) => Err(pipe_err(e, during, timeout)),
        }
    }

    /// Reads one container. Data payloads are streamed into one buffer with progress.
    fn read_container(
        &mut self,
        timeout: Duration,
        progress: &mut dyn FnMut(u64, u64),
    ) -> Result<(Header, Vec<u8>)> {
        self.fill(HEADER_LEN, timeout, "container from camera")?;
        let header = Header::parse(&self.pending[..HEADER_LEN])?;
        let total = header.length as usize;
        if header.kind != Kind::Data && total > HEADER_LEN + 4 * container::MAX_PARAMS {
            return Err(PtpError::malformed(
                "container",
                0,
                format!("{:?} container of {total} bytes", header.kind),
            ));
        }
        crate::check_object_size(header.payload_len() as u64, "a USB data container")?;
        let mut payload = Vec::with_capacity(header.payload_len().min(crate::PREALLOCATE_MAX));
        payload.extend_from_slice(&self.pending[HEADER_LEN..self.pending.len().min(total)]);
        self.pending.drain(..self.pending.len().min(total));
        // Each read within the timeout, and the whole phase within the time its size allows
        // (`crate::data_deadline`): a camera that sends a byte now and then cannot hold the
        // capture for hours.
        let phase = crate::data_deadline(timeout, header.payload_len() as u64);
        let deadline = std::time::Instant::now() + phase;
        while payload.len() < header.payload_len() {
            progress(payload.len() as u64, header.payload_len() as u64);
            let left = deadline.saturating_duration_since(std::time::Instant::now());
            if left.is_zero() {
                return Err(PtpError::Timeout {
                    what: "data",
                    after: phase,
                });
            }
            let n = match self.read_bulk_in(timeout.min(left), timeout, "data phase") {
                // Cut short by the phase's deadline: say so, not the per-read timeout.
                Err(PtpError::Timeout { .. }) if std::time::Instant::now() >= deadline => {
                    return Err(PtpError::Timeout {
                        what: "data",
                        after: phase,
                    })
                }
                r => r?,
            };
            let need = header.payload_len() - payload.len();
            payload.extend_from_slice(&self.buf[..n.min(need)]);
            self.pending.extend_from_slice(&self.buf[n.min(need)..n]);
        }
        progress(payload.len() as u64, header.payload_len() as u64);
        Ok((header, payload))
    }
}

impl<P: BulkPipe> Transport for UsbTransport<P> {
    fn transact(
        &mut self,
        op: &Message,
        data_out: Option<&[u8]>,
        response_timeout: Duration,
        progress: Progress,
    ) -> Result<(Option<Vec<u8>>, Message)> {
        self.pending.clear();
        let command = container::encode_message(Kind::Command, op);
        self.write_transfer(&command, response_timeout)?;
        if let Some(data) = data_out {
            let mut c = container::encode_header(Kind::Data, op.code, op.tid, data.len());
            c.extend_from_slice(data);
            self.write_transfer(&c, response_timeout)?;
        }
        let mut data_in = None;
        loop {
            let (h, payload) = self.read_container(response_timeout, progress)?;
            if h.tid != op.tid {
                return Err(PtpError::Protocol(format!(
                    "camera answered transaction {} while {} ({:#06x}) was running",
                    h.tid, op.tid, op.code
                )));
            }
            match h.kind {
                Kind::Data if data_in.is_none() => data_in = Some(payload),
                Kind::Response => return Ok((data_in, container::decode_message(&h, &payload)?)),
                k => {
                    return Err(PtpError::Protocol(format!(
                        "unexpected {k:?} container in transaction {}",
                        op.tid
                    )))
                }
            }
        }
    }

    fn poll_event(&mut self, timeout: Duration) -> Result<Option<crate::container::Message>> {
        let mut buf = [0u8; 64];
        match self.pipe.read(Endpoint::Interrupt, &mut buf, timeout) {
            Ok(0) | Err(PipeError::Timeout) => Ok(None),
            Ok(n) => {
                let (h, p) = container::decode(&buf[..n])?;
                if h.kind != Kind::Event {
                    return Err(PtpError::malformed(
                        "event",
                        4,
                        format!("{:?} container on the interrupt endpoint", h.kind),
                    ));
                }
                Ok(Some(container::decode_message(&h, p)?))
            }
            Err(e) => Err(pipe_err(e, "event read", timeout)),
        }
    }

    /// Device Reset, then clear both bulk halts, then wait until Get Device Status says OK.
    fn reset(&mut self) -> Result<()> {
        let t = Duration::from_secs(5);
        self.pending.clear();
        self.pipe
            .class_request(class_request::DEVICE_RESET, &[], 0)
            .map_err(|e| {
                // A camera that cannot take a control request on its default endpoint, after
                // a bulk transfer failed, has left the bus: a camera unplugged mid-download
                // gives an I/O error here as often as "no device".
                let e = match e {
                    PipeError::Other(_) => PipeError::Gone,
                    e => e,
                };
                pipe_err(e, "device reset", t)
            })?;
        let _ = self.pipe.clear_halt(Endpoint::BulkIn);
        let _ = self.pipe.clear_halt(Endpoint::BulkOut);
        let start = Instant::now();
        while start.elapsed() < t {
            let status = self
                .pipe
                .class_request(class_request::GET_DEVICE_STATUS, &[], 64)
                .map_err(|e| pipe_err(e, "device status", t))?;
            if status.len() >= 4
                && u16::from_le_bytes([status[2], status[3]]) != crate::codes::rc::DEVICE_BUSY
            {
                return Ok(());
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        Err(PtpError::Timeout {
            what: "device status after reset",
            after: t,
        })
    }

    fn describe(&self) -> String {
        self.pipe.describe()
    }
}

/// Cancels a running transaction with the class Cancel request (code 0x4001 and the id).
pub fn cancel<P: BulkPipe>(t: &mut UsbTransport<P>, tid: u32) -> Result<()> {
    let mut data = 0x4001u16.to_le_bytes().to_vec();
    data.extend_from_slice(&tid.to_le_bytes());
    t.pipe
        .class_request(class_request::CANCEL, &data, 0)
        .map(|_| ())
        .map_err(|e| pipe_err(e, "cancel", Duration::from_secs(1)))
}

pub use rusb_pipe::{list_still_image_devices, open_usb, RusbPipe, UsbCameraInfo};

mod rusb_pipe {
    use super::*;
    use rusb::{Direction, TransferType, UsbContext};

    /// libusb failing before any device is looked at: the machine gives no USB access.
    fn no_usb(e: rusb::Error) -> PtpError {
        PtpError::NoUsb {
            reason: e.to_string(),
        }
    }

    /// Vendor ids we know make PTP cameras, for devices that do not announce class 6/1/1
    /// at the interface (or announce a vendor class, as some THETA firmwares do).
    pub const KNOWN_VENDORS: [(u16, &str); 4] = [
        (0x04b0, "Nikon"),
        (0x05ca, "Ricoh"),
        (0x04a9, "Canon"),
        (0x054c, "Sony"),
    ];

    #[derive(Debug, Clone)]
    pub struct UsbCameraInfo {
        pub vendor_id: u16,
        pub product_id: u16,
        pub bus: u8,
        pub address: u8,
        pub interface: u8,
        pub vendor: Option<&'static str>,
    }

    impl UsbCameraInfo {
        pub fn selector(&self) -> String {
            format!("usb:{:04x}:{:04x}", self.vendor_id, self.product_id)
        }
    }

    pub struct RusbPipe {
        handle: rusb::DeviceHandle<rusb::Context>,
        interface: u8,
        bulk_in: u8,
        bulk_out: u8,
        interrupt: u8,
        max_packet: usize,
        name: String,
    }

    fn map(e: rusb::Error) -> PipeError {
        match e {
            rusb::Error::Timeout => PipeError::Timeout,
            rusb::Error::Pipe => PipeError::Stall,
            rusb::Error::NoDevice | rusb::Error::NotFound => PipeError::Gone,
            e => PipeError::Other(e.to_string()),
        }
    }

    struct Found {
        interface: u8,
        bulk_in: u8,
        bulk_out: u8,
        interrupt: u8,
        max_packet: usize,
    }

    fn still_image_interface(dev: &rusb::Device<rusb::Context>) -> Option<Found> {
        let config = dev
            .active_config_descriptor()
            .or_else(|_| dev.config_descriptor(0))
            .ok()?;
        for iface in config.interfaces() {
            for alt in iface.descriptors() {
                let class = (alt.class_code(), alt.sub_class_code(), alt.protocol_code());
                if class != (6, 1, 1) && class.0 != 0xff {
                    continue;
                }
                let (mut bi, mut bo, mut int, mut mps) = (None, None, None, 512);
                for ep in alt.endpoint_descriptors() {
                    match (ep.transfer_type(), ep.direction()) {
                        (TransferType::Bulk, Direction::In) => {
                            bi = Some(ep.address());
                            mps = ep.max_packet_size() as usize;
                        }
                        (TransferType::Bulk, Direction::Out) => bo = Some(ep.address()),
                        (TransferType::Interrupt, Direction::In) => int = Some(ep.address()),
                        _ => {}
                    }
                }
                if let (Some(bulk_in), Some(bulk_out), Some(interrupt)) = (bi, bo, int) {
                    return Some(Found {
                        interface: alt.interface_number(),
                        bulk_in,
                        bulk_out,
                        interrupt,
                        max_packet: mps,
                    });
                }
            }
        }
        None
    }

    /// Every USB device with a still-image interface (class 6/1/1 or a vendor interface with
    /// the PTP endpoint triple on a known camera vendor).
    pub fn list_still_image_devices() -> Result<Vec<UsbCameraInfo>> {
        let ctx = rusb::Context::new().map_err(no_usb)?;
        let mut out = Vec::new();
        for dev in ctx.devices().map_err(no_usb)?.iter() {
            let Ok(desc) = dev.device_descriptor() else {
                continue;
            };
            let Some(found) = still_image_interface(&dev) else {
                continue;
            };
            let vendor = KNOWN_VENDORS
                .iter()
                .find(|v| v.0 == desc.vendor_id())
                .map(|v| v.1);
            out.push(UsbCameraInfo {
                vendor_id: desc.vendor_id(),
                product_id: desc.product_id(),
                bus: dev.bus_number(),
                address: dev.address(),
                interface: found.interface,
                vendor,
            });
        }
        Ok(out)
    }

    /// Opens the first still-image device matching `vendor`/`product` (either may be
    /// omitted), detaching a kernel driver and claiming the interface.
    pub fn open_usb(vendor: Option<u16>, product: Option<u16>) -> Result<RusbPipe> {
        let ctx = rusb::Context::new().map_err(no_usb)?;
        let devices = ctx.devices().map_err(no_usb)?;
        for dev in devices.iter() {
            let Ok(desc) = dev.device_descriptor() else {
                continue;
            };
            if vendor.is_some_and(|v| v != desc.vendor_id())
                || product.is_some_and(|p| p != desc.product_id())
            {
                continue;
            }
            let Some(f) = still_image_interface(&dev) else {
                continue;
            };
            let name = format!(
                "usb:{:04x}:{:04x} (bus {} address {})",
                desc.vendor_id(),
                desc.product_id(),
                dev.bus_number(),
                dev.address()
            );
            let handle = dev.open().map_err(|e| match e {
                rusb::Error::Access => PtpError::Permission {
                    device: name.clone(),
                },
                e => PtpError::Io(format!("opening {name}: {e}")),
            })?;
            let _ = handle.set_auto_detach_kernel_driver(true);
            handle.claim_interface(f.interface).map_err(|e| match e {
                rusb::Error::Busy => PtpError::Claimed {
                    device: name.clone(),
                },
                rusb::Error::Access => PtpError::Permission {
                    device: name.clone(),
                },
                e => PtpError::Io(format!("claiming {name}: {e}")),
            })?;
            return Ok(RusbPipe {
                handle,
                interface: f.interface,
                bulk_in: f.bulk_in,
                bulk_out: f.bulk_out,
                interrupt: f.interrupt,
                max_packet: f.max_packet,
                name,
            });
        }
        Err(PtpError::NotFound(match (vendor, product) {
            (None, None) => "no PTP camera on USB (is it switched on and in PTP/MTP mode?)".into(),
            _ => format!(
                "no PTP camera on USB matching {:04x}:{:04x} (is it plugged in, switched on and in PTP/MTP mode?)",
                vendor.unwrap_or(0),
                product.unwrap_or(0)
            ),
        }))
    }

    impl BulkPipe for RusbPipe {
        fn max_packet(&self) -> usize {
            self.max_packet
        }
        fn write(&mut self, data: &[u8], timeout: Duration) -> Result<usize, PipeError> {
            self.handle
                .write_bulk(self.bulk_out, data, timeout)
                .map_err(map)
        }
        fn read(
            &mut self,
            ep: Endpoint,
            buf: &mut [u8],
            timeout: Duration,
        ) -> Result<usize, PipeError> {
            match ep {
                Endpoint::Interrupt => self.handle.read_interrupt(self.interrupt, buf, timeout),
                _ => self.handle.read_bulk(self.bulk_in, buf, timeout),
            }
            .map_err(map)
        }
        fn clear_halt(&mut self, ep: Endpoint) -> Result<(), PipeError> {
            let addr = match ep {
                Endpoint::BulkIn => self.bulk_in,
                Endpoint::BulkOut => self.bulk_out,
                Endpoint::Interrupt => self.interrupt,
            };
            self.handle.clear_halt(addr).map_err(map)
        }
        fn class_request(
            &mut self,
            request: u8,
            data_out: &[u8],
            data_in: usize,
        ) -> Result<Vec<u8>, PipeError> {
            let t = Duration::from_secs(5);
            let index = self.interface as u16;
            if data_in > 0 {
                let mut buf = vec![0u8; data_in];
                let rt = rusb::request_type(
                    Direction::In,
                    rusb::RequestType::Class,
                    rusb::Recipient::Interface,
                );
                let n = self
                    .handle
                    .read_control(rt, request, 0, index, &mut buf, t)
                    .map_err(map)?;
                buf.truncate(n);
                Ok(buf)
            } else {
                let rt = rusb::request_type(
                    Direction::Out,
                    rusb::RequestType::Class,
                    rusb::Recipient::Interface,
                );
                self.handle
                    .write_control(rt, request, 0, index, data_out, t)
                    .map_err(map)?;
                Ok(Vec::new())
            }
        }
        fn describe(&self) -> String {
            self.name.clone()
        }
    }

    impl Drop for RusbPipe {
        fn drop(&mut self) {
            let _ = self.handle.release_interface(self.interface);
        }
    }
}
