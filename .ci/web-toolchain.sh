#!/usr/bin/env bash
# The toolchain that builds the engine for wasm32-unknown-unknown (issue 49): rustup's std for that target
# cannot be downloaded here, so Debian bookworm-security's rustc-web/cargo-web/rust-web-src (installed as
# /usr/bin/rustc and /usr/bin/cargo; build with -Zbuild-std) and lld-19's wasm-ld; plus the wasm-bindgen CLI
# whose version equals Cargo.lock's wasm-bindgen (the two must match), installed once under
# /var/cache/raypatch so a machine that keeps that folder pays its ~11 min build only once.
# Prints the wasm-bindgen binary's path on its last line.
set -euo pipefail
cd "$(dirname "$0")/.."

if [ "$(id -u)" != 0 ]; then SUDO=sudo; else SUDO=; fi
if [ ! -x /usr/bin/cargo ] || [ ! -x /usr/lib/llvm-19/bin/wasm-ld ] || [ ! -d /usr/lib/rustlib/src/rust/library ]; then
    $SUDO apt-get update -qq >&2
    $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
        rustc-web cargo-web rust-web-src lld-19 >&2
fi

version="$(awk '/^name = "wasm-bindgen"$/ { getline; gsub(/version = |"/, ""); print; exit }' Cargo.lock)"
[ -n "$version" ] || { echo "web-toolchain: no wasm-bindgen in Cargo.lock" >&2; exit 1; }
root="/var/cache/raypatch/wasm-bindgen-$version"
if [ ! -x "$root/bin/wasm-bindgen" ]; then
    $SUDO mkdir -p "$root"
    # Without --locked: the CLI's own lock file wants a webpki-roots version the registry no longer has.
    # rustup's cargo (first on PATH) builds it for the host; any recent stable does.
    $SUDO env PATH="$PATH" nice cargo install --quiet wasm-bindgen-cli --version "$version" --root "$root" >&2
fi
echo "$root/bin/wasm-bindgen"
