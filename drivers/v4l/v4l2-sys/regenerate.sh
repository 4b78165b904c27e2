#!/bin/sh
# Remakes src/bindings.rs from the kernel's <linux/videodev2.h>. Needs libclang (Debian:
# libclang-dev), linux-libc-dev, and bindgen's command line at the version the `v4l` crate's
# own v4l2-sys-mit uses:  cargo install bindgen-cli --version 0.65.1
# Only what V4L2 defines is kept (its types, the time types `v4l` names, and V4L2's constants);
# bindgen adds the kernel types those depend on.
set -eu
cd "$(dirname "$0")"
wrapper=$(mktemp --suffix=.h)
trap 'rm -f "$wrapper"' EXIT
echo '#include <linux/videodev2.h>' > "$wrapper"
bindgen "$wrapper" \
  --allowlist-type 'v4l2_.*|time_t|timeval|timespec' \
  --allowlist-var 'V4L2_.*|VIDEO_.*' \
  -o src/bindings.rs
