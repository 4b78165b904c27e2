//! Helpers for the integration tests that run the real binary, as a user would.

// Each test file uses some of these, and Rust builds this module into each one.
#![allow(dead_code)]

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Output, Stdio};

/// Runs `brdfd ARGS` in `dir` and waits for it.
pub fn brdfd(args: &[&str], dir: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_brdfd"))
        .args(args)
        .current_dir(dir)
        .output()
        .expect("brdfd runs")
}

/// Standard output and standard error.
pub fn text(o: &Output) -> (String, String) {
    (
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

/// Both streams in one string, for matching messages wherever they went.
pub fn out(o: &Output) -> String {
    let (a, b) = text(o);
    a + &b
}

/// A `brdfd sim ...` process, stopped when dropped.
pub struct Simulator {
    child: Child,
    /// The last word of the simulator's first line: the address or path to connect to.
    pub addr: String,
}

impl Simulator {
    /// Starts `brdfd ARGS` and waits for the line it prints when it is ready.
    pub fn start(args: &[&str]) -> Simulator {
        let mut child = Command::new(env!("CARGO_BIN_EXE_brdfd"))
            .args(args)
            .stdout(Stdio::piped())
            .spawn()
            .expect("brdfd sim starts");
        let mut line = String::new();
        BufReader::new(child.stdout.take().expect("piped stdout"))
            .read_line(&mut line)
            .expect("the simulator prints its address");
        let addr = line.trim().rsplit(' ').next().unwrap_or("").to_string();
        Simulator { child, addr }
    }
}

impl Drop for Simulator {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}
