//! The simulated camera as a real USB device, through Linux's FunctionFS: a still-image
//! interface (class 6/1/1: bulk-in, bulk-out, interrupt-in) whose endpoints are files. A
//! gadget made in configfs with an `ffs.NAME` function, mounted (`mount -t functionfs NAME
//! DIR`) and bound to a device controller (a board's, or `dummy_hcd`'s loopback one), then
//! enumerates on the host like a camera, and a host's libusb or gphoto2 talks to it over a
//! real USB stack. The framing is the in-memory pipe's (`usb::Framing`).

use std::fs::{File, OpenOptions};
use std::io::{self, Read, Write};
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use brdfd_ptp::transport::usb::PipeError;

use super::usb::{Endpoints, Framing, MAX_PACKET};
use super::SharedResponder;

const DESCRIPTORS_MAGIC_V2: u32 = 3;
const STRINGS_MAGIC: u32 = 2;
const HAS_FS_DESC: u32 = 1;
const HAS_HS_DESC: u32 = 2;

/// FunctionFS's ep0 events (`struct usb_functionfs_event`: the setup packet, a type, padding).
const EVENT_LEN: usize = 12;
const EVENT_ENABLE: u8 = 2;
const EVENT_SETUP: u8 = 4;

/// The interface and its three endpoints, at one speed: bulk packets of `bulk` bytes, the
/// interrupt endpoint polled every `interval` (frames at full speed, 2^(n-1) microframes at
/// high speed).
fn interface(bulk: u16, interval: u8) -> Vec<u8> {
    let mut d = vec![9, 4, 0, 0, 3, 6, 1, 1, 1];
    for (address, attributes, size, interval) in [
        (0x81, 2, bulk, 0),
        (0x02, 2, bulk, 0),
        (0x83, 3, 64u16, interval),
    ] {
        d.extend_from_slice(&[7, 5, address, attributes]);
        d.extend_from_slice(&size.to_le_bytes());
        d.push(interval);
    }
    d
}

/// The descriptors FunctionFS wants first on ep0 (format v2), full and high speed.
fn descriptors() -> Vec<u8> {
    let (fs, hs) = (interface(64, 10), interface(MAX_PACKET as u16, 8));
    let mut d = Vec::new();
    for word in [
        DESCRIPTORS_MAGIC_V2,
        (20 + fs.len() + hs.len()) as u32,
        HAS_FS_DESC | HAS_HS_DESC,
        4,
        4,
    ] {
        d.extend_from_slice(&word.to_le_bytes());
    }
    d.extend_from_slice(&fs);
    d.extend_from_slice(&hs);
    d
}

/// The interface's name (string 1), in US English.
fn strings(name: &str) -> Vec<u8> {
    let mut body = 0x0409u16.to_le_bytes().to_vec();
    body.extend_from_slice(name.as_bytes());
    body.push(0);
    let mut d = Vec::new();
    for word in [STRINGS_MAGIC, (16 + body.len()) as u32, 1, 1] {
        d.extend_from_slice(&word.to_le_bytes());
    }
    d.extend_from_slice(&body);
    d
}

/// Events a camera keeps for a host that does not read its interrupt endpoint (a Nikon's
/// host polls GetEvent instead); later ones are dropped, as a full event queue drops them.
const QUEUED_EVENTS: usize = 64;

/// The endpoint files once the host has configured the interface.
struct Files {
    bulk_in: Mutex<File>,
    /// To the thread that writes the interrupt endpoint: a write there waits for the host
    /// to poll, which must not hold up the bulk endpoints.
    events: std::sync::mpsc::SyncSender<Vec<u8>>,
}

impl Endpoints for Files {
    fn bulk_in(&self, transfer: Vec<u8>) -> bool {
        self.bulk_in.lock().unwrap().write_all(&transfer).is_ok()
    }

    fn fail_bulk_in(&self, e: PipeError) {
        // FunctionFS halts an endpoint when its file is used in the wrong direction: a read
        // on an IN endpoint sets the halt (and fails with EBADMSG). The host sees a stall
        // until it clears the halt. Leaving the bus is done by unbinding the gadget.
        if matches!(e, PipeError::Stall) {
            let halted = self.bulk_in.lock().unwrap().read(&mut [0u8; 1]);
            tracing::debug!("simulated camera: bulk-in halted ({halted:?})");
        }
    }

    fn interrupt_in(&self, transfer: Vec<u8>) {
        let _ = self.events.try_send(transfer);
    }
}

/// Serves the camera on the FunctionFS mounted at `dir` until the process ends: writes the
/// descriptors (after which the gadget can be bound to a controller), then answers ep0's
/// events, and the bulk endpoints from each enable to the next disable, across unbinding and
/// binding again (unplugging and plugging in).
pub fn serve(dir: &Path, name: &str, responder: SharedResponder) -> io::Result<()> {
    let mut ep0 = OpenOptions::new()
        .read(true)
        .write(true)
        .open(dir.join("ep0"))?;
    ep0.write_all(&descriptors())?;
    ep0.write_all(&strings(name))?;
    let framing = Arc::new(Mutex::new(Framing::default()));
    let mut events = [0u8; 4 * EVENT_LEN];
    loop {
        let n = ep0.read(&mut events)?;
        for e in events[..n].chunks_exact(EVENT_LEN) {
            match e[8] {
                EVENT_ENABLE => {
                    let (dir, responder, framing) =
                        (dir.to_path_buf(), responder.clone(), framing.clone());
                    std::thread::Builder::new()
                        .name("sim-ptp-functionfs".into())
                        .spawn(move || {
                            if let Err(e) = bulk(&dir, &responder, &framing) {
                                tracing::debug!("simulated camera: bulk endpoints closed: {e}");
                            }
                        })?;
                }
                EVENT_SETUP => setup(&mut ep0, e, &framing, &responder)?,
                // Unplugged: the camera waits to be plugged in again (bound), as a real one
                // does. A disable ends the bulk thread's reads; bind, suspend and resume ask
                // nothing.
                _ => {}
            }
        }
    }
}

/// A control request to the interface: the class requests, answered or stalled.
fn setup(
    ep0: &mut File,
    event: &[u8],
    framing: &Mutex<Framing>,
    responder: &SharedResponder,
) -> io::Result<()> {
    let (request_type, request) = (event[0], event[1]);
    let length = u16::from_le_bytes([event[6], event[7]]) as usize;
    let device_to_host = request_type & 0x80 != 0;
    let class = request_type & 0x60 == 0x20;
    // An OUT request's data stage comes first (Cancel's six bytes); reading it acknowledges.
    if !device_to_host {
        let mut data = vec![0u8; length];
        if !class {
            // Stall: the wrong direction.
            let _ = ep0.write(&[]);
            return Ok(());
        }
        ep0.read_exact(&mut data)?;
    }
    let answer = class
        .then(|| framing.lock().unwrap().class_request(request, responder))
        .flatten();
    match (answer, device_to_host) {
        (Some(a), true) => {
            ep0.write_all(&a[..a.len().min(length)])?;
        }
        (Some(_), false) => {}
        // Stalled by reading when the host reads, and the other way round.
        (None, true) => {
            let _ = ep0.read(&mut [0u8; 0]);
        }
        (None, false) => {
            let _ = ep0.write(&[]);
        }
    }
    Ok(())
}

/// The bulk endpoints from an enable until the host lets go (the reads then fail).
fn bulk(dir: &Path, responder: &SharedResponder, framing: &Mutex<Framing>) -> io::Result<()> {
    // Non-blocking: I/O on an endpoint of a disabled function (unbound, unplugged) then
    // fails, where it would wait for the next enable and reach the next host with this
    // connection's bytes. Transfers on an enabled endpoint still wait to complete.
    let open = |n: &str, write: bool| -> io::Result<File> {
        let path: PathBuf = dir.join(n);
        OpenOptions::new()
            .read(true)
            .write(write)
            .custom_flags(libc::O_NONBLOCK)
            .open(path)
    };
    let mut interrupt = open("ep3", true)?;
    let (events, queue) = std::sync::mpsc::sync_channel::<Vec<u8>>(QUEUED_EVENTS);
    std::thread::Builder::new()
        .name("sim-ptp-events".into())
        .spawn(move || {
            for e in queue {
                if interrupt.write_all(&e).is_err() {
                    return;
                }
            }
        })?;
    let files = Files {
        // Readable too: a read is how the endpoint is halted (`fail_bulk_in`).
        bulk_in: Mutex::new(open("ep1", true)?),
        events,
    };
    let mut bulk_out = open("ep2", false)?;
    let mut buf = vec![0u8; 1 << 20];
    loop {
        let n = bulk_out.read(&mut buf)?;
        if !framing
            .lock()
            .unwrap()
            .bulk_out(&buf[..n], responder, &files)
        {
            return Ok(());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_descriptors_say_their_own_length_and_hold_a_still_image_interface() {
        let d = descriptors();
        assert_eq!(
            u32::from_le_bytes(d[4..8].try_into().unwrap()) as usize,
            d.len()
        );
        // Interface: class 6 (still image), subclass 1, protocol 1, three endpoints.
        assert_eq!(&d[20..29], &[9, 4, 0, 0, 3, 6, 1, 1, 1]);
        // High speed: 512-byte bulk packets.
        let hs = &d[20 + 30..];
        assert_eq!(&hs[9..16], &[7, 5, 0x81, 2, 0x00, 0x02, 0]);
        let s = strings("camera");
        assert_eq!(
            u32::from_le_bytes(s[4..8].try_into().unwrap()) as usize,
            s.len()
        );
    }
}
