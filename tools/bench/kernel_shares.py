#!/usr/bin/env python3
"""Where the GPU time goes, from raypatch-bench's kernels.csv: per configuration (model, size, encode or render),
the ops that take the most time, by kernel, with their share. tools/bench/gpu_bench.sh prints it after each sweep,
so that the log of a GPU run says what limits each figure even when the results folder does not come back.

    python3 tools/bench/kernel_shares.py OUT/kernels.csv [TOP]     # default: the 8 largest ops per configuration
"""
import csv
import sys
from collections import defaultdict


def main():
    if len(sys.argv) not in (2, 3):
        sys.exit("usage: kernel_shares.py KERNELS_CSV [TOP]")
    path = sys.argv[1]
    top = int(sys.argv[2]) if len(sys.argv) == 3 else 8
    try:
        with open(path, newline="") as f:
            rows = list(csv.DictReader(f))
    except OSError as e:
        sys.exit(f"{path}: cannot read: {e.strerror}")
    missing = {"config", "op", "kernel", "dispatches", "ms", "share"} - set(rows[0] if rows else {})
    if missing:
        sys.exit(f"{path}: expected raypatch-bench's kernels.csv (columns config, op, kernel, dispatches, ms, share)")
    by_config = defaultdict(list)
    for row in rows:
        by_config[row["config"]].append(row)
    for config, rows in by_config.items():
        # kernels.csv holds, per configuration, a row per kernel (op `*`) and a row per op (layers folded).
        kernels = [r for r in rows if r["op"] == "*"]
        ops = [r for r in rows if r["op"] != "*"]
        total = sum(float(r["ms"]) for r in kernels)
        print(f"{config}: {total:.3f} ms of GPU time in {sum(int(r['dispatches']) for r in kernels)} dispatches")
        print("  by kernel: " + ", ".join(f"{r['kernel']} {float(r['ms']):.3f} ms ({float(r['share']):.0%})"
                                          for r in sorted(kernels, key=lambda r: -float(r["ms"]))))
        for r in sorted(ops, key=lambda r: -float(r["ms"]))[:top]:
            print(f"  {float(r['ms']):8.3f} ms {float(r['share']):4.0%} x{int(r['dispatches']):<3} {r['kernel']:<16} {r['op']}")

if __name__ == "__main__":
    main()
