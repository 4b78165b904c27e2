//! The simulated camera's state machine, independent of the link: sessions, storage,
//! properties, capture, events, and injected faults.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use brdfd_ptp::codes::{event, format, op, prop, rc};
use brdfd_ptp::container::Message;
use brdfd_ptp::dataset::{encode_nikon_events, DevicePropDesc, Form, ObjectInfo, Value};
use brdfd_ptp::wire::Writer;

use super::canon::EosBody;
use super::profiles::{self, Profile};
use super::sony::SonyBody;
use crate::{ImageSource, Shot};

const SDRAM_HANDLE: u32 = 0xFFFF_0001;
const INVALID_DEVICE_PROP_VALUE: u16 = 0x201C;

/// Faults to inject; each is used up when it fires, so a test sets one and watches the
/// client recover.
#[derive(Debug, Clone, Default)]
pub struct Faults {
    /// Answer the next N operations (after OpenSession) with DeviceBusy.
    pub busy_storm: u32,
    /// Drop the link after this many bytes of the next object download.
    pub disconnect_in_download: Option<usize>,
    /// Wait this long before the next response.
    pub stall: Option<Duration>,
    /// Send the next response with a corrupt length.
    pub corrupt_next_response: bool,
    /// USB: halt (stall) the bulk-in endpoint after this many bytes of the next object
    /// download, abandoning the transfer, as a camera does that cannot finish one.
    pub halt_in_download: Option<usize>,
    /// Never answer OpenSession until the link is reset (a wedged camera).
    pub wedged: bool,
    /// Power off when asked to capture after this many captures (a flat battery): the link
    /// drops, and the camera answers nothing more.
    pub power_off_after_captures: Option<u32>,
    /// Name every shot's files as the first shot's (`DSC_0001.NEF`), as a camera can after
    /// a card change, or when it shoots to its memory and numbers nothing.
    pub same_file_names: bool,
}

impl Responder {
    /// A Sony body that speaks at most control protocol 2.00, as bodies before the a7 IV's
    /// generation do: it then takes its exposure only in notches.
    pub fn speak_sony_protocol_2(&mut self) {
        if let Some(sony) = &mut self.sony {
            sony.max_protocol = 200;
        }
    }

    /// A Sony that lists automatic ISO last, and is set to it: a body whose notch out of
    /// automatic goes down, not up.
    pub fn list_sony_auto_iso_last(&mut self) {
        if let Some(sony) = &mut self.sony {
            sony.list_auto_iso_last();
        }
    }

    /// Puts a THETA to sleep (property 0xD80E reads 1), as its sleep timer would.
    pub fn fall_asleep(&mut self) {
        if let Some(d) = self.props.get_mut(&prop::RICOH_SLEEP) {
            d.current = Value::UInt(1);
        }
    }
}

/// What the link must do beyond sending the reply, for faults that live on the wire.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum WireFault {
    /// Send this many bytes of the data phase, then drop the link.
    DropAfter(usize),
    CorruptResponse,
    /// Send this many bytes of the data phase, then halt the bulk-in endpoint and abandon
    /// the transaction (USB).
    HaltBulkIn(usize),
    /// Say nothing at all.
    Silence,
    /// Drop the link at once (the camera powered off).
    Hangup,
}

pub struct Reply {
    pub data: Option<Vec<u8>>,
    pub response: Message,
    /// Events for the event channel (USB interrupt endpoint, PTP/IP event connection).
    pub events: Vec<Message>,
    pub delay: Option<Duration>,
    pub fault: Option<WireFault>,
}

struct Object {
    info: ObjectInfo,
    data: Vec<u8>,
}

/// How long a simulated body stays busy processing a frame after the exposure. A real D5100
/// takes about half a second for a JPEG; the simulation keeps the client's polling real but
/// short.
const PROCESSING: std::time::Duration = std::time::Duration::from_millis(100);

pub struct Responder {
    profile: Profile,
    source: Arc<dyn ImageSource>,
    session: Option<u32>,
    props: BTreeMap<u16, DevicePropDesc>,
    objects: BTreeMap<u32, Object>,
    /// Nikon SDRAM: the shot's other files (the JPEG of a RAW + JPEG shot), each handed out
    /// on the SDRAM handle once the one before has been read or deleted.
    sdram_queue: std::collections::VecDeque<Object>,
    next_handle: u32,
    shots: u32,
    /// Nikon: events waiting for GetEvent, held back until the exposure is over; DeviceReady
    /// answers busy until the frame is processed, and for at least `device_ready_busy` polls.
    nikon_events: Vec<(u16, u32)>,
    exposed_at: Option<std::time::Instant>,
    busy_until: Option<std::time::Instant>,
    device_ready_busy: u32,
    /// Time the camera has spent busy with exposures so far: the device's own time.
    busy_total: std::time::Duration,
    /// A Canon EOS body's remote release, properties and records.
    eos: Option<EosBody>,
    /// A Sony body's connection and properties.
    sony: Option<SonyBody>,
    /// The operations the body's DeviceInfo lists: the only ones it answers.
    operations: Vec<u16>,
    /// Events sent with the first reply after their time (a shot's ObjectAdded once it is
    /// processed), for bodies that announce on the event channel.
    due_events: Vec<(std::time::Instant, Message)>,
    pub faults: Faults,
    /// Off ([`Faults::power_off_after_captures`]): nothing is answered any more.
    pub powered_off: bool,
    /// Operations seen, for tests that check what a client did.
    pub log: Vec<u16>,
}

pub type SharedResponder = Arc<Mutex<Responder>>;

impl Responder {
    pub fn new(profile: Profile, source: Arc<dyn ImageSource>) -> Responder {
        Responder {
            profile,
            source,
            session: None,
            props: profiles::properties(profile)
                .into_iter()
                .map(|d| (d.code, d))
                .collect(),
            objects: BTreeMap::new(),
            sdram_queue: Default::default(),
            next_handle: 1,
            shots: 0,
            nikon_events: Vec::new(),
            exposed_at: None,
            busy_until: None,
            device_ready_busy: 0,
            busy_total: std::time::Duration::ZERO,
            eos: profile.is_canon_eos().then(EosBody::default),
            sony: profile.is_sony().then(SonyBody::default),
            due_events: Vec::new(),
            operations: profiles::device_info(profile).operations,
            faults: Faults::default(),
            powered_off: false,
            log: Vec::new(),
        }
    }

    pub fn shared(self) -> SharedResponder {
        Arc::new(Mutex::new(self))
    }

    pub fn profile(&self) -> Profile {
        self.profile
    }

    /// What a Device Reset or a dropped connection does: the session ends.
    pub fn reset(&mut self) {
        self.session = None;
        self.faults.wedged = false;
        self.busy_until = None;
        self.exposed_at = None;
        self.device_ready_busy = 0;
        if let Some(eos) = &mut self.eos {
            eos.end_session();
        }
        if let Some(sony) = &mut self.sony {
            sony.end_session();
        }
    }

    /// Seconds the camera has spent exposing and processing shots (Nikon profile).
    pub fn busy_seconds(&self) -> f64 {
        self.busy_total.as_secs_f64()
    }

    fn before(t: Option<std::time::Instant>) -> bool {
        t.is_some_and(|t| std::time::Instant::now() < t)
    }

    /// Host-to-device data phases the device expects for an operation. Vendors' codes
    /// overlap (0x9207 is Nikon's InitiateCaptureRecInMedia and Sony's ControlDevice), so it
    /// depends on the body.
    pub fn expects_data_out(&self, code: u16) -> bool {
        match code {
            op::SET_DEVICE_PROP_VALUE => true,
            op::CANON_EOS_SET_DEVICE_PROP_VALUE_EX => self.eos.is_some(),
            op::SONY_SDIO_SET_EXT_DEVICE_PROP_VALUE | op::SONY_SDIO_CONTROL_DEVICE => {
                self.sony.is_some()
            }
            _ => false,
        }
    }

    pub fn handle(&mut self, m: &Message, data_out: Option<&[u8]>) -> Reply {
        self.log.push(m.code);
        let mut reply = Reply {
            data: None,
            response: Message::new(rc::OK, m.tid, &[]),
            events: Vec::new(),
            delay: self.faults.stall.take(),
            fault: None,
        };
        let capture = matches!(
            m.code,
            op::INITIATE_CAPTURE
                | op::NIKON_INITIATE_CAPTURE_REC_IN_SDRAM
                | op::NIKON_INITIATE_CAPTURE_REC_IN_MEDIA
                | op::CANON_EOS_REMOTE_RELEASE_ON
        );
        if capture
            && self
                .faults
                .power_off_after_captures
                .is_some_and(|n| self.shots >= n)
        {
            self.powered_off = true;
        }
        if self.powered_off {
            reply.fault = Some(WireFault::Hangup);
            return reply;
        }
        if self.faults.wedged && m.code == op::OPEN_SESSION {
            reply.fault = Some(WireFault::Silence);
            return reply;
        }
        if self.faults.corrupt_next_response {
            self.faults.corrupt_next_response = false;
            reply.fault = Some(WireFault::CorruptResponse);
        }
        let code = match self.session {
            None if !matches!(m.code, op::GET_DEVICE_INFO | op::OPEN_SESSION) => {
                rc::SESSION_NOT_OPEN
            }
            Some(_) if self.faults.busy_storm > 0 && m.code != op::OPEN_SESSION => {
                self.faults.busy_storm -= 1;
                rc::DEVICE_BUSY
            }
            _ => self.dispatch(m, data_out, &mut reply),
        };
        reply.response.code = code;
        if code != rc::OK {
            reply.data = None;
        }
        let now = std::time::Instant::now();
        self.due_events.retain(|(at, e)| {
            let due = *at <= now;
            if due {
                reply.events.push(e.clone());
            }
            !due
        });
        tracing::debug!(
            "simulated {:?}: op {:#06x} {:x?} tid {} -> {:#06x}{}",
            self.profile,
            m.code,
            m.params,
            m.tid,
            code,
            reply
                .data
                .as_ref()
                .map_or(String::new(), |d| format!(", {} bytes", d.len()))
        );
        reply
    }

    fn dispatch(&mut self, m: &Message, data_out: Option<&[u8]>, reply: &mut Reply) -> u16 {
        // What the body's DeviceInfo does not list, it refuses (an EOS body or a Sony refuses
        // InitiateCapture; the a7 IV, DeleteObject).
        if !self.operations.contains(&m.code) {
            return rc::OPERATION_NOT_SUPPORTED;
        }
        if let Some(code) = self.dispatch_canon_eos(m, data_out, reply) {
            return code;
        }
        if let Some(code) = self.dispatch_sony(m, data_out, reply) {
            return code;
        }
        let p = |i| m.param(i);
        match m.code {
            op::GET_DEVICE_INFO => {
                reply.data = Some(profiles::device_info(self.profile).encode());
            }
            op::OPEN_SESSION => {
                if p(0) == 0 {
                    return rc::INVALID_PARAMETER;
                }
                if self.session.is_some() {
                    return rc::SESSION_ALREADY_OPEN;
                }
                self.session = Some(p(0));
            }
            op::CLOSE_SESSION => {
                self.session = None;
                if let Some(eos) = &mut self.eos {
                    eos.end_session();
                }
                if let Some(sony) = &mut self.sony {
                    sony.end_session();
                }
            }
            op::GET_STORAGE_IDS => {
                // A Sony in PC remote mode lists no store, as the a7 IV's dump shows.
                let ids = match self.sony {
                    Some(_) => Vec::new(),
                    None => vec![self.profile.storage_id()],
                };
                reply.data = Some(Writer::new().u32_array(&ids).finish())
            }
            op::GET_STORAGE_INFO => {
                if p(0) != self.profile.storage_id() || self.sony.is_some() {
                    return rc::INVALID_STORAGE_ID;
                }
                let used = self.objects.values().map(|o| o.data.len() as u64).sum();
                reply.data = Some(profiles::storage_info(self.profile, used).encode());
            }
            op::GET_NUM_OBJECTS => reply.response.params = vec![self.card_handles().len() as u32],
            op::GET_OBJECT_HANDLES => {
                reply.data = Some(Writer::new().u32_array(&self.card_handles()).finish())
            }
            op::GET_OBJECT_INFO => match self.objects.get(&p(0)) {
                Some(o) => reply.data = Some(o.info.encode()),
                None => return rc::INVALID_OBJECT_HANDLE,
            },
            op::GET_OBJECT | op::GET_PARTIAL_OBJECT => {
                let Some(o) = self.objects.get(&p(0)) else {
                    return rc::INVALID_OBJECT_HANDLE;
                };
                let (start, len) = if m.code == op::GET_PARTIAL_OBJECT {
                    let s = (p(1) as usize).min(o.data.len());
                    (s, (p(2) as usize).min(o.data.len() - s))
                } else {
                    (0, o.data.len())
                };
                reply.data = Some(o.data[start..start + len].to_vec());
                if m.code == op::GET_PARTIAL_OBJECT {
                    reply.response.params = vec![len as u32];
                }
                if let Some(n) = self.faults.disconnect_in_download.take() {
                    reply.fault = Some(WireFault::DropAfter(n));
                } else if let Some(n) = self.faults.halt_in_download.take() {
                    reply.fault = Some(WireFault::HaltBulkIn(n));
                }
                let read_to_end = start + len == o.data.len();
                if p(0) == self.memory_handle() && read_to_end && reply.fault.is_none() {
                    // Nikon frees the SDRAM image once it has been read, and hands out the
                    // shot's next file on the same handle.
                    self.next_sdram_file();
                }
            }
            op::DELETE_OBJECT => {
                if !self.objects.contains_key(&p(0)) {
                    return rc::INVALID_OBJECT_HANDLE;
                }
                if p(0) == self.memory_handle() {
                    self.next_sdram_file();
                } else {
                    self.objects.remove(&p(0));
                }
            }
            op::GET_DEVICE_PROP_DESC => match self.props.get(&(p(0) as u16)) {
                Some(d) => reply.data = Some(d.encode()),
                None => return rc::DEVICE_PROP_NOT_SUPPORTED,
            },
            op::GET_DEVICE_PROP_VALUE => match self.props.get(&(p(0) as u16)) {
                Some(d) => reply.data = Some(d.current.to_bytes(d.datatype)),
                None => return rc::DEVICE_PROP_NOT_SUPPORTED,
            },
            op::SET_DEVICE_PROP_VALUE => {
                return self.set_prop(p(0) as u16, data_out.unwrap_or(&[]), reply)
            }
            op::INITIATE_CAPTURE => {
                if self.int_prop(prop::RICOH_SLEEP, 0) == 1 {
                    // A sleeping THETA takes no pictures until a client wakes it.
                    return rc::DEVICE_BUSY;
                }
                let handles = match self.shoot(false) {
                    Ok(h) => h,
                    Err(c) => return c,
                };
                for h in handles {
                    reply
                        .events
                        .push(Message::new(event::OBJECT_ADDED, m.tid, &[h]));
                }
                reply
                    .events
                    .push(Message::new(event::CAPTURE_COMPLETE, m.tid, &[]));
            }
            op::NIKON_INITIATE_CAPTURE_REC_IN_SDRAM | op::NIKON_INITIATE_CAPTURE_REC_IN_MEDIA
                if self.is_nikon() =>
            {
                let sdram = m.code == op::NIKON_INITIATE_CAPTURE_REC_IN_SDRAM;
                let handles = match self.shoot(sdram) {
                    Ok(h) => h,
                    Err(c) => return c,
                };
                // The exposure takes its time, and then the camera processes the frame.
                self.start_busy();
                if sdram {
                    self.nikon_events
                        .push((event::NIKON_OBJECT_ADDED_IN_SDRAM, SDRAM_HANDLE));
                    self.nikon_events
                        .push((event::NIKON_CAPTURE_COMPLETE_REC_IN_SDRAM, 0));
                } else {
                    for h in handles {
                        self.nikon_events.push((event::OBJECT_ADDED, h));
                    }
                    self.nikon_events.push((event::CAPTURE_COMPLETE, 0));
                }
            }
            op::NIKON_GET_EVENT if self.is_nikon() => {
                let events = if Responder::before(self.exposed_at) {
                    Vec::new()
                } else {
                    std::mem::take(&mut self.nikon_events)
                };
                reply.data = Some(encode_nikon_events(&events));
            }
            op::NIKON_DEVICE_READY if self.is_nikon() => {
                if Responder::before(self.busy_until) || self.device_ready_busy > 0 {
                    self.device_ready_busy = self.device_ready_busy.saturating_sub(1);
                    return rc::DEVICE_BUSY;
                }
            }
            op::NIKON_GET_VENDOR_PROP_CODES if self.is_nikon() => {
                let vendor: Vec<u16> = self
                    .props
                    .keys()
                    .copied()
                    .filter(|c| *c >= 0xD000)
                    .collect();
                reply.data = Some(Writer::new().u16_array(&vendor).finish());
            }
            op::NIKON_CHANGE_CAMERA_MODE | op::NIKON_AF_DRIVE if self.is_nikon() => {}
            _ => return rc::OPERATION_NOT_SUPPORTED,
        }
        rc::OK
    }

    /// A Canon EOS body's own operations; `None` for the others (and for other profiles).
    fn dispatch_canon_eos(
        &mut self,
        m: &Message,
        data_out: Option<&[u8]>,
        reply: &mut Reply,
    ) -> Option<u16> {
        let exposing = Responder::before(self.busy_until);
        let eos = self.eos.as_mut()?;
        let p = |i| m.param(i);
        Some(match m.code {
            op::CANON_EOS_SET_REMOTE_MODE => {
                eos.set_remote_mode(p(0));
                rc::OK
            }
            op::CANON_EOS_SET_EVENT_MODE => {
                eos.set_event_mode(p(0));
                rc::OK
            }
            op::CANON_EOS_GET_EVENT => {
                reply.data = Some(eos.get_event(exposing));
                rc::OK
            }
            op::CANON_EOS_SET_DEVICE_PROP_VALUE_EX => eos.set_value(data_out.unwrap_or(&[])),
            // The body's buttons locked and unlocked: nothing to lock here.
            op::CANON_EOS_PC_HDD_CAPACITY
            | op::CANON_EOS_SET_UI_LOCK
            | op::CANON_EOS_RESET_UI_LOCK
            | op::CANON_EOS_KEEP_DEVICE_ON
            | op::CANON_EOS_REMOTE_RELEASE_OFF => rc::OK,
            op::CANON_EOS_GET_STORAGE_IDS => {
                let ids = [self.profile.storage_id()];
                reply.data = Some(Writer::new().u32_array(&ids).finish());
                rc::OK
            }
            op::CANON_EOS_GET_STORAGE_INFO if p(0) != self.profile.storage_id() => {
                rc::INVALID_STORAGE_ID
            }
            op::CANON_EOS_GET_STORAGE_INFO => {
                let used = self.objects.values().map(|o| o.data.len() as u64).sum();
                reply.data = Some(profiles::storage_info(self.profile, used).encode());
                rc::OK
            }
            op::CANON_EOS_TRANSFER_COMPLETE => match self.objects.get(&p(0)) {
                // Only a file held for the host is let go; a card's file stays on the card.
                Some(o) if o.info.storage_id == 0 => {
                    self.objects.remove(&p(0));
                    rc::OK
                }
                _ => rc::INVALID_OBJECT_HANDLE,
            },
            op::CANON_EOS_REMOTE_RELEASE_ON if exposing => rc::DEVICE_BUSY,
            // Half way (1) focuses, which a lens at MF skips; fully (2, or 3 for both at
            // once) shoots.
            op::CANON_EOS_REMOTE_RELEASE_ON if p(0) & 2 == 0 => rc::OK,
            op::CANON_EOS_REMOTE_RELEASE_ON if !eos.in_remote_mode() => rc::GENERAL_ERROR,
            op::CANON_EOS_REMOTE_RELEASE_ON => self.eos_shoot().err().unwrap_or(rc::OK),
            _ => return None,
        })
    }

    /// A Sony body's own operations; `None` for the others (and for other profiles).
    fn dispatch_sony(
        &mut self,
        m: &Message,
        data_out: Option<&[u8]>,
        reply: &mut Reply,
    ) -> Option<u16> {
        let files = self.files_in_memory();
        let exposing = Responder::before(self.busy_until);
        let sony = self.sony.as_mut()?;
        let p = |i| m.param(i);
        let data = data_out.unwrap_or(&[]);
        Some(match m.code {
            op::SONY_SDIO_CONNECT => {
                // The step answers with a data phase, which hosts read and drop.
                reply.data = Some(vec![0; 8]);
                sony.connect(p(0))
            }
            op::SONY_SDIO_GET_EXT_DEVICE_INFO => {
                reply.data = Some(sony.ext_device_info(p(0)));
                rc::OK
            }
            op::SONY_SDIO_GET_ALL_EXT_DEVICE_PROP_INFO => {
                reply.data = Some(sony.all_props(files));
                rc::OK
            }
            op::SONY_SDIO_SET_EXT_DEVICE_PROP_VALUE => {
                let code = sony.set(p(0) as u16, data);
                if code == rc::OK {
                    reply
                        .events
                        .push(Message::new(event::SONY_DEVICE_PROP_CHANGED, 0, &[p(0)]));
                }
                code
            }
            op::SONY_SDIO_CONTROL_DEVICE if !sony.connected() => rc::ACCESS_DENIED,
            op::SONY_SDIO_CONTROL_DEVICE => {
                let pressed = data.get(..2) == Some(&[2, 0]);
                match p(0) as u16 {
                    // The shutter button's full press shoots (a lens at MF needs no focus).
                    prop::SONY_SHUTTER_RELEASE if pressed && exposing => rc::DEVICE_BUSY,
                    prop::SONY_SHUTTER_RELEASE if pressed => {
                        self.sony_shoot().err().unwrap_or(rc::OK)
                    }
                    prop::SONY_SHUTTER_RELEASE | prop::SONY_SHUTTER_HALF_RELEASE => rc::OK,
                    code => match sony.step(code, data) {
                        Some(rc::OK) => {
                            reply.events.push(Message::new(
                                event::SONY_DEVICE_PROP_CHANGED,
                                0,
                                &[p(0)],
                            ));
                            rc::OK
                        }
                        Some(refused) => refused,
                        None => rc::PARAMETER_NOT_SUPPORTED,
                    },
                }
            }
            _ => return None,
        })
    }

    /// A shot on the Sony body: its files in memory, announced once it is processed.
    fn sony_shoot(&mut self) -> Result<(), u16> {
        self.shoot(true)?;
        self.start_busy();
        if let Some(at) = self.busy_until {
            let handle = brdfd_ptp::sony::MEMORY_HANDLE;
            let added = Message::new(event::SONY_OBJECT_ADDED, 0, &[handle]);
            self.due_events.push((at, added));
        }
        Ok(())
    }

    /// A shot on the EOS body: its files on the card, or held for the host, and the records
    /// that announce them once the exposure and processing are over.
    fn eos_shoot(&mut self) -> Result<(), u16> {
        let to_host = self.eos.as_ref().is_some_and(EosBody::to_host);
        let handles = self.shoot(false)?;
        let mut files = Vec::new();
        for h in handles {
            let Some(o) = self.objects.get_mut(&h) else {
                continue;
            };
            if to_host {
                o.info.storage_id = 0;
            }
            files.push(brdfd_ptp::canon::EosObject {
                handle: h,
                storage_id: o.info.storage_id,
                format: o.info.format,
                size: o.info.compressed_size,
                parent: o.info.parent,
                name: o.info.filename.clone(),
            });
        }
        self.start_busy();
        if let Some(eos) = &mut self.eos {
            eos.shot(files);
        }
        Ok(())
    }

    /// The camera busy for the exposure and then processing the frame.
    fn start_busy(&mut self) {
        let busy = std::time::Duration::from_secs_f64(self.shot_settings().shutter_s.max(0.0))
            + PROCESSING;
        self.busy_until = Some(std::time::Instant::now() + busy);
        self.busy_total += busy;
    }

    /// The release pressed from outside (a trigger box or a cable on the remote socket): the
    /// camera shoots with its current settings and stores the files on its card, where a
    /// client finds them listed; a Nikon also queues ObjectAdded for GetEvent. Returns
    /// whether it shot: an off camera, a sleeping THETA or one still rendering its scene does
    /// not.
    pub fn press_release(&mut self) -> bool {
        if self
            .faults
            .power_off_after_captures
            .is_some_and(|n| self.shots >= n)
        {
            self.powered_off = true;
        }
        if self.powered_off || self.int_prop(prop::RICOH_SLEEP, 0) == 1 {
            return false;
        }
        let Ok(handles) = self.shoot(false) else {
            return false;
        };
        self.start_busy();
        if self.is_nikon() {
            for h in handles {
                self.nikon_events.push((event::OBJECT_ADDED, h));
            }
        } else if self.eos.is_some() {
            let files = handles
                .iter()
                .filter_map(|h| self.objects.get(h).map(|o| (h, o)))
                .map(|(&handle, o)| brdfd_ptp::canon::EosObject {
                    handle,
                    storage_id: o.info.storage_id,
                    format: o.info.format,
                    size: o.info.compressed_size,
                    parent: o.info.parent,
                    name: o.info.filename.clone(),
                })
                .collect();
            if let Some(eos) = &mut self.eos {
                eos.shot(files);
            }
        }
        true
    }

    fn is_nikon(&self) -> bool {
        self.profile == Profile::NikonD5100
    }

    /// The files on the card: not those in a Nikon's SDRAM or held for an EOS body's host.
    fn card_handles(&self) -> Vec<u32> {
        self.objects
            .iter()
            .filter(|(&h, o)| h != SDRAM_HANDLE && o.info.storage_id != 0)
            .map(|(&h, _)| h)
            .collect()
    }

    fn int_prop(&self, code: u16, default: i64) -> i64 {
        self.props
            .get(&code)
            .and_then(|d| d.current.as_i64())
            .unwrap_or(default)
    }

    /// The current exposure, as the camera would shoot it.
    pub fn shot_settings(&self) -> Shot {
        if self.profile.is_theta() {
            // RICOH's rational shutter; automatic exposure shoots 1/100 s. The V's aperture
            // is fixed at f/2.0; the Z1's is its F-Number.
            let shutter = self
                .props
                .get(&brdfd_theta::usb::code::SHUTTER_SPEED)
                .and_then(|d| match d.current {
                    Value::UInt(v) => brdfd_theta::usb::shutter_from_u64(v),
                    _ => None,
                });
            return Shot {
                shutter_s: shutter.unwrap_or(0.01),
                f_number: match self.profile.theta_apertures() {
                    [] => crate::theta::THETA_V_F_NUMBER,
                    [first, ..] => self.int_prop(prop::F_NUMBER, *first as i64) as f64 / 100.0,
                },
                iso: self.int_prop(prop::EXPOSURE_INDEX, 100) as u32,
                raw: false,
                sequence: self.shots + 1,
            };
        }
        let vendor_exposure = match (&self.eos, &self.sony) {
            (Some(eos), _) => Some(eos.exposure()),
            (_, Some(sony)) => Some(sony.exposure()),
            _ => None,
        };
        if let Some((shutter_s, f_number, iso)) = vendor_exposure {
            return Shot {
                shutter_s,
                f_number,
                iso,
                raw: false,
                sequence: self.shots + 1,
            };
        }
        Shot {
            shutter_s: self.int_prop(prop::EXPOSURE_TIME, 100) as f64 / 1e4,
            f_number: self.int_prop(prop::F_NUMBER, 200) as f64 / 100.0,
            iso: self.int_prop(prop::EXPOSURE_INDEX, 100) as u32,
            raw: self.int_prop(prop::COMPRESSION_SETTING, 2) >= 4,
            sequence: self.shots + 1,
        }
    }

    /// Takes a picture: the files the compression setting asks for (RAW, JPEG, or both,
    /// RAW first as a Nikon writes them), each an object. Returns their handles; in SDRAM
    /// the first is on the SDRAM handle and the others wait their turn.
    fn shoot(&mut self, sdram: bool) -> Result<Vec<u32>, u16> {
        if !self.source.ready() {
            // Still making its first picture (a simulator rendering its scene): a real camera
            // that cannot shoot yet answers DeviceBusy, and clients retry.
            return Err(rc::DEVICE_BUSY);
        }
        let shot = self.shot_settings();
        let failed = |e: String| {
            tracing::error!("simulated camera: image source failed: {e}");
            rc::GENERAL_ERROR
        };
        let raw = match shot.raw {
            true => self.source.raw(&shot).map_err(failed)?,
            false => None,
        };
        // Compression setting 4 is RAW alone; a source without RAW files gives its JPEG.
        let jpeg = raw.is_none() || self.int_prop(prop::COMPRESSION_SETTING, 2) != 4;
        let mut files = Vec::new();
        if let Some((ext, data)) = raw {
            let format = if ext.eq_ignore_ascii_case("DNG") {
                format::DNG
            } else {
                format::UNDEFINED
            };
            files.push((format, ext, data));
        }
        if jpeg {
            files.push((
                format::EXIF_JPEG,
                "JPG",
                self.source.photo(&shot).map_err(failed)?,
            ));
        }
        self.shots += 1;
        let (w, h) = self.source.dimensions();
        self.sdram_queue.clear();
        let mut handles = Vec::new();
        for (format, ext, data) in files {
            let info = ObjectInfo {
                storage_id: if sdram { 0 } else { self.profile.storage_id() },
                format,
                compressed_size: data.len().min(u32::MAX as usize) as u32,
                thumb_format: format::EXIF_JPEG,
                width: w,
                height: h,
                bit_depth: if format == format::EXIF_JPEG { 24 } else { 16 },
                filename: match self.profile {
                    p if p.is_theta() => format!("R{:07}.{ext}", 10_000 + self.shots),
                    p if p.is_canon_eos() => format!("IMG_{:04}.{ext}", self.shots % 10_000),
                    p if p.is_sony() => format!("DSC{:05}.{ext}", self.shots % 100_000),
                    _ if self.faults.same_file_names => format!("DSC_0001.{ext}"),
                    _ => format!("DSC_{:04}.{ext}", self.shots % 10_000),
                },
                capture_date: format!("20261122T1200{:02}", self.shots % 60),
                ..Default::default()
            };
            let object = Object { info, data };
            if sdram {
                self.sdram_queue.push_back(object);
            } else {
                self.next_handle += 1;
                let handle = 0x2B00_0000 + self.next_handle;
                self.objects.insert(handle, object);
                handles.push(handle);
            }
        }
        if sdram {
            self.next_sdram_file();
            handles.push(self.memory_handle());
        }
        Ok(handles)
    }

    /// Where a shot kept in the camera's memory is read: Nikon's SDRAM handle, or Sony's.
    fn memory_handle(&self) -> u32 {
        match self.sony {
            Some(_) => brdfd_ptp::sony::MEMORY_HANDLE,
            None => SDRAM_HANDLE,
        }
    }

    /// A shot in memory (Nikon's SDRAM, Sony's): its next file takes the memory handle, or
    /// the handle is freed.
    fn next_sdram_file(&mut self) {
        let handle = self.memory_handle();
        match self.sdram_queue.pop_front() {
            Some(o) => self.objects.insert(handle, o),
            None => self.objects.remove(&handle),
        };
    }

    /// The files of a shot waiting in memory: none while it is being exposed and processed.
    fn files_in_memory(&self) -> usize {
        if Responder::before(self.busy_until) || !self.objects.contains_key(&self.memory_handle()) {
            return 0;
        }
        1 + self.sdram_queue.len()
    }

    fn set_prop(&mut self, code: u16, data: &[u8], reply: &mut Reply) -> u16 {
        let Some(desc) = self.props.get_mut(&code) else {
            return rc::DEVICE_PROP_NOT_SUPPORTED;
        };
        if !desc.writable {
            return rc::ACCESS_DENIED;
        }
        let Ok(v) = Value::from_bytes(data, desc.datatype) else {
            return INVALID_DEVICE_PROP_VALUE;
        };
        let ok = match (&desc.form, v.as_i64()) {
            (Form::Enum(values), _) => values.contains(&v),
            (Form::Range { min, max, step }, Some(x)) => {
                let (a, b, s) = (
                    min.as_i64().unwrap_or(0),
                    max.as_i64().unwrap_or(0),
                    step.as_i64().unwrap_or(1).max(1),
                );
                (a..=b).contains(&x) && (x - a) % s == 0
            }
            _ => true,
        };
        if !ok {
            return INVALID_DEVICE_PROP_VALUE;
        }
        if desc.current != v {
            desc.current = v;
            reply
                .events
                .push(Message::new(event::DEVICE_PROP_CHANGED, 0, &[code as u32]));
        }
        rc::OK
    }
}
