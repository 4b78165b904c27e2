//! `brdfd config check`: validate configuration files before a session uses them.
//!
//! A file's kind comes from `--kind`, else from where it sits (`rigs/`, `materials/`,
//! `geometry/`, `brdfd.toml`), else from its content, so a rig copied to `my-rig.toml` is still
//! a rig. Every error in a file is reported, not only the first: after a syntax or type error
//! on a line, that line is set aside and the file read again; once it reads, every value that
//! makes no sense is reported, each with its line and field.

use std::path::{Path, PathBuf};

use anyhow::bail;
use brdfd_core::geometry::SceneGeometry;
use brdfd_rig::calibrate::Target;
use brdfd_rig::config::{ConfigError, DaemonConfig, MaterialPreset, Rig};

#[derive(clap::Subcommand)]
pub enum ConfigCommand {
    /// Check files: daemon settings (`brdfd.toml`), rigs, material presets, geometry and
    /// calibration targets. The
    /// kind comes from --kind, else the file's folder or name, else its content.
    Check {
        /// The files to check.
        files: Vec<PathBuf>,
        /// What the files are, when neither their place nor their content says.
        #[arg(long, value_enum)]
        kind: Option<Kind>,
    },
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Kind {
    Rig,
    Material,
    Geometry,
    /// A calibration target (`brdfd calibrate radiometry --target`).
    Target,
    Daemon,
}

/// At most this many errors are listed per file.
const MAX_ERRORS: usize = 20;

impl Kind {
    /// From the folder the file sits in, or its name.
    fn of_path(path: &Path) -> Option<Kind> {
        let folder = path
            .parent()
            .and_then(|p| p.file_name())
            .and_then(|n| n.to_str());
        match folder {
            Some("rigs") => Some(Kind::Rig),
            Some("materials") => Some(Kind::Material),
            Some("geometry") => Some(Kind::Geometry),
            Some("targets") => Some(Kind::Target),
            _ if path.file_name().is_some_and(|n| n == "brdfd.toml") => Some(Kind::Daemon),
            _ => None,
        }
    }

    /// From the keys only one kind has at the top of the file.
    fn of_text(text: &str) -> Option<Kind> {
        let table: toml::Table = toml::from_str(text).ok()?;
        let has = |k: &str| table.contains_key(k);
        if has("devices") || has("brackets") || has("geometry") {
            Some(Kind::Rig)
        } else if has("simulate_as") {
            Some(Kind::Material)
        } else if has("camera") {
            Some(Kind::Geometry)
        } else if has("albedo") {
            Some(Kind::Target)
        } else if has("api") || has("state_dir") || has("token") {
            Some(Kind::Daemon)
        } else {
            None
        }
    }

    /// A one-line description of a valid file; else its syntax or type error, or every value
    /// in it that makes no sense, located.
    fn check(self, file: &str, text: &str) -> Result<String, Vec<ConfigError>> {
        // In the file's order, as they are read and fixed.
        let located = |found: Vec<ConfigError>| -> Vec<ConfigError> {
            let mut found: Vec<ConfigError> = found.into_iter().map(|e| e.locate(text)).collect();
            found.sort_by_key(|e| match e {
                ConfigError::Invalid { line: Some(l), .. } => *l,
                _ => usize::MAX,
            });
            found
        };
        let one = |e: ConfigError| vec![e.locate(text)];
        match self {
            Kind::Rig => {
                let r = Rig::parse_unchecked(file, text).map_err(one)?;
                // Accepted only if the capture can run it too: its devices in their roles,
                // and every camera's gain.
                let mut found = r.problems();
                let (roles, more) = brdfd_rig::plan::problems(&r);
                found.extend(more);
                if found.is_empty() {
                    Ok(describe_rig(&r, &roles))
                } else {
                    Err(located(found))
                }
            }
            Kind::Material => MaterialPreset::parse_all(file, text)
                .map(|m| format!("material preset, simulated as {}", m.simulate_as)),
            Kind::Geometry => {
                brdfd_rig::config::parse::<SceneGeometry>(file, text)
                    .and_then(|mut g| {
                        // The checks a rig's [geometry] gets (issue 40: `fx = nan` passed here).
                        g.check().map_err(|e| {
                            brdfd_rig::config::invalid(
                                file,
                                brdfd_rig::config::geometry_field("", &e),
                                e,
                            )
                        })?;
                        // A mesh is read and checked as the capture reads it, beside the file.
                        let dir = Path::new(file).parent().unwrap_or(Path::new("."));
                        g.resolve_files(dir);
                        let mesh = g
                            .shape
                            .as_ref()
                            .map(|s| s.mesh())
                            .transpose()
                            .map_err(|e| {
                                brdfd_rig::config::invalid(file, "shape.file", e.to_string())
                            })?;
                        Ok(match mesh.flatten() {
                            Some(m) => {
                                format!("geometry, a mesh of {} triangles", m.triangles.len())
                            }
                            None => "geometry".to_string(),
                        })
                    })
                    .map_err(one)
            }
            Kind::Target => brdfd_rig::config::parse::<Target>(file, text)
                .and_then(|t| {
                    t.check(file)?;
                    Ok(format!("calibration target, albedo {:?}", t.albedo.0))
                })
                .map_err(one),
            Kind::Daemon => DaemonConfig::parse(file, text)
                .map(|d| format!("daemon settings, API on {}", d.api))
                .map_err(one),
        }
    }
}

/// A valid rig in a line: what plays each role.
fn describe_rig(r: &Rig, roles: &brdfd_rig::plan::Roles) -> String {
    let named = |s: &Option<brdfd_rig::selector::Selector>, simulated: bool| match s {
        Some(s) => s.to_string(),
        None if simulated => "simulated".into(),
        None => "-".into(),
    };
    let d = &r.devices;
    let sim = r.simulated;
    let turning = if roles.turntable {
        format!("turntable {}", named(&d.turntable, sim))
    } else {
        "turned by hand".into()
    };
    let shutter = if roles.shutter {
        format!(", shutter {}", named(&d.shutter, sim))
    } else {
        String::new()
    };
    format!(
        "rig{}: dslr {}, fallback camera {}, theta {}, {turning}{shutter}",
        if sim { " (simulated)" } else { "" },
        if roles.dslr {
            named(&d.dslr, sim)
        } else {
            "-".into()
        },
        named(&d.fallback_camera, false),
        named(&d.theta, sim),
    )
}

/// The file's description if it is valid, else every error found in it.
fn check_file(kind: Kind, file: &str, text: &str) -> Result<String, Vec<ConfigError>> {
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    let mut errors = Vec::new();
    // Keys set aside: a later "missing field" for one of them is our doing, not the file's.
    let mut set_aside: Vec<String> = Vec::new();
    loop {
        let e = match kind.check(file, &(lines.join("\n") + "\n")) {
            Ok(what) if errors.is_empty() => return Ok(what),
            Ok(_) => return Err(errors),
            // The values' mistakes: the file reads, so they are all there is left to say.
            Err(found)
                if found
                    .iter()
                    .any(|e| !matches!(e, ConfigError::Parse { .. })) =>
            {
                errors.extend(found);
                return Err(errors);
            }
            Err(mut found) => found.remove(0),
        };
        if set_aside
            .iter()
            .any(|k| e.to_string().contains(&format!("missing field `{k}`")))
        {
            return Err(errors);
        }
        // Set the line aside (as a comment, so that later lines keep their numbers) and read
        // on. Only a whole `key = value` line can go without changing what the rest means: an
        // error elsewhere (a table header, inside a multi-line value, or with no line) ends
        // the list.
        let line = match &e {
            ConfigError::Parse { line: Some(l), .. } => Some(*l),
            _ => None,
        };
        errors.push(e);
        match line {
            Some(l)
                if errors.len() < MAX_ERRORS
                    && lines.get(l - 1).is_some_and(|t| a_whole_key_value(t)) =>
            {
                if let Some((key, _)) = lines[l - 1].split_once('=') {
                    set_aside.push(key.trim().to_string());
                }
                lines[l - 1].insert(0, '#');
            }
            _ => return Err(errors),
        }
    }
}

/// Whether a line is a complete `key = value` on its own (not a header, not part of a value
/// that spans lines, not already a comment).
fn a_whole_key_value(line: &str) -> bool {
    let t = line.trim_start();
    !t.starts_with('[')
        && !t.starts_with('#')
        && toml::from_str::<toml::Table>(line).is_ok_and(|table| table.len() == 1)
}

pub fn run(cmd: ConfigCommand) -> anyhow::Result<()> {
    let ConfigCommand::Check { files, kind } = cmd;
    if files.is_empty() {
        bail!("name the files to check, for example config/rigs/*.toml");
    }
    let mut failed = 0;
    for f in &files {
        let file = f.display().to_string();
        let text = match std::fs::read_to_string(f) {
            Ok(t) => t,
            Err(e) => {
                failed += 1;
                println!("ERR {file}: {e}");
                continue;
            }
        };
        let Some(kind) = kind
            .or_else(|| Kind::of_path(f))
            .or_else(|| Kind::of_text(&text))
        else {
            failed += 1;
            println!(
                "ERR {file}: cannot tell what kind of file this is (no [devices], simulate_as, \
                 [camera], albedo or api in it): give --kind rig|material|geometry|target|daemon"
            );
            continue;
        };
        match check_file(kind, &file, &text) {
            Ok(what) => println!("ok  {file}: {what}"),
            Err(errors) => {
                failed += 1;
                for e in errors {
                    println!("ERR {e}");
                }
            }
        }
    }
    if failed > 0 {
        bail!("{failed} of {} files have errors", files.len());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const RIG: &str = include_str!("../../config/rigs/bench.toml");
    /// The bench rig with every camera's gain, as `calibrate radiometry` would write them.
    const GAINS: &str = "\n[calibration.theta]\ngain = 1.0\n[calibration.dslr_raw]\ngain = 10.0\n[calibration.dslr_jpeg]\ngain = 10.0\n[calibration.fallback]\ngain = 0.6\n";

    #[test]
    fn a_copied_file_is_known_by_its_content() {
        assert_eq!(Kind::of_text(RIG), Some(Kind::Rig));
        let preset = include_str!("../../config/materials/gold.toml");
        assert_eq!(Kind::of_text(preset), Some(Kind::Material));
        let geometry = include_str!("../../config/geometry/eval-sphere.toml");
        assert_eq!(Kind::of_text(geometry), Some(Kind::Geometry));
        assert_eq!(
            Kind::of_text(include_str!("../../config/brdfd.toml")),
            Some(Kind::Daemon)
        );
        assert_eq!(Kind::of_text("x = 1\n"), None);
    }

    #[test]
    fn every_error_is_reported_with_its_line() {
        let calibrated = format!("{RIG}{GAINS}");
        let broken = calibrated
            .replace("dslr_iso = 100", "dslr_iso = \"a hundred\"")
            .replace("theta_iso = 100", "theta_iso = 100\nflash = true");
        let errors = check_file(Kind::Rig, "my-rig.toml", &broken).unwrap_err();
        let line_of = |needle: &str| broken.lines().position(|l| l.contains(needle)).unwrap() + 1;
        let lines: Vec<Option<usize>> = errors
            .iter()
            .map(|e| match e {
                ConfigError::Parse { line, .. } => *line,
                _ => None,
            })
            .collect();
        assert_eq!(
            lines,
            [Some(line_of("a hundred")), Some(line_of("flash"))],
            "{errors:?}"
        );
        assert!(errors[1].to_string().contains("flash"), "{}", errors[1]);
        assert!(check_file(Kind::Rig, "bench.toml", &calibrated).is_ok());
        // The shipped template is not calibrated: it says what to run.
        let errors = check_file(Kind::Rig, "bench.toml", RIG).unwrap_err();
        assert!(
            errors[0].to_string().contains("brdfd calibrate radiometry"),
            "{errors:?}"
        );
        // An unknown table: setting its header aside would move its keys into the table
        // above and report errors the file does not have, so the list ends there.
        let header = RIG.replace("[brackets]", "[flash]\nbright = 1\n\n[brackets]");
        let errors = check_file(Kind::Rig, "my-rig.toml", &header).unwrap_err();
        assert_eq!(errors.len(), 1, "{errors:?}");
        assert!(errors[0].to_string().contains("flash"), "{}", errors[0]);
    }
}
