//! RAW files decoded in a child process, bounded in memory and time.
//!
//! The structure check ([`super::tiff`]) refuses the files known to take a decoder down, but
//! the decoder (rawler) is large, and a file it mishandles in a way not yet known could still
//! make it allocate without bound or loop. In the daemon's own process that would abort a
//! capture's process and every session it serves. So the `brdfd` binary decodes each RAW file
//! in a child, `brdfd decode-raw`, that gets the file on stdin, limits its own address space,
//! and writes the decoded frame to stdout; the parent kills it past its time. A child that
//! runs out of either fails that file with a clear error, and the capture's process lives on.
//!
//! The library decodes in-process unless [`use_child_processes`] was called (the binary does,
//! at startup).

use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use brdfd_core::raster::Raster;

use super::{Exposure, Frame, RadiometryError, WhiteBalance};

/// The program that decodes: `<program> decode-raw`.
static PROGRAM: OnceLock<PathBuf> = OnceLock::new();

/// Decode RAW files in child processes of `program` (the `brdfd` binary) from now on.
pub fn use_child_processes(program: PathBuf) {
    let _ = PROGRAM.set(program);
}

/// The child process's program, if RAW files are decoded in one.
pub fn program() -> Option<&'static Path> {
    PROGRAM.get().map(PathBuf::as_path)
}

/// What one decode may use.
#[derive(Debug, Clone, Copy)]
pub struct Budget {
    /// Address space of the child, bytes.
    pub memory: u64,
    pub time: Duration,
}

impl Budget {
    /// For a file of `len` bytes: 1 GiB for the process, and 64 bytes per byte of file. A
    /// decoded frame takes about 14 bytes per sensor pixel (the sensor's values, then three
    /// floats), and a camera's file holds at least a byte per pixel. Two minutes: a 24 MP file
    /// decodes in about a second on 2 cores.
    pub fn for_file(len: usize) -> Budget {
        Budget {
            memory: (1 << 30) + 64 * len as u64,
            time: Duration::from_secs(120),
        }
    }
}

/// The frame on the wire from child to parent: a tag, then little-endian numbers.
const TAG: &[u8; 8] = b"BRDFDFR1";
/// What a child exits with when the file cannot be decoded (its reason on stderr).
pub const UNDECODABLE: i32 = 3;

/// Decodes `bytes` in a child of `program` within `budget`.
pub fn decode(
    program: &Path,
    bytes: &[u8],
    file: &str,
    wb: WhiteBalance,
    budget: Budget,
) -> Result<Frame, RadiometryError> {
    let mut command = Command::new(program);
    // `--name=…`: a camera's file name may start with a dash.
    command.args([
        "decode-raw".to_string(),
        format!("--name={file}"),
        format!("--memory-bytes={}", budget.memory),
        format!("--seconds={}", budget.time.as_secs().max(1)),
    ]);
    if let WhiteBalance::Fixed([r, g, b]) = wb {
        command.arg(format!("--white-balance={r},{g},{b}"));
    }
    // The child's first words on stderr are its cause, not a log line. Its address space is
    // what the budget bounds: few malloc arenas and threads keep the reserved part small on a
    // machine with many cores.
    let threads = std::thread::available_parallelism().map_or(2, |n| n.get().min(8));
    command
        .env_remove("BRDFD_LOG")
        .env("MALLOC_ARENA_MAX", "2")
        .env("RAYON_NUM_THREADS", threads.to_string());
    let mut child = command
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| {
            RadiometryError::decode(file, format!("RAW: cannot start the decoder process: {e}"))
        })?;
    let (mut stdin, mut stdout, mut stderr) = (
        child.stdin.take().expect("piped stdin"),
        child.stdout.take().expect("piped stdout"),
        child.stderr.take().expect("piped stderr"),
    );
    let started = Instant::now();
    let (status, frame, err) = std::thread::scope(|s| {
        // A child that dies early closes its stdin: the write then fails, and its status
        // says why.
        s.spawn(move || {
            let _ = stdin.write_all(bytes);
        });
        let frame = s.spawn(move || read_frame(&mut stdout));
        let err = s.spawn(move || {
            let mut v = String::new();
            let _ = stderr.read_to_string(&mut v);
            v
        });
        let status = loop {
            let stop = match child.try_wait() {
                Ok(Some(status)) => break Ok(status),
                Ok(None) if started.elapsed() > budget.time => format!(
                    "RAW: the decoder took longer than {} on this file, and was stopped",
                    humantime::format_duration(budget.time)
                ),
                Ok(None) => {
                    std::thread::sleep(Duration::from_millis(5));
                    continue;
                }
                Err(e) => format!("RAW: waiting for the decoder: {e}"),
            };
            // Killed, so that its pipes close and the threads above end.
            let _ = child.kill();
            let _ = child.wait();
            break Err(stop);
        };
        (
            status,
            frame.join().expect("the reader does not panic"),
            err.join().expect("the reader does not panic"),
        )
    });
    let status = status.map_err(|e| RadiometryError::decode(file, e))?;
    let first_line = err
        .lines()
        .map(str::trim)
        .find(|l| !l.is_empty())
        .unwrap_or("no message");
    if status.code() == Some(UNDECODABLE) {
        // The child's own words: `file: reason`, as RadiometryError prints it.
        let reason = first_line.trim_start_matches(&format!("{file}: "));
        return Err(RadiometryError::decode(file, reason));
    }
    if !status.success() {
        // An allocation past the budget aborts: Rust says so on stderr, then SIGABRT.
        let reason = if first_line.starts_with("memory allocation of") {
            format!(
                "RAW: the decoder needed more than its {} MB of memory on this file, and was \
                 stopped ({first_line})",
                budget.memory >> 20
            )
        } else {
            let how = match status.code() {
                Some(code) => format!("exited with status {code}"),
                None => "was stopped by a signal".to_string(),
            };
            format!("RAW: the decoder {how} on this file ({first_line})")
        };
        return Err(RadiometryError::decode(file, reason));
    }
    match frame {
        Ok(Some(frame)) => Ok(frame),
        Ok(None) => Err(RadiometryError::decode(
            file,
            "RAW: the decoder's answer is cut short",
        )),
        Err(e) => Err(RadiometryError::decode(
            file,
            format!("RAW: reading the decoder: {e}"),
        )),
    }
}

/// The child's side: decodes `bytes` in this process and writes the frame to `out`.
pub fn write_frame(frame: &Frame, out: &mut impl Write) -> std::io::Result<()> {
    let mut head = Vec::with_capacity(64);
    head.extend(TAG);
    head.extend((frame.values.width as u64).to_le_bytes());
    head.extend((frame.values.height as u64).to_le_bytes());
    for v in [
        frame.exposure.shutter_s,
        frame.exposure.f_number,
        frame.exposure.iso,
    ] {
        head.extend(v.to_le_bytes());
    }
    for v in frame.white_balance {
        head.extend(v.to_le_bytes());
    }
    let mut out = std::io::BufWriter::new(out);
    out.write_all(&head)?;
    for v in frame.values.pixels.iter().flatten() {
        out.write_all(&v.to_le_bytes())?;
    }
    out.flush()
}

/// A frame from the child: its header, then exactly its pixels, read into one buffer of
/// their size. `None` if the answer is cut short or says more than its header.
fn read_frame(r: &mut impl Read) -> std::io::Result<Option<Frame>> {
    let mut head = [0u8; 8 + 8 + 8 + 3 * 8 + 3 * 4];
    if !read_all(r, &mut head)? || &head[..8] != TAG {
        return Ok(None);
    }
    let u64_ = |at: usize| u64::from_le_bytes(head[at..at + 8].try_into().expect("8 bytes"));
    let f64_ = |at: usize| f64::from_le_bytes(head[at..at + 8].try_into().expect("8 bytes"));
    let f32_ = |at: usize| f32::from_le_bytes(head[at..at + 4].try_into().expect("4 bytes"));
    let (width, height) = (u64_(8) as usize, u64_(16) as usize);
    let exposure = Exposure {
        shutter_s: f64_(24),
        f_number: f64_(32),
        iso: f64_(40),
    };
    let white_balance = [f32_(48), f32_(52), f32_(56)];
    // No larger than a RAW file's image may be (the structure check's limit).
    let n = width.saturating_mul(height);
    if n as u64 > super::tiff::MAX_PIXELS {
        return Ok(None);
    }
    let mut bytes = vec![0u8; n * 12];
    if !read_all(r, &mut bytes)? || r.read(&mut [0u8; 1])? != 0 {
        return Ok(None);
    }
    let f = |p: &[u8]| f32::from_le_bytes(p.try_into().expect("4 bytes"));
    let pixels = bytes
        .chunks_exact(12)
        .map(|p| [f(&p[0..4]), f(&p[4..8]), f(&p[8..12])])
        .collect();
    Ok(Some(Frame {
        values: Raster {
            width,
            height,
            pixels,
        },
        exposure,
        white_balance,
    }))
}

/// Fills `buf`; false if the stream ends first.
fn read_all(r: &mut impl Read, buf: &mut [u8]) -> std::io::Result<bool> {
    match r.read_exact(buf) {
        Ok(()) => Ok(true),
        Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => Ok(false),
        Err(e) => Err(e),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_frame_crosses_the_pipe_exactly_and_a_cut_one_is_refused() {
        let frame = Frame {
            values: Raster {
                width: 2,
                height: 1,
                pixels: vec![[0.25, 1.0, f32::MIN_POSITIVE], [0.0, 0.5, 0.75]],
            },
            exposure: Exposure {
                shutter_s: 1.0 / 250.0,
                f_number: 8.0,
                iso: 200.0,
            },
            white_balance: [2.0, 1.0, 1.5],
        };
        let mut wire = Vec::new();
        write_frame(&frame, &mut wire).unwrap();
        let back = read_frame(&mut &wire[..]).unwrap().unwrap();
        assert_eq!(back.values.pixels, frame.values.pixels);
        assert_eq!(back.exposure, frame.exposure);
        assert_eq!(back.white_balance, frame.white_balance);
        assert!(read_frame(&mut &wire[..wire.len() - 1]).unwrap().is_none());
        assert!(read_frame(&mut &b"BRDFDFR1"[..]).unwrap().is_none());
        let mut longer = wire.clone();
        longer.push(0);
        assert!(read_frame(&mut &longer[..]).unwrap().is_none());
    }
}
