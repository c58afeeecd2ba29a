#!/usr/bin/env bash
# The viewer in a real browser (tests/browser/viewer.test.mjs): Debian's Chromium driven by playwright-core
# (pinned in tests/browser/package-lock.json) against the release render-frame. Skipped, with a line saying
# why, only where Chromium cannot be installed.
set -euo pipefail
cd "$(dirname "$0")/.."

if [ "$(id -u)" != 0 ]; then SUDO=sudo; else SUDO=; fi
install() { $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$@" >/dev/null; }
command -v chromium >/dev/null || install chromium || true
if ! command -v chromium >/dev/null; then
    echo "browser test skipped: Debian's chromium package could not be installed (apt-get install chromium failed)"
    exit 0
fi
command -v npm >/dev/null || install nodejs npm
cargo build --release -p raypatch-cli
cd tests/browser
npm ci --no-audit --no-fund --silent
CHROMIUM="$(command -v chromium)" node viewer.test.mjs
