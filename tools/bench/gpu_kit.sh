#!/usr/bin/env bash
# Builds the kit that tools/bench/gpu_bench.sh runs on a lent GPU machine (no Rust toolchain, no package registry
# there): .gpu/kit.tar.xz (ignored by git) with
#   bin/    render-frame and raypatch-bench, release, stripped
#   tests/  the golden, kernels, api and executor test binaries (`cargo test --release --no-run`), stripped: they find
#           assets/ and shaders/ through the checkout path baked into them, recorded in build-path
#   debs/   the Vulkan loader and glvnd (libvulkan1, libglvnd0, libegl1, libgl1, libglx0, libopengl0,
#           libgles2): NVIDIA's Vulkan driver (libGLX_nvidia.so.0) needs libGLdispatch from glvnd, and without
#           it wgpu sees no adapter
# The tensor step (gpu_bench.sh OUT tensor) needs nothing more: raypatch-bench --coop-tune, the kernels and golden
# binaries (their `coop` and tensor-path tests), tools/bench/*.py from the checkout.
# Run from the repository root where cargo and apt-get work (Debian 12 here; the binaries need glibc 2.36 or
# later), then carry .gpu to the GPU machine (the device tool: carry [".gpu"]) and run tools/bench/gpu_bench.sh.
set -euo pipefail
cd "$(dirname "$0")/../.."
kit=$(mktemp -d)
trap 'rm -rf "$kit"' EXIT
mkdir -p "$kit/bin" "$kit/tests" "$kit/debs" .gpu
grep -qx '/.gpu/' .git/info/exclude 2>/dev/null || echo /.gpu/ >>.git/info/exclude

cargo build --release -p raypatch-bench -p raypatch-cli
for program in render-frame raypatch-bench; do
    strip -o "$kit/bin/$program" "target/release/$program"
done
# The test binaries cargo built, by target name (the JSON lines cargo prints for each artifact).
cargo test --release --no-run --test golden --test kernels --test api --test executor --message-format=json 2>/dev/null |
    python3 -c '
import json, sys
for line in sys.stdin:
    m = json.loads(line)
    if m.get("reason") == "compiler-artifact" and m.get("executable") and m["target"]["kind"] == ["test"]:
        print(m["target"]["name"], m["executable"])
' | while read -r name executable; do
    strip -o "$kit/tests/$name" "$executable"
done
for test in golden kernels api executor; do
    [ -x "$kit/tests/$test" ] || { echo "gpu_kit: no $test test binary" >&2; exit 1; }
done
pwd >"$kit/build-path"
(cd "$kit/debs" && apt-get download libvulkan1 libglvnd0 libegl1 libgl1 libglx0 libopengl0 libgles2)
# Through a temporary name: a kit being written is never taken for a whole one.
tar -cJf .gpu/kit.tar.xz.part -C "$kit" .
mv .gpu/kit.tar.xz.part .gpu/kit.tar.xz
echo "gpu_kit: .gpu/kit.tar.xz, $(du -h .gpu/kit.tar.xz | cut -f1) (binaries of $(git rev-parse --short HEAD))"
