//! The simulated camera as a PTP/IP server: real TCP, so any PTP/IP client (ours, gphoto2)
//! can talk to it.

use std::io::Write;
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread;
use std::time::Duration;

use brdfd_ptp::transport::ptpip::{
    data_phase, dataphase, read_packet, ty, Packet, PROTOCOL_VERSION,
};
use brdfd_ptp::wire::{Reader, Writer};

use super::{SharedResponder, WireFault};

pub struct Server {
    pub addr: SocketAddr,
    stop: Arc<AtomicBool>,
    thread: Option<thread::JoinHandle<()>>,
}

impl Server {
    /// Listens on `addr` (port 0 picks one) and serves until dropped or stopped.
    pub fn start(addr: &str, responder: SharedResponder) -> std::io::Result<Server> {
        let listener = TcpListener::bind(addr)?;
        let addr = listener.local_addr()?;
        let stop = Arc::new(AtomicBool::new(false));
        let flag = stop.clone();
        let thread = thread::Builder::new()
            .name("sim-ptpip".into())
            .spawn(move || accept_loop(listener, responder, flag))?;
        Ok(Server {
            addr,
            stop,
            thread: Some(thread),
        })
    }

    pub fn stop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            // The accept loop blocks (a poll would add its period to every connection a
            // client opens): a connection of our own wakes it to see the flag.
            let mut wake = self.addr;
            if wake.ip().is_unspecified() {
                wake.set_ip(match wake {
                    SocketAddr::V4(_) => std::net::Ipv4Addr::LOCALHOST.into(),
                    SocketAddr::V6(_) => std::net::Ipv6Addr::LOCALHOST.into(),
                });
            }
            // Until it has seen one: a connection that fails (its interface gone, say) is
            // tried again, for a while; past that the thread is left blocked in `accept`,
            // to end at the next connection, rather than hang whoever stops the camera.
            let deadline = std::time::Instant::now() + Duration::from_secs(2);
            while !t.is_finished() && std::time::Instant::now() < deadline {
                let _ = TcpStream::connect_timeout(&wake, Duration::from_millis(200));
                thread::sleep(Duration::from_millis(2));
            }
            if t.is_finished() {
                let _ = t.join();
            }
        }
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        self.stop();
    }
}

type EventStream = Arc<Mutex<Option<TcpStream>>>;

fn accept_loop(listener: TcpListener, responder: SharedResponder, stop: Arc<AtomicBool>) {
    // Command connections waiting for their event connection, by connection number.
    let waiting: Arc<Mutex<Vec<(u32, EventStream)>>> = Arc::default();
    let mut next_conn = 1u32;
    loop {
        let accepted = listener.accept();
        if stop.load(Ordering::SeqCst) {
            break;
        }
        let (mut s, peer) = match accepted {
            Ok(x) => x,
            // Out of descriptors, say: not a reason to stop serving, nor to spin.
            Err(_) => {
                thread::sleep(Duration::from_millis(10));
                continue;
            }
        };
        let _ = s.set_nonblocking(false);
        let _ = s.set_nodelay(true);
        let _ = s.set_read_timeout(Some(Duration::from_secs(5)));
        if responder.lock().unwrap().powered_off {
            // Nothing listens on a camera that is off: the connection is closed at once.
            continue;
        }
        let Ok(first) = read_packet(&mut s) else {
            continue;
        };
        match first.ty {
            ty::INIT_COMMAND_REQUEST => {
                let conn = next_conn;
                next_conn += 1;
                let mut w = Writer::new();
                w.u32(conn).bytes(b"brdfd-simulated!");
                for u in "brdfd simulated camera".encode_utf16() {
                    w.u16(u);
                }
                w.u16(0).u32(PROTOCOL_VERSION);
                if s.write_all(&Packet::new(ty::INIT_COMMAND_ACK, w.finish()).to_bytes())
                    .is_err()
                {
                    continue;
                }
                tracing::debug!("simulated PTP/IP camera: command connection {conn} from {peer}");
                // A new initiator means the previous connection is gone: its session ends.
                responder.lock().unwrap().reset();
                let events: EventStream = Arc::default();
                waiting.lock().unwrap().push((conn, events.clone()));
                let r = responder.clone();
                let stop = stop.clone();
                thread::spawn(move || serve_commands(s, r, events, stop));
            }
            ty::INIT_EVENT_REQUEST => {
                let conn = Reader::new(&first.body, "InitEventRequest")
                    .u32()
                    .unwrap_or(0);
                let slot = waiting
                    .lock()
                    .unwrap()
                    .iter()
                    .find(|(c, _)| *c == conn)
                    .map(|(_, e)| e.clone());
                match slot {
                    Some(e) => {
                        // Ack and install under the slot's lock: no event can go out before
                        // the ack, and once the initiator has the ack, its next command's
                        // events find the stream in place.
                        let mut slot = e.lock().unwrap();
                        let _ = s.write_all(&Packet::new(ty::INIT_EVENT_ACK, vec![]).to_bytes());
                        *slot = Some(s);
                    }
                    None => {
                        let _ = s.write_all(
                            &Packet::new(ty::INIT_FAIL, 1u32.to_le_bytes().to_vec()).to_bytes(),
                        );
                    }
                }
            }
            _ => {}
        }
    }
}

fn serve_commands(
    mut s: TcpStream,
    responder: SharedResponder,
    events: EventStream,
    stop: Arc<AtomicBool>,
) {
    let _ = s.set_read_timeout(Some(Duration::from_millis(200)));
    while !stop.load(Ordering::SeqCst) {
        let p = match read_packet(&mut s) {
            Ok(p) => p,
            Err(brdfd_ptp::PtpError::Io(_)) => continue, // read timeout: check the stop flag
            Err(_) => return,
        };
        if p.ty != ty::OPERATION_REQUEST {
            continue;
        }
        let Ok(phase) = Reader::new(&p.body, "OperationRequest").u32() else {
            return;
        };
        let Ok(m) = p.message(4) else { return };
        let data_out = if phase == dataphase::OUT {
            match read_data_out(&mut s) {
                Some(d) => Some(d),
                None => return,
            }
        } else {
            None
        };
        let r = responder.lock().unwrap().handle(&m, data_out.as_deref());
        if let Some(d) = r.delay {
            thread::sleep(d);
        }
        let mut out = Vec::new();
        match r.fault {
            Some(WireFault::Silence) => continue,
            Some(WireFault::Hangup) => {
                let _ = s.shutdown(std::net::Shutdown::Both);
                return;
            }
            _ => {}
        }
        if let Some(data) = &r.data {
            out.extend(data_phase(m.tid, data));
            if let Some(WireFault::DropAfter(n)) = r.fault {
                // Part of the data, then the connection drops, as when Wi-Fi goes.
                let _ = s.write_all(&out[..(n + 28).min(out.len())]);
                let _ = s.shutdown(std::net::Shutdown::Both);
                return;
            }
        }
        let mut resp = Packet::from_message(ty::OPERATION_RESPONSE, None, &r.response).to_bytes();
        if r.fault == Some(WireFault::CorruptResponse) {
            resp[..4].copy_from_slice(&3u32.to_le_bytes());
        }
        out.extend(resp);
        if s.write_all(&out).is_err() {
            return;
        }
        if let Some(e) = events.lock().unwrap().as_mut() {
            for ev in &r.events {
                let _ = e.write_all(&Packet::from_message(ty::EVENT, None, ev).to_bytes());
            }
        }
    }
}

fn read_data_out(s: &mut TcpStream) -> Option<Vec<u8>> {
    let start = read_packet(s).ok()?;
    if start.ty != ty::START_DATA {
        return None;
    }
    let mut data = Vec::new();
    loop {
        let p = read_packet(s).ok()?;
        match p.ty {
            ty::DATA => data.extend_from_slice(p.body.get(4..)?),
            ty::END_DATA => {
                data.extend_from_slice(p.body.get(4..)?);
                return Some(data);
            }
            _ => return None,
        }
    }
}
