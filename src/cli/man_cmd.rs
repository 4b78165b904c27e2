//! `brdfd man`: one man page per command, into the user's man path by default. The pages are
//! clap_mangen's, dated and titled as man(7) asks, and cleaned of the spacing it writes that
//! mandoc's lint flags. It does not compress the pages or update man's index database: man-db
//! finds a new page in a folder on its path without one.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use anyhow::Context;
use clap::Args;

#[derive(Args)]
pub struct ManArgs {
    /// Folder to write the pages into [default: $XDG_DATA_HOME/man/man1, else
    /// ~/.local/share/man/man1]
    #[arg(value_name = "DIR")]
    dir: Option<PathBuf>,
    /// The folder, given as an option (the same as DIR)
    #[arg(long, value_name = "DIR", conflicts_with = "dir")]
    out: Option<PathBuf>,
}

/// The build's date (build.rs: SOURCE_DATE_EPOCH when set, so that a reproducible build
/// writes the same pages), as `.TH` wants it.
const BUILD_DATE: &str = env!("BRDFD_BUILD_DATE");

pub fn run(a: ManArgs, cmd: clap::Command) -> anyhow::Result<()> {
    let dir = match a.dir.or(a.out) {
        Some(d) => d,
        None => user_man_dir()?,
    };
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let mut cmd = cmd.disable_help_subcommand(true);
    cmd.build();
    let source = format!("brdfd {}", env!("CARGO_PKG_VERSION"));
    let mut written = 0;
    write_pages(&cmd, &dir, &source, &mut written)?;
    println!("{written} man pages in {}", dir.display());
    match man_root(&dir) {
        Some(root) if on_man_path(root) == Some(false) => println!(
            "man does not look in {0} yet: add `export MANPATH=\"{0}:$MANPATH\"` to your \
             shell's profile",
            root.display()
        ),
        Some(_) => println!("try: man brdfd"),
        None => println!("try: man -l {}", dir.join("brdfd.1").display()),
    }
    Ok(())
}

/// `$XDG_DATA_HOME/man/man1`, else `~/.local/share/man/man1`: the user's own man path, the
/// one man-db searches for a user whose PATH holds ~/.local/bin.
fn user_man_dir() -> anyhow::Result<PathBuf> {
    // The XDG spec says a relative value is invalid and to be ignored.
    let data = std::env::var_os("XDG_DATA_HOME")
        .map(PathBuf::from)
        .filter(|p| p.is_absolute())
        .or_else(|| {
            std::env::var_os("HOME")
                .filter(|h| !h.is_empty())
                .map(|h| PathBuf::from(h).join(".local/share"))
        })
        .context("no user man path: give a folder (brdfd man DIR) or set HOME")?;
    Ok(data.join("man/man1"))
}

/// The pages of `cmd` and of every visible subcommand, as clap_mangen's `generate_to` names
/// them (`brdfd-session-show.1`), which is what the systemd unit's `man:` link looks up.
fn write_pages(
    cmd: &clap::Command,
    dir: &Path,
    source: &str,
    written: &mut usize,
) -> anyhow::Result<()> {
    for sub in cmd.get_subcommands().filter(|s| !s.is_hide_set()) {
        write_pages(sub, dir, source, written)?;
    }
    let man = clap_mangen::Man::new(cmd.clone())
        .title(
            cmd.get_display_name()
                .unwrap_or(cmd.get_name())
                .to_uppercase(),
        )
        .date(BUILD_DATE)
        .source(source)
        .manual("User Commands");
    let mut page = Vec::new();
    man.render(&mut page)?;
    let path = dir.join(man.get_filename());
    std::fs::write(&path, tidy(&String::from_utf8(page)?))
        .with_context(|| format!("writing {}", path.display()))?;
    *written += 1;
    Ok(())
}

/// clap_mangen separates an option's help from its possible values with a break, an empty
/// line (a paragraph space) and another break, and writes an empty line for an option without
/// help; a break next to a space does nothing, and mandoc's lint warns about each. One `.sp`,
/// or the break alone, gives the same page.
fn tidy(page: &str) -> String {
    page.replace("\n.br\n\n.br\n", "\n.sp\n")
        .replace("\n\n.br\n", "\n.br\n")
}

/// The man path entry a `manN` folder belongs to, or `None` for a folder man cannot search.
fn man_root(dir: &Path) -> Option<&Path> {
    let name = dir.file_name()?.to_str()?;
    let section = name.strip_prefix("man")?;
    (!section.is_empty() && section.chars().all(|c| c.is_ascii_alphanumeric()))
        .then(|| dir.parent())
        .flatten()
}

/// Whether `manpath` lists `root`; `None` where there is no `manpath` to ask.
fn on_man_path(root: &Path) -> Option<bool> {
    let out = Command::new("manpath")
        .stdin(Stdio::null())
        .stderr(Stdio::null())
        .output()
        .ok()
        .filter(|o| o.status.success())?;
    let listed = String::from_utf8_lossy(&out.stdout);
    let root = std::fs::canonicalize(root).unwrap_or_else(|_| root.to_path_buf());
    Some(
        listed
            .trim()
            .split(':')
            .any(|p| std::fs::canonicalize(p).is_ok_and(|p| p == root) || Path::new(p) == root),
    )
}
