//! `brdfd capture`: capture a material and estimate it, as one session on disk.
//!
//! When a daemon (`brdfd serve`) answers at the configured API address, the capture runs
//! there: the daemon owns the devices. Otherwise the same flow runs in this process, on
//! devices it opens for the one capture. Either way the operator sees the same progress and
//! the same lines, and is told which happened.

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{bail, Context as _};
use brdfd_api::answers::{Health, SessionDetail};
use brdfd_rig::config::{DaemonConfig, Rig};
use brdfd_rig::flow::{self, Context};
use brdfd_rig::session::{safe_file_name, PhaseTime, Session, State};
use brdfd_rig::settings::CaptureSettings;
use brdfd_rig::{Cancel, Devices, Event, Plan, Progress, KEEP_ALIVE};

use super::client::{Busy, Daemon};
use super::estimate_cmd::{ColourArg, ModelArg, SolveArg};
use super::progress::{Bars, Terminal};

#[derive(clap::Args)]
pub struct CaptureArgs {
    /// Material name: a preset (gold, gold-part, chrome, paint, fabric; config/materials), a
    /// test material's short name (plastic, latex) or its MERL name (e.g. nickel). Names are
    /// lower-case; capitals are taken as the same letters.
    #[arg(short, long, value_parser = lower_case)]
    pub material: String,
    /// Use the simulated rig: the devices' simulators on loopback, rendering the material.
    #[arg(long, conflicts_with = "rig")]
    pub simulate: bool,
    /// A hardware rig file (see config/rigs/bench.toml).
    #[arg(short, long)]
    pub rig: Option<PathBuf>,
    /// Environment map for the simulated rig; the embedded procedural studio if absent.
    #[arg(long)]
    pub env: Option<PathBuf>,
    /// NBRDF file for the simulated material; the embedded test materials if absent.
    #[arg(long)]
    pub nbrdf: Option<PathBuf>,
    /// Image size of the simulated camera.
    #[arg(long, default_value_t = 256, value_parser = super::image_size)]
    pub size: usize,
    /// Simulated rig: put the material's projection onto the basis on the bench, so that the
    /// estimate can be checked against known coefficients.
    #[arg(long, requires = "simulate")]
    pub in_span: bool,
    /// Fit one BRDF to the whole part, even where its colour departs from place to place:
    /// otherwise such a part is split into two materials, each estimated on its own pixels
    /// and written in its own folder (material-1/, material-2/).
    #[arg(long)]
    pub one_material: bool,
    /// Pixels to estimate from (a number or `all`); the material preset's, else 20.
    #[arg(long)]
    pub pixels: Option<brdfd_rig::PixelCount>,
    /// The BRDF model; the material preset's, else `hybrid` (see `brdfd estimate --help`).
    #[arg(long, value_enum)]
    pub model: Option<ModelArg>,
    /// Basis model: how the coefficients are solved; the material preset's, else `prior`
    /// (docs/evaluation.md).
    #[arg(long, value_enum)]
    pub solve: Option<SolveArg>,
    /// Basis model: how colour is modelled; the material preset's, else `auto` (docs/method.md).
    #[arg(long, value_enum)]
    pub colour: Option<ColourArg>,
    /// Shutter speeds of the DSLR's exposure bracket, in seconds; the material preset's,
    /// else the rig's.
    #[arg(long, value_delimiter = ',')]
    pub bracket: Vec<f64>,
    /// Views on the turntable: the object turned `--turn` degrees between them, under the
    /// same light, for more normals in one estimate; the rig's turntable plan, else 1.
    #[arg(long)]
    pub views: Option<usize>,
    /// Turntable step between views, degrees; the rig's, else 30.
    #[arg(long, allow_hyphen_values = true)]
    pub turn: Option<f64>,
    /// Where sessions are stored (in-process captures); else BRDFD_STATE_DIR, else the
    /// daemon config's, else the XDG data directory.
    #[arg(long)]
    pub state_dir: Option<PathBuf>,
    /// Also write the results and the raw files to this folder.
    #[arg(short, long)]
    pub out: Option<PathBuf>,
    /// Also print the estimate's coefficients and each phase's time (both are in the
    /// session: `result/coefficients.json`, `manifest.json`).
    #[arg(long, short)]
    pub verbose: bool,
    #[command(flatten)]
    pub daemon: DaemonArgs,
}

/// Where to look for a running daemon.
#[derive(clap::Args)]
pub struct DaemonArgs {
    /// The daemon's API address (IP:PORT); else brdfd.toml's `api`.
    #[arg(long, env = "BRDFD_DAEMON")]
    pub daemon: Option<String>,
    /// Run in this process even if a daemon is running.
    #[arg(long)]
    pub in_process: bool,
    /// The daemon config to read `api`, `token` and `state_dir` from; else BRDFD_CONFIG, else
    /// ~/.config/brdfd/brdfd.toml (XDG) if it exists, else the built-in defaults.
    #[arg(short, long)]
    pub config: Option<PathBuf>,
}

impl DaemonArgs {
    pub fn config(&self) -> anyhow::Result<DaemonConfig> {
        Ok(DaemonConfig::load(self.config.as_deref())?.0)
    }

    /// The daemon this command would talk to, if one runs there; says nothing.
    pub fn running(&self, config: &DaemonConfig) -> anyhow::Result<Option<Daemon>> {
        let addr = self.daemon.clone().unwrap_or_else(|| config.api.clone());
        let token = std::env::var("BRDFD_TOKEN").ok().or(config.token.clone());
        Daemon::find(&addr, token)
    }

    /// The running daemon, unless `--in-process`; says which way the work goes.
    pub fn find(&self, config: &DaemonConfig) -> anyhow::Result<Option<Daemon>> {
        if self.in_process {
            println!("running in this process (--in-process)");
            return Ok(None);
        }
        let d = self.running(config)?;
        match &d {
            Some(d) => println!("running in the daemon at {}", d.base),
            None => println!(
                "no daemon at {}; running in this process",
                self.daemon.as_deref().unwrap_or(&config.api)
            ),
        }
        Ok(d)
    }
}

/// A name as brdfd spells names, in lower case: `Gold` is `gold`, where a name with a capital
/// would only be refused. A name that is no valid name either way is left as typed, for its
/// error to quote.
fn lower_case(name: &str) -> Result<String, std::convert::Infallible> {
    let lower = name.to_lowercase();
    Ok(match brdfd_api::plan::is_valid_name(&lower) {
        true => lower,
        false => name.to_string(),
    })
}

/// The plan as the daemon takes it: scene files (`--env`, `--nbrdf`) by bare name, which the
/// daemon looks up in its state directory's `scenes/` folder; it takes no path from a client.
fn daemon_plan(
    plan: Plan,
    (env, nbrdf): (Option<PathBuf>, Option<PathBuf>),
) -> anyhow::Result<Plan> {
    let bare = |flag: &str, p: Option<PathBuf>| -> anyhow::Result<Option<PathBuf>> {
        match p {
            Some(p)
                if !matches!(
                    p.components().collect::<Vec<_>>()[..],
                    [std::path::Component::Normal(_)]
                ) =>
            {
                bail!(
                "{flag} {}: the daemon takes scene files by name from the `{}` folder of its state directory; copy the file there and give its name, or capture with --in-process",
                p.display(),
                brdfd_daemon::SCENES_DIR
            )
            }
            other => Ok(other),
        }
    };
    Ok(Plan {
        env: bare("--env", env)?,
        nbrdf: bare("--nbrdf", nbrdf)?,
        ..plan
    })
}

pub fn run(a: CaptureArgs) -> anyhow::Result<()> {
    if a.views == Some(0) {
        bail!("--views must be at least 1");
    }
    let scene_names = (a.env.clone(), a.nbrdf.clone());
    let plan = Plan {
        material: a.material,
        size: a.size,
        pixels: a.pixels,
        model: a.model.map(Into::into),
        solve: a.solve.map(Into::into),
        colour: a.colour.map(Into::into),
        bracket: a.bracket,
        views: a.views,
        turn: a.turn,
        // Stored absolute, so a resume from another folder finds them.
        env: a.env.map(|p| std::path::absolute(&p).unwrap_or(p)),
        nbrdf: a.nbrdf.map(|p| std::path::absolute(&p).unwrap_or(p)),
        in_span: a.in_span,
        one_material: a.one_material,
    };
    plan.validate()?;
    let config = a.daemon.config()?;
    let rig = match (&a.rig, a.simulate) {
        (Some(p), _) => Some((Rig::read(p)?, std::fs::read_to_string(p)?)),
        (None, true) => Some((
            Rig::simulated(),
            include_str!("../../config/rigs/simulated.toml").to_string(),
        )),
        (None, false) => None,
    };
    let daemon = a.daemon.find(&config)?;
    // In this process the settings are resolved and checked before a session exists; a
    // daemon resolves them itself, against its own rig and scene files (the plan's are this
    // machine's).
    let settings = match (&daemon, &rig) {
        (None, Some((r, _))) => Some(CaptureSettings::resolve(&plan, r)?),
        _ => None,
    };
    if let Some(d) = daemon {
        let health: Health = d.typed("/health")?;
        let simulated = health.rig.simulated;
        match &rig {
            Some(_) if a.rig.is_some() => bail!(
                "the daemon at {} owns the rig's devices: capture through it without --rig, or stop it and capture with --in-process",
                d.base
            ),
            Some(_) if !simulated => bail!(
                "the daemon at {} runs a hardware rig, and --simulate was asked: stop it, or use --in-process",
                d.base
            ),
            _ => {}
        }
        let plan = daemon_plan(plan, scene_names)?;
        let id = match d.start(&plan) {
            Ok(id) => id,
            Err(e) if e.is::<Busy>() => return Err(e.context("the capture was not started")),
            Err(e) => return Err(e),
        };
        return follow(&d, &id, a.out.as_deref(), a.verbose);
    }
    let (Some((rig, rig_text)), Some(settings)) = (rig, settings) else {
        bail!("no rig: give --rig FILE for a hardware rig (config/rigs/bench.toml is a template), or --simulate for the simulated one");
    };
    let state = brdfd_rig::session::state_dir(a.state_dir.as_deref(), config.state_dir.as_deref())?;
    let mut session = settings.new_session(&state, &rig_text)?;
    println!(
        "session {} in {}",
        session.manifest().id,
        session.dir.display()
    );
    in_process(&mut session, &settings, &rig, a.out.as_deref(), a.verbose)
}

/// Runs the flow here, on devices opened for this capture.
fn in_process(
    session: &mut Session,
    settings: &CaptureSettings,
    rig: &Rig,
    out: Option<&Path>,
    verbose: bool,
) -> anyhow::Result<()> {
    let devices = Devices::start(rig, KEEP_ALIVE)?;
    let bars = Arc::new(Bars::new());
    let cancel = Cancel::default();
    interrupt_cancels(&cancel, &session.manifest().id, bars.clone());
    let cx = Context {
        rig,
        devices: &devices,
        progress: bars,
        cancel: cancel.clone(),
        operator: Arc::new(Terminal),
    };
    if let Err(e) = flow::execute(session, settings, &cx) {
        // Stopped by Ctrl-C, not by a failure of its own (which is reported as it is).
        if cancel.is_cancelled() && brdfd_rig::error::is_cancellation(&e) {
            let id = &session.manifest().id;
            bail!("session {id} interrupted; what was captured is kept: `brdfd session resume {id}` continues it");
        }
        return Err(e.into());
    }
    if verbose {
        print_details(&session.dir, &session.manifest().phases)?;
    }
    println!(
        "session {} done: {}",
        session.manifest().id,
        session.dir.display()
    );
    if let Some(out) = out {
        export_flat(session, out)?;
    }
    Ok(())
}

/// Ctrl-C, SIGTERM or SIGHUP stops the capture at its next check (a frame, a pass of the
/// estimate: within seconds), which records the session as interrupted; another one a second
/// or more later quits at once.
fn interrupt_cancels(cancel: &Cancel, id: &str, bars: Arc<Bars>) {
    let (cancel, id) = (cancel.clone(), id.to_string());
    let first = std::sync::OnceLock::new();
    let handler = ctrlc::set_handler(move || {
        // The cancel before any word: after a hang-up the terminal is gone, and what is said
        // can fail. A panic here would end the handler's thread, and with it every later
        // signal's handling.
        if !cancel.is_cancelled() {
            cancel.cancel();
            first.get_or_init(std::time::Instant::now);
            let waiting = match bars.under_way().join(", ") {
                w if w.is_empty() => "the current step".to_string(),
                w => w,
            };
            let _ = writeln!(
                std::io::stderr(),
                "\nstopping: waiting for {waiting} to stop, a few seconds at most (Ctrl-C again to quit at once)"
            );
            return;
        }
        // A closed terminal sends SIGHUP twice in a moment (the shell, then the kernel): only
        // a later signal is someone asking again.
        if first
            .get()
            .is_some_and(|t| t.elapsed() < REPEAT_MEANS_QUIT_AFTER)
        {
            return;
        }
        let _ = writeln!(
            std::io::stderr(),
            "\nquitting now; session {id} may still say it is capturing: `brdfd session resume {id}` continues it"
        );
        std::process::exit(130);
    });
    if let Err(e) = handler {
        tracing::warn!("Ctrl-C will not stop the capture cleanly: {e}");
    }
}

/// How long after the first signal a second one is taken as "quit now".
const REPEAT_MEANS_QUIT_AFTER: std::time::Duration = std::time::Duration::from_secs(1);

/// The bars of a capture in the daemon, and this terminal's operator: a capture that waits
/// for the object to be turned by hand is told so once Enter is pressed.
struct Answering<'a> {
    bars: Bars,
    daemon: &'a Daemon,
    id: &'a str,
}

impl Progress for Answering<'_> {
    fn event(&self, e: Event) {
        let view = match &e {
            Event::WaitingForOperator { view, .. } => Some(*view),
            _ => None,
        };
        self.bars.event(e);
        let Some(view) = view else { return };
        // The stream replays the capture's past: only a wait that is still on is asked.
        let waiting = || -> anyhow::Result<bool> {
            let s: SessionDetail = self.daemon.typed(&format!("/sessions/{}", self.id))?;
            Ok(s.waiting_for_view == Some(view))
        };
        let told = waiting().and_then(|on| {
            if !on {
                return Ok(());
            }
            let hint = "Ctrl-C stops following; the capture waits in the daemon";
            if Terminal::enter(hint, &waiting)? {
                self.daemon.proceed(self.id, view)
            } else {
                self.bars.event(Event::Message {
                    text: format!("  view {view}'s turn was confirmed elsewhere"),
                });
                Ok(())
            }
        });
        if let Err(e) = told {
            // The capture waits in the daemon; another client can still answer it.
            eprintln!("  {e:#}");
        }
    }
}

/// Follows a capture in the daemon to its end.
pub fn follow(d: &Daemon, id: &str, out: Option<&Path>, verbose: bool) -> anyhow::Result<()> {
    println!("session {id} (in the daemon)");
    // Leaving stops only the watching: the capture is the daemon's, and goes on.
    let detach = {
        let id = id.to_string();
        ctrlc::set_handler(move || {
            // Said as it can be: after a hang-up the terminal is gone.
            let _ = writeln!(std::io::stderr(), "\nstopped following; the capture continues in the daemon. `brdfd session follow {id}` watches it again, `brdfd session cancel {id}` stops it");
            std::process::exit(130);
        })
    };
    if let Err(e) = detach {
        tracing::warn!("Ctrl-C will end the program without a word: {e}");
    }
    let last = d.follow(
        id,
        &Answering {
            bars: Bars::new(),
            daemon: d,
            id,
        },
    )?;
    let stored: SessionDetail = d.typed(&format!("/sessions/{id}"))?;
    let phases: Vec<PhaseTime> = stored.manifest.phases;
    match last {
        Event::Finished {
            state: State::Done, ..
        } => {
            let dir = PathBuf::from(&stored.dir);
            if verbose {
                print_details(&dir, &phases)?;
            }
            println!("session {id} done: {}", dir.display());
            if let Some(out) = out {
                let state = dir
                    .parent()
                    .and_then(Path::parent)
                    .context("the session's folder")?;
                export_flat(&Session::open(state, id)?, out)?;
            }
            Ok(())
        }
        Event::Finished { error, .. } => bail!(
            "session {id} failed in the daemon: {}; `brdfd session resume {id}` continues it",
            error.unwrap_or_default()
        ),
        _ => bail!("the daemon's event stream for {id} ended without an outcome"),
    }
}

/// Continues a session from its last complete step, in the daemon if one runs.
pub fn resume(state: &Path, id: &str, daemon: &DaemonArgs) -> anyhow::Result<()> {
    let config = daemon.config()?;
    if let Some(d) = daemon.find(&config)? {
        let id = d.resume(id)?;
        return follow(&d, &id, None, false);
    }
    let mut session = Session::open(state, id)?;
    let plan = brdfd_daemon::resumable(&mut session)?;
    let mut rig = Rig::parse(
        &format!("the rig stored in session {id}"),
        &session.manifest().rig,
    )?;
    // Captured before each camera had its gain: resumed as it was captured.
    if let Some(note) = rig.calibration.adopt_ratios() {
        println!("{note}");
    }
    let settings = CaptureSettings::resolve(&plan, &rig)?;
    println!(
        "resuming session {} (was {})",
        session.manifest().id,
        session.manifest().state
    );
    in_process(&mut session, &settings, &rig, None, false)
}

/// `--verbose`: the coefficients from the session's `result/coefficients.json`, and the phases.
fn print_details(session_dir: &Path, phases: &[PhaseTime]) -> anyhow::Result<()> {
    let r =
        brdfd_report::results::StoredResult::read(&session_dir.join("result/coefficients.json"))?;
    println!(
        "{}",
        brdfd_report::results::coefficient_lines(
            "coefficients",
            &r.columns,
            &r.coefficient_values()
        )
    );
    print_phases(phases);
    Ok(())
}

fn print_phases(phases: &[PhaseTime]) {
    let (all, device): (f64, f64) = phases.iter().fold((0.0, 0.0), |(a, d), p| {
        (a + p.seconds, d + p.device_seconds)
    });
    println!("phases (wall time; of it, the simulated devices' own):");
    for p in phases {
        println!(
            "  {:<52} {:>7.3} s  ({:.3} s)",
            p.name, p.seconds, p.device_seconds
        );
    }
    println!(
        "  {:<52} {:>7.3} s  ({:.3} s); brdfd's own: {:.3} s",
        "all phases",
        all,
        device,
        all - device
    );
}

/// Copies a done session's results, first-view photo, panorama and raw files into one
/// folder, the raw files named by device and order (`theta-01-R0010001.JPG`,
/// `dslr-01-DSC_0001.JPG`, `view2-dslr-01-...` with several views): the order keeps apart
/// the files of a camera that reuses names.
fn export_flat(session: &Session, out: &Path) -> anyhow::Result<()> {
    let copy = |from: PathBuf, to: PathBuf| {
        std::fs::copy(&from, &to)
            .with_context(|| format!("copying {} to {}", from.display(), to.display()))
    };
    std::fs::create_dir_all(out.join("raw"))
        .with_context(|| format!("creating {}", out.display()))?;
    let mut results = Vec::new();
    for e in std::fs::read_dir(session.dir.join("result"))? {
        let e = e?;
        // A part split into materials has each one's results in a folder of its own.
        if e.file_type()?.is_dir() {
            super::copy_dir(&e.path(), &out.join(e.file_name()))?;
            results.push(format!("{}/", e.file_name().to_string_lossy()));
        } else {
            copy(e.path(), out.join(e.file_name()))?;
            results.push(e.file_name().to_string_lossy().into_owned());
        }
    }
    copy(
        session.dir.join("derived/photo-view1.exr"),
        out.join("photo.exr"),
    )?;
    copy(
        session.dir.join("derived/panorama.exr"),
        out.join("panorama.exr"),
    )?;
    let views = session
        .manifest()
        .steps
        .iter()
        .filter(|s| s.complete && s.name.starts_with("view"))
        .count();
    let mut raw = 0;
    for step in session.manifest().steps.iter().filter(|s| s.complete) {
        for (k, f) in step.files.iter().enumerate() {
            let name = safe_file_name(f.device_name(step));
            let flat = match step.name.as_str() {
                "panorama" => format!("theta-{:02}-{name}", k + 1),
                view if views > 1 => format!("{view}-dslr-{:02}-{name}", k + 1),
                _ => format!("dslr-{:02}-{name}", k + 1),
            };
            std::fs::write(out.join("raw").join(flat), session.read_raw(f)?)?;
            raw += 1;
        }
    }
    // The report first: it is where a reader starts.
    results.sort_by_key(|n| (n != "report.html", n.clone()));
    println!(
        "wrote {} files in {}: {}, photo.exr, panorama.exr, and {raw} camera files in raw/",
        results.len() + 2 + raw,
        out.display(),
        results.join(", ")
    );
    Ok(())
}
