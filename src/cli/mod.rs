//! Command-line definitions (clap) and dispatch. Each subcommand's work lives in the library
//! crates; this module turns raw arguments into their typed options.

mod basis_cmd;
mod calibrate_cmd;
mod capture;
mod client;
mod config_cmd;
mod decode_raw;
mod devices_cmd;
mod estimate_cmd;
mod geometry_args;
mod man_cmd;
mod perf;
mod perf_ptp;
mod pose_cmd;
mod progress;
mod ptp_cmd;
mod serial_cmd;
mod serve;
mod session_cmd;
mod sim;
mod theta_cmd;
#[cfg(test)]
mod tree_check;
mod v4l_cmd;

use std::path::PathBuf;

use anyhow::Context as _;
use clap::{Parser, Subcommand};

pub use geometry_args::GeometryArgs;

#[derive(Parser)]
#[command(
    name = "brdfd",
    version,
    about = "BRDF acquisition with a DSLR and a 360° camera, estimated on a data-driven basis"
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

// `--help` lists them in this order: `capture` first, as what a new user comes for.
#[derive(Subcommand)]
pub enum Command {
    /// Capture a material at the bench and estimate its BRDF (in the daemon if one runs).
    Capture(capture::CaptureArgs),
    /// Build or inspect PCA bases.
    Basis {
        #[command(subcommand)]
        command: basis_cmd::BasisCommand,
    },
    /// Estimate a BRDF from a photo, an environment map and the object's geometry.
    Estimate(estimate_cmd::EstimateArgs),
    /// Render a BRDF (MERL file, NBRDF material, or an estimate) on a geometry under a map.
    Render(estimate_cmd::RenderArgs),
    /// Run the evaluation (the paper's protocol, or relighting with --relight) on reference data
    /// and write tables and figures (docs/evaluation.md describes both).
    Eval(EvalArgs),
    /// Calibrate the rig: each camera's gain from a grey card, the object camera's pose from
    /// a printed board.
    Calibrate {
        #[command(subcommand)]
        command: calibrate_cmd::CalibrateCommand,
    },
    /// Run the daemon: own the rig's devices and serve the HTTP API on loopback.
    Serve(serve::ServeArgs),
    /// Measure the speed of the estimation core and the PTP link (medians of repeated runs).
    Bench(perf::BenchArgs),
    /// Talk to one PTP camera directly (USB or PTP/IP): info, capture, brackets.
    Ptp {
        #[command(subcommand)]
        command: ptp_cmd::PtpCommand,
    },
    /// Talk to the 360° camera (RICOH THETA) directly, over HTTP or USB: info, light capture.
    Theta {
        #[command(subcommand)]
        command: theta_cmd::ThetaCommand,
    },
    /// A serial trigger box, turntable or release cable: info, fire, rotate, home.
    Serial {
        #[command(subcommand)]
        command: serial_cmd::SerialCommand,
    },
    /// A V4L2 camera (the fallback object camera, or a THETA in UVC mode).
    V4l {
        #[command(subcommand)]
        command: v4l_cmd::V4lCommand,
    },
    /// Stored sessions: list, show, resume, export.
    Session(session_cmd::SessionArgs),
    /// Check configuration files (daemon, rigs, materials, geometry).
    Config {
        #[command(subcommand)]
        command: config_cmd::ConfigCommand,
    },
    /// List what is plugged in and whether brdfd can open it.
    Devices(devices_cmd::DevicesArgs),
    /// Print a shell completion script, e.g. `brdfd completions bash > ~/.local/share/bash-completion/completions/brdfd`.
    Completions {
        /// The shell to write the script for.
        #[arg(value_enum)]
        shell: clap_complete::Shell,
    },
    /// Write man pages (brdfd.1 and one per subcommand), by default into the user's man path.
    ///
    /// With no folder they go to $XDG_DATA_HOME/man/man1, else ~/.local/share/man/man1, where
    /// `man brdfd` and the systemd unit's `man:brdfd-serve(1)` find them (man-db searches it
    /// when ~/.local/bin is on PATH; else add it to MANPATH, as the command then says).
    Man(man_cmd::ManArgs),
    /// Run a simulated device until stopped.
    Sim {
        #[command(subcommand)]
        command: sim::SimCommand,
    },
    /// Decode one RAW file, from stdin to stdout, within a memory budget: the child process
    /// captures decode RAW files in.
    #[command(hide = true)]
    DecodeRaw(decode_raw::DecodeRawArgs),
}

#[derive(clap::Args)]
pub struct EvalArgs {
    /// The reference data folder (holds merl-nbrdf/ and envmaps/).
    #[arg(long, env = "BRDFD_DATA")]
    pub data: PathBuf,
    /// Where the tables and figures go.
    #[arg(short, long, default_value = "eval")]
    pub out: PathBuf,
    /// Image size of the evaluation sphere, in pixels.
    #[arg(long, default_value_t = 256, value_parser = image_size)]
    pub size: usize,
    /// Skip leave-one-out over all 100 materials (it dominates the run time).
    #[arg(long)]
    pub no_loo: bool,
    /// Also measure the grid and normalisation choices (bivariate binning, φd reduction, mean).
    #[arg(long)]
    pub choices: bool,
    /// Principal components to estimate with (the paper's 5 unless told otherwise).
    #[arg(long, default_value_t = brdfd_core::basis::DEFAULT_K)]
    pub k: usize,
    /// Run the relighting evaluation instead (the headline measure): estimate under each
    /// --capture map, relight under every other map, compare with the truth. Its documented
    /// table (docs/evaluation.md) is made with --size 64, in about 5 minutes on 2 cores.
    #[arg(long)]
    pub relight: bool,
    /// With --relight: every one of the 100 MERL materials instead of the test set, each
    /// estimated with a basis and measured materials built from the other 99 (the paper's
    /// method, the analytic baseline and the default only).
    #[arg(long, requires = "relight")]
    pub leave_one_out: bool,
    /// Maps the relighting evaluation captures under (names in the data folder's envmaps/).
    #[arg(long, value_delimiter = ',', default_value = "grace,courtyard")]
    pub capture: Vec<String>,
    /// Only these materials in the relighting evaluation (comma-separated); all if absent.
    #[arg(long, value_delimiter = ',')]
    pub materials: Vec<String>,
}

/// An image size in pixels on the command line: 8 to 8192, so that a typo cannot ask for an
/// image whose buffers alone exceed the machine's memory.
pub fn image_size(s: &str) -> Result<usize, String> {
    let n: usize = s
        .parse()
        .map_err(|e| format!("{s:?} is not a size in pixels: {e}"))?;
    if (8..=8192).contains(&n) {
        Ok(n)
    } else {
        Err(format!("{n} is outside 8 to 8192 pixels"))
    }
}

/// Says why a rig file a calibration just wrote cannot capture yet, if it cannot.
fn warn_not_ready(saved: &brdfd_rig::rig_file::Saved) {
    if let Some(why) = &saved.not_ready {
        eprintln!("  warning: the rig is not ready to capture yet: {why}");
    }
}

/// An evaluation's progress, a line on stderr as each material (or variant) begins: the runs
/// take 5 to 25 minutes, and stdout is kept for the report.
fn eval_progress(start: std::time::Instant) -> impl Fn(brdfd_eval::Progress) {
    move |p| {
        let s = start.elapsed().as_secs();
        eprintln!(
            "[{:2}:{:02}] {}: {} of {}, {}",
            s / 60,
            s % 60,
            p.stage,
            p.index,
            p.total,
            p.item
        );
    }
}

impl Command {
    /// Whether the command only reports: ended by SIGPIPE when its reader goes away, rather
    /// than going on (a capture, the daemon, a simulator).
    pub fn ends_quietly_on_a_closed_pipe(&self) -> bool {
        // Only listings: anything that drives a device, copies files or runs a capture must
        // not die half-way because its reader went away.
        match self {
            Command::Session(a) => matches!(
                a.command,
                session_cmd::SessionCommand::List { .. } | session_cmd::SessionCommand::Show { .. }
            ),
            Command::Basis {
                command: basis_cmd::BasisCommand::Show { .. },
            } => true,
            Command::Config { .. }
            | Command::Devices(_)
            | Command::Completions { .. }
            | Command::Man(_) => true,
            _ => false,
        }
    }
}

/// Copies a session's folder (or a part of it) to `to`, without the dot files an
/// interrupted write leaves.
fn copy_dir(from: &std::path::Path, to: &std::path::Path) -> anyhow::Result<()> {
    std::fs::create_dir_all(to).with_context(|| format!("creating {}", to.display()))?;
    for e in std::fs::read_dir(from)? {
        let e = e?;
        let name = e.file_name();
        // Temporary files of an interrupted write are not part of the session.
        if name.to_string_lossy().starts_with('.') {
            continue;
        }
        let (src, dst) = (e.path(), to.join(&name));
        if e.file_type()?.is_dir() {
            copy_dir(&src, &dst)?;
        } else {
            std::fs::copy(&src, &dst).with_context(|| format!("copying {}", src.display()))?;
        }
    }
    Ok(())
}

pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Basis { command } => basis_cmd::run(command),
        Command::Estimate(a) => estimate_cmd::estimate(a),
        Command::Render(a) => estimate_cmd::render(a),
        Command::Eval(a) if a.relight => {
            let report = brdfd_eval::relight::run(
                &brdfd_eval::relight::RelightConfig {
                    data: a.data,
                    out: a.out,
                    size: a.size,
                    capture_maps: a.capture,
                    materials: a.materials,
                    leave_one_out: a.leave_one_out,
                },
                &eval_progress(std::time::Instant::now()),
            )?;
            println!("{report}");
            Ok(())
        }
        Command::Eval(a) => {
            let report = brdfd_eval::paper::run(
                &brdfd_eval::paper::EvalConfig {
                    data: a.data,
                    out: a.out,
                    size: a.size,
                    leave_one_out: !a.no_loo,
                    choices: a.choices,
                    k: a.k,
                },
                &eval_progress(std::time::Instant::now()),
            )?;
            println!("{report}");
            Ok(())
        }
        Command::Capture(a) => capture::run(a),
        Command::Calibrate { command } => calibrate_cmd::run(command),
        Command::Serve(a) => serve::run(a),
        Command::Bench(a) => perf::run(a),
        Command::Ptp { command } => ptp_cmd::run(command),
        Command::Theta { command } => theta_cmd::run(command),
        Command::Serial { command } => serial_cmd::run(command),
        Command::V4l { command } => v4l_cmd::run(command),
        Command::Devices(a) => devices_cmd::run(a),
        Command::Config { command } => config_cmd::run(command),
        Command::Session(a) => session_cmd::run(a),
        Command::Sim { command } => sim::run(command),
        Command::DecodeRaw(a) => decode_raw::run(a),
        Command::Completions { shell } => {
            let mut cmd = <Cli as clap::CommandFactory>::command();
            // Into memory first: the generator panics on a write error, such as a closed pipe.
            let mut script = Vec::new();
            clap_complete::generate(shell, &mut cmd, "brdfd", &mut script);
            std::io::Write::write_all(&mut std::io::stdout(), &script)?;
            Ok(())
        }
        Command::Man(a) => man_cmd::run(a, <Cli as clap::CommandFactory>::command()),
    }
}
