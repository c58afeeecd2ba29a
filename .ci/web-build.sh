#!/usr/bin/env bash
# Builds crates for wasm32-unknown-unknown with Debian's toolchain (.ci/web-toolchain.sh installs it): std built
# from rust-web-src (-Zbuild-std, allowed on a stable compiler by RUSTC_BOOTSTRAP), linked by lld-19's wasm-ld,
# into target/wasm (apart from the native build's target/release). Arguments go to cargo, e.g. `-p raypatch-web`.
# rustup's proxies come first on PATH, so Debian's cargo and rustc are called by path.
set -euo pipefail
cd "$(dirname "$0")/.."
export RUSTC=/usr/bin/rustc RUSTC_BOOTSTRAP=1
export CARGO_TARGET_WASM32_UNKNOWN_UNKNOWN_LINKER=/usr/lib/llvm-19/bin/wasm-ld
exec /usr/bin/cargo build -Zbuild-std=std,panic_abort --target wasm32-unknown-unknown --release \
    --target-dir target/wasm "$@"
