//! For targets whose reader takes a path: the input written to a file of a given extension
//! in one temporary folder for the whole run.

use std::io::Write;
use std::path::PathBuf;
use std::sync::OnceLock;

pub fn write(ext: &str, data: &[u8]) -> PathBuf {
    static DIR: OnceLock<tempfile::TempDir> = OnceLock::new();
    let dir = DIR.get_or_init(|| {
        // In memory where there is a tmpfs: a file on disk rewritten at every execution costs
        // the disk's time, not ours.
        tempfile::tempdir_in("/dev/shm")
            .or_else(|_| tempfile::tempdir())
            .expect("a temporary folder")
    });
    let path = dir.path().join(format!("input.{ext}"));
    // Written over, then cut to its length, rather than truncated first (`fs::write`): ext4
    // flushes a file truncated to zero and rewritten when it is closed (auto_da_alloc), which
    // made every execution wait for the disk (300 a second instead of thousands).
    let mut file = std::fs::OpenOptions::new()
        .write(true)
        .create(true)
        .truncate(false)
        .open(&path)
        .expect("the temporary file opens");
    file.write_all(data).expect("the temporary file is written");
    file.set_len(data.len() as u64)
        .expect("the temporary file is cut to the input's length");
    path
}
