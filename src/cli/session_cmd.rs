//! `brdfd session`: the sessions stored on disk: list, show (with every checksum verified),
//! resume an interrupted one, export one.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use brdfd_report::materials::PartRecord;
use brdfd_rig::session::{Manifest, Session, State};

#[derive(clap::Args)]
pub struct SessionArgs {
    #[command(subcommand)]
    pub command: SessionCommand,
    /// Where sessions are stored; else BRDFD_STATE_DIR, else the `state_dir` of the daemon's
    /// config (BRDFD_CONFIG, else ~/.config/brdfd/brdfd.toml), else the XDG data directory:
    /// the daemon's own order.
    #[arg(long, global = true)]
    pub state_dir: Option<PathBuf>,
}

#[derive(clap::Subcommand)]
pub enum SessionCommand {
    /// Every session, oldest first: id, state, material, model and fit, created.
    List {
        /// One JSON object per session, as an array.
        #[arg(long)]
        json: bool,
    },
    /// One session: a summary, then its manifest, with every raw file's checksum verified.
    Show {
        /// The session: its id, the start of its id or of its last part (`3f2a` for
        /// 20261122-233000-gold-3f2a1b) if only one session has it, or `latest`.
        id: String,
    },
    /// Continue an interrupted or failed session from its last complete step (in the daemon
    /// if one is running).
    Resume {
        /// The session: its id, the start of its id or of its last part (`3f2a` for
        /// 20261122-233000-gold-3f2a1b) if only one session has it, or `latest`.
        id: String,
        #[command(flatten)]
        daemon: super::capture::DaemonArgs,
    },
    /// Stop a capture: in the daemon if one runs it; else a session left capturing by a
    /// process that is gone is recorded as interrupted.
    Cancel {
        /// The session: its id, the start of its id or of its last part (`3f2a` for
        /// 20261122-233000-gold-3f2a1b) if only one session has it, or `latest`.
        id: String,
        #[command(flatten)]
        daemon: super::capture::DaemonArgs,
    },
    /// Watch a capture running in the daemon until it ends.
    Follow {
        /// The session: its id, the start of its id or of its last part (`3f2a` for
        /// 20261122-233000-gold-3f2a1b) if only one session has it, or `latest`.
        id: String,
        #[command(flatten)]
        daemon: super::capture::DaemonArgs,
    },
    /// Copy a session (manifest, raw, derived, result) to a folder, after verifying it.
    Export {
        /// The session: its id, the start of its id or of its last part (`3f2a` for
        /// 20261122-233000-gold-3f2a1b) if only one session has it, or `latest`.
        id: String,
        /// The folder to copy it into, as a folder named by the session's id.
        #[arg(long)]
        to: PathBuf,
    },
}

pub fn run(a: SessionArgs) -> anyhow::Result<()> {
    let given = match &a.command {
        SessionCommand::Resume { daemon, .. }
        | SessionCommand::Cancel { daemon, .. }
        | SessionCommand::Follow { daemon, .. } => daemon.config.as_deref(),
        _ => None,
    };
    let (config, _) = brdfd_rig::config::DaemonConfig::load(given)?;
    let state = brdfd_rig::session::state_dir(a.state_dir.as_deref(), config.state_dir.as_deref())?;
    let id = |id: &str| resolve_id(&state, id);
    match a.command {
        SessionCommand::List { json } => list(&state, json)?,
        SessionCommand::Show { id: i } => {
            let s = Session::open(&state, &id(&i)?)?;
            for line in summary(&s) {
                println!("{line}");
            }
            println!(
                "\nmanifest:\n{}",
                serde_json::to_string_pretty(&s.manifest())?
            );
            let n = s.verify()?;
            println!("{n} raw files verified (sha256)");
        }
        SessionCommand::Resume { id: i, daemon } => {
            super::capture::resume(&state, &id(&i)?, &daemon)?
        }
        SessionCommand::Cancel { id: i, daemon } => cancel(&state, &id(&i)?, &daemon)?,
        SessionCommand::Follow { id: i, daemon } => {
            let id = id(&i)?;
            let Some(d) = daemon.running(&daemon.config()?)? else {
                bail!("no daemon runs, so nothing is capturing {id} to follow: `brdfd session show {id}` shows where it stands");
            };
            super::capture::follow(&d, &id, None, false)?
        }
        SessionCommand::Export { id: i, to } => {
            let id = id(&i)?;
            let s = Session::open(&state, &id)?;
            let n = s.verify()?;
            if s.manifest().state != State::Done {
                eprintln!("note: session {id} is {}, not done", s.manifest().state);
            }
            let dest = to.join(&id);
            super::copy_dir(&s.dir, &dest)?;
            println!("{} ({n} raw files verified)", dest.display());
        }
    }
    Ok(())
}

/// `latest` is the newest session (ids start with their creation time); a whole id is itself;
/// else the one session whose id, or whose random last part, starts with `id`, as git takes
/// a commit's prefix. Resolved here, against the sessions on disk, so that the daemon's API
/// only ever sees whole ids.
fn resolve_id(state: &Path, id: &str) -> anyhow::Result<String> {
    if id == "latest" {
        return Session::list(state)?
            .pop()
            .map(|m| m.id)
            .with_context(|| format!("no sessions in {}, so none is the latest", state.display()));
    }
    // Session::open says what is wrong with a name that is not one.
    if brdfd_rig::config::validate_name("session id", id).is_err()
        || brdfd_rig::session::session_dir(state, id)
            .join("manifest.json")
            .is_file()
    {
        return Ok(id.to_string());
    }
    let ids: Vec<String> = Session::list(state)?.into_iter().map(|m| m.id).collect();
    match_id(&ids, id).map(str::to_string).map_err(|e| {
        anyhow::anyhow!(
            "{e} in {} (`brdfd session list` shows them)",
            state.display()
        )
    })
}

/// Shown of the sessions an ambiguous prefix names, at most.
const AMBIGUOUS_SHOWN: usize = 5;

/// The one id among `ids` that starts with `prefix`, or whose random last part (after the
/// last `-`) does.
fn match_id<'a>(ids: &'a [String], prefix: &str) -> Result<&'a str, String> {
    let found: Vec<&str> = ids
        .iter()
        .map(String::as_str)
        .filter(|id| {
            id.starts_with(prefix) || id.rsplit('-').next().is_some_and(|r| r.starts_with(prefix))
        })
        .collect();
    match found[..] {
        [one] => Ok(one),
        [] => Err(format!("no session id starts with {prefix:?}")),
        _ => Err(format!(
            "{prefix:?} begins {} session ids ({}{}): give more of the id",
            found.len(),
            found[..found.len().min(AMBIGUOUS_SHOWN)].join(", "),
            if found.len() > AMBIGUOUS_SHOWN {
                ", ..."
            } else {
                ""
            }
        )),
    }
}

/// What a session's result says of itself, read once.
struct Outcome {
    model: String,
    /// Whether the estimate relights with an anisotropic lobe it chose over `model`; `fit`
    /// is then the lobe's.
    anisotropic_lobe: bool,
    fit: f64,
    /// The assumptions of the model the photo says are broken.
    flags: Vec<brdfd_report::results::StoredFlag>,
    /// The materials the part was split into, each estimated on its own pixels; empty for a
    /// part of one material.
    materials: Vec<PartRecord>,
    /// The materials' re-render of the photo together, when split: what the split is judged
    /// by, where `fit` is the one BRDF fitted to the whole part.
    split_fit: Option<f64>,
    /// The verdict the estimate was given, and in words; absent for results written before
    /// it was kept.
    verdict: Option<(String, String)>,
}

/// The result a session wrote, if it got that far.
fn result_of(dir: &Path) -> Option<Outcome> {
    let r =
        brdfd_report::results::StoredResult::read(&dir.join("result/coefficients.json")).ok()?;
    Some(Outcome {
        anisotropic_lobe: matches!(r.chosen_lobe(), Ok(Some(_))),
        fit: r.fit_error?,
        model: r.model,
        flags: r.flags,
        split_fit: r.materials.as_ref().map(|m| m.fit_error),
        materials: r.materials.map_or(Vec::new(), |m| m.parts),
        verdict: r.verdict.zip(r.verdict_text),
    })
}

fn list(state: &Path, json: bool) -> anyhow::Result<()> {
    let all = Session::list(state)?;
    let rows: Vec<(Manifest, Option<Outcome>)> = all
        .into_iter()
        .map(|m| {
            let r = result_of(&brdfd_rig::session::session_dir(state, &m.id));
            (m, r)
        })
        .collect();
    if json {
        let v: Vec<serde_json::Value> = rows
            .iter()
            .map(|(m, r)| {
                serde_json::json!({
                    "id": m.id,
                    "state": m.state,
                    "material": m.material,
                    "created": m.created,
                    "model": r.as_ref().map(|r| &r.model),
                    "anisotropic_lobe": r.as_ref().map(|r| r.anisotropic_lobe),
                    "verdict": r.as_ref().and_then(|r| r.verdict.as_ref().map(|v| &v.0)),
                    "fit_error": r.as_ref().map(|r| r.fit),
                    "materials_fit_error": r.as_ref().and_then(|r| r.split_fit),
                    "materials": r.as_ref().map(|r| r.materials.iter().map(|p| serde_json::json!({
                        "folder": p.folder,
                        "share": p.share,
                        "fit_error": p.fit_error.is_finite().then_some(p.fit_error),
                    })).collect::<Vec<_>>()),
                })
            })
            .collect();
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    if rows.is_empty() {
        println!("no sessions in {}", state.display());
        return Ok(());
    }
    let width = rows
        .iter()
        .map(|(m, _)| m.id.len())
        .max()
        .unwrap_or(2)
        .max(2);
    println!(
        "{:<width$}  {:<10}  {:<12}  {:<10}  {:<7}  {:>6}  CREATED",
        "ID", "STATE", "MATERIAL", "MODEL", "VERDICT", "FIT"
    );
    for (m, r) in &rows {
        // The verdict, not the fit alone: a good fit can be an unsteady estimate.
        let verdict = r
            .as_ref()
            .and_then(|r| r.verdict.as_ref())
            .map_or("-", |v| v.0.as_str());
        let (model, fit) = match r {
            // A part split into materials: one estimate of the model per material, and their
            // fit together.
            Some(r) if !r.materials.is_empty() => (
                format!("{}×{}", r.model, r.materials.len()),
                format!("{:.3}", r.split_fit.unwrap_or(r.fit)),
            ),
            // The lobe relights, and the fit is its own.
            Some(r) if r.anisotropic_lobe => ("aniso".to_string(), format!("{:.3}", r.fit)),
            Some(r) => (r.model.clone(), format!("{:.3}", r.fit)),
            None => ("-".to_string(), "-".to_string()),
        };
        println!(
            "{:<width$}  {:<10}  {:<12}  {:<10}  {:<7}  {:>6}  {}",
            m.id,
            m.state.name(),
            m.material,
            model,
            verdict,
            fit,
            m.created
        );
    }
    Ok(())
}

/// What a person wants first: where the session stands, why, and what it found.
fn summary(s: &Session) -> Vec<String> {
    let m = &s.manifest();
    let mut lines = vec![
        format!(
            "session {}: {}, material {}",
            m.id,
            m.state.name(),
            m.material
        ),
        format!("created {} by {}", m.created, m.software),
        format!("folder {}", s.dir.display()),
    ];
    if let Some(t) = m.history.last() {
        if let Some(reason) = &t.reason {
            lines.push(format!("last change {}: {reason}", t.at));
        }
    }
    match result_of(&s.dir) {
        Some(r) => {
            // The verdict first, as the capture said it: the fit below is one of the numbers
            // it weighs, and a good fit can be an unsteady or flagged estimate.
            if let Some((_, text)) = &r.verdict {
                lines.push(format!("verdict: {text}"));
            }
            let model = if r.anisotropic_lobe {
                format!("an anisotropic GGX lobe, chosen over the {} model", r.model)
            } else {
                format!("{} model", r.model)
            };
            lines.push(format!(
                "estimate: {model}, fit to the photo {:.4} ({})",
                r.fit,
                brdfd_core::estimate::fit_verdict(r.fit)
            ));
            // A broken assumption makes the fit's word optimistic: said right under it.
            lines.extend(r.flags.iter().map(|f| format!("  flagged: {}", f.text)));
            if !r.materials.is_empty() {
                lines.push(format!(
                    "split into {} materials, each estimated on its own pixels, which fit the photo together to {:.4} (the fit above is of one BRDF for the whole part):",
                    r.materials.len(),
                    r.split_fit.unwrap_or(f64::NAN)
                ));
                lines.extend(r.materials.iter().map(|p| {
                    format!(
                        "  {}: {:.0}% of the pixels, fit to its photo {:.4} ({}); its results in result/{}/",
                        p.folder.replace('-', " "),
                        100.0 * p.share,
                        p.fit_error,
                        brdfd_core::estimate::fit_verdict(p.fit_error),
                        p.folder
                    )
                }));
            }
        }
        None if m.state != State::Done => lines.push(format!(
            "no estimate yet: `brdfd session resume {}` continues it",
            m.id
        )),
        None => {}
    }
    lines
}

/// Cancels through the daemon when one runs; else records a session that a vanished process
/// left capturing as interrupted, so that it can be resumed.
fn cancel(state: &Path, id: &str, daemon: &super::capture::DaemonArgs) -> anyhow::Result<()> {
    if let Some(d) = daemon.running(&daemon.config()?)? {
        d.cancel(id)?;
        println!("asked the daemon to stop {id} at its next step; what was captured is kept");
        return Ok(());
    }
    let mut s = Session::open(state, id)?;
    if matches!(s.manifest().state, State::Done | State::Failed) {
        println!("session {id} is already {}", s.manifest().state);
        return Ok(());
    }
    // Another process capturing it holds the claim: only it can stop cleanly.
    let _claim = s.claim().with_context(|| {
        format!("session {id} is being captured by another process: press Ctrl-C there")
    })?;
    s.set_state(
        State::Failed,
        Some("cancelled by `brdfd session cancel`; what was captured is kept".into()),
    )?;
    println!("session {id} recorded as interrupted: `brdfd session resume {id}` continues it");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::match_id;

    #[test]
    fn a_unique_start_of_an_id_or_of_its_last_part_names_the_session() {
        let ids = [
            "20261122-233000-gold-3f2a1b".to_string(),
            "20261122-233500-gold-3f9c00".to_string(),
            "20261123-080000-chrome-a0c4e2".to_string(),
        ];
        assert_eq!(match_id(&ids, "20261123"), Ok(ids[2].as_str()));
        assert_eq!(match_id(&ids, "3f2a"), Ok(ids[0].as_str()));
        assert_eq!(match_id(&ids, "a0c"), Ok(ids[2].as_str()));
        let e = match_id(&ids, "3f").unwrap_err();
        assert!(
            e.contains("begins 2 session ids") && e.contains("give more"),
            "{e}"
        );
        let e = match_id(&ids, "20261122").unwrap_err();
        assert!(e.contains(&ids[0]) && e.contains(&ids[1]), "{e}");
        let e = match_id(&ids, "ffff").unwrap_err();
        assert!(e.contains("no session id starts with \"ffff\""), "{e}");
    }
}
