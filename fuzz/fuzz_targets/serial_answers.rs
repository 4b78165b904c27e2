//! A trigger box and turntable that answers brdfd's rig-protocol client with whatever the
//! fuzzer says. The client runs a whole exchange over an in-memory serial port, as a capture
//! does: `ID?` when it opens, `ID?` and `POS?` as keep-alives, turns (`POS?` then `ROT`),
//! homing; a command left without its answer makes the next one resynchronise.
//!
//! The input is the device's side in turns split at NUL bytes: turn k is what the device
//! sends once it has read the client's k-th command line (log lines, the answer, stray
//! lines). The client drops input that is waiting when it sends a command, as on a real port,
//! so a turn's bytes after the answer are not taken for the next command's. An empty turn is
//! a device that stays silent (the client waits out its timeout); after the last turn the
//! device is unplugged.
#![no_main]
#[path = "allocation_limit.rs"]
mod allocation_limit;

use std::cell::RefCell;
use std::collections::VecDeque;
use std::io::{ErrorKind, Read, Write};
use std::time::Duration;

use brdfd_serial::{RigController, RigTimeouts};
use libfuzzer_sys::fuzz_target;
use serialport::{ClearBuffer, DataBits, FlowControl, Parity, SerialPort, StopBits};

struct Device {
    /// What the device has sent and the client has not read yet. `clear` takes `&self`.
    sent: RefCell<VecDeque<u8>>,
    /// The turns still to come, one per command line the client writes.
    turns: VecDeque<Vec<u8>>,
}

impl Read for Device {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let mut sent = self.sent.borrow_mut();
        if sent.is_empty() {
            // Silent until the next command; unplugged once it has nothing more to say.
            return if self.turns.is_empty() {
                Ok(0)
            } else {
                Err(ErrorKind::TimedOut.into())
            };
        }
        let n = buf.len().min(sent.len());
        for (b, s) in buf.iter_mut().zip(sent.drain(..n)) {
            *b = s;
        }
        Ok(n)
    }
}

impl Write for Device {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        // The client writes each command line whole, in one call.
        if buf.contains(&b'\n') {
            let turn = self.turns.pop_front().unwrap_or_default();
            self.sent.borrow_mut().extend(turn);
        }
        Ok(buf.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl SerialPort for Device {
    fn name(&self) -> Option<String> {
        Some("fuzz".into())
    }
    fn baud_rate(&self) -> serialport::Result<u32> {
        Ok(brdfd_serial::BAUD_RATE)
    }
    fn data_bits(&self) -> serialport::Result<DataBits> {
        Ok(DataBits::Eight)
    }
    fn flow_control(&self) -> serialport::Result<FlowControl> {
        Ok(FlowControl::None)
    }
    fn parity(&self) -> serialport::Result<Parity> {
        Ok(Parity::None)
    }
    fn stop_bits(&self) -> serialport::Result<StopBits> {
        Ok(StopBits::One)
    }
    fn timeout(&self) -> Duration {
        Duration::ZERO
    }
    fn set_baud_rate(&mut self, _: u32) -> serialport::Result<()> {
        Ok(())
    }
    fn set_data_bits(&mut self, _: DataBits) -> serialport::Result<()> {
        Ok(())
    }
    fn set_flow_control(&mut self, _: FlowControl) -> serialport::Result<()> {
        Ok(())
    }
    fn set_parity(&mut self, _: Parity) -> serialport::Result<()> {
        Ok(())
    }
    fn set_stop_bits(&mut self, _: StopBits) -> serialport::Result<()> {
        Ok(())
    }
    fn set_timeout(&mut self, _: Duration) -> serialport::Result<()> {
        Ok(())
    }
    fn write_request_to_send(&mut self, _: bool) -> serialport::Result<()> {
        Ok(())
    }
    fn write_data_terminal_ready(&mut self, _: bool) -> serialport::Result<()> {
        Ok(())
    }
    fn read_clear_to_send(&mut self) -> serialport::Result<bool> {
        Ok(false)
    }
    fn read_data_set_ready(&mut self) -> serialport::Result<bool> {
        Ok(false)
    }
    fn read_ring_indicator(&mut self) -> serialport::Result<bool> {
        Ok(false)
    }
    fn read_carrier_detect(&mut self) -> serialport::Result<bool> {
        Ok(false)
    }
    fn bytes_to_read(&self) -> serialport::Result<u32> {
        Ok(self.sent.borrow().len() as u32)
    }
    fn bytes_to_write(&self) -> serialport::Result<u32> {
        Ok(0)
    }
    fn clear(&self, which: ClearBuffer) -> serialport::Result<()> {
        if matches!(which, ClearBuffer::Input | ClearBuffer::All) {
            self.sent.borrow_mut().clear();
        }
        Ok(())
    }
    fn try_clone(&self) -> serialport::Result<Box<dyn SerialPort>> {
        Err(serialport::Error::new(
            serialport::ErrorKind::Unknown,
            "an in-memory port is not cloned",
        ))
    }
    fn set_break(&self) -> serialport::Result<()> {
        Ok(())
    }
    fn clear_break(&self) -> serialport::Result<()> {
        Ok(())
    }
}

fuzz_target!(|data: &[u8]| {
    let device = Device {
        sent: RefCell::new(VecDeque::new()),
        turns: data.split(|&b| b == 0).map(<[u8]>::to_vec).collect(),
    };
    // A silent device, or an answer without its line's end, costs the client its whole
    // timeout, spun on a port that answers at once: 100 µs keeps such inputs fast (a turn's
    // bytes are read in microseconds) and turns take no time.
    let timeouts = RigTimeouts {
        answer: Duration::from_micros(100),
        min_speed_deg_s: 1e6,
        home: Duration::from_micros(100),
        boot: Duration::from_micros(100),
    };
    let Ok(mut rig) = RigController::new(Box::new(device), timeouts) else {
        return;
    };
    // The daemon's keep-alives, a view's turn, the next turn, and homing. No shutter pulse:
    // its timeout is the pulse (1 ms at least) and more, and its answer is a bare OK.
    let _ = rig.identify();
    let _ = rig.position();
    let _ = rig.rotate(45.0);
    let _ = rig.rotate(-90.0);
    let _ = rig.home();
    let _ = rig.identify();
});
