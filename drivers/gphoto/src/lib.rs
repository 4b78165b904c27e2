//! Any camera libgphoto2 drives, as brdfd's object camera: found, set to an exposure, fired and
//! downloaded through the system's libgphoto2 (the `gphoto2` crate's bindings).
//!
//! brdfd's own PTP driver (`brdfd-ptp`) speaks the standard flow, Nikon's, Canon's EOS and
//! Sony's, and is what a rig uses by default. This backend is for the other bodies libgphoto2
//! knows (its camera list has some 2,900), behind brdfd's `gphoto2` cargo feature: it links the
//! system's libgphoto2 and needs libclang to build, which the default build must not.
//!
//! Exposure is set through libgphoto2's configuration widgets, whose names and value strings
//! are libgphoto2's own across vendors (`shutterspeed` "1/60", `f-number` "f/8", `iso` "100");
//! [`exposure`] reads and chooses among them.

pub mod exposure;

use std::time::{Duration, Instant};

use gphoto2::camera::CameraEvent;
use gphoto2::list::CameraDescriptor;
use gphoto2::widget::RadioWidget;
use gphoto2::{Camera, Context};

pub use exposure::{Applied, Exposure};

/// What went wrong, and in which step.
#[derive(Debug, thiserror::Error)]
pub enum GphotoError {
    /// Nothing libgphoto2 can drive is connected, or nothing at the port given.
    #[error("libgphoto2 finds no camera{0}")]
    NotFound(String),
    /// libgphoto2 refused or failed a step.
    // The library's words are the source, not the message: a chain printed whole would
    // otherwise say them twice.
    #[error("libgphoto2, {step}")]
    Library {
        step: String,
        #[source]
        source: gphoto2::Error,
    },
    /// A shot fired from outside that the camera announced no file for.
    #[error("the {model} announced no file within {seconds:.0} s of being fired from outside")]
    NoFile { model: String, seconds: f64 },
    /// The camera has no control for a setting the rig asks for.
    #[error("{0}")]
    Unsupported(String),
}

pub type Result<T> = std::result::Result<T, GphotoError>;

/// Adds the step to a libgphoto2 error.
trait Step<T> {
    fn step(self, step: impl FnOnce() -> String) -> Result<T>;
}

impl<T> Step<T> for gphoto2::Result<T> {
    fn step(self, step: impl FnOnce() -> String) -> Result<T> {
        self.map_err(|source| GphotoError::Library {
            step: step(),
            source,
        })
    }
}

/// A camera libgphoto2 detects: its model as libgphoto2 names it, and its port
/// (`usb:001,004`, `ptpip:HOST`, `serial:/dev/ttyS0`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Detected {
    pub model: String,
    pub port: String,
}

/// libgphoto2's model for a camera on PTP/IP: its port cannot be detected, only named.
const PTPIP_MODEL: &str = "PTP/IP Camera";

/// How long a shot's later files (the JPEG of a RAW + JPEG pair) may take to be announced
/// after the first; libgphoto2 reports them as events.
const MORE_FILES_WAIT: Duration = Duration::from_millis(1500);

/// Files a single shot may make: more is a camera announcing files it did not make.
const MAX_FILES_PER_SHOT: usize = 8;

/// The cameras libgphoto2 detects on USB (and serial), with their ports.
pub fn detect() -> Result<Vec<Detected>> {
    let context = Context::new().step(|| "starting".into())?;
    let list = context
        .list_cameras()
        .wait()
        .step(|| "detecting cameras".into())?;
    Ok(list
        .map(|d| Detected {
            model: d.model,
            port: d.port,
        })
        .collect())
}

/// A camera opened through libgphoto2.
pub struct GphotoCamera {
    context: Context,
    /// Always `Some` but while it is dropped (see the `Drop` impl).
    camera: Option<Camera>,
    model: String,
    port: String,
}

impl Drop for GphotoCamera {
    fn drop(&mut self) {
        let guard = self.port.starts_with("ptpip:").then(Fd0Guard::save);
        // The camera's disconnect runs (and finishes) here: the crate waits for it.
        drop(self.camera.take());
        if let Some(g) = guard {
            g.restore();
        }
    }
}

/// libgphoto2's PTP/IP disconnect (2.5.30, Debian's) also closes the socket of the third
/// connection only Fuji's PTP/IP opens, which for every other camera still holds 0 from its
/// zeroed set-up: it closes the process's fd 0. Left so, the next file or socket brdfd opens
/// takes fd 0, and the next such disconnect would close it under its owner. So fd 0 is
/// duplicated before the disconnect and put back after, if it went. (If another thread opens
/// a file in the microseconds between the two, that file takes fd 0 and keeps it, and it is
/// fd 0's first owner, standard input, that is lost: brdfd's own PTP/IP driver, `ptpip:HOST`,
/// has no such window and is the one to use for a PTP/IP body.)
struct Fd0Guard(Option<std::os::fd::OwnedFd>);

impl Fd0Guard {
    fn save() -> Fd0Guard {
        use std::os::fd::FromRawFd;
        // SAFETY: F_DUPFD_CLOEXEC duplicates fd 0 only if it is open (else it fails with EBADF
        // and nothing is saved); the duplicate is a new descriptor that this guard owns.
        let fd = unsafe { libc::fcntl(0, libc::F_DUPFD_CLOEXEC, 3) };
        Fd0Guard((fd >= 0).then(|| unsafe { std::os::fd::OwnedFd::from_raw_fd(fd) }))
    }

    fn restore(self) {
        use std::os::fd::AsRawFd;
        let Some(saved) = self.0 else { return };
        // SAFETY: F_GETFD only asks whether fd 0 is open; dup2 onto a free fd 0 takes no
        // descriptor from anyone.
        unsafe {
            if libc::fcntl(0, libc::F_GETFD) == -1 {
                tracing::debug!("libgphoto2's PTP/IP disconnect closed fd 0; putting it back");
                if libc::dup2(saved.as_raw_fd(), 0) == -1 {
                    tracing::warn!(
                        "fd 0 could not be put back after libgphoto2 closed it: {}",
                        std::io::Error::last_os_error()
                    );
                }
            }
        }
    }
}

impl GphotoCamera {
    /// Opens the camera at `port` (as [`detect`] lists it, or `ptpip:HOST[:PORT]`), or the
    /// first camera libgphoto2 detects when `port` is `None`.
    pub fn open(port: Option<&str>) -> Result<GphotoCamera> {
        let context = Context::new().step(|| "starting".into())?;
        let descriptor = match port {
            // A PTP/IP camera is not detected: libgphoto2 is told what it is.
            Some(p) if p.starts_with("ptpip:") => CameraDescriptor {
                model: PTPIP_MODEL.into(),
                port: p.into(),
            },
            _ => {
                let found: Vec<CameraDescriptor> = context
                    .list_cameras()
                    .wait()
                    .step(|| "detecting cameras".into())?
                    .collect();
                found
                    .into_iter()
                    .find(|d| port.is_none_or(|p| d.port == p))
                    .ok_or_else(|| {
                        GphotoError::NotFound(match port {
                            Some(p) => format!(" at {p}"),
                            None => String::new(),
                        })
                    })?
            }
        };
        let camera = context
            .get_camera(&descriptor)
            .wait()
            .step(|| format!("opening the {} at {}", descriptor.model, descriptor.port))?;
        // libgphoto2 connects on the first call that needs the camera: one is made here, so
        // that a busy or unreachable body fails to open rather than at its first shot.
        camera.storages().wait().step(|| {
            format!(
                "connecting to the {} at {}",
                descriptor.model, descriptor.port
            )
        })?;
        // A PTP/IP camera's model is only known once it answers.
        let model = match camera.abilities().model() {
            m if m == PTPIP_MODEL => text_setting(&camera, "cameramodel").unwrap_or(m.into()),
            m => m.into(),
        };
        tracing::info!(
            model,
            port = descriptor.port,
            "libgphoto2 opened the camera"
        );
        Ok(GphotoCamera {
            context,
            camera: Some(camera),
            model,
            port: descriptor.port,
        })
    }

    fn camera(&self) -> &Camera {
        self.camera
            .as_ref()
            .expect("the camera is taken only when it is dropped")
    }

    /// The camera's model, as it names itself or as libgphoto2's list does.
    pub fn model(&self) -> &str {
        &self.model
    }

    /// The port it is on, as libgphoto2 writes it.
    pub fn port(&self) -> &str {
        &self.port
    }

    /// The camera's serial number, if it reports one.
    pub fn serial(&self) -> Option<String> {
        text_setting(self.camera(), "serialnumber").filter(|s| !s.is_empty())
    }

    /// Asks the camera something cheap, so that a link that went away is noticed between
    /// captures.
    pub fn keep_alive(&self) -> Result<()> {
        self.camera()
            .storages()
            .wait()
            .step(|| "asking the camera for its stores".into())?;
        Ok(())
    }

    /// Sets what `e` names to the camera's nearest values; what it applied, read back.
    pub fn set_exposure(&self, e: &Exposure) -> Result<Applied> {
        let mut applied = Applied::default();
        if let Some(s) = e.shutter_s {
            applied.shutter_s = Some(self.set_shutter(s)?);
        }
        if let Some(f) = e.f_number {
            applied.f_number =
                Some(self.set_nearest(exposure::APERTURE, f, exposure::parse_f_number)?);
        }
        if let Some(iso) = e.iso {
            applied.iso = Some(
                self.set_nearest(exposure::ISO, f64::from(iso), exposure::parse_iso)?
                    .round() as u32,
            );
        }
        Ok(applied)
    }

    /// Sets the first of `names` the camera has to its choice nearest `want` (as `parse`
    /// reads choices), and returns the value it holds afterwards.
    fn set_nearest(
        &self,
        names: &[&str],
        want: f64,
        parse: fn(&str) -> Option<f64>,
    ) -> Result<f64> {
        let (name, widget) = names
            .iter()
            .find_map(|n| {
                self.camera()
                    .config_key::<RadioWidget>(n)
                    .wait()
                    .ok()
                    .map(|w| (*n, w))
            })
            .ok_or_else(|| {
                GphotoError::Unsupported(format!(
                    "the {} has no {} setting libgphoto2 can change",
                    self.model, names[0]
                ))
            })?;
        let choices: Vec<String> = widget.choices_iter().collect();
        let (choice, _) = exposure::nearest(&choices, want, parse).ok_or_else(|| {
            GphotoError::Unsupported(format!(
                "the {}'s {name} offers no value brdfd can read ({choices:?})",
                self.model
            ))
        })?;
        if widget.choice() != choice {
            widget
                .set_choice(&choice)
                .step(|| format!("choosing {name} {choice}"))?;
            self.camera()
                .set_config(&widget)
                .wait()
                .step(|| format!("setting {name} to {choice}"))?;
        }
        let now = self
            .camera()
            .config_key::<RadioWidget>(name)
            .wait()
            .step(|| format!("reading {name} back"))?
            .choice();
        parse(&now).ok_or_else(|| {
            GphotoError::Unsupported(format!(
                "the {}'s {name} reads {now:?} after it was set to {choice:?}",
                self.model
            ))
        })
    }

    /// Sets the shutter speed nearest `seconds`; the time the camera holds afterwards.
    pub fn set_shutter(&self, seconds: f64) -> Result<f64> {
        self.set_nearest(exposure::SHUTTER, seconds, exposure::parse_shutter)
    }

    /// Fires the camera and downloads what the shot made, in the order libgphoto2 reports
    /// the files (a RAW + JPEG body's second file comes as an event after the first).
    /// `progress` gets bytes done and the total known so far.
    pub fn capture(&self, progress: &mut dyn FnMut(u64, u64)) -> Result<Vec<(String, Vec<u8>)>> {
        let first = self
            .camera()
            .capture_image()
            .wait()
            .step(|| format!("capturing with the {}", self.model))?;
        let mut paths = vec![(first.folder().into_owned(), first.name().into_owned())];
        self.more_files(&mut paths, MORE_FILES_WAIT)?;
        self.download(paths, progress)
    }

    /// Forgets the events libgphoto2 still holds (a late file of an earlier shot), so that
    /// what comes after a shot fired from outside is that shot's.
    pub fn forget_pending_events(&self) -> Result<()> {
        for _ in 0..MAX_FILES_PER_SHOT * 4 {
            match self
                .camera()
                .wait_event(Duration::ZERO)
                .wait()
                .step(|| "reading the camera's pending events".into())?
            {
                CameraEvent::Timeout => break,
                other => tracing::debug!(?other, "dropped before a fired shot"),
            }
        }
        Ok(())
    }

    /// The files of a shot fired from outside (a trigger box, a release cable), announced
    /// within `wait`, downloaded.
    pub fn files_of_fired_shot(
        &self,
        wait: Duration,
        progress: &mut dyn FnMut(u64, u64),
    ) -> Result<Vec<(String, Vec<u8>)>> {
        let mut paths = Vec::new();
        self.more_files(&mut paths, wait)?;
        if paths.is_empty() {
            return Err(GphotoError::NoFile {
                model: self.model.clone(),
                seconds: wait.as_secs_f64(),
            });
        }
        self.more_files(&mut paths, MORE_FILES_WAIT)?;
        self.download(paths, progress)
    }

    /// Adds the files the camera announces until it has nothing more to say (a timeout or
    /// its capture complete), waiting at most `wait`; with no file yet, it waits for one.
    fn more_files(&self, paths: &mut Vec<(String, String)>, wait: Duration) -> Result<()> {
        let deadline = Instant::now() + wait;
        let had = paths.len();
        while let Some(left) = deadline.checked_duration_since(Instant::now()) {
            match self
                .camera()
                .wait_event(left)
                .wait()
                .step(|| "waiting for the shot's files".into())?
            {
                CameraEvent::NewFile(p) => {
                    if paths.len() == MAX_FILES_PER_SHOT {
                        return Err(GphotoError::Unsupported(format!(
                            "the {} announced more than {MAX_FILES_PER_SHOT} files for one shot",
                            self.model
                        )));
                    }
                    paths.push((p.folder().into_owned(), p.name().into_owned()));
                    // Waiting for a fired shot's first file: it has come, and its others
                    // get their own, shorter wait.
                    if had == 0 {
                        break;
                    }
                }
                // libgphoto2 may say so before `left` is up; with no file yet, the shot is
                // still to come.
                CameraEvent::Timeout | CameraEvent::CaptureComplete if had > 0 => break,
                _ => {}
            }
        }
        Ok(())
    }

    fn download(
        &self,
        paths: Vec<(String, String)>,
        progress: &mut dyn FnMut(u64, u64),
    ) -> Result<Vec<(String, Vec<u8>)>> {
        let mut files = Vec::with_capacity(paths.len());
        let mut done = 0u64;
        for (folder, name) in paths {
            let file = self
                .camera()
                .fs()
                .download(&folder, &name)
                .wait()
                .step(|| format!("downloading {folder}/{name}"))?;
            let data = file
                .get_data(&self.context)
                .wait()
                .step(|| format!("reading {folder}/{name}"))?;
            done += data.len() as u64;
            progress(done, done);
            files.push((name, data.into_vec()));
        }
        Ok(files)
    }
}

/// A text setting's value (`cameramodel`, `serialnumber`), if the camera has it.
fn text_setting(camera: &Camera, name: &str) -> Option<String> {
    camera
        .config_key::<gphoto2::widget::TextWidget>(name)
        .wait()
        .ok()
        .map(|w| w.value())
}
