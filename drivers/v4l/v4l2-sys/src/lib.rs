//! Raw V4L2 bindings, generated once from `<linux/videodev2.h>` and checked in.
//!
//! The `v4l` crate reads these through `v4l2-sys-mit`, whose build script runs bindgen (and so
//! needs libclang) on every build. A fresh machine has no libclang, so brdfd patches that crate
//! with this one: same name, no build script, and the items `v4l` uses (V4L2's types and
//! constants, and the time types; see `regenerate.sh`). `regenerate.sh` beside this file
//! remakes `bindings.rs`.
//!
//! The bindings carry bindgen's layout tests, so `cargo test -p v4l2-sys-mit` checks every
//! struct's size, alignment and field offsets on the machine it runs on. They were generated
//! on x86_64; the V4L2 ABI is the same on every 64-bit Linux (LP64), and 32-bit targets are
//! refused below rather than given wrong layouts.
#![allow(clippy::all)]
#![allow(deref_nullptr)]
#![allow(non_camel_case_types)]
#![allow(non_snake_case)]
#![allow(non_upper_case_globals)]
#![allow(rustdoc::all)]

#[cfg(not(all(target_os = "linux", target_pointer_width = "64")))]
compile_error!(
    "brdfd's pre-generated V4L2 bindings are for 64-bit Linux; run regenerate.sh for this target"
);

include!("bindings.rs");
