//! The `brdfd` binary: parses the command line and calls the workspace's library crates (the
//! rig, the daemon, the core, the report; docs/architecture.md). Errors print as a chain and
//! exit with status 1 (2 for usage errors, from clap).

mod cli;

use clap::Parser;

fn main() -> std::process::ExitCode {
    let args = cli::Cli::parse();
    // `--simulate` and rig files that say `simulated = true` run on the simulated rig.
    brdfd_simrig::provide();
    if args.command.ends_quietly_on_a_closed_pipe() {
        // `brdfd session list | head` should end quietly, as other tools do, not panic on the
        // closed pipe (Rust ignores SIGPIPE by default). Every other command keeps ignoring
        // it: a reader or client that goes away must not stop a capture, a device or a copy.
        // SAFETY: called before any thread starts; SIG_DFL is a valid disposition.
        unsafe {
            libc::signal(libc::SIGPIPE, libc::SIG_DFL);
        }
    }
    // A simulator logs each transaction it serves; everything else is quiet unless asked.
    let serve_log;
    let default = match &args.command {
        cli::Command::Sim { .. } => "warn,brdfd_sim=debug",
        // The daemon logs as its config says (`log` in brdfd.toml).
        cli::Command::Serve(a) => {
            serve_log = a.log_filter();
            serve_log.as_str()
        }
        _ => "warn",
    };
    // rawler (the RAW decoder) warns on every file whose lens its database lacks, which says
    // nothing about the measurement; its errors reach the user as brdfd's own.
    let filter = tracing_subscriber::EnvFilter::try_from_env("BRDFD_LOG").unwrap_or_else(|_| {
        tracing_subscriber::EnvFilter::new(default)
            .add_directive("rawler=off".parse().expect("a valid directive"))
            // The board detector logs each stage that finds nothing; brdfd says what it means.
            .add_directive("calib_targets=off".parse().expect("a valid directive"))
    });
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        // Colour only for a person at a terminal who has not asked for none
        // (https://no-color.org): a log file or journal gets plain text.
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()) && !no_color())
        .init();
    // RAW files are decoded in a child process of this binary, bounded in memory and time,
    // so that a file the decoder mishandles cannot take a capture (or the daemon) down.
    // On Linux through /proc/self/exe, which stays this very binary after a package upgrade
    // replaced the file on disk.
    if !matches!(args.command, cli::Command::DecodeRaw(_)) {
        let own = std::path::Path::new("/proc/self/exe");
        let exe = if own.exists() {
            Ok(own.to_path_buf())
        } else {
            std::env::current_exe()
        };
        match exe {
            Ok(exe) => brdfd_radiometry::isolated::use_child_processes(exe),
            Err(e) => tracing::warn!("RAW files will be decoded in this process: {e}"),
        }
    }
    match cli::run(args) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            for cause in e.chain().skip(1) {
                eprintln!("  caused by: {cause}");
            }
            std::process::ExitCode::FAILURE
        }
    }
}

/// NO_COLOR set to anything but the empty string (https://no-color.org).
fn no_color() -> bool {
    std::env::var_os("NO_COLOR").is_some_and(|v| !v.is_empty())
}
