//! `brdfd serve`: the daemon. Starts the rig's device workers, serves the API, and on
//! SIGINT or SIGTERM cancels a running capture (which keeps what it captured and stays
//! resumable), waits for it, and exits.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use anyhow::Context;
use brdfd_daemon::{api, Daemon};
use brdfd_rig::config::Rig;

#[derive(clap::Args)]
pub struct ServeArgs {
    /// The daemon config (API address, token, state directory, log); else BRDFD_CONFIG, else
    /// ~/.config/brdfd/brdfd.toml (XDG) if it exists, else the built-in defaults.
    #[arg(short, long)]
    pub config: Option<PathBuf>,
    /// The rig file of the bench's devices.
    #[arg(short, long, required_unless_present = "simulate")]
    pub rig: Option<PathBuf>,
    /// Run the simulated rig (simulators on loopback) instead of hardware.
    #[arg(long, conflicts_with = "rig")]
    pub simulate: bool,
    /// Listen here instead of the config's `api` (port 0 picks a free port; the address is
    /// printed).
    #[arg(long)]
    pub api: Option<String>,
    /// Where sessions are stored; else BRDFD_STATE_DIR, else the config's, else the XDG data
    /// directory.
    #[arg(long)]
    pub state_dir: Option<PathBuf>,
    /// Seconds between keep-alive requests to idle devices.
    #[arg(long, default_value_t = brdfd_rig::KEEP_ALIVE.as_secs_f64())]
    pub keep_alive: f64,
    /// Open API connections at most; a new one beyond closes the oldest idle one. Default:
    /// the open-file limit less 256 for the daemon's own files, at most 4,096.
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..))]
    pub max_connections: Option<u64>,
    /// Seconds a connection may take to send a request's head (new or idle between
    /// requests) before it is closed.
    #[arg(long, default_value_t = 10.0)]
    pub header_timeout: f64,
    /// Seconds a response may wait for the client to take more of it before the connection
    /// is dropped.
    #[arg(long, default_value_t = 30.0)]
    pub write_timeout: f64,
}

impl ServeArgs {
    /// The config's log filter; an unreadable config is reported by `run`, so "info" here.
    pub fn log_filter(&self) -> String {
        brdfd_rig::config::DaemonConfig::load(self.config.as_deref())
            .map_or_else(|_| "info".into(), |(c, _)| c.log)
    }
}

pub fn run(a: ServeArgs) -> anyhow::Result<()> {
    let (mut config, config_source) = brdfd_rig::config::DaemonConfig::load(a.config.as_deref())?;
    let source = match &a.api {
        Some(api) => {
            config.api = api.clone();
            "--api".to_string()
        }
        None => config_source,
    };
    let addr = config.check_api(&source)?;
    // Positive, and within what a Duration holds (a huge number would panic).
    let seconds = |v: f64, flag: &str| {
        Duration::try_from_secs_f64(v)
            .ok()
            .filter(|d| !d.is_zero())
            .with_context(|| format!("{flag} must be a positive number of seconds, not {v}"))
    };
    let keep_alive = seconds(a.keep_alive, "--keep-alive")?;
    let header_timeout = seconds(a.header_timeout, "--header-timeout")?;
    let write_timeout = seconds(a.write_timeout, "--write-timeout")?;
    let mut limits = brdfd_daemon::server::Limits {
        header_timeout,
        write_timeout,
        ..Default::default()
    };
    if let Some(n) = a.max_connections {
        limits.max_connections = usize::try_from(n).unwrap_or(usize::MAX);
    }
    let (rig, rig_text) = match &a.rig {
        Some(p) => (Rig::read(p)?, std::fs::read_to_string(p)?),
        None => (
            Rig::simulated(),
            include_str!("../../config/rigs/simulated.toml").to_string(),
        ),
    };
    // The daemon keeps the devices open whatever the calibration; captures wait for it.
    if let Err(e) = brdfd_rig::plan::check(&rig) {
        eprintln!("warning: captures will be refused until the rig can be run: {e} (the daemon reads its rig when it starts: stop it to calibrate, since it holds the devices, then start it again)");
    }
    let state = brdfd_rig::session::state_dir(a.state_dir.as_deref(), config.state_dir.as_deref())?;
    // Absolute, so that the paths the API gives out mean the same to every client.
    let state = std::path::absolute(&state).unwrap_or(state);
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    runtime.block_on(async move {
        // Bound before the devices start, so that a taken port fails fast and clearly.
        let listener = tokio::net::TcpListener::bind(addr)
            .await
            .with_context(|| format!("listening on {addr}"))?;
        let bound = listener.local_addr()?;
        let simulated = rig.simulated;
        let mut daemon = tokio::task::block_in_place(|| {
            Daemon::start(
                rig,
                rig_text,
                state.clone(),
                config.token.clone(),
                keep_alive,
            )
        })?;
        daemon.hosts = config.hosts.clone();
        daemon.max_event_streams =
            (limits.max_connections / 2).clamp(1, brdfd_daemon::MAX_EVENT_STREAMS);
        let daemon = Arc::new(daemon);
        // Scripts and tests wait for this line.
        println!(
            "brdfd daemon listening on http://{bound} ({} rig; sessions in {})",
            if simulated { "simulated" } else { "hardware" },
            state.display()
        );
        use std::io::Write;
        std::io::stdout().flush()?;
        let app = api::router(daemon.clone());
        let d = daemon.clone();
        tracing::debug!(?limits, "serving");
        brdfd_daemon::server::serve(listener, app, limits, async move {
            shutdown_signal().await;
            tracing::info!("shutting down");
            println!("shutting down");
            // The capture's end is written before the server stops answering, so event
            // streams see `finished` and close.
            let _ = tokio::task::spawn_blocking(move || d.shut_down()).await;
        })
        .await
        .context("serving the API")?;
        println!("stopped");
        Ok(())
    })
}

async fn shutdown_signal() {
    let terminate = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    tokio::select! {
        _ = tokio::signal::ctrl_c() => {}
        _ = terminate => {}
    }
}
