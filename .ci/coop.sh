#!/usr/bin/env bash
# The tensor path (MatmulKernel::Coop, cooperative matrices) on a CPU driver that has them: Mesa 26's lavapipe, in
# the Debian trixie chroot of .ci/coop-chroot.sh (8x8x8 f16 tiles, subgroups of 8). The test binaries are built
# here on the host and run inside it, the checkout bind-mounted at the same path:
#   1. the tensor kernels' tests (tests/kernels: `coop` in their names), against float64 products of the
#      f16-rounded operands, with their mutation checks;
#   2. the golden renders of every family at the f16-act precision on the tensor kernels (tests/golden.rs);
#   3. the same kernel tests again under Khronos' validation layer, which must report no error.
# Ends with one line `coop: N passed, M failed`. Where this machine cannot make the chroot (not root, no AVX2),
# it says why and exits 0: the ordinary tests still run. A fresh machine pays ~75 s for the chroot (kept after).
set -euo pipefail
cd "$(dirname "$0")/.."
checkout=$PWD

set +e
root=$(bash .ci/coop-chroot.sh | tail -n1)
made=$?
set -e
if [ "$made" = 3 ]; then
  echo "coop: skipped (the Mesa 26 chroot cannot be made here; see the line above)"
  exit 0
elif [ "$made" != 0 ]; then
  echo "coop: making the chroot failed (exit $made)" >&2
  exit 1
fi

# The test binaries, built on the host (their paths from cargo's JSON messages).
binaries=$(cargo test --release --no-run --test kernels --test golden --message-format=json 2>/dev/null \
  | python3 -c 'import json, sys
for line in sys.stdin:
    m = json.loads(line)
    if m.get("reason") == "compiler-artifact" and m.get("executable") and m["target"]["kind"] == ["test"]:
        print(m["target"]["name"], m["executable"])')
kernels=$(awk '$1 == "kernels" {print $2}' <<<"$binaries")
golden=$(awk '$1 == "golden" {print $2}' <<<"$binaries")
[ -x "$kernels" ] && [ -x "$golden" ] || { echo "coop: the test binaries were not built" >&2; exit 1; }

mounted=()
unmount() { for ((i = ${#mounted[@]} - 1; i >= 0; i--)); do umount "${mounted[$i]}" 2>/dev/null || true; done; }
trap unmount EXIT
mount_in() { # mount_in SOURCE TARGET [ARGS..]: mounts SOURCE on ROOT/TARGET unless it already is.
  local target="$root$2"
  mkdir -p "$target"
  mountpoint -q "$target" || { mount "${@:3}" "$1" "$target"; mounted+=("$target"); }
}
mount_in proc /proc -t proc
mount_in /dev /dev --bind
mount_in "$checkout" "$checkout" --bind
mkdir -p "$root/tmp"

passed=0
failed=0
# run NAME ENV.. -- BINARY ARGS..: one test binary inside the chroot; counts its tests.
run() {
  local name=$1 log
  shift
  log=$(mktemp)
  echo "coop: $name"
  # In the checkout (the tests find their assets from it), with a clean environment and a cache of its own.
  if chroot "$root" /bin/sh -c 'cd "$0" && exec "$@"' "$checkout" env -i HOME=/tmp PATH=/usr/bin:/bin \
      RAYPATCH_CACHE_DIR=/tmp/raypatch-cache "$@" --test-threads=2 2>&1 | tee "$log" \
      | grep -E '^(test |tests run on|tensor kernels|thread|coop)|passed|tolerance|error' ; then :; fi
  local p f
  p=$(grep -oE 'test result: [a-z]+\. ([0-9]+) passed' "$log" | grep -oE '[0-9]+ passed' | awk '{s+=$1} END {print s+0}')
  f=$(grep -oE '([0-9]+) failed;' "$log" | awk '{s+=$1} END {print s+0}')
  if ! grep -q 'test result: ok' "$log"; then f=$((f > 0 ? f : 1)); fi
  passed=$((passed + p))
  failed=$((failed + f))
  if [ -n "${VALIDATION_CHECK:-}" ] && grep -qE 'VUID|Validation (Error|Warning)' "$log"; then
    echo "coop: the validation layer reported:" >&2
    grep -E 'VUID|Validation (Error|Warning)' "$log" | sort | uniq -c | head -20 >&2
    failed=$((failed + 1))
  fi
  rm -f "$log"
}

run "tensor kernel tests" "$kernels" coop
run "golden renders on the tensor path" "$golden" golden_cases_on_the_tensor_path
VALIDATION_CHECK=1 run "tensor kernel tests under Khronos' validation layer" \
  VK_LOADER_LAYERS_ENABLE='*validation*' VK_INSTANCE_LAYERS=VK_LAYER_KHRONOS_validation "$kernels" coop
echo "coop: $passed passed, $failed failed"
[ "$failed" = 0 ]
