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

use super::raw::WhiteBalance;
use super::{Exposure, Frame, RadiometryError};

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

fn decode_error(file: &str, reason: impl std::fmt::Display) -> RadiometryError {
    RadiometryError::Decode {
        file: file.into(),
        reason: reason.to_string(),
    }
}

/// Decodes `bytes` in a child of `program` within `budget`.
pub fn decode(
    program: &Path,
    bytes: &[u8],
    file: &str,
    wb: WhiteBalance,
    budget: Budget,
) -> Result<Frame, RadiometryError> {
    let mut command = Command::new(program);
    command
        .args(["decode-raw", "--name", file, "--memory-bytes"])
        .arg(budget.memory.to_string());
    if let WhiteBalance::Fixed([r, g, b]) = wb {
        command.args(["--white-balance", &format!("{r},{g},{b}")]);
    }
    let mut child = command
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| {
            decode_error(
                file,
                format!("RAW: cannot start the decoder ({}): {e}", program.display()),
            )
        })?;
    let (mut stdin, mut stdout, mut stderr) = (
        child.stdin.take().expect("piped stdin"),
        child.stdout.take().expect("piped stdout"),
        child.stderr.take().expect("piped stderr"),
    );
    let started = Instant::now();
    let (status, out, err) = std::thread::scope(|s| {
        // A child that dies early closes its stdin: the write then fails, and its status
        // says why.
        s.spawn(move || {
            let _ = stdin.write_all(bytes);
        });
        let out = s.spawn(move || {
            let mut v = Vec::new();
            stdout.read_to_end(&mut v).map(|_| v)
        });
        let err = s.spawn(move || {
            let mut v = String::new();
            let _ = stderr.read_to_string(&mut v);
            v
        });
        let status = loop {
            match child.try_wait() {
                Ok(Some(status)) => break Ok(status),
                Ok(None) if started.elapsed() > budget.time => {
                    let _ = child.kill();
                    let _ = child.wait();
                    break Err(format!(
                        "RAW: the decoder took longer than {} on this file, and was stopped",
                        humantime::format_duration(budget.time)
                    ));
                }
                Ok(None) => std::thread::sleep(Duration::from_millis(5)),
                Err(e) => break Err(format!("RAW: waiting for the decoder: {e}")),
            }
        };
        (
            status,
            out.join().expect("the reader does not panic"),
            err.join().expect("the reader does not panic"),
        )
    });
    let status = status.map_err(|e| decode_error(file, e))?;
    if status.code() == Some(UNDECODABLE) {
        // The child's own words, its last line: `file: reason`, as RadiometryError prints it.
        let last = err
            .lines()
            .rev()
            .find(|l| !l.trim().is_empty())
            .unwrap_or("");
        let reason = last.trim().trim_start_matches(&format!("{file}: "));
        return Err(decode_error(file, reason));
    }
    if !status.success() {
        let how = match status.code() {
            Some(code) => format!("exited with status {code}"),
            None => "was stopped by a signal".to_string(),
        };
        return Err(decode_error(
            file,
            format!(
                "RAW: the decoder {how} on this file: it needed more than its {} MB of memory, \
                 or the file made it crash ({})",
                budget.memory >> 20,
                // The first line says what failed ("memory allocation of … bytes failed", a
                // panic's place); the rest is backtrace advice.
                err.lines()
                    .find(|l| !l.trim().is_empty())
                    .unwrap_or("no message")
                    .trim()
            ),
        ));
    }
    let out = out.map_err(|e| decode_error(file, format!("RAW: reading the decoder: {e}")))?;
    read_frame(&out).ok_or_else(|| decode_error(file, "RAW: the decoder's answer is truncated"))
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

fn read_frame(b: &[u8]) -> Option<Frame> {
    let mut at = 0;
    let mut take = |n: usize| {
        let s = b.get(at..at + n)?;
        at += n;
        Some(s)
    };
    if take(8)? != TAG {
        return None;
    }
    let u64_ = |s: &[u8]| u64::from_le_bytes(s.try_into().expect("8 bytes"));
    let f64_ = |s: &[u8]| f64::from_le_bytes(s.try_into().expect("8 bytes"));
    let f32_ = |s: &[u8]| f32::from_le_bytes(s.try_into().expect("4 bytes"));
    let (width, height) = (u64_(take(8)?) as usize, u64_(take(8)?) as usize);
    let exposure = Exposure {
        shutter_s: f64_(take(8)?),
        f_number: f64_(take(8)?),
        iso: f64_(take(8)?),
    };
    let white_balance = [f32_(take(4)?), f32_(take(4)?), f32_(take(4)?)];
    let n = width.checked_mul(height)?.checked_mul(12)?;
    let pixels = take(n)?
        .chunks_exact(12)
        .map(|p| [f32_(&p[0..4]), f32_(&p[4..8]), f32_(&p[8..12])])
        .collect();
    Some(Frame {
        values: Raster {
            width,
            height,
            pixels,
        },
        exposure,
        white_balance,
    })
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
        let back = read_frame(&wire).unwrap();
        assert_eq!(back.values.pixels, frame.values.pixels);
        assert_eq!(back.exposure, frame.exposure);
        assert_eq!(back.white_balance, frame.white_balance);
        assert!(read_frame(&wire[..wire.len() - 1]).is_none());
        assert!(read_frame(b"BRDFDFR1").is_none());
    }
}
