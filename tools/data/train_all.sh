#!/usr/bin/env bash
# Makes the scene sets (unless present) and trains SRT and RP-SRT k = 2, 4, 8 with the same step budget, each
# exported to $RUNS/<name>/model.safetensors and logged to $RUNS/<name>.log. This is how the bundled models were
# trained (docs/QUALITY.md): the four runs at once, one CPU thread each, on a 2-core machine (about 62 minutes).
#
#   tools/data/train_all.sh              # all four models
#   tools/data/train_all.sh 4            # only RP-SRT k=4 (arguments: patch sizes, 1 = SRT)
#   PRESET=gpu BATCH=32 STEPS=N THREADS=8 tools/data/train_all.sh # on a CUDA machine (train.py picks cuda when present)
#
# Environment: DATA (scene sets, default /work/data/msn-like), RUNS (default target/runs), PRESET (cpu), STEPS
# (3000), BATCH (8), LR (5e-4; the official 1e-4 barely leaves the mean colour in a few thousand steps, see
# tools/README.md), THREADS (1 per run), TRAIN_SCENES (20000).
# A run that was interrupted resumes from its checkpoint when the same command is run again.
set -euo pipefail
cd "$(dirname "$0")/../.."

DATA=${DATA:-/work/data/msn-like}
RUNS=${RUNS:-target/runs}
PRESET=${PRESET:-cpu}
STEPS=${STEPS:-3000}
BATCH=${BATCH:-8}
LR=${LR:-5e-4}
THREADS=${THREADS:-1}
TRAIN_SCENES=${TRAIN_SCENES:-20000}
SHARD=1000

# Each set is complete when its last file exists (files are written atomically, in seed order).
last_shard=$(printf 'shard-%05d.safetensors' $(( (TRAIN_SCENES + SHARD - 1) / SHARD - 1 )))
[ -f "$DATA/train/$last_shard" ] ||
  python3 tools/data/make_scenes.py --split train --count "$TRAIN_SCENES" --shard-size $SHARD --pngs 0 \
    --out "$DATA/train"
[ -f "$DATA/val/scene-1000199.safetensors" ] ||
  python3 tools/data/make_scenes.py --split val --count 200 --pngs 0 --out "$DATA/val"
[ -f "$DATA/test/scene-2000299.safetensors" ] ||
  python3 tools/data/make_scenes.py --split test --count 300 --pngs 8 --out "$DATA/test"

patch_sizes=("$@")
[ $# -gt 0 ] || patch_sizes=(1 2 4 8)
every=$(( STEPS >= 20 ? STEPS / 20 : 1 ))
mkdir -p "$RUNS"
pids=()
for k in "${patch_sizes[@]}"; do
  if [ "$k" = 1 ]; then name=srt; else name=rpsrt-k$k; fi
  python3 tools/data/train.py --k "$k" --preset "$PRESET" --train "$DATA/train" --val "$DATA/val" --out "$RUNS/$name" \
    --steps "$STEPS" --batch "$BATCH" --lr "$LR" --threads "$THREADS" --val-scenes 32 \
    --val-every "$every" --log-every 50 --checkpoint-every "$every" > "$RUNS/$name.log" 2>&1 &
  pids+=($!)
done
status=0
for pid in "${pids[@]}"; do wait "$pid" || status=1; done
[ $status = 0 ] || echo "train_all.sh: a run failed, see $RUNS/*.log" >&2
exit $status
