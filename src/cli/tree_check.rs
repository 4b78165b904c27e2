//! Checks of the command line as a whole, walked through clap's command tree: every option and
//! subcommand a user can see says what it is for, no command has two options on one short
//! flag, and `--help` lists the command a new user wants first (issue 42).
//!
//! clap makes some of these checks itself, but only in debug builds, and the tests run in
//! release.

use std::collections::HashMap;

use clap::CommandFactory;

use super::Cli;

/// `--out`, `-o`, or a positional's `<FILES>`: the argument as `--help` shows it.
fn shown(a: &clap::Arg) -> String {
    match (a.get_long(), a.get_short()) {
        (Some(l), _) => format!("--{l}"),
        (None, Some(s)) => format!("-{s}"),
        (None, None) => format!("<{}>", a.get_id().as_str().to_uppercase()),
    }
}

/// What `cmd` and everything under it lack: options and subcommands without help, and short
/// flags that two options of one command share (clap would take the first in a release
/// build, and the second would be unreachable by it).
fn walk(cmd: &clap::Command, path: &str, problems: &mut Vec<String>) {
    let mut shorts: HashMap<char, String> = HashMap::new();
    for a in cmd.get_arguments().filter(|a| !a.is_hide_set()) {
        if a.get_help().is_none() && a.get_long_help().is_none() {
            problems.push(format!("`{path} {}` has no help text", shown(a)));
        }
        if let Some(s) = a.get_short() {
            if let Some(other) = shorts.insert(s, shown(a)) {
                problems.push(format!("`{path}`: -{s} is both {other} and {}", shown(a)));
            }
        }
    }
    for sub in cmd.get_subcommands().filter(|s| !s.is_hide_set()) {
        let sub_path = format!("{path} {}", sub.get_name());
        if sub.get_about().is_none() && sub.get_long_about().is_none() {
            problems.push(format!("`{sub_path}` has no help text"));
        }
        walk(sub, &sub_path, problems);
    }
}

#[test]
fn every_visible_argument_and_subcommand_has_help_and_shorts_do_not_clash() {
    let mut cmd = Cli::command();
    // Built, so that global options (`session --state-dir`) are in every subcommand they
    // reach, and clap's own `--help` and `help` are there as a user meets them.
    cmd.build();
    let mut problems = Vec::new();
    walk(&cmd, "brdfd", &mut problems);
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

#[test]
fn help_lists_capture_first() {
    let help = Cli::command().render_help().to_string();
    let first = help
        .lines()
        .skip_while(|l| !l.starts_with("Commands:"))
        .nth(1)
        .unwrap_or_default();
    assert!(first.trim_start().starts_with("capture "), "{help}");
}

#[test]
fn common_options_have_their_conventional_short_flags() {
    let cmd = Cli::command();
    let short = |path: &[&str], long: &str| {
        let mut c = &cmd;
        for p in path {
            c = c
                .find_subcommand(p)
                .unwrap_or_else(|| panic!("no subcommand {p}"));
        }
        c.get_arguments()
            .find(|a| a.get_long() == Some(long))
            .unwrap_or_else(|| panic!("brdfd {} has no --{long}", path.join(" ")))
            .get_short()
    };
    assert_eq!(short(&["capture"], "material"), Some('m'));
    assert_eq!(short(&["capture"], "rig"), Some('r'));
    assert_eq!(short(&["capture"], "out"), Some('o'));
    assert_eq!(short(&["capture"], "verbose"), Some('v'));
    assert_eq!(short(&["estimate"], "out"), Some('o'));
    assert_eq!(short(&["render"], "out"), Some('o'));
    assert_eq!(short(&["serve"], "rig"), Some('r'));
    assert_eq!(short(&["serve"], "config"), Some('c'));
    assert_eq!(short(&["ptp", "info"], "port"), Some('p'));
    assert_eq!(short(&["theta", "capture"], "port"), Some('p'));
    assert_eq!(short(&["serial", "rotate"], "port"), Some('p'));
}
