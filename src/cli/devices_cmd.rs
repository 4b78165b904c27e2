//! `brdfd devices`: what is plugged in, and whether brdfd can open each device. Where it
//! cannot, the line says why and what to do (the drivers' errors carry that help).

use std::time::Duration;

use brdfd_serial::{RigController, RigTimeouts, SerialError};
use brdfd_theta::{HttpTimeouts, Theta, ThetaError};

#[derive(clap::Args)]
pub struct DevicesArgs {
    /// Where to look for a THETA over Wi-Fi (its access-point address by default).
    #[arg(long, default_value = "http://192.168.1.1")]
    pub theta: String,
    /// Do not look for a THETA over Wi-Fi.
    #[arg(long)]
    pub no_theta_http: bool,
    /// How long the Wi-Fi THETA and serial devices have to answer, in milliseconds.
    #[arg(long, default_value_t = 1500)]
    pub timeout_ms: u64,
    /// One JSON object per device found (section, selector, ok, text), as an array.
    #[arg(long)]
    pub json: bool,
}

/// One line of the listing: a device found (with the selector a rig file names it by, and
/// whether brdfd can open it), or a note about a section.
#[derive(serde::Serialize)]
struct Found {
    section: &'static str,
    selector: Option<String>,
    ok: bool,
    /// What drives the device: `brdfd` (its own drivers) or `libgphoto2` (the `gphoto2`
    /// feature); none on a note.
    backend: Option<&'static str>,
    text: String,
}

/// What each section found, in order: its heading, then its lines.
struct Listing {
    rows: Vec<Found>,
    section: &'static str,
}

impl Listing {
    fn device(&mut self, selector: String, ok: bool, text: String) {
        self.device_on("brdfd", selector, ok, text);
    }

    fn device_on(&mut self, backend: &'static str, selector: String, ok: bool, text: String) {
        self.rows.push(Found {
            section: self.section,
            selector: Some(selector),
            ok,
            backend: Some(backend),
            text,
        });
    }

    fn note(&mut self, text: String) {
        self.rows.push(Found {
            section: self.section,
            selector: None,
            ok: false,
            backend: None,
            text,
        });
    }
}

pub fn run(a: DevicesArgs) -> anyhow::Result<()> {
    let timeout = Duration::from_millis(a.timeout_ms);
    let mut l = Listing {
        rows: Vec::new(),
        section: "PTP cameras on USB (DSLRs, THETAs)",
    };
    ptp_cameras(&mut l);
    #[cfg(feature = "gphoto2")]
    {
        l.section = "Cameras libgphoto2 detects (the gphoto2 feature)";
        gphoto_cameras(&mut l);
    }
    if !a.no_theta_http {
        l.section = "THETA over Wi-Fi";
        theta_http(&mut l, &a.theta, timeout);
    }
    l.section = "V4L2 cameras";
    v4l_devices(&mut l);
    l.section = "Serial ports";
    serial_ports(&mut l, timeout);
    if a.json {
        println!("{}", serde_json::to_string_pretty(&l.rows)?);
        return Ok(());
    }
    let mut heading = "";
    for r in &l.rows {
        if r.section != heading {
            heading = r.section;
            println!("{heading}:");
        }
        match &r.selector {
            Some(sel) => println!("  {sel}  {}", r.text),
            None => println!("  {}", r.text),
        }
    }
    Ok(())
}

fn ptp_cameras(l: &mut Listing) {
    let list = match brdfd_ptp::transport::usb::list_still_image_devices() {
        Ok(l) => l,
        Err(e) => {
            // The driver's error says what to check (the same as `ptp info` says).
            l.note(e.to_string());
            return;
        }
    };
    if list.is_empty() {
        l.note("none found".into());
    }
    for info in list {
        let sel = info.selector();
        let theta = info.vendor_id == brdfd_theta::usb::RICOH_VENDOR;
        match super::ptp_cmd::open(&sel) {
            Ok(cam) => {
                let i = &cam.info;
                let flow = super::ptp_cmd::CaptureFlow::of(&cam);
                let how = match flow {
                    _ if theta => "THETA over USB".to_string(),
                    super::ptp_cmd::CaptureFlow::None => "brdfd's PTP driver has no capture flow for it; a brdfd built with the gphoto2 feature drives it through libgphoto2 (gphoto2:PORT)".into(),
                    f => format!("brdfd's PTP driver, {} capture", f.name()),
                };
                let text = format!(
                    "{} {} (serial {}), {how}: ok",
                    i.manufacturer, i.model, i.serial_number,
                );
                l.device(sel.to_string(), true, text);
                let _ = cam.close();
            }
            Err(e) => {
                let model = brdfd_theta::usb::PRODUCTS
                    .iter()
                    .find(|(p, _)| theta && *p == info.product_id)
                    .map_or_else(
                        || format!("{} camera", info.vendor.unwrap_or("unknown")),
                        |(_, name)| format!("RICOH {name}"),
                    );
                let text = format!(
                    "{model} (bus {} address {}): cannot open: {e:#}",
                    info.bus, info.address
                );
                l.device(sel.to_string(), false, text);
            }
        }
    }
}

/// The cameras the system's libgphoto2 detects, by the selector that drives them through it.
/// They are not opened here: brdfd's own listing above has opened those it drives itself.
#[cfg(feature = "gphoto2")]
fn gphoto_cameras(l: &mut Listing) {
    match brdfd_gphoto::detect() {
        Ok(found) if found.is_empty() => l.note("none found".into()),
        Ok(found) => {
            for d in found {
                l.device_on("libgphoto2", format!("gphoto2:{}", d.port), true, d.model);
            }
        }
        Err(e) => l.note(brdfd_rig::error::said(&e)),
    }
}

fn theta_http(l: &mut Listing, url: &str, timeout: Duration) {
    let timeouts = HttpTimeouts {
        request: timeout,
        retry_budget: Duration::ZERO,
        ..HttpTimeouts::default()
    };
    let sel = format!("osc:{url}");
    match Theta::connect_http(url, None, timeouts) {
        Ok(t) => l.device(sel, true, format!("{}: ok", t.describe())),
        Err(ThetaError::Auth { .. }) => l.device(
            sel,
            false,
            "a THETA in client mode: it asks for a password; give --user and --password-file to `brdfd theta`".into(),
        ),
        Err(e @ ThetaError::Unsupported(_)) => l.device(sel, false, e.to_string()),
        Err(_) => l.note(format!("none answered within {timeout:?} at {url}")),
    }
}

fn v4l_devices(l: &mut Listing) {
    let nodes = brdfd_v4l::device::list_devices();
    if nodes.is_empty() {
        l.note("none found".into());
    }
    for n in nodes {
        let sel = format!("v4l:{}", n.path);
        match n.status {
            Ok(formats) => {
                let best = brdfd_v4l::choose_format(&formats)
                    .map(|(f, w, h)| format!("{f:?} {w}×{h}"))
                    .unwrap_or_else(|| "no YUYV or MJPG format".into());
                l.device(sel, true, format!("{}  {best}: ok", n.name));
            }
            Err(e) => l.device(sel, false, format!("{}: cannot open: {e}", n.name)),
        }
    }
}

fn serial_ports(l: &mut Listing, timeout: Duration) {
    let ports = match brdfd_serial::list_ports() {
        Ok(p) => p,
        Err(e) => {
            l.note(format!("cannot list serial ports: {e}"));
            return;
        }
    };
    if ports.is_empty() {
        l.note("none found".into());
    }
    // A survey waits no longer than asked: a board that is still booting is said to be
    // silent (the capture waits for it).
    let timeouts = RigTimeouts {
        answer: timeout,
        boot: timeout,
        ..RigTimeouts::default()
    };
    for p in ports {
        let sel = format!("serial:{}", p.path);
        match RigController::open(&p.path, timeouts) {
            Ok(rig) => {
                let id = &rig.identity;
                let text = format!(
                    "{}  {} {}{}{}: ok",
                    p.kind,
                    id.name,
                    id.version,
                    if id.can_fire { " FIRE" } else { "" },
                    if id.can_rotate { " ROT" } else { "" }
                );
                l.device(sel, true, text);
            }
            // A G-code controller, which a turntable may be on: it printed its banner, or
            // took the `?` in `ID?` for its real-time status question.
            Err(SerialError::Protocol { line, .. }) if brdfd_serial::looks_like_grbl(&line) => {
                l.device(
                    format!("grbl:{}", p.path),
                    true,
                    format!(
                        "{}: a GRBL G-code controller ({line}); as a turntable: grbl:AXIS:{}, AXIS the one the table is on (grbl:{} for A, on a four-axis build)",
                        p.kind, p.path, p.path
                    ),
                )
            }
            // Opens, but nothing speaks the rig protocol: a bare adapter, or an Arduino
            // still booting (opening the port resets most of them).
            Err(SerialError::Timeout { .. } | SerialError::Protocol { .. }) => l.device(
                sel,
                true,
                format!(
                    "{}: opens, no rig-protocol answer (as a release cable: cable:dtr:{})",
                    p.kind, p.path
                ),
            ),
            Err(e) => l.device(sel, false, format!("{}: cannot open: {e}", p.kind)),
        }
    }
}
