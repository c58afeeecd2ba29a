#!/usr/bin/env bash
# The engine in the browser (issue 49): builds the wasm package (crates/raypatch-web) and the page (web/) into
# target/web (index.html at its root, the bundled model and scene under assets/; any static host serves it), then
# tests it in headless Chromium on WebGPU (SwiftShader) against native render-frame (tests/browser/web.test.mjs).
# Ends with `web: N passed, M failed`. The toolchain (.ci/web-toolchain.sh) is Debian's, the wasm-bindgen CLI
# cached in /var/cache/raypatch. `WEB_BUILD_ONLY=1` stops after the build.
set -euo pipefail
cd "$(dirname "$0")/.."

wasm_bindgen="$(bash .ci/web-toolchain.sh | tail -n 1)"
bash .ci/web-build.sh --quiet -p raypatch-web
out=target/web
rm -rf "$out"
mkdir -p "$out/assets"
"$wasm_bindgen" --target web --out-dir "$out/pkg" target/wasm/wasm32-unknown-unknown/release/raypatch_web.wasm
cp web/index.html web/app.js web/style.css "$out/"
cp assets/models/fitted_scene-2000000_rpsrt_k4.safetensors assets/scenes/scene-2000000.safetensors "$out/assets/"
wasm="$out/pkg/raypatch_web_bg.wasm"
echo "web: built $out ($(stat -c %s "$wasm") bytes of wasm, $(gzip -9 -c "$wasm" | wc -c) gzipped)"
[ -z "${WEB_BUILD_ONLY:-}" ] || exit 0

if [ "$(id -u)" != 0 ]; then SUDO=sudo; else SUDO=; fi
install() { $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$@" >/dev/null; }
command -v chromium >/dev/null || install chromium
command -v npm >/dev/null || install nodejs npm
cargo build --release -p raypatch-cli
cd tests/browser
npm ci --no-audit --no-fund --silent
CHROMIUM="$(command -v chromium)" node web.test.mjs
