//! RICOH THETA for brdfd: the 360° camera that measures the light around the object.
//!
//! One device, two links ([`Theta`] holds a private enum of them):
//! - [`http`]: the THETA Web API (Open Spherical Camera API v2.1 with RICOH's extensions),
//!   over Wi-Fi, in access-point mode (192.168.1.1) or client mode (HTTP Digest);
//! - [`usb`]: PTP over USB with RICOH's vendor properties, on `brdfd-ptp`.
//!
//! [`Theta::prepare`] sets the camera up for light measurement (no sleep, manual exposure,
//! no filters, fixed white balance) and [`Theta::capture`] shoots a manual exposure bracket
//! and downloads every frame unchanged. Merging the frames into a linear HDR map is the
//! radiometry's job (`brdfd_radiometry`), which reads each frame's EXIF.
//!
//! The API is blocking, like the other drivers: the daemon runs each device in its own
//! worker thread. The HTTP link drives its async client on a small runtime of its own, so
//! [`Theta`] must not be used from inside an async task.
//!
//! Not here: the live-preview stream, video, and the THETA's UVC mode (that is a V4L2 source).

pub mod error;
pub mod http;
pub mod osc;
pub mod usb;

use serde_json::json;

pub use error::{Result, ThetaError};
pub use http::{Credentials, HttpTimeouts, OscClient};

use brdfd_ptp::Camera;

/// Most shots one `_autoBracket` takes on a THETA V (19 on recent firmware, 13 on all); longer
/// plans are shot as several brackets.
pub const MAX_BRACKET: usize = 13;
/// `offDelay` and `sleepDelay` value that disables the timer.
const TIMER_DISABLED: u32 = 65535;
/// Colour temperature for the fixed white balance of a bracket (daylight, kelvin).
pub const DEFAULT_COLOR_TEMPERATURE: u32 = 5000;

/// One exposure of the panorama.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Exposure {
    pub shutter_s: f64,
    pub iso: u32,
}

/// The exposures to shoot. Each frame's EXIF, not this plan, is what the HDR merge uses.
#[derive(Debug, Clone, PartialEq)]
pub struct BracketPlan {
    pub shots: Vec<Exposure>,
}

impl BracketPlan {
    /// A light probe of a bench under lamps and windows: ISO 100, 1/16000 s to 1 s in two-stop
    /// steps (8 frames). With the JPEG's own range of about 8 stops this covers about 22 stops,
    /// from shadows to a bare lamp.
    pub fn light_probe() -> BracketPlan {
        let shutters = [
            1.0 / 16000.0,
            1.0 / 4000.0,
            1.0 / 1000.0,
            1.0 / 250.0,
            1.0 / 60.0,
            1.0 / 15.0,
            1.0 / 4.0,
            1.0,
        ];
        BracketPlan {
            shots: shutters
                .iter()
                .map(|&shutter_s| Exposure {
                    shutter_s,
                    iso: 100,
                })
                .collect(),
        }
    }

    /// One frame, for a quick look (not HDR: highlights clip).
    pub fn single(e: Exposure) -> BracketPlan {
        BracketPlan { shots: vec![e] }
    }
}

/// A frame as the camera sent it.
#[derive(Debug, Clone)]
pub struct Frame {
    /// The camera's file name (`R0010005.JPG`).
    pub name: String,
    pub data: Vec<u8>,
    /// What was asked for, after snapping to the camera's supported values.
    pub asked: Exposure,
}

/// The link a [`Theta`] talks over.
enum Link {
    Http {
        runtime: tokio::runtime::Runtime,
        client: OscClient,
    },
    Usb(Camera),
}

/// A RICOH THETA on one of its links.
pub struct Theta {
    link: Link,
    pub model: String,
    pub serial: String,
    pub firmware: String,
    /// Supported shutter speeds and ISOs, from the camera; plans snap to these.
    shutter_support: Vec<f64>,
    iso_support: Vec<u32>,
}

impl Theta {
    /// Connects over HTTP (`http://192.168.1.1` in access-point mode) and reads `/osc/info`.
    pub fn connect_http(
        base: &str,
        credentials: Option<Credentials>,
        timeouts: HttpTimeouts,
    ) -> Result<Theta> {
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .map_err(|e| ThetaError::Unreachable {
                what: "starting the HTTP runtime".into(),
                camera: base.into(),
                reason: e.to_string(),
            })?;
        let client = OscClient::new(base, credentials, timeouts)?;
        let info = runtime.block_on(client.info())?;
        if !info.api_level.contains(&2) {
            return Err(ThetaError::Unsupported(format!(
                "{} firmware {} speaks only API level 1; update its firmware to use the THETA Web API v2.1",
                info.model, info.firmware_version
            )));
        }
        tracing::info!(model = %info.model, firmware = %info.firmware_version, "THETA over HTTP at {base}");
        Ok(Theta {
            link: Link::Http { runtime, client },
            model: info.model,
            serial: info.serial_number,
            firmware: info.firmware_version,
            shutter_support: Vec::new(),
            iso_support: Vec::new(),
        })
    }

    /// A THETA reached over PTP (USB, or any transport `brdfd-ptp` offers).
    pub fn from_ptp(camera: Camera) -> Result<Theta> {
        let i = &camera.info;
        if !i.manufacturer.starts_with("Ricoh") && !i.model.contains("THETA") {
            return Err(ThetaError::Unsupported(format!(
                "{} {} is not a RICOH THETA",
                i.manufacturer, i.model
            )));
        }
        Ok(Theta {
            model: i.model.clone(),
            serial: i.serial_number.clone(),
            firmware: i.device_version.clone(),
            link: Link::Usb(camera),
            shutter_support: Vec::new(),
            iso_support: Vec::new(),
        })
    }

    /// "RICOH THETA V (serial 00165759, firmware 3.50.1) over HTTP".
    pub fn describe(&self) -> String {
        format!(
            "{} (serial {}, firmware {}) over {}",
            self.model,
            self.serial,
            self.firmware,
            self.link()
        )
    }

    /// The link it is reached by: `HTTP at URL` or `USB (PTP)`.
    pub fn link(&self) -> String {
        match &self.link {
            Link::Http { client, .. } => format!("HTTP at {}", client.base()),
            Link::Usb(_) => "USB (PTP)".into(),
        }
    }

    /// Sets the camera up for light measurement; returns a line per setting, as applied.
    #[tracing::instrument(skip(self), fields(model = %self.model))]
    pub fn prepare(&mut self) -> Result<Vec<String>> {
        match &mut self.link {
            Link::Http { runtime, client } => {
                let (report, shutters, isos) = runtime.block_on(prepare_http(client))?;
                self.shutter_support = shutters;
                self.iso_support = isos;
                Ok(report)
            }
            Link::Usb(cam) => {
                let p = usb::prepare(cam)?;
                let desc = cam.prop_desc(usb::code::SHUTTER_SPEED)?;
                self.shutter_support = desc
                    .allowed()
                    .into_iter()
                    .filter_map(|v| usb::shutter_from_u64(v as u64))
                    .collect();
                let iso = cam.prop_desc(brdfd_ptp::codes::prop::EXPOSURE_INDEX)?;
                self.iso_support = iso.allowed().into_iter().map(|v| v as u32).collect();
                let mut report = vec![
                    format!("woke up from sleep: {}", p.woke_up),
                    "manual exposure, single shots, filter off, daylight white balance, sleep and power-off timers off".into(),
                ];
                report.extend(
                    p.skipped
                        .iter()
                        .map(|s| format!("skipped (not on this model): {s}")),
                );
                Ok(report)
            }
        }
    }

    /// The plan snapped to what the camera supports (after [`Theta::prepare`]).
    pub fn snap(&self, plan: &BracketPlan) -> BracketPlan {
        BracketPlan {
            shots: plan
                .shots
                .iter()
                .map(|e| Exposure {
                    shutter_s: nearest(&self.shutter_support, e.shutter_s),
                    iso: nearest(
                        &self
                            .iso_support
                            .iter()
                            .map(|&i| i as f64)
                            .collect::<Vec<_>>(),
                        e.iso as f64,
                    ) as u32,
                })
                .collect(),
        }
    }

    /// Shoots the plan and downloads every frame, in plan order.
    #[tracing::instrument(skip(self, plan, progress), fields(model = %self.model, shots = plan.shots.len()))]
    pub fn capture(
        &mut self,
        plan: &BracketPlan,
        progress: &mut (dyn FnMut(&str, f64) + Send),
    ) -> Result<Vec<Frame>> {
        if plan.shots.is_empty() {
            return Err(ThetaError::Unsupported("an empty bracket plan".into()));
        }
        let plan = self.snap(plan);
        match &mut self.link {
            Link::Http { runtime, client } => {
                runtime.block_on(capture_http(client, &plan, progress))
            }
            Link::Usb(cam) => {
                let mut frames = Vec::with_capacity(plan.shots.len());
                for (i, e) in plan.shots.iter().enumerate() {
                    usb::wake(cam)?;
                    let shutter_s = usb::set_shutter(cam, e.shutter_s)?;
                    let iso = cam.set_iso(e.iso)?;
                    let label = format!("frame {}/{}", i + 1, plan.shots.len());
                    let shot = usb::shoot(cam, &mut |phase, f| {
                        progress(&format!("{label} {phase}"), f)
                    })?;
                    frames.push(Frame {
                        name: shot.info.filename,
                        data: shot.data,
                        asked: Exposure { shutter_s, iso },
                    });
                }
                Ok(frames)
            }
        }
    }

    /// A cheap request that tells whether the camera still answers, and keeps it from
    /// sleeping: `/osc/state` over HTTP; over USB, a read of the sleep property, waking the
    /// camera if it dozed off.
    pub fn keep_alive(&mut self) -> Result<()> {
        match &mut self.link {
            Link::Http { runtime, client } => runtime.block_on(client.state()).map(|_| ()),
            Link::Usb(cam) => usb::wake(cam).map(|_| ()),
        }
    }

    /// Ends the session (USB: CloseSession; HTTP has none in API v2.1).
    pub fn close(self) -> Result<()> {
        match self.link {
            Link::Http { .. } => Ok(()),
            Link::Usb(cam) => Ok(cam.close()?),
        }
    }
}

fn nearest(support: &[f64], want: f64) -> f64 {
    support
        .iter()
        .copied()
        .filter(|s| *s > 0.0)
        .min_by(|a, b| (a / want).ln().abs().total_cmp(&(b / want).ln().abs()))
        .unwrap_or(want)
}

/// Options for light measurement, each set on its own so that one a model lacks is skipped
/// rather than failing the rest. The first two are required.
fn light_measurement_options() -> Vec<(&'static str, serde_json::Value, bool)> {
    vec![
        ("still-image mode", json!({ "captureMode": "image" }), true),
        ("manual exposure", json!({ "exposureProgram": 1 }), true),
        (
            "sleep and power-off timers off",
            json!({ "offDelay": TIMER_DISABLED, "sleepDelay": TIMER_DISABLED }),
            false,
        ),
        ("filter off", json!({ "_filter": "off" }), false),
        // The Z1 and X only: their self-timer and "my setting" functions shoot otherwise
        // than asked. Never in the same setOptions as exposureDelay, which they refuse.
        (
            "normal shooting function",
            json!({ "_function": "normal" }),
            false,
        ),
        ("self-timer off", json!({ "exposureDelay": 0 }), false),
        (
            "fixed white balance",
            json!({ "whiteBalance": "_colorTemperature", "_colorTemperature": DEFAULT_COLOR_TEMPERATURE }),
            false,
        ),
    ]
}

async fn prepare_http(client: &OscClient) -> Result<(Vec<String>, Vec<f64>, Vec<u32>)> {
    let mut report = Vec::new();
    for (name, options, required) in light_measurement_options() {
        match client.set_options(options).await {
            Ok(()) => report.push(name.to_string()),
            Err(ThetaError::Command { code, .. })
                if !required && code.starts_with("invalidParameter") =>
            {
                tracing::info!("THETA does not take {name}: {code}");
                report.push(format!("skipped (not on this model): {name}"));
            }
            Err(e) => return Err(e),
        }
    }
    if let Some(format) = largest_jpeg(client).await? {
        match client.set_options(json!({ "fileFormat": format })).await {
            Ok(()) => report.push(format!(
                "JPEG {}×{}",
                format["width"].as_u64().unwrap_or(0),
                format["height"].as_u64().unwrap_or(0)
            )),
            Err(ThetaError::Command { code, .. }) if code.starts_with("invalidParameter") => {
                report.push("skipped (not on this model): JPEG file format".into())
            }
            Err(e) => return Err(e),
        }
    }
    let support = client
        .get_options(&["shutterSpeedSupport", "isoSupport"])
        .await?;
    let numbers = |key: &str| -> Vec<f64> {
        support
            .get(key)
            .and_then(|v| v.as_array())
            .map(|a| a.iter().filter_map(|x| x.as_f64()).collect())
            .unwrap_or_default()
    };
    let shutters = numbers("shutterSpeedSupport");
    let isos: Vec<u32> = numbers("isoSupport")
        .into_iter()
        .map(|i| i as u32)
        .collect();
    if shutters.is_empty() {
        return Err(ThetaError::Unsupported(
            "the THETA lists no shutter speeds (shutterSpeedSupport); manual exposure needs firmware with the v2.1 API".into(),
        ));
    }
    Ok((report, shutters, isos))
}

/// The camera's largest JPEG still format, from `fileFormatSupport`: the HDR merge reads
/// JPEGs, a Z1 left at RAW+ writes a DNG beside each, and an X may be at its smaller size.
/// None where the camera lists no formats.
async fn largest_jpeg(client: &OscClient) -> Result<Option<serde_json::Value>> {
    let support = match client.get_options(&["fileFormatSupport"]).await {
        Ok(support) => support,
        Err(ThetaError::Command { code, .. }) if code.starts_with("invalidParameter") => {
            return Ok(None)
        }
        Err(e) => return Err(e),
    };
    Ok(support
        .get("fileFormatSupport")
        .and_then(|s| s.as_array())
        .and_then(|formats| {
            formats
                .iter()
                .filter(|f| f["type"] == "jpeg")
                .max_by_key(|f| f["width"].as_u64().unwrap_or(0))
                .cloned()
        }))
}

fn bracket_shot(e: &Exposure) -> osc::BracketShot {
    osc::BracketShot {
        shutter_speed: e.shutter_s,
        iso: e.iso,
        color_temperature: Some(DEFAULT_COLOR_TEMPERATURE),
        exposure_program: Some(1),
        white_balance: Some("_colorTemperature".into()),
        exposure_compensation: None,
        aperture: None,
    }
}

async fn capture_http(
    client: &OscClient,
    plan: &BracketPlan,
    progress: &mut (dyn FnMut(&str, f64) + Send),
) -> Result<Vec<Frame>> {
    let mut urls: Vec<(String, Exposure)> = Vec::new();
    if let [e] = plan.shots.as_slice() {
        client
            .set_options(json!({ "exposureProgram": 1, "shutterSpeed": e.shutter_s, "iso": e.iso }))
            .await?;
        // The phase is said in the bench's words; the OSC command's name is for the log.
        let done = client
            .run("camera.takePicture", json!({}), &mut |_, f| {
                progress("shooting one frame", f)
            })
            .await?;
        let files = done.file_urls();
        let [url] = files.as_slice() else {
            return Err(ThetaError::Malformed {
                what: "camera.takePicture".into(),
                reason: format!("expected one fileUrl, got {files:?}"),
            });
        };
        urls.push((url.clone(), *e));
    } else {
        for chunk in plan.shots.chunks(MAX_BRACKET) {
            let bracket = osc::AutoBracket {
                number: chunk.len() as u32,
                parameters: chunk.iter().map(bracket_shot).collect(),
            };
            client
                .set_options(json!({ "_autoBracket": bracket }))
                .await?;
            let label = format!("shooting a bracket of {}", chunk.len());
            let done = client
                .run(
                    "camera.startCapture",
                    json!({ "_mode": "bracket" }),
                    &mut |_, f| progress(&label, f),
                )
                .await?;
            let files = done.file_urls();
            if files.len() != chunk.len() {
                return Err(ThetaError::Malformed {
                    what: "camera.startCapture (bracket)".into(),
                    reason: format!(
                        "a {}-shot bracket returned {} files; the bracket was cut short (battery, or cancelled on the camera)",
                        chunk.len(),
                        files.len()
                    ),
                });
            }
            urls.extend(files.into_iter().zip(chunk.iter().copied()));
        }
    }
    let mut frames = Vec::with_capacity(urls.len());
    let n = urls.len();
    for (i, (url, asked)) in urls.into_iter().enumerate() {
        let label = format!("download {}/{n}", i + 1);
        let data = client
            .download(&url, &mut |_, f| progress(&label, f))
            .await?;
        let name = url.rsplit('/').next().unwrap_or("frame.jpg").to_string();
        frames.push(Frame { name, data, asked });
    }
    Ok(frames)
}
