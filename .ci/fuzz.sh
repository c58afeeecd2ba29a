#!/usr/bin/env bash
# Runs every cargo fuzz target (fuzz/) for FUZZ_SECONDS each (default 20), from the committed corpus plus the
# golden model and scene files. Needs a nightly toolchain (libFuzzer's sanitizer coverage); without one it
# says so and exits 0: tests/fuzz_corpus.rs still runs the targets' entry points on stable.
set -euo pipefail
cd "$(dirname "$0")/.."

seconds=${FUZZ_SECONDS:-20}
# libFuzzer's per-input timeout (-timeout): an input that takes longer fails the run (issue 50: a search the
# input could make quadratic). The targets read inputs of at most -max_len in well under a second.
input_timeout=${FUZZ_INPUT_TIMEOUT:-5}
if ! rustup toolchain list 2>/dev/null | grep -q '^nightly'; then
    echo "fuzz: no nightly toolchain here, cargo fuzz skipped (tests/fuzz_corpus.rs ran the targets on stable)"
    exit 0
fi
command -v cargo-fuzz >/dev/null || cargo install cargo-fuzz --locked --quiet

# A scratch corpus per target: the committed inputs and the golden files (new finds stay in target/).
work=target/fuzz-corpus
rm -rf "$work"
for t in safetensors_file model_file scene_file frames_folder checkpoint_file checkpoint_pickle; do
    mkdir -p "$work/$t"
    cp fuzz/corpus/"$t"/* "$work/$t"/ 2>/dev/null || true
done
for f in assets/golden/*/*.safetensors; do
    name="$(basename "$(dirname "$f")")-$(basename "$f")"
    cp "$f" "$work/safetensors_file/$name"
    case "$f" in
        */model.safetensors) cp "$f" "$work/model_file/$name" ;;
        */scene.safetensors) cp "$f" "$work/scene_file/$name" ;;
    esac
done

for t in safetensors_file model_file scene_file frames_folder checkpoint_file checkpoint_pickle; do
    echo "fuzz: $t for ${seconds}s, at most ${input_timeout}s an input"
    # -rss_limit_mb: memory must stay bounded on any input; -timeout: no input may hang.
    status=0
    # --dev: a debug build (compiles in a fraction of the time, and overflow checks catch more).
    cargo +nightly fuzz run --dev --sanitizer none "$t" "$work/$t" -- \
        -max_total_time="$seconds" -rss_limit_mb=2048 -timeout="$input_timeout" -max_len=1048576 -print_final_stats=1 \
        > "$work/$t.log" 2>&1 || status=$?
    grep -E '^stat::(number_of_executed_units|peak_rss_mb)' "$work/$t.log" || true
    if [ "$status" -ne 0 ]; then
        tail -n 40 "$work/$t.log" >&2
        echo "fuzz: $t failed (the input is in fuzz/artifacts/$t; add it to fuzz/corpus/$t once fixed)" >&2
        exit 1
    fi
done
