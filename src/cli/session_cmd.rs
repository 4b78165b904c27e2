//! `brdfd session`: the sessions stored on disk: list, show (with every checksum verified),
//! resume an interrupted one, export one.

use std::path::{Path, PathBuf};

use anyhow::Context;
use brdfd::session::{Session, State};

#[derive(clap::Args)]
pub struct SessionArgs {
    #[command(subcommand)]
    pub command: SessionCommand,
    /// Where sessions are stored; else BRDFD_STATE_DIR, else the XDG data directory.
    #[arg(long, global = true)]
    pub state_dir: Option<PathBuf>,
}

#[derive(clap::Subcommand)]
pub enum SessionCommand {
    /// Every session: id, state, material, created.
    List,
    /// One session's manifest, with every raw file's checksum verified.
    Show { id: String },
    /// Continue an interrupted or failed session from its last complete step (in the daemon
    /// if one is running).
    Resume {
        id: String,
        #[command(flatten)]
        daemon: super::capture::DaemonArgs,
    },
    /// Copy a session (manifest, raw, derived, result) to a folder, after verifying it.
    Export {
        id: String,
        #[arg(long)]
        to: PathBuf,
    },
}

pub fn run(a: SessionArgs) -> anyhow::Result<()> {
    let state = brdfd::session::state_dir(a.state_dir.as_deref(), None)?;
    match a.command {
        SessionCommand::List => {
            let all = Session::list(&state)?;
            if all.is_empty() {
                println!("no sessions in {}", state.display());
            }
            for m in all {
                println!("{}  {:?}  {}  {}", m.id, m.state, m.material, m.created);
            }
        }
        SessionCommand::Show { id } => {
            let s = Session::open(&state, &id)?;
            println!("{}", serde_json::to_string_pretty(&s.manifest)?);
            let n = s.verify()?;
            println!("{n} raw files verified (sha256)");
        }
        SessionCommand::Resume { id, daemon } => super::capture::resume(&state, &id, &daemon)?,
        SessionCommand::Export { id, to } => {
            let s = Session::open(&state, &id)?;
            let n = s.verify()?;
            if s.manifest.state != State::Done {
                eprintln!("note: session {id} is {:?}, not done", s.manifest.state);
            }
            let dest = to.join(&id);
            copy_dir(&s.dir, &dest)?;
            println!("{} ({n} raw files verified)", dest.display());
        }
    }
    Ok(())
}

fn copy_dir(from: &Path, to: &Path) -> anyhow::Result<()> {
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
