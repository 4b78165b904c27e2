//! `brdfd decode-raw`: the child process a capture decodes each RAW file in
//! (`brdfd_radiometry::isolated` says why). Not a command for people: hidden from `--help`.

use std::io::Read;

use brdfd_radiometry::isolated::{write_frame, UNDECODABLE};
use brdfd_radiometry::raw::{decode_raw_here, WhiteBalance};

#[derive(clap::Args)]
pub struct DecodeRawArgs {
    /// The file's name, for messages (its extension tells the format).
    #[arg(long)]
    pub name: String,
    /// Address space this process may use, bytes: past it an allocation fails and the
    /// process ends, which the parent reports.
    #[arg(long)]
    pub memory_bytes: u64,
    /// Processor time this process may use, seconds: a decoder that loops is stopped even if
    /// the process that started it is gone.
    #[arg(long)]
    pub seconds: u64,
    /// Fixed white balance multipliers `R,G,B` instead of the file's as-shot ones.
    #[arg(long, value_parser = parse_white_balance)]
    pub white_balance: Option<WhiteBalance>,
}

fn parse_white_balance(s: &str) -> Result<WhiteBalance, String> {
    let v: Vec<f32> = s
        .split(',')
        .map(|x| x.trim().parse::<f32>().map_err(|e| format!("{x:?}: {e}")))
        .collect::<Result<_, _>>()?;
    match v[..] {
        [r, g, b] => Ok(WhiteBalance::Fixed([r, g, b])),
        _ => Err(format!("three numbers R,G,B, not {s:?}")),
    }
}

/// Reads the file from stdin and writes the frame to stdout; a file that cannot be decoded
/// exits with [`UNDECODABLE`] and the reason on stderr.
pub fn run(a: DecodeRawArgs) -> anyhow::Result<()> {
    // Ended with the process that started it (a daemon killed mid-decode), so that it
    // cannot spin on alone. Linux only; elsewhere the processor-time limit stops it.
    #[cfg(target_os = "linux")]
    // SAFETY: PR_SET_PDEATHSIG takes a signal number and touches no memory of ours.
    unsafe {
        libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL);
    }
    for (resource, value, what) in [
        (libc::RLIMIT_AS, a.memory_bytes, "memory"),
        (libc::RLIMIT_CPU, a.seconds, "processor time"),
    ] {
        let limit = libc::rlimit {
            rlim_cur: value,
            rlim_max: value,
        };
        // SAFETY: setrlimit reads the struct it is given, which lives across the call.
        if unsafe { libc::setrlimit(resource, &limit) } != 0 {
            anyhow::bail!(
                "cannot limit the decoder's {what}: {}",
                std::io::Error::last_os_error()
            );
        }
    }
    let mut bytes = Vec::new();
    std::io::stdin().read_to_end(&mut bytes)?;
    let wb = a.white_balance.unwrap_or(WhiteBalance::AsShot);
    match decode_raw_here(&bytes, &a.name, wb) {
        Ok(frame) => Ok(write_frame(&frame, &mut std::io::stdout().lock())?),
        Err(e) => {
            eprintln!("{e}");
            std::process::exit(UNDECODABLE);
        }
    }
}
