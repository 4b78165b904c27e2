//! `brdfd config check`: validate configuration files before a session uses them.

use std::path::PathBuf;

use anyhow::bail;
use brdfd::config::{DaemonConfig, MaterialPreset, Rig};
use brdfd::core::geometry::SceneGeometry;

#[derive(clap::Subcommand)]
pub enum ConfigCommand {
    /// Check files: `brdfd.toml`, `rigs/*.toml`, `materials/*.toml`, `geometry/*.toml`
    /// (the kind comes from the file's folder or name).
    Check { files: Vec<PathBuf> },
}

pub fn run(cmd: ConfigCommand) -> anyhow::Result<()> {
    let ConfigCommand::Check { files } = cmd;
    if files.is_empty() {
        bail!("name the files to check, for example config/rigs/*.toml");
    }
    let mut failed = 0;
    for f in &files {
        let folder = f
            .parent()
            .and_then(|p| p.file_name())
            .and_then(|n| n.to_str())
            .unwrap_or("");
        let result: anyhow::Result<String> = match folder {
            "rigs" => Rig::read(f).map(|r| {
                format!(
                    "rig{}: dslr {}, theta {}, turntable {}",
                    if r.simulated { " (simulated)" } else { "" },
                    r.devices.dslr.map_or("-".into(), |s| s.to_string()),
                    r.devices.theta.map_or("-".into(), |s| s.to_string()),
                    r.devices.turntable.map_or("-".into(), |s| s.to_string())
                )
            }).map_err(Into::into),
            "materials" => MaterialPreset::read(f)
                .map(|m| format!("material preset, simulated as {}", m.simulate_as))
                .map_err(Into::into),
            "geometry" => SceneGeometry::read(f)
                .map(|_| "geometry".to_string())
                .map_err(Into::into),
            _ if f.file_name().is_some_and(|n| n == "brdfd.toml") => DaemonConfig::read(f)
                .map(|d| format!("daemon settings, API on {}", d.api))
                .map_err(Into::into),
            _ => Err(anyhow::anyhow!(
                "cannot tell what kind of file this is: put it in rigs/, materials/ or geometry/, or name it brdfd.toml"
            )),
        };
        match result {
            Ok(what) => println!("ok  {}: {what}", f.display()),
            Err(e) => {
                failed += 1;
                println!("ERR {e:#}");
            }
        }
    }
    if failed > 0 {
        bail!("{failed} of {} files have errors", files.len());
    }
    Ok(())
}
