#!/usr/bin/env bash
# The GPU figures of docs/PERFORMANCE.md in one command, on a machine with a GPU and PyTorch but no Rust
# toolchain or package registry (a lent GPU machine): the binaries are built where cargo works and carried in
# .gpu/ (ignored by git; stripped, 20 MB), with the Vulkan loader's .deb in case the machine has none. Where
# cargo works (Debian 12 here; the binaries need glibc 2.36 or later), from the repository root:
#
#     cargo build --release -p raypatch-bench -p raypatch-cli && mkdir -p .gpu && echo /.gpu/ >>.git/info/exclude
#     strip -o .gpu/raypatch-bench target/release/raypatch-bench && strip -o .gpu/render-frame target/release/render-frame
#     (cd .gpu && apt-get download libvulkan1)
#
# then on the GPU machine, in a copy of the checkout with .gpu/ in it (the device tool: carry [".gpu"]):
#
#     bash tools/gpu_bench.sh OUT_DIR [STEP ...]
#
# STEPs (default: all, in this order), each command under its own time limit; never run on a GPU yet, so where a
# machine allows 10 minutes per command, run `info gemm`, `rpsrt`, `srt` and `families` as four commands (each
# stays under 9 minutes by those limits):
#     info      the GPU, its driver, the adapters the engine sees, PyTorch's CUDA device, and the bundled
#               model's first and repeated renders (render-frame --timings: pipeline compilation, cold and
#               cached, and the render's median)
#     gemm      the hot linear layers on every matmul kernel the adapter runs and in PyTorch (cuBLAS, no TF32)
#     rpsrt     the official RP-SRT k=8 at every size, per-kernel breakdown, PyTorch CUDA eager and
#               torch.compile at 120x160 and 480x640 on the same weights and inputs
#     srt       the official SRT (k=1) likewise
#     families  the official RP-OSRT k=8 and RP-DeFiNe k=16 likewise
# OUT_DIR gets two files: gpu-bench.log (everything printed) and gpu-bench.tar.gz (each step's results
# folder and log). The exit code is the number of commands that failed (0: all ran).
set -u
out=${1:?usage: bash tools/gpu_bench.sh OUT_DIR [info|gemm|rpsrt|srt|families ...]}
shift
steps=("$@")
[ ${#steps[@]} -eq 0 ] && steps=(info gemm rpsrt srt families)
for s in "${steps[@]}"; do
    case $s in
        info | gemm | rpsrt | srt | families) ;;
        *)
            echo "gpu_bench: unknown step $s: expected info, gemm, rpsrt, srt or families" >&2
            exit 2
            ;;
    esac
done
bin=.gpu
for program in raypatch-bench render-frame; do
    if [ ! -x "$bin/$program" ]; then
        echo "gpu_bench: $bin/$program is missing: build it where cargo works and carry .gpu/ (see this script)" >&2
        exit 2
    fi
done
mkdir -p "$out"
work=$(mktemp -d)

# The Vulkan loader (wgpu opens libvulkan.so.1 at run time), unpacked from the carried .deb if the system has none.
if ! ldconfig -p | grep -q 'libvulkan\.so\.1'; then
    for deb in "$bin"/*.deb; do
        [ -f "$deb" ] && dpkg -x "$deb" /
    done
    ldconfig
fi
# The NVIDIA driver's Vulkan ICD, where the image keeps it outside the loader's search path.
icd=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
if [ -z "${VK_DRIVER_FILES:-}" ] && [ -f "$icd" ]; then
    export VK_DRIVER_FILES=$icd
fi

failed=0
# run NAME SECONDS COMMAND...: COMMAND under a time limit, its output in the step's log too.
run() {
    local name=$1 seconds=$2
    shift 2
    echo "== $name: $*"
    local started=$SECONDS
    timeout "$seconds" "$@" 2>&1 | tee -a "$work/$name.log"
    local code=${PIPESTATUS[0]}
    echo "== $name: exit $code after $((SECONDS - started)) s"
    [ "$code" -eq 0 ] || failed=$((failed + 1))
}

# sweep NAME SECONDS GMAC ARGS...: official models on the GPU, PyTorch on its CUDA device (the harness's default
# when the engine runs on a GPU), eager and compiled, and the float64 CPU reference (a minute or two for an
# official encode) where the encode and render take at most GMAC billion multiply-adds.
sweep() {
    local name=$1 seconds=$2 gmac=$3
    shift 3
    run "$name" "$seconds" "$bin/raypatch-bench" "$@" --pytorch-compile --repeats 20 --max-reference-gmac "$gmac" \
        --out "$work/$name"
}

measure() {
    for s in "${steps[@]}"; do
        case $s in
            info)
                run info 30 nvidia-smi
                run info 30 python3 -c "import torch; print('torch', torch.__version__, 'cuda:', \
torch.cuda.is_available() and torch.cuda.get_device_name(0))"
                run info 30 "$bin/render-frame" --list-adapters
                # The pipeline cache starts empty on a fresh machine: the first render compiles, the second reads it.
                export RAYPATCH_CACHE_DIR=$work/pipeline-cache
                run info 90 "$bin/render-frame" --timings --out "$work/info-render.png"
                run info 90 "$bin/render-frame" --timings --repeat 200 --out "$work/info-render.png"
                unset RAYPATCH_CACHE_DIR
                ;;
            gemm) run gemm 270 "$bin/raypatch-bench" --gemm --repeats 50 --out "$work/gemm" ;;
            rpsrt) sweep rpsrt 540 25 --only official:8 ;;
            srt) sweep srt 400 0 --only official:1 ;;
            families) sweep families 540 25 --only official-osrt:8 --only official-define:16 ;;
        esac
    done
    tar -czf "$out/gpu-bench.tar.gz" -C "$work" --exclude scratch --exclude pipeline-cache .
    echo "gpu_bench: ${#steps[@]} step(s), $failed command(s) failed; results in $out/gpu-bench.tar.gz"
    return "$failed"
}

measure 2>&1 | tee "$out/gpu-bench.log"
code=${PIPESTATUS[0]}
rm -rf "$work"
exit "$code"
