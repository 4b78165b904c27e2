//! The `brdfd` binary: parses the command line and calls the library. Errors print as a chain
//! and exit with status 1 (2 for usage errors, from clap).

mod cli;

use clap::Parser;

fn main() -> std::process::ExitCode {
    let args = cli::Cli::parse();
    // A simulator logs each transaction it serves; everything else is quiet unless asked.
    let serve_log;
    let default = match &args.command {
        cli::Command::Sim { .. } => "warn,brdfd_sim=info",
        // The daemon logs as its config says (`log` in brdfd.toml).
        cli::Command::Serve(a) => {
            serve_log = a.log_filter();
            serve_log.as_str()
        }
        _ => "warn",
    };
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_env("BRDFD_LOG")
                .unwrap_or_else(|_| default.into()),
        )
        .with_writer(std::io::stderr)
        .init();
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
