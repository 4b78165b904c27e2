//! `brdfd theta`: the 360° camera on its own, over HTTP (THETA Web API) or USB (PTP): what it
//! reports, and a light-measurement capture merged into an HDR environment map. Also the
//! panorama step that `brdfd capture` runs.

use std::path::PathBuf;

use anyhow::{bail, Context};
use brdfd_core::envmap::EnvMap;
use brdfd_radiometry::panorama::merge_bracket;
use brdfd_rig::selector::Selector;
use brdfd_rig::Event;
use brdfd_theta::{BracketPlan, Credentials, Exposure, Frame, HttpTimeouts, Theta};

#[derive(clap::Subcommand)]
pub enum ThetaCommand {
    /// Print what the camera reports: model, serial, firmware, link.
    Info {
        #[command(flatten)]
        port: ThetaPort,
        /// Print it as JSON.
        #[arg(long)]
        json: bool,
    },
    /// Shoot an exposure bracket for light measurement, save the frames unchanged and the
    /// merged linear map as `panorama.exr`.
    Capture(ThetaCaptureArgs),
}

#[derive(clap::Args)]
pub struct ThetaPort {
    /// `osc:http://HOST[:PORT]` or `http://HOST[:PORT]` (access-point mode:
    /// http://192.168.1.1), `usb` (the first RICOH camera), `usb:VVVV:PPPP`, or
    /// `ptpip:HOST[:PORT]`.
    #[arg(short, long, default_value = "http://192.168.1.1")]
    pub port: String,
    /// HTTP Digest user, for a THETA in client mode (THETAxx<serial>).
    #[arg(long, env = "BRDFD_THETA_USER")]
    pub user: Option<String>,
    #[command(flatten)]
    pub password: PasswordArgs,
}

/// The variable a THETA's Digest password may come from, out of sight of `ps`.
pub const PASSWORD_VAR: &str = "BRDFD_THETA_PASSWORD";

/// A THETA's HTTP Digest password: from a file or standard input, or the environment
/// ([`PASSWORD_VAR`]), where other users cannot see it as they can see the command line.
#[derive(clap::Args)]
pub struct PasswordArgs {
    /// HTTP Digest password (the serial number unless it was changed). Other users can see
    /// it in `ps`: prefer --password-file, or BRDFD_THETA_PASSWORD in the environment.
    #[arg(long, conflicts_with = "password_file")]
    pub password: Option<String>,
    /// Read the password from the first line of FILE (`-`: standard input).
    #[arg(long, value_name = "FILE")]
    pub password_file: Option<PathBuf>,
}

/// The most of a password file read: a password is its first line.
const PASSWORD_FILE_BYTES: u64 = 4096;

/// A password file others can read is no secret: said, as ssh does of a key.
fn warn_if_others_can_read(path: &std::path::Path, f: &std::fs::File) {
    use std::os::unix::fs::PermissionsExt;
    if let Ok(m) = f.metadata() {
        if m.is_file() && m.permissions().mode() & 0o077 != 0 {
            tracing::warn!(
                "{}: others can read this password file (mode {:o}); `chmod 600` it",
                path.display(),
                m.permissions().mode() & 0o777
            );
        }
    }
}

impl PasswordArgs {
    /// The password given, and whether it was asked for on the command line (a password
    /// from the environment is there for whichever command needs one, so it is no mistake
    /// to have it set without a user).
    pub fn resolve(&self) -> anyhow::Result<(Option<String>, bool)> {
        if let Some(p) = &self.password {
            return Ok((Some(p.clone()), true));
        }
        if let Some(file) = &self.password_file {
            use std::io::{IsTerminal, Read};
            // The first line is all that is read, and never more than a password's worth: a
            // device or a huge file given by mistake must not hang the command.
            let mut text = String::new();
            if file.as_os_str() == "-" {
                if std::io::stdin().is_terminal() {
                    bail!("--password-file -: standard input is a terminal, which would show the password as it is typed; pipe it in, or name a file");
                }
                std::io::stdin()
                    .take(PASSWORD_FILE_BYTES)
                    .read_to_string(&mut text)
                    .context("reading the password from standard input")?;
            } else {
                let f = std::fs::File::open(file)
                    .with_context(|| format!("reading the password from {}", file.display()))?;
                warn_if_others_can_read(file, &f);
                f.take(PASSWORD_FILE_BYTES)
                    .read_to_string(&mut text)
                    .with_context(|| format!("reading the password from {}", file.display()))?;
            }
            let first = text.lines().next().unwrap_or("").to_string();
            if first.is_empty() {
                bail!("no password in {}: its first line is empty", file.display());
            }
            return Ok((Some(first), true));
        }
        Ok((
            std::env::var(PASSWORD_VAR).ok().filter(|p| !p.is_empty()),
            false,
        ))
    }

    /// User and password together, or neither.
    pub fn credentials(&self, user: Option<&str>) -> anyhow::Result<Option<(String, String)>> {
        match (user, self.resolve()?) {
            (Some(user), (Some(password), _)) => Ok(Some((user.to_string(), password))),
            (None, (_, false)) => Ok(None),
            (None, (_, true)) => bail!("a password without a user: give --user too"),
            (Some(_), (None, _)) => bail!(
                "--user without a password: give --password-file FILE (or - for standard input), set {PASSWORD_VAR}, or give --password"
            ),
        }
    }
}

#[derive(clap::Args)]
pub struct ThetaCaptureArgs {
    #[command(flatten)]
    pub port: ThetaPort,
    /// Shutter speeds in seconds; the light-probe bracket (1/16000 s to 1 s) if absent; one
    /// value shoots a single frame.
    #[arg(long, value_delimiter = ',')]
    pub shutter: Vec<f64>,
    /// ISO sensitivity of every shot.
    #[arg(long, default_value_t = 100)]
    pub iso: u32,
    /// Folder for the frames and `panorama.exr`.
    #[arg(short, long, default_value = ".")]
    pub out: PathBuf,
}

/// Opens the THETA a port selector names.
pub fn open(p: &ThetaPort, timeouts: HttpTimeouts) -> anyhow::Result<Theta> {
    let credentials = p
        .password
        .credentials(p.user.as_deref())?
        .map(|(user, password)| Credentials { user, password });
    Ok(brdfd_rig::open::theta(
        &p.port.parse::<Selector>()?,
        credentials,
        timeouts,
    )?)
}

/// Prepares the camera and shoots the plan: the frames as the camera sent them, each
/// checked against its EXIF. Progress lines go to stderr.
pub fn shoot_panorama(theta: &mut Theta, plan: &BracketPlan) -> anyhow::Result<Vec<Frame>> {
    let lines = |e: Event| match e {
        Event::Message { text } => eprintln!("{text}"),
        Event::Warning { text } => eprintln!("  warning: {text}"),
        _ => {}
    };
    let frames = brdfd_rig::light::shoot_panorama(theta, plan, &lines)?;
    for f in &frames {
        brdfd_rig::light::check_exposure(&lines, f);
    }
    Ok(frames)
}

/// Shoots the plan and merges it: the map (in radiance units given by `gain`) and the
/// frames.
pub fn capture_panorama(
    theta: &mut Theta,
    plan: &BracketPlan,
    gain: [f64; 3],
) -> anyhow::Result<(EnvMap, Vec<Frame>)> {
    let frames = shoot_panorama(theta, plan)?;
    let files: Vec<(String, Vec<u8>)> = frames
        .iter()
        .map(|f| (f.name.clone(), f.data.clone()))
        .collect();
    let merged = merge_bracket(&files, gain).context("merging the panorama bracket")?;
    if merged.clipped_pixels > 0 {
        eprintln!(
            "  warning: {} pixels clip even in the shortest frame; they carry at least {:.1}% of the light, which is underestimated",
            merged.clipped_pixels,
            merged.clipped_share * 100.0
        );
    }
    Ok((merged.map, frames))
}

pub fn plan_from(shutter: &[f64], iso: u32) -> BracketPlan {
    if shutter.is_empty() {
        return BracketPlan::light_probe();
    }
    BracketPlan {
        shots: shutter
            .iter()
            .map(|&shutter_s| Exposure { shutter_s, iso })
            .collect(),
    }
}

pub fn run(cmd: ThetaCommand) -> anyhow::Result<()> {
    match cmd {
        ThetaCommand::Info { port, json } => {
            let theta = open(&port, HttpTimeouts::default())?;
            if json {
                let info = serde_json::json!({
                    "model": theta.model,
                    "serial_number": theta.serial,
                    "firmware": theta.firmware,
                    "link": theta.link(),
                });
                println!("{}", serde_json::to_string_pretty(&info)?);
            } else {
                println!("{}", theta.describe());
            }
            theta.close()?;
        }
        ThetaCommand::Capture(a) => {
            let mut theta = open(&a.port, HttpTimeouts::default())?;
            println!("{}", theta.describe());
            std::fs::create_dir_all(&a.out)
                .with_context(|| format!("creating {}", a.out.display()))?;
            let plan = plan_from(&a.shutter, a.iso);
            // A real camera's gain is unknown until calibrated: the map is in relative
            // units (pixel value per unit exposure factor).
            let (map, frames) = capture_panorama(&mut theta, &plan, [1.0; 3])?;
            for f in &frames {
                let path = brdfd_rig::session::write_new(&a.out, &f.name, &f.data)?;
                println!(
                    "{} ({} bytes, asked {} s ISO {})",
                    path.display(),
                    f.data.len(),
                    f.asked.shutter_s,
                    f.asked.iso
                );
            }
            let exr = a.out.join("panorama.exr");
            map.write_exr(&exr)?;
            println!(
                "{} ({}×{}, linear, relative units)",
                exr.display(),
                map.width,
                map.height
            );
            theta.close()?;
        }
    }
    Ok(())
}
