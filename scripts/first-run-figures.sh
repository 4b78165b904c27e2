#!/usr/bin/env bash
# The figures of a newcomer's first run (issue 19), as medians of RUNS runs on this machine:
#   - the README's main command with an empty render cache, then with a warm one;
#   - how long `brdfd sim camera` and `brdfd sim theta` take to accept connections.
# Uses the release binary (build it first: cargo build --release). Usage:
#   scripts/first-run-figures.sh [RUNS]
set -euo pipefail
cd "$(dirname "$0")/.."
runs=${1:-3}
bin=target/release/brdfd
[ -x "$bin" ] || { echo "build first: cargo build --release" >&2; exit 1; }
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

median() { sort -g | awk '{v[NR]=$1} END {print (NR%2 ? v[(NR+1)/2] : (v[NR/2]+v[NR/2+1])/2)}'; }
seconds() { # wall seconds of a command
  local t0 t1; t0=$(date +%s.%N); "$@" >/dev/null 2>&1; t1=$(date +%s.%N)
  echo "$t1 - $t0" | bc -l
}
main_command() { # the README's main command, on its own state and cache directories
  BRDFD_RENDER_CACHE="$work/cache-$1" BRDFD_DAEMON=127.0.0.1:9 \
    "$bin" capture --simulate --material gold --state-dir "$work/state"
}
until_listening() { # seconds until a simulator prints its address line
  local out="$work/sim.out" t0 t1 pid
  : >"$out"
  t0=$(date +%s.%N)
  BRDFD_RENDER_CACHE=off "$bin" sim "$@" >"$out" 2>/dev/null &
  pid=$!
  until grep -q . "$out"; do sleep 0.005; done
  t1=$(date +%s.%N)
  kill "$pid"; wait "$pid" 2>/dev/null || true
  echo "$t1 - $t0" | bc -l
}

echo "cores: $(nproc); runs: $runs"
cold=(); warm=()
for i in $(seq "$runs"); do
  cold+=("$(seconds main_command "cold$i")")   # a fresh cache each time
  warm+=("$(seconds main_command "cold$i")")   # the cache the previous run filled
done
printf 'main command, empty render cache: median %.2f s (%s)\n' \
  "$(printf '%s\n' "${cold[@]}" | median)" "$(printf '%.2f ' "${cold[@]}")"
printf 'main command, warm render cache:  median %.2f s (%s)\n' \
  "$(printf '%s\n' "${warm[@]}" | median)" "$(printf '%.2f ' "${warm[@]}")"
for sim in camera theta; do
  t=()
  for i in $(seq "$runs"); do
    case $sim in
      camera) t+=("$(until_listening camera --ptpip 127.0.0.1:0)") ;;
      theta) t+=("$(until_listening theta --http 127.0.0.1:0)") ;;
    esac
  done
  printf 'sim %-6s accepts connections after: median %.3f s (%s)\n' "$sim" \
    "$(printf '%s\n' "${t[@]}" | median)" "$(printf '%.3f ' "${t[@]}")"
done
