#!/usr/bin/env bash
# Makes the scene sets (unless present) and trains SRT and RP-SRT k = 2, 4, 8 one after the other, each exported to
# $RUNS/<name>/model.safetensors. Run from anywhere; the plan and its measurements are in tools/README.md.
#
#   tools/train_all.sh              # all four models
#   tools/train_all.sh 4            # only RP-SRT k=4 (arguments: patch sizes, 1 = SRT)
#   PRESET=gpu STEPS=N BATCH=32 tools/train_all.sh   # on a CUDA machine (train.py picks cuda when present)
#
# Environment: DATA (scene sets, default /work/data/msn-like), RUNS (default target/runs), PRESET (cpu), STEPS (3000),
# BATCH (16), LR (1e-4, the official rate), THREADS (2), TRAIN_SCENES (50000).
# A run that was interrupted resumes from its checkpoint when the same command is run again.
set -euo pipefail
cd "$(dirname "$0")/.."

DATA=${DATA:-/work/data/msn-like}
RUNS=${RUNS:-target/runs}
PRESET=${PRESET:-cpu}
STEPS=${STEPS:-3000}
BATCH=${BATCH:-16}
LR=${LR:-1e-4}
THREADS=${THREADS:-2}
TRAIN_SCENES=${TRAIN_SCENES:-50000}
SHARD=1000

# Each set is complete when its last file exists (files are written atomically, in seed order).
last_shard=$(printf 'shard-%05d.safetensors' $(( (TRAIN_SCENES + SHARD - 1) / SHARD - 1 )))
[ -f "$DATA/train/$last_shard" ] ||
  python3 tools/make_scenes.py --split train --count "$TRAIN_SCENES" --shard-size $SHARD --out "$DATA/train"
[ -f "$DATA/val/scene-1000199.safetensors" ] ||
  python3 tools/make_scenes.py --split val --count 200 --out "$DATA/val"
[ -f "$DATA/test/scene-2000499.safetensors" ] ||
  python3 tools/make_scenes.py --split test --count 500 --out "$DATA/test"

patch_sizes=("$@")
[ $# -gt 0 ] || patch_sizes=(1 2 4 8)
every=$(( STEPS >= 20 ? STEPS / 20 : 1 ))
for k in "${patch_sizes[@]}"; do
  if [ "$k" = 1 ]; then name=srt-$PRESET; else name=rpsrt-k$k-$PRESET; fi
  python3 tools/train.py --k "$k" --preset "$PRESET" --train "$DATA/train" --val "$DATA/val" --out "$RUNS/$name" \
    --steps "$STEPS" --batch "$BATCH" --lr "$LR" --threads "$THREADS" --val-scenes 64 \
    --val-every "$every" --checkpoint-every "$every"
done
