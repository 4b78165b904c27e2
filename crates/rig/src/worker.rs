//! One thread per device. USB, serial and V4L2 calls block, and a camera must see one
//! conversation at a time, so each device lives on its own thread and is lent to jobs in
//! turn. Between jobs the thread keeps the device awake, notices when it has gone, and opens
//! it again.

use std::sync::mpsc::{self, RecvTimeoutError};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use serde::Serialize;

use super::error::{said, DeviceError, DeviceUnavailable, FailureCode};

/// What a worker needs of its device.
pub trait Device: Send + 'static {
    /// "NIKON D5100 (serial 3000123)": for the device list and the session's manifest.
    fn identity(&self) -> String;
    /// A cheap request that keeps the device from sleeping; an error means it has gone.
    fn keep_alive(&mut self) -> Result<(), DeviceError>;
}

/// Opens a device: called at start, and again whenever the device has been lost.
pub type Opener<D> = Box<dyn FnMut() -> Result<D, DeviceError> + Send>;

/// A job gets the device, or why it could not be opened. It returns whether it failed, and
/// the delivery of its answer, which the worker makes after checking the device: a caller
/// that hears of a failure then also sees the device's state after it.
type Job<D> = Box<dyn FnOnce(Result<&mut D, OpenFailure>) -> (bool, Deliver) + Send>;

/// Why the device could not be opened for a job: the opener's words and their code.
#[derive(Clone)]
struct OpenFailure {
    message: String,
    code: FailureCode,
}
type Deliver = Box<dyn FnOnce() + Send>;

/// A device's state as the daemon reports it.
#[derive(Debug, Clone, Serialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct DeviceStatus {
    /// The rig fields whose roles the device plays: "dslr", "fallback_camera", "theta",
    /// "turntable", "shutter", or "turntable, shutter" for a box that is both.
    pub role: String,
    /// The selector it was opened from (`usb:04b0:0429`, `osc:http://...`).
    pub selector: String,
    pub state: Link,
    /// The identity of the open device, or of the last one that was.
    pub identity: Option<String>,
    pub last_error: Option<String>,
    /// How many times the device was opened (1 while nothing went wrong).
    pub opened: u32,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[serde(rename_all = "snake_case")]
pub enum Link {
    /// Not yet opened.
    Closed,
    Open,
    /// Lost (unplugged, asleep beyond waking, unreachable); it is opened again before the next
    /// job, and retried between jobs.
    Lost,
}

/// A device on its own thread.
pub struct Worker<D: Device> {
    jobs: Option<mpsc::Sender<Job<D>>>,
    status: Arc<Mutex<DeviceStatus>>,
    thread: Option<JoinHandle<()>>,
}

/// A job's answer, to wait for.
pub struct Pending<R>(mpsc::Receiver<Result<R, DeviceError>>, String);

impl<R> Pending<R> {
    pub fn wait(self) -> Result<R, DeviceError> {
        self.0
            .recv()
            .unwrap_or(Err(DeviceError::WorkerStopped(self.1)))
    }
}

impl<D: Device> Worker<D> {
    /// Starts the worker. The device is opened on the worker's thread straight away (a
    /// failure is reported in the status and retried), and kept alive every `keep_alive`.
    pub fn spawn(role: &str, selector: &str, open: Opener<D>, keep_alive: Duration) -> Worker<D> {
        let status = Arc::new(Mutex::new(DeviceStatus {
            role: role.into(),
            selector: selector.into(),
            state: Link::Closed,
            identity: None,
            last_error: None,
            opened: 0,
        }));
        let (tx, rx) = mpsc::channel::<Job<D>>();
        let thread = {
            let status = status.clone();
            std::thread::Builder::new()
                .name(format!("device-{role}"))
                .spawn(move || run(rx, open, status, keep_alive))
                .expect("spawning a device thread")
        };
        Worker {
            jobs: Some(tx),
            status,
            thread: Some(thread),
        }
    }

    pub fn status(&self) -> DeviceStatus {
        self.status.lock().expect("status lock").clone()
    }

    /// Runs `f` on the device, on the device's thread, opening the device first if it is not
    /// open. An error from `f` makes the worker check the device, and drop it if it no longer
    /// answers, so that the next job opens it afresh.
    pub(crate) fn submit<R: Send + 'static>(
        &self,
        f: impl FnOnce(&mut D) -> Result<R, DeviceError> + Send + 'static,
    ) -> Pending<R> {
        let (tx, rx) = mpsc::sync_channel(1);
        let DeviceStatus { role, selector, .. } = self.status();
        let job: Job<D> = Box::new(move |d| {
            let r = d
                .map_err(|e| {
                    DeviceError::Unavailable(DeviceUnavailable {
                        role,
                        selector,
                        message: e.message,
                        code: e.code,
                    })
                })
                .and_then(f);
            let failed = r.is_err();
            (
                failed,
                Box::new(move || {
                    let _ = tx.send(r);
                }),
            )
        });
        let role = self.status().role;
        if let Some(jobs) = &self.jobs {
            // A send fails only when the thread has ended; `wait` then says so.
            let _ = jobs.send(job);
        }
        Pending(rx, role)
    }

    /// `submit`, then `wait`.
    pub fn call<R: Send + 'static>(
        &self,
        f: impl FnOnce(&mut D) -> Result<R, DeviceError> + Send + 'static,
    ) -> Result<R, DeviceError> {
        self.submit(f).wait()
    }
}

impl<D: Device> Drop for Worker<D> {
    fn drop(&mut self) {
        // Closing the queue ends the thread after its current job; the device is dropped
        // (closed) there.
        self.jobs.take();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn run<D: Device>(
    jobs: mpsc::Receiver<Job<D>>,
    mut open: Opener<D>,
    status: Arc<Mutex<DeviceStatus>>,
    keep_alive: Duration,
) {
    let set = |f: &dyn Fn(&mut DeviceStatus)| f(&mut status.lock().expect("status lock"));
    let mut device: Option<D> = None;
    let mut try_open = |device: &mut Option<D>| -> Result<(), OpenFailure> {
        if device.is_some() {
            return Ok(());
        }
        match open() {
            Ok(d) => {
                let id = d.identity();
                tracing::info!(device = %id, "opened");
                set(&|s| {
                    s.state = Link::Open;
                    s.identity = Some(id.clone());
                    s.last_error = None;
                    s.opened += 1;
                });
                *device = Some(d);
                Ok(())
            }
            Err(e) => {
                let msg = said(&e);
                set(&|s| {
                    s.last_error = Some(msg.clone());
                    if s.state == Link::Open {
                        s.state = Link::Lost;
                    }
                });
                Err(OpenFailure {
                    message: msg,
                    code: opening_code(&e),
                })
            }
        }
    };
    let lose = |device: &mut Option<D>, why: String| {
        tracing::warn!("device lost: {why}");
        *device = None;
        set(&|s| {
            s.state = Link::Lost;
            s.last_error = Some(why.clone());
        });
    };
    let _ = try_open(&mut device);
    let mut next_tick = Instant::now() + keep_alive;
    loop {
        let wait = next_tick.saturating_duration_since(Instant::now());
        match jobs.recv_timeout(wait) {
            Ok(job) => {
                if let Err(e) = try_open(&mut device) {
                    job(Err(e)).1();
                    continue;
                }
                let d = device.as_mut().expect("opened above");
                let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| job(Ok(d))));
                match outcome {
                    // The caller's `wait` reports the panic as the worker stopping the job.
                    Err(_) => lose(&mut device, "a job panicked; the device is reopened".into()),
                    Ok((failed, deliver)) => {
                        // A job that failed may have lost the device; one keep-alive tells.
                        if failed {
                            if let Err(e) = device.as_mut().expect("still open").keep_alive() {
                                lose(&mut device, said(&e));
                            }
                        }
                        deliver();
                    }
                }
                next_tick = Instant::now() + keep_alive;
            }
            Err(RecvTimeoutError::Timeout) => {
                match device.as_mut() {
                    Some(d) => {
                        if let Err(e) = d.keep_alive() {
                            lose(&mut device, said(&e));
                        }
                    }
                    None => {
                        let _ = try_open(&mut device);
                    }
                }
                next_tick = Instant::now() + keep_alive;
            }
            Err(RecvTimeoutError::Disconnected) => return,
        }
    }
}

/// The code of a device that could not be opened. A device that hangs up while it is being
/// opened (a camera switched off, whose network stack still accepts the connection) was never
/// there for this capture: missing, not lost.
fn opening_code(e: &DeviceError) -> FailureCode {
    match e.code().unwrap_or(FailureCode::Failed) {
        FailureCode::DeviceLost => FailureCode::DeviceMissing,
        code => code,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};

    /// A device that can be unplugged from the outside.
    struct Fake {
        serial: u32,
        plugged: Arc<AtomicBool>,
        pings: Arc<AtomicU32>,
    }

    impl Device for Fake {
        fn identity(&self) -> String {
            format!("fake {}", self.serial)
        }
        fn keep_alive(&mut self) -> Result<(), DeviceError> {
            self.pings.fetch_add(1, Ordering::SeqCst);
            if self.plugged.load(Ordering::SeqCst) {
                Ok(())
            } else {
                Err(DeviceError::Cannot("unplugged".into()))
            }
        }
    }

    fn fake_worker(keep_alive: Duration) -> (Worker<Fake>, Arc<AtomicBool>, Arc<AtomicU32>) {
        let plugged = Arc::new(AtomicBool::new(true));
        let pings = Arc::new(AtomicU32::new(0));
        let serial = Arc::new(AtomicU32::new(0));
        let (p, q) = (plugged.clone(), pings.clone());
        let open: Opener<Fake> = Box::new(move || {
            if !p.load(Ordering::SeqCst) {
                return Err(DeviceError::Cannot("no such device".into()));
            }
            Ok(Fake {
                serial: serial.fetch_add(1, Ordering::SeqCst),
                plugged: p.clone(),
                pings: q.clone(),
            })
        });
        (
            Worker::spawn("dslr", "fake:0", open, keep_alive),
            plugged,
            pings,
        )
    }

    #[test]
    fn jobs_run_on_the_open_device_in_order() {
        let (w, _, _) = fake_worker(Duration::from_secs(60));
        let a = w.submit(|d| Ok(d.identity()));
        let b = w.submit(|d| Ok(d.serial + 10));
        assert_eq!(a.wait().unwrap(), "fake 0");
        assert_eq!(b.wait().unwrap(), 10);
        let s = w.status();
        assert_eq!((s.state, s.opened), (Link::Open, 1));
    }

    #[test]
    fn an_unplugged_device_is_noticed_between_jobs_and_reopened_when_back() {
        let (w, plugged, pings) = fake_worker(Duration::from_millis(5));
        assert_eq!(w.call(|d| Ok(d.serial)).unwrap(), 0);
        plugged.store(false, Ordering::SeqCst);
        let start = Instant::now();
        while w.status().state != Link::Lost {
            assert!(start.elapsed() < Duration::from_secs(10), "never noticed");
            std::thread::sleep(Duration::from_millis(2));
        }
        assert!(pings.load(Ordering::SeqCst) >= 1);
        // While it is gone, a job gets a clear error rather than hanging.
        let err = w.call(|d| Ok(d.serial)).unwrap_err().to_string();
        assert!(
            err.contains("the dslr (fake:0) could not be opened"),
            "{err}"
        );
        assert!(err.contains("no such device"), "{err}");
        assert_eq!(w.status().last_error.as_deref(), Some("no such device"));
        plugged.store(true, Ordering::SeqCst);
        // The next job opens it afresh: a new device (serial 1), opened twice in all.
        assert_eq!(w.call(|d| Ok(d.serial)).unwrap(), 1);
        assert_eq!(w.status().opened, 2);
    }

    #[test]
    fn a_failed_job_that_lost_the_device_makes_the_next_job_reopen_it() {
        let (w, plugged, _) = fake_worker(Duration::from_secs(60));
        let p = plugged.clone();
        let err = w.call(move |_d| -> Result<(), DeviceError> {
            // The camera goes away mid-job, then comes back.
            p.store(false, Ordering::SeqCst);
            Err(DeviceError::Cannot("transfer failed".into()))
        });
        assert!(err.is_err());
        assert_eq!(w.status().state, Link::Lost);
        plugged.store(true, Ordering::SeqCst);
        assert_eq!(w.call(|d| Ok(d.serial)).unwrap(), 1);
    }

    #[test]
    fn a_device_that_cannot_be_opened_fails_its_jobs_with_the_openers_code() {
        let open: Opener<Fake> = Box::new(|| {
            Err(DeviceError::from(brdfd_serial::SerialError::Busy {
                port: "/dev/ttyACM0".into(),
            }))
        });
        let w = Worker::spawn(
            "turntable",
            "serial:/dev/ttyACM0",
            open,
            Duration::from_secs(60),
        );
        let e = w.call(|d| Ok(d.serial)).unwrap_err();
        let DeviceError::Unavailable(unavailable) = &e else {
            panic!("not the opener's error: {e:?}");
        };
        assert_eq!(unavailable.code, FailureCode::DeviceBusy);
        assert_eq!(e.code(), Some(FailureCode::DeviceBusy));
        assert!(e.to_string().contains("in use by another program"), "{e}");
        assert_eq!(
            crate::error::failure_code(
                anyhow::Error::from(e).context("turning to view 2").as_ref()
            ),
            FailureCode::DeviceBusy
        );
    }
}
