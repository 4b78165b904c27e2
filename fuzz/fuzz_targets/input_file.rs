//! For targets whose reader takes a path: the input written to a file of a given extension
//! in one temporary folder for the whole run.

use std::path::PathBuf;
use std::sync::OnceLock;

pub fn write(ext: &str, data: &[u8]) -> PathBuf {
    static DIR: OnceLock<tempfile::TempDir> = OnceLock::new();
    let dir = DIR.get_or_init(|| tempfile::tempdir().expect("a temporary folder"));
    let path = dir.path().join(format!("input.{ext}"));
    std::fs::write(&path, data).expect("the temporary file is written");
    path
}
