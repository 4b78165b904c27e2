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
}

pub fn run(a: DevicesArgs) -> anyhow::Result<()> {
    let timeout = Duration::from_millis(a.timeout_ms);
    ptp_cameras();
    if !a.no_theta_http {
        theta_http(&a.theta, timeout);
    }
    v4l_devices();
    serial_ports(timeout);
    Ok(())
}

fn ptp_cameras() {
    println!("PTP cameras on USB (DSLRs, THETAs):");
    let list = match brdfd_ptp::transport::usb::list_still_image_devices() {
        Ok(l) => l,
        Err(e) => {
            // Inside a container or sandbox, usbfs (/dev/bus/usb) is usually not there.
            println!(
                "  cannot list USB devices: {e} (no USB access here? a container needs /dev/bus/usb passed in)"
            );
            return;
        }
    };
    if list.is_empty() {
        println!("  none found");
    }
    for info in list {
        let sel = info.selector();
        let theta = info.vendor_id == brdfd_theta::usb::RICOH_VENDOR;
        match super::ptp_cmd::open(&sel) {
            Ok(cam) => {
                let i = &cam.info;
                println!(
                    "  {sel}  {} {} (serial {}){}: ok",
                    i.manufacturer,
                    i.model,
                    i.serial_number,
                    if theta { ", THETA over USB" } else { "" }
                );
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
                println!(
                    "  {sel}  {model} (bus {} address {}): cannot open: {e:#}",
                    info.bus, info.address
                );
            }
        }
    }
}

fn theta_http(url: &str, timeout: Duration) {
    println!("THETA over Wi-Fi ({url}):");
    let timeouts = HttpTimeouts {
        request: timeout,
        retry_budget: Duration::ZERO,
        ..HttpTimeouts::default()
    };
    match Theta::connect_http(url, None, timeouts) {
        Ok(t) => println!("  osc:{url}  {}: ok", t.describe()),
        Err(ThetaError::Auth { .. }) => println!(
            "  osc:{url}  a THETA in client mode: it asks for a password; give --user and --password to `brdfd theta`"
        ),
        Err(e @ ThetaError::Unsupported(_)) => println!("  osc:{url}  {e}"),
        Err(_) => println!("  none answered within {timeout:?}"),
    }
}

fn v4l_devices() {
    println!("V4L2 cameras:");
    let nodes = brdfd_v4l::device::list_devices();
    if nodes.is_empty() {
        println!("  none found");
    }
    for n in nodes {
        match n.status {
            Ok(formats) => {
                let best = brdfd_v4l::choose_format(&formats)
                    .map(|(f, w, h)| format!("{f:?} {w}×{h}"))
                    .unwrap_or_else(|| "no YUYV or MJPG format".into());
                println!("  v4l:{}  {}  {best}: ok", n.path, n.name);
            }
            Err(e) => println!("  v4l:{}  {}: cannot open: {e}", n.path, n.name),
        }
    }
}

fn serial_ports(timeout: Duration) {
    println!("Serial ports:");
    let ports = match brdfd_serial::list_ports() {
        Ok(p) => p,
        Err(e) => {
            println!("  cannot list serial ports: {e}");
            return;
        }
    };
    if ports.is_empty() {
        println!("  none found");
    }
    let timeouts = RigTimeouts {
        answer: timeout,
        ..RigTimeouts::default()
    };
    for p in ports {
        match RigController::open(&p.path, timeouts) {
            Ok(rig) => {
                let id = &rig.identity;
                println!(
                    "  serial:{}  {}  {} {}{}{}: ok",
                    p.path,
                    p.kind,
                    id.name,
                    id.version,
                    if id.can_fire { " FIRE" } else { "" },
                    if id.can_rotate { " ROT" } else { "" }
                );
            }
            // Opens, but nothing speaks the rig protocol: a bare adapter, or an Arduino
            // still booting (opening the port resets most of them).
            Err(SerialError::Timeout { .. } | SerialError::Protocol { .. }) => println!(
                "  serial:{}  {}: opens, no rig-protocol answer (as a release cable: cable:dtr:{})",
                p.path, p.kind, p.path
            ),
            Err(e) => println!("  serial:{}  {}: cannot open: {e}", p.path, p.kind),
        }
    }
}
