//! An in-memory USB pipe: the host end implements [`BulkPipe`], the device end is driven by
//! a simulator thread. Transfers keep their boundaries, so the USB framing code (zero-length
//! packets, multi-transfer data phases, stalls) runs exactly as on a bench.

use std::sync::mpsc::{channel, Receiver, RecvTimeoutError, Sender};
use std::time::Duration;

use crate::transport::usb::{BulkPipe, Endpoint, PipeError};

/// What the host sends to the device.
pub enum ToDevice {
    Bulk(Vec<u8>),
    Control {
        request: u8,
        data: Vec<u8>,
        reply: Sender<Result<Vec<u8>, PipeError>>,
    },
    ClearHalt(Endpoint),
}

/// What the device sends to the host on an IN endpoint: a transfer, or a failure the host's
/// next read on that endpoint sees (a stall, a vanished device).
pub enum FromDevice {
    Transfer(Vec<u8>),
    Fail(PipeError),
}

pub struct HostPipe {
    to_device: Sender<ToDevice>,
    bulk_in: Receiver<FromDevice>,
    interrupt: Receiver<FromDevice>,
    current: Vec<u8>,
    max_packet: usize,
}

pub struct DevicePipe {
    pub from_host: Receiver<ToDevice>,
    pub bulk_in: Sender<FromDevice>,
    pub interrupt: Sender<FromDevice>,
}

pub fn pair(max_packet: usize) -> (HostPipe, DevicePipe) {
    let (to_device, from_host) = channel();
    let (bi_tx, bi_rx) = channel();
    let (int_tx, int_rx) = channel();
    (
        HostPipe {
            to_device,
            bulk_in: bi_rx,
            interrupt: int_rx,
            current: Vec::new(),
            max_packet,
        },
        DevicePipe {
            from_host,
            bulk_in: bi_tx,
            interrupt: int_tx,
        },
    )
}

fn recv(rx: &Receiver<FromDevice>, timeout: Duration) -> Result<Vec<u8>, PipeError> {
    match rx.recv_timeout(timeout) {
        Ok(FromDevice::Transfer(t)) => Ok(t),
        Ok(FromDevice::Fail(e)) => Err(e),
        Err(RecvTimeoutError::Timeout) => Err(PipeError::Timeout),
        Err(RecvTimeoutError::Disconnected) => Err(PipeError::Gone),
    }
}

impl BulkPipe for HostPipe {
    fn max_packet(&self) -> usize {
        self.max_packet
    }

    fn write(&mut self, data: &[u8], _timeout: Duration) -> Result<usize, PipeError> {
        self.to_device
            .send(ToDevice::Bulk(data.to_vec()))
            .map_err(|_| PipeError::Gone)?;
        Ok(data.len())
    }

    fn read(
        &mut self,
        ep: Endpoint,
        buf: &mut [u8],
        timeout: Duration,
    ) -> Result<usize, PipeError> {
        if ep == Endpoint::Interrupt {
            let t = recv(&self.interrupt, timeout)?;
            let n = t.len().min(buf.len());
            buf[..n].copy_from_slice(&t[..n]);
            return Ok(n);
        }
        if self.current.is_empty() {
            self.current = recv(&self.bulk_in, timeout)?;
            if self.current.is_empty() {
                return Ok(0);
            }
        }
        let n = self.current.len().min(buf.len());
        buf[..n].copy_from_slice(&self.current[..n]);
        self.current.drain(..n);
        Ok(n)
    }

    fn clear_halt(&mut self, ep: Endpoint) -> Result<(), PipeError> {
        self.to_device
            .send(ToDevice::ClearHalt(ep))
            .map_err(|_| PipeError::Gone)
    }

    fn class_request(
        &mut self,
        request: u8,
        data_out: &[u8],
        _data_in: usize,
    ) -> Result<Vec<u8>, PipeError> {
        let (reply, rx) = channel();
        self.to_device
            .send(ToDevice::Control {
                request,
                data: data_out.to_vec(),
                reply,
            })
            .map_err(|_| PipeError::Gone)?;
        let answer = rx
            .recv_timeout(Duration::from_secs(5))
            .map_err(|_| PipeError::Gone)?;
        // Control requests here are resets and cancels: whatever the device had queued
        // for the aborted transaction is void.
        while self.bulk_in.try_recv().is_ok() {}
        self.current.clear();
        answer
    }

    fn describe(&self) -> String {
        "usb:memory (simulated)".into()
    }
}
