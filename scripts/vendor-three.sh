#!/usr/bin/env bash
# Fetches three.js for the web page's 3D viewer from npm into crates/daemon/src/web/vendor/three/:
# the library, the three add-ons the viewer imports and the one GLTFLoader imports, unchanged
# except that their bare `'three'` import names the file beside them (the page's security
# policy allows no inline import map). three.js is MIT-licensed (its LICENSE goes with it). The daemon compiles the
# files in, so the viewer works on a bench with no network.
set -euo pipefail
version=0.166.1
# npm's own integrity string for three@0.166.1; the tarball must match it.
integrity="sha512-LtuafkKHHzm61AQA1be2MAYIw1IjmhOUxhBa0prrLpEMWbV7ijvxCRHjSgHPGp2493wLBzwKV46tA9nivLEgKg=="
out=$(cd "$(dirname "$0")/.." && pwd)/crates/daemon/src/web/vendor/three
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
(cd "$work" && npm pack --silent "three@$version" >/dev/null)
tarball="$work/three-$version.tgz"
got="sha512-$(openssl dgst -sha512 -binary "$tarball" | base64 -w0)"
[ "$got" = "$integrity" ] || { echo "three@$version: integrity $got, expected $integrity" >&2; exit 1; }
tar xzf "$tarball" -C "$work"
p="$work/package"
mkdir -p "$out"
cp "$p/build/three.module.min.js" "$p/LICENSE" "$out/"
for f in loaders/GLTFLoader.js loaders/RGBELoader.js controls/OrbitControls.js utils/BufferGeometryUtils.js; do
  sed -e "s#from 'three'#from './three.module.min.js'#" \
      -e "s#from '../utils/BufferGeometryUtils.js'#from './BufferGeometryUtils.js'#" \
      "$p/examples/jsm/$f" >"$out/$(basename "$f")"
done
echo "three@$version in $out"
