//! `brdfd serial`: the trigger box, turntable or release cable on its own, for checking the
//! wiring at the bench.

use anyhow::bail;
use brdfd_rig::selector::Selector;
use brdfd_serial::{ControlLine, GrblTurntable, RigController, ShutterCable};

#[derive(clap::Subcommand)]
pub enum SerialCommand {
    /// What the device says it is (`ID?`) and where the turntable stands.
    Info {
        #[command(flatten)]
        port: SerialPort,
        /// Print it as JSON.
        #[arg(long)]
        json: bool,
    },
    /// Press the shutter for `--ms` milliseconds (rig protocol or release cable).
    Fire {
        #[command(flatten)]
        port: SerialPort,
        /// How long the shutter is held, in milliseconds.
        #[arg(long, default_value_t = 200)]
        ms: u32,
    },
    /// Turn the turntable by `--deg` degrees (negative turns back).
    Rotate {
        #[command(flatten)]
        port: SerialPort,
        /// Degrees to turn by; negative turns back.
        #[arg(long, allow_hyphen_values = true)]
        deg: f64,
    },
    /// Turn the turntable to its home switch.
    Home(SerialPort),
}

#[derive(clap::Args)]
pub struct SerialPort {
    /// `serial:/dev/ttyUSB0` (rig protocol), `grbl:[AXIS:]/dev/ttyUSB0` (a GRBL controller's
    /// turntable) or `cable:dtr:/dev/ttyUSB0` / `cable:rts:...`.
    #[arg(short, long)]
    pub port: String,
}

fn rig(port: &str) -> anyhow::Result<RigController> {
    match port.parse::<Selector>()? {
        Selector::Serial(path) => Ok(brdfd_rig::open::turntable(&path)?),
        Selector::Grbl { .. } => {
            bail!("a GRBL controller turns the table only: it has no shutter output brdfd fires")
        }
        other => bail!("{other} is not a rig-protocol device; use serial:/dev/ttyX"),
    }
}

/// The GRBL controller a selector names, if it names one.
fn grbl(port: &str) -> anyhow::Result<Option<GrblTurntable>> {
    match port.parse::<Selector>()? {
        // As it is: `serial info` looks without homing, `serial home` homes.
        Selector::Grbl { axis, path } => Ok(Some(GrblTurntable::open(
            &path,
            axis,
            brdfd_serial::RigTimeouts::default(),
        )?)),
        _ => Ok(None),
    }
}

pub fn run(cmd: SerialCommand) -> anyhow::Result<()> {
    match cmd {
        SerialCommand::Info { port, json } => {
            if let Some(mut g) = grbl(&port.port)? {
                return grbl_info(&mut g, json);
            }
            let mut r = rig(&port.port)?;
            let id = r.identity.clone();
            if json {
                let position = if id.can_rotate {
                    Some(r.position()?)
                } else {
                    None
                };
                let info = serde_json::json!({
                    "port": r.port_name(),
                    "name": id.name,
                    "version": id.version,
                    "can_fire": id.can_fire,
                    "can_rotate": id.can_rotate,
                    "position_deg": position,
                });
                println!("{}", serde_json::to_string_pretty(&info)?);
                return Ok(());
            }
            println!(
                "{}: {} version {}; shutter output: {}; turntable: {}",
                r.port_name(),
                id.name,
                id.version,
                if id.can_fire { "yes" } else { "no" },
                if id.can_rotate { "yes" } else { "no" }
            );
            if id.can_rotate {
                println!("position {:.2}°", r.position()?);
            }
        }
        SerialCommand::Fire { port, ms } => match port.port.parse::<Selector>()? {
            Selector::Cable { rts, path } => {
                let line = if rts {
                    ControlLine::Rts
                } else {
                    ControlLine::Dtr
                };
                ShutterCable::new(brdfd_serial::open(&path)?, line, false)?.fire(ms)?;
                println!("fired {ms} ms on {line:?} of {path}");
            }
            _ => {
                rig(&port.port)?.fire(ms)?;
                println!("fired {ms} ms");
            }
        },
        SerialCommand::Rotate { port, deg } => {
            let at = match grbl(&port.port)? {
                Some(mut g) => g.rotate(deg)?,
                None => rig(&port.port)?.rotate(deg)?,
            };
            println!("at {at:.2}°");
        }
        SerialCommand::Home(p) => {
            let at = match grbl(&p.port)? {
                Some(mut g) => g.home()?,
                None => rig(&p.port)?.home()?,
            };
            println!("at {at:.2}°");
        }
    }
    Ok(())
}

/// `serial info` for a GRBL controller: its state and where the table stands, as it is.
fn grbl_info(g: &mut GrblTurntable, json: bool) -> anyhow::Result<()> {
    let status = g.status()?;
    let id = g.identity.clone();
    if json {
        let info = serde_json::json!({
            "port": g.port_name(),
            "name": id.banner,
            "axis": id.axis.to_string(),
            "state": status.state,
            "can_fire": false,
            "can_rotate": true,
            "position_deg": status.position.rem_euclid(360.0),
        });
        println!("{}", serde_json::to_string_pretty(&info)?);
        return Ok(());
    }
    println!(
        "{}: {}, turntable on the {} axis; state {}; position {:.2}°",
        g.port_name(),
        id.banner,
        id.axis,
        status.state,
        status.position.rem_euclid(360.0)
    );
    Ok(())
}
