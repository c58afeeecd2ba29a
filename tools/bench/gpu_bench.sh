#!/usr/bin/env bash
# The GPU figures of docs/PERFORMANCE.md and the GPU run of the kernel, golden and API tests, in one command on
# a lent GPU machine (a GPU, its driver and PyTorch; no Rust toolchain, no package registry). Build the kit
# where cargo works (tools/bench/gpu_kit.sh writes .gpu/kit.tar.xz), carry .gpu (the device tool: carry [".gpu"]),
# and there, from the repository root:
#
#     bash tools/bench/gpu_bench.sh OUT_DIR [STEP ...]
#
# Issue 41's "done when" figures, each checked against its bound, in ONE device call (its commands 8 minutes at most,
# about 5 expected on an H100; the host step below):
#
#     bash tools/bench/gpu_bench.sh OUT_DIR host
#
# STEPs (default: all but host, in this order; each command under its own time limit, the limits adding up to about
# 23 minutes, more than one device call of 10 minutes holds: run `info tests gemm lab breakdown` in one call (limits 9
# minutes; it took about 3 on an H200), `rpsrt srt families viewer` in another (limits 10 minutes; the sweeps time
# PyTorch eager and compiled at every size; a sweep cut short keeps the tables of the sizes it measured, and its
# log has each configuration's line, PyTorch's times included), and `variants` in a third when device time
# allows (limits 4.5 minutes)):
#     info      the GPU, its driver, PyTorch's CUDA device, the adapters the engine sees, the bundled model's
#               first and repeated renders (render-frame --timings: pipelines compiled cold, then cached), and the
#               official RP-SRT k=8's encode and first render in a fresh process from an empty pipeline cache
#     tests     the kernel, golden, API and executor tests on the GPU (every kernel variant the GPU runs; the
#               executor's: renders' staging, readout and sequences kept in flight)
#     gemm      the hot linear layers on every matmul kernel the GPU runs (`Coop`, f16 tensor cores, where it has
#               16x16x16 f16 cooperative matrices) and in PyTorch (cuBLAS, no TF32)
#     lab       the GEMM lab: the engine's GEMM kernels beside outer-product tilings (tools/bench/gemm_lab.py)
#     breakdown the engine alone (no PyTorch, no float64 reference: about a minute) on the official RP-SRT k=8, SRT,
#               RP-OSRT k=8 and RP-DeFiNe k=16: where each encode's and render's GPU time goes, by kernel and op
#     variants  the same with every op on the `Rows` family (--matmul-kernel rows), then with no subgroup variant
#               (--no-subgroups: flash attention a query row per invocation): per op, the time the other variant
#               would take, to decide which runs where (device.rs) from measurements
#     rpsrt     the official RP-SRT k=8 at every size, one view and 8 and 32 at once, the per-kernel breakdown,
#               PyTorch CUDA eager and torch.compile on the same weights and inputs; every row has the wall time,
#               the GPU time and the host's (wall − GPU) side by side (tables.md, results.csv), and beside each
#               8- and 32-view batched call the same views rendered as `render-frame --view all` renders them
#               (a frame per view, batched under the memory budget; tables.md "Several views")
#     srt       the official SRT (k=1) likewise (one view)
#     families  the official RP-OSRT k=8 and RP-DeFiNe k=16 likewise, one view and 8 and 32 at once
#     viewer    the live viewer's frames per second (render-frame --serve and tools/bench/viewer_fps.py)
#     host      issue 41's six criteria in one call, alone (its commands' limits add up to 470 s, clipped to a
#               deadline of RAYPATCH_GPU_BENCH_HOST_SECONDS, default 480, from the step's start): the official
#               RP-SRT k=8 sweep first, in a fresh process with empty pipeline and driver caches (its first
#               record's load, first encode and first render are the first frame; every later shape's first
#               render counts the pipelines it compiled), then the API, golden, kernel and executor tests, then
#               RP-DeFiNe k=16 480x640 against PyTorch fp32 eager, then the RP-OSRT k=8 and RP-DeFiNe k=16 sweeps
#               (engine alone; 1, 8 and 32 views, 120x160 to 960x1280, each beside `--view all`'s path).
#               tools/bench/host_check.py turns their results.json files and the tests' exit codes into
#               host-check.md (a row per criterion: figure, bound, PASS/FAIL/NOT MEASURED, source file), written
#               after every command into OUT_DIR and the archive's host/ folder: a run cut short keeps what it
#               measured. RAYPATCH_GPU_BENCH_QUICK=1: small random models stand in for the official ones at one
#               size each, PyTorch wherever it runs, to try the step where no GPU is (minutes on lavapipe)
#     tensor    issue 47's tensor path (--precision f16-act on cooperative matrices) in one call, alone (its
#               commands' limits add up to 480 s, clipped to a deadline of RAYPATCH_GPU_BENCH_TENSOR_SECONDS,
#               default 480): the tensor tests (kernels `coop`, golden renders on the tensor path); the tuner
#               (raypatch-bench --coop-tune: every tiling that fits, on the official models' GEMM shapes, the fastest
#               per shape class written into the run's RAYPATCH_CACHE_DIR/coop-tuning.tsv, which the later
#               commands read, copied into OUT_DIR; and the tensor GEMM's TFLOP/s at 4096^3); the official SRT at
#               120x160 and RP-SRT k=8 with 32 views of 120x160, at f32 and f16-act, PyTorch eager and compiled
#               (fp32, and bf16 autocast where the bench has it) beside the f32 records; cuBLAS f16 and bf16 at
#               4096^3 and the tuned shapes (tools/bench/bench_gemm_pytorch.py). tools/bench/tensor_check.py
#               writes tensor-check.md (a row per figure: figure, bound, PASS/FAIL/NOT MEASURED, source file)
#               after every command into OUT_DIR and the archive's tensor/ folder. RAYPATCH_GPU_BENCH_QUICK=1:
#               small random models, the tuner's stand-in shapes and 512^3 (lavapipe: about 5 minutes).
#               RAYPATCH_GPU_BENCH_CHROOT=DIR: the engine's binaries run in the chroot DIR (.ci/coop-chroot.sh's
#               Mesa 26 lavapipe, this checkout mounted at the same path), the Python parts here
# OUT_DIR gets two files, rewritten as each step finishes (a run cut short still returns what it did):
# gpu-bench.log (everything printed) and gpu-bench.tar.gz (each step's results folder and log). The exit code
# is the number of commands that failed (0: all ran).
set -u
out=${1:?usage: bash tools/bench/gpu_bench.sh OUT_DIR [info|tests|gemm|lab|breakdown|variants|rpsrt|srt|families|viewer|host|tensor ...]}
shift
steps=("$@")
[ ${#steps[@]} -eq 0 ] && steps=(info tests gemm lab breakdown variants rpsrt srt families viewer)
for s in "${steps[@]}"; do
    case $s in
        info | tests | gemm | lab | breakdown | variants | rpsrt | srt | families | viewer | host | tensor) ;;
        *)
            echo "gpu_bench: unknown step $s: expected info, tests, gemm, lab, breakdown, variants, rpsrt, srt, families, viewer, host or tensor" >&2
            exit 2
            ;;
    esac
done
if [ ! -f .gpu/kit.tar.xz ]; then
    echo "gpu_bench: .gpu/kit.tar.xz is missing: run tools/bench/gpu_kit.sh where cargo works and carry .gpu" >&2
    exit 2
fi
mkdir -p "$out"
out=$(cd "$out" && pwd)
# RAYPATCH_GPU_BENCH_CHROOT=DIR: the engine's binaries run in that chroot (the checkout mounted at the same path, as
# .ci/coop.sh mounts it), so the work folder lies in the checkout where both see it.
chroot_dir=${RAYPATCH_GPU_BENCH_CHROOT:-}
device=()
if [ -n "$chroot_dir" ]; then
    mkdir -p .gpu/work
    work=$(mktemp -d -p "$(pwd)/.gpu/work")
    device=(chroot "$chroot_dir" env -C "$(pwd)" HOME=/tmp)
else
    work=$(mktemp -d)
fi
kit=$work/kit
mkdir -p "$kit" "$work/results"
if ! tar -xJf .gpu/kit.tar.xz -C "$kit"; then
    echo "gpu_bench: .gpu/kit.tar.xz: cannot unpack (cut short or damaged): run tools/bench/gpu_kit.sh again" >&2
    rm -rf "$work"
    exit 2
fi
bin=$kit/bin

# The Vulkan loader and glvnd, unpacked from the kit where the system lacks them (a chroot has its own).
if [ -z "$chroot_dir" ] && { ! ldconfig -p | grep -q 'libvulkan\.so\.1' || ! ldconfig -p | grep -q 'libGLdispatch\.so\.0'; }; then
    for deb in "$kit"/debs/*.deb; do
        dpkg -x "$deb" /
    done
    ldconfig
fi
# The NVIDIA driver's Vulkan ICD, where the image keeps it outside the loader's search path.
icd=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
if [ -z "${VK_DRIVER_FILES:-}" ] && [ -f "$icd" ]; then
    export VK_DRIVER_FILES=$icd
fi
# The test binaries read assets/ and shaders/ through the path they were built at: point it at this checkout.
build_path=$(cat "$kit/build-path")
if [ "$build_path" != "$(pwd)" ] && [ ! -e "$build_path" ]; then
    mkdir -p "$(dirname "$build_path")" && ln -s "$(pwd)" "$build_path"
fi

failed=0
# The host step's deadline (in $SECONDS; empty: none); the last command's exit code (-1: not run, the deadline
# had passed), seconds and time limit.
deadline=
code=0
took=0
limit=0
# run NAME SECONDS COMMAND...: COMMAND under a time limit (at most what is left before the deadline), its output
# in the step's log too.
run() {
    local name=$1 seconds=$2
    shift 2
    if [ -n "$deadline" ] && [ $((deadline - SECONDS)) -lt "$seconds" ]; then
        seconds=$((deadline - SECONDS))
    fi
    if [ "$seconds" -le 0 ]; then
        echo "== $name: not run, the step's deadline has passed: $*"
        code=-1 took=0 limit=0 failed=$((failed + 1))
        return
    fi
    limit=$seconds
    echo "== $name: $* (at $(date +%T), limit $seconds s)"
    local started=$SECONDS
    timeout "$seconds" "$@" 2>&1 | tee -a "$work/results/$name.log"
    code=${PIPESTATUS[0]} took=$((SECONDS - started))
    echo "== $name: exit $code after $took s"
    [ "$code" -eq 0 ] || failed=$((failed + 1))
}

# sweep NAME SECONDS GMAC ARGS...: official models on the GPU, PyTorch on its CUDA device (the harness's default
# when the engine runs on a GPU), eager and compiled, and the float64 CPU reference where the encode and render
# take at most GMAC billion multiply-adds.
sweep() {
    local name=$1 seconds=$2 gmac=$3
    shift 3
    run "$name" "$seconds" "$bin/raypatch-bench" "$@" --pytorch-compile --repeats 20 --max-reference-gmac "$gmac" \
        --out "$work/results/$name"
    shares "$name"
}

# engine_only NAME SECONDS ARGS...: the official models' sweeps on the engine alone (no PyTorch, no float64 reference),
# and where their GPU time went.
engine_only() {
    local name=$1 seconds=$2
    shift 2
    run "$name" "$seconds" "$bin/raypatch-bench" --only official:8 --only official:1 --only official-osrt:8 \
        --only official-define:16 --no-pytorch --max-reference-gmac 0 --repeats 10 "$@" --out "$work/results/$name"
    shares "$name"
}

# shares NAME: where the GPU time of step NAME's sweep went (its kernels.csv), into the log.
shares() {
    [ -f "$work/results/$1/kernels.csv" ] && python3 tools/bench/kernel_shares.py "$work/results/$1/kernels.csv" 6
}

# The viewer's frames per second: render-frame --serve (bundled model and scene) on a free port, one page's
# renders for 5 s at each of its sizes, then Ctrl-C.
viewer() {
    local log=$work/results/viewer-server.log url=
    "$bin/render-frame" --serve --port 0 >"$log" 2>&1 &
    local server=$!
    for _ in $(seq 40); do
        url=$(grep -o 'http://[0-9.:]*/' "$log" | head -n 1) && [ -n "$url" ] && break
        sleep 0.5
    done
    if [ -n "$url" ]; then
        run viewer 20 python3 tools/bench/viewer_fps.py "$url" 5
    else
        echo "== viewer: the server printed no URL in 20 s"
        cat "$log"
        failed=$((failed + 1))
    fi
    kill -INT "$server" 2>/dev/null
    wait "$server"
}

# The host step: issue 41's criteria (the header says what it runs). Its estimate on an H100, worst case, from the
# figures of 2026-11-27 (/work/shared/measurements/h100-2026-11-27: engine at a8320a0, walls 1.6-5.5x the GPU
# times, every new shape compiling its ~34 pipelines in ~2 s); with the issue's work in (walls near the GPU time,
# no compiles per shape) each sweep takes about half. A configuration costs its first render, 0.25 s of warm-up
# runs, then up to 20 runs within 3 s (--repeat-seconds), and as much again for `--view all`'s path:
#   unpacking the kit (before the step)                                              ~10 s
#   nvidia-smi, the adapters                                                          ~2 s (limits 10 + 10)
#   rpsrt: RP-SRT k=8 (41 M parameters: 3 s to make, 0.4 s to load, 1.8 s to encode cold); per size, 1, 8 and 32
#     views (GPU 1.2 / 5.2 / 13 ms at 120x160, 6.1 / 42 / 165 ms at 480x640, ~4x that at 960x1280): 120x160 15 s
#     (with the skips and breakdown), 240x320 14 s, 480x640 21 s, 960x1280 31 s; f16 and f16-act at 120x160 9 s
#                                                                                   ~100 s (limit 150)
#   tests: kernels, golden, api, executor (the H200 ran them in about a minute)      ~60 s (limits 45+20+40+15)
#   define-pytorch: RP-DeFiNe k=16 480x640, 1 view (GPU 3.3 ms), and PyTorch eager in a process of its own
#     (import, CUDA start, 20 runs)                                                    ~20 s (limit 50)
#   families: RP-OSRT k=8 at 120x160 (GPU 1.2 ms a view; with its segmentation skips) 17 s; RP-DeFiNe k=16 at
#     240x320, 480x640, 960x1280 (GPU 1.6 / 3.3 / 7-22 ms a view; 32 views up to ~0.7 s) 60 s; making and
#     encoding both 15 s                                                               ~95 s (limit 130)
#   host_check.py and the archive after each command                                  ~2 s
# In all ~290 s expected, 480 s at most (limits 470): one device call of 600 s with the machine's start.
host() {
    local r=$work/results/host quick=${RAYPATCH_GPU_BENCH_QUICK:-}
    deadline=$((SECONDS + ${RAYPATCH_GPU_BENCH_HOST_SECONDS:-480}))
    mkdir -p "$r"
    # The sweeps' models, sizes, views and repeats; quick: small random models, one size each (small k=4 stands in
    # for RP-DeFiNe k=16 at a size where the harness times PyTorch on the CPU).
    local rpsrt=(--only official:8 --sizes 120x160,240x320,480x640,960x1280)
    local define=(--only official-define:16 --sizes 480x640)
    local families=(--only official-osrt:8 --only official-define:16 --sizes 120x160,240x320,480x640,960x1280)
    local common=(--max-reference-gmac 0 --repeats 20 --repeat-seconds 3)
    if [ -n "$quick" ]; then
        rpsrt=(--only small:8 --sizes 120x160)
        define=(--only small:4 --sizes 120x160)
        families=(--only small:4 --sizes 120x160)
        common=(--max-reference-gmac 0 --repeats 3 --repeat-seconds 1)
    fi
    if command -v nvidia-smi >/dev/null; then
        run host 10 nvidia-smi
    fi
    run host 10 "$bin/render-frame" --list-adapters
    # A fresh machine's first frame: the engine's pipeline cache and the driver's shader cache start empty (the
    # NVIDIA driver keeps its cache in __GL_SHADER_DISK_CACHE_PATH where that folder exists); the later
    # commands share the engine's cache.
    local cache=$work/host-pipeline-cache
    mkdir -p "$work/host-driver-cache"
    RAYPATCH_CACHE_DIR=$cache __GL_SHADER_DISK_CACHE_PATH=$work/host-driver-cache run host 150 "$bin/raypatch-bench" \
        "${rpsrt[@]}" --views 8,32 --no-pytorch "${common[@]}" --out "$r/rpsrt"
    host_check "$r"
    for test in kernels:45 golden:20 api:40 executor:15; do
        run host "${test#*:}" "$kit/tests/${test%:*}" --test-threads 4
        printf '%s\t%s\t%s\t%s\n' "${test%:*}" "$code" "$took" "$limit" >>"$r/tests.tsv"
    done
    host_check "$r"
    RAYPATCH_CACHE_DIR=$cache run host 50 "$bin/raypatch-bench" "${define[@]}" "${common[@]}" --out "$r/define-pytorch"
    host_check "$r"
    RAYPATCH_CACHE_DIR=$cache run host 130 "$bin/raypatch-bench" "${families[@]}" --views 8,32 --no-pytorch \
        "${common[@]}" --out "$r/families"
    host_check "$r"
    deadline=
    cat "$r/host-check.md"
}

# The tensor step: issue 47's tensor path (the header says what it runs). Its estimate on an H100 (no measurement yet;
# from the host step's figures: the official RP-SRT k=8 at 120x160 renders in ~1-5 ms, each PyTorch run with
# torch.compile takes ~20-40 s, and a pipeline compiles in ~50 ms):
#   nvidia-smi, the adapters                                                          ~2 s (limits 10 + 10)
#   tests: kernels `coop`, golden renders on the tensor path                          ~40 s (limits 45 + 45)
#   tune: up to 27 tilings x 9 shapes, a pipeline each, 10 runs of <= 2 GMAC; 4096^3  ~60 s (limit 120, no new
#     tiling after 80 s)
#   srt: SRT 120x160 at f32 (PyTorch eager, compiled, autocast) and f16-act            ~60 s (limit 80)
#   rpsrt: RP-SRT k=8 120x160, 1 and 32 views, f32 (PyTorch beside) and f16-act         ~90 s (limit 120)
#   cublas: f16 and bf16, 4096^3 and the tuned shapes                                  ~15 s (limits 15 + 15)
# In all ~270 s expected, 480 s at most (limits 460): one device call of 600 s with the machine's start.
tensor() {
    local r=$work/results/tensor quick=${RAYPATCH_GPU_BENCH_QUICK:-}
    deadline=$((SECONDS + ${RAYPATCH_GPU_BENCH_TENSOR_SECONDS:-480}))
    mkdir -p "$r"
    # The run's cache folder: the tuner writes its tilings there, every later command reads them.
    local cache=$work/tensor-cache
    mkdir -p "$cache"
    export RAYPATCH_CACHE_DIR=$cache
    # The models and sizes; quick: small random models (PyTorch wherever it runs), the tuner's stand-in shapes.
    local srt=(--only official:1) rpsrt=(--only official:8) tune=() side=4096
    local common=(--sizes 120x160 --max-reference-gmac 0 --repeats 20 --repeat-seconds 3 --pytorch-compile)
    local limits=(45 45 120 80 120 15)
    if [ -n "$quick" ]; then
        srt=(--only small:1) rpsrt=(--only small:8) tune=(--quick) side=512
        common=(--sizes 120x160 --max-reference-gmac 0 --repeats 3 --repeat-seconds 1 --pytorch-compile)
        limits=(240 240 150 150 150 60)
    fi
    # f16-act beside f32 (PyTorch is timed beside the f32 records): `--precision` where the bench has it, else the
    # sweep's own choice, which adds f16-act where the linear layers run on `tiled` (GPUs; lavapipe: asked for).
    local help
    help=$("${device[@]}" "$bin/raypatch-bench" --help 2>&1)
    if ! grep -q -- --coop-tune <<<"$help"; then
        echo "gpu_bench: the kit's raypatch-bench has no --coop-tune: run tools/bench/gpu_kit.sh again"
    fi
    if grep -q -- '--precision' <<<"$help"; then
        common+=(--precision f32 --precision f16-act)
    elif [ -n "$quick" ]; then
        common+=(--matmul-kernel tiled)
    fi
    grep -q -- '--pytorch-autocast' <<<"$help" && common+=(--pytorch-autocast)
    if command -v nvidia-smi >/dev/null; then
        run tensor 10 nvidia-smi
    fi
    run tensor 10 "${device[@]}" "$bin/render-frame" --list-adapters
    : >"$r/tests.tsv"
    tensor_test "kernels coop" "${limits[0]}" "$kit/tests/kernels" coop
    tensor_test "golden tensor path" "${limits[1]}" "$kit/tests/golden" golden_cases_on_the_tensor_path
    tensor_check "$r"
    run tensor "${limits[2]}" "${device[@]}" "$bin/raypatch-bench" --coop-tune "${tune[@]}" --tune-seconds \
        $((limits[2] * 2 / 3)) --out "$r/tune"
    [ -f "$cache/coop-tuning.tsv" ] && cp "$cache/coop-tuning.tsv" "$r/coop-tuning.tsv" &&
        cp "$cache/coop-tuning.tsv" "$out/coop-tuning.tsv"
    tensor_check "$r"
    run tensor "${limits[3]}" "${device[@]}" "$bin/raypatch-bench" "${srt[@]}" "${common[@]}" --out "$r/srt"
    tensor_check "$r"
    run tensor "${limits[4]}" "${device[@]}" "$bin/raypatch-bench" "${rpsrt[@]}" --views 32 "${common[@]}" \
        --out "$r/rpsrt"
    tensor_check "$r"
    # cuBLAS's f16 and bf16 GEMMs (PyTorch here, on CUDA where it has it): the square and the tuner's shapes.
    local shapes=(--shape "${side}x${side}x${side}") cuda=cpu
    if [ -z "$quick" ]; then
        shapes+=(--shape 300x1536x1536 --shape 4800x768x2304 --shape 19200x1536x1536)
    fi
    python3 -c 'import torch, sys; sys.exit(0 if torch.cuda.is_available() else 1)' 2>/dev/null && cuda=cuda
    for dtype in float16 bfloat16; do
        run tensor "${limits[5]}" sh -c 'python3 tools/bench/bench_gemm_pytorch.py "$@" >"$0.part" && mv "$0.part" "$0"' \
            "$r/cublas-$dtype.json" --device "$cuda" --dtype "$dtype" --repeats 20 "${shapes[@]}"
    done
    tensor_check "$r"
    deadline=
    unset RAYPATCH_CACHE_DIR
    cat "$r/tensor-check.md"
}

# tensor_test NAME SECONDS BINARY FILTER: one tensor test binary's tests matching FILTER; its exit code, seconds,
# limit and tests passed into tests.tsv.
tensor_test() {
    local name=$1 seconds=$2 binary=$3 filter=$4 log=$work/results/tensor-test.log
    run tensor-test "$seconds" "${device[@]}" "$binary" --test-threads 4 "$filter"
    cat "$log" >>"$work/results/tensor.log"
    local passed
    passed=$(grep -o '[0-9]* passed' "$log" | tail -n 1 | cut -d' ' -f1)
    rm -f "$log"
    printf '%s\t%s\t%s\t%s\t%s\n' "$name" "$code" "$took" "$limit" "${passed:-0}" >>"$work/results/tensor/tests.tsv"
}

# tensor_check DIR: tensor-check.md from what the tensor step measured so far, into DIR, OUT_DIR and the archive.
tensor_check() {
    python3 tools/bench/tensor_check.py "$1" ${RAYPATCH_GPU_BENCH_QUICK:+--quick} &&
        cp "$1/tensor-check.md" "$out/tensor-check.md"
    save
}

# host_check DIR: host-check.md from what the host step measured so far, into DIR, OUT_DIR and the archive.
host_check() {
    python3 tools/bench/host_check.py "$1" ${RAYPATCH_GPU_BENCH_QUICK:+--quick} &&
        cp "$1/host-check.md" "$out/host-check.md"
    save
}

# The results so far, into OUT_DIR (after every step); not the sweeps' scratch folders (model files, tens of MB).
save() {
    tar -czf "$out/gpu-bench.tar.gz.part" --exclude=scratch -C "$work/results" . &&
        mv "$out/gpu-bench.tar.gz.part" "$out/gpu-bench.tar.gz"
}

# The GPU's clocks, power and load every 100 ms while the steps run (clocks.csv in the archive): a GPU that idles
# between short submissions may not raise its clocks, which shows here beside the steps' start times in the log.
monitor_clocks() {
    command -v nvidia-smi >/dev/null || return 0
    nvidia-smi --query-gpu=timestamp,clocks.sm,clocks.mem,power.draw,utilization.gpu,pstate --format=csv -lms 100 \
        >"$work/results/clocks.csv" 2>&1 &
    clocks=$!
}

measure() {
    monitor_clocks
    for s in "${steps[@]}"; do
        case $s in
            info)
                run info 10 nvidia-smi
                run info 20 python3 -c "import torch; print('torch', torch.__version__, 'cuda:', \
torch.cuda.is_available() and torch.cuda.get_device_name(0))"
                run info 10 "$bin/render-frame" --list-adapters
                # The pipeline cache starts empty on a fresh machine: the first render compiles, the second reads it.
                export RAYPATCH_CACHE_DIR=$work/pipeline-cache
                run info 45 "$bin/render-frame" --timings --out "$work/results/info-render.png"
                run info 35 "$bin/render-frame" --timings --repeat 200 --out "$work/results/info-render.png"
                # The official RP-SRT k=8's first frame in a fresh process from an empty cache (issue 41's bar: load +
                # encode + first render within 1 s): the first record's load, first encode and first render.
                export RAYPATCH_CACHE_DIR=$work/pipeline-cache-first
                run info 60 "$bin/raypatch-bench" --only official:8 --no-pytorch --max-render-seconds 0.02 \
                    --max-reference-gmac 0 --repeats 1 --out "$work/results/first-frame"
                unset RAYPATCH_CACHE_DIR
                ;;
            tests)
                for test in kernels golden api executor; do
                    run tests 50 "$kit/tests/$test" --test-threads 4
                done
                ;;
            gemm) run gemm 45 "$bin/raypatch-bench" --gemm --repeats 50 --out "$work/results/gemm" ;;
            lab)
                run lab 10 python3 tools/bench/gemm_lab.py "$work/lab"
                run lab 40 "$bin/raypatch-bench" --gemm-lab "$work/lab" --out "$work/results/lab"
                ;;
            breakdown) engine_only breakdown 120 ;;
            variants)
                engine_only rows 180 --matmul-kernel rows
                engine_only no-subgroups 90 --no-subgroups
                ;;
            rpsrt) sweep rpsrt 240 25 --only official:8 --views 8,32 ;;
            srt) sweep srt 120 0 --only official:1 ;;
            families) sweep families 210 25 --only official-osrt:8 --only official-define:16 --views 8,32 ;;
            viewer) viewer ;;
            host) host ;;
            tensor) tensor ;;
        esac
        save
    done
    [ -n "${clocks:-}" ] && kill "$clocks" 2>/dev/null && save
    echo "gpu_bench: ${#steps[@]} step(s), $failed command(s) failed; results in $out/gpu-bench.tar.gz"
    return "$failed"
}

measure 2>&1 | tee "$out/gpu-bench.log"
code=${PIPESTATUS[0]}
rm -rf "$work"
exit "$code"
