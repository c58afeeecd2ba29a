"""Training curves of train.py runs: validation PSNR and training loss against step.

    python3 tools/bench/plot_curves.py --out docs/quality/training_curves.png NAME=RUN_DIR [NAME=RUN_DIR ...]

Reads RUN_DIR/curve.csv (written by train.py) of each run, draws both panels into --out, and copies each curve
next to it, named after the run folder (RUN_DIR's last component).csv. A curve with a heldout_psnr column (train.py
--watch) is drawn too, dashed.
"""

import argparse
import csv
import shutil
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def read_curve(path):
    with open(path, newline="") as file:
        rows = list(csv.DictReader(file))
    if not rows or not {"step", "train_seconds", "loss", "val_psnr"} <= rows[0].keys():
        raise ValueError(f"{path}: expected train.py's curve.csv (step, train_seconds, lr, loss, val_psnr)")
    return rows


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, required=True, help="PNG to write")
    parser.add_argument("--psnr-title", default="validation PSNR (first --val-scenes validation scenes)",
                        help="title of the PSNR panel")
    parser.add_argument("runs", nargs="+", help="NAME=RUN_DIR")
    args = parser.parse_args(argv)
    curves = {}
    try:
        for run in args.runs:
            name, sep, folder = run.rpartition("=")
            if not sep:
                raise ValueError(f"{run}: expected NAME=RUN_DIR")
            curves[name] = (Path(folder) / "curve.csv", read_curve(Path(folder) / "curve.csv"))
    except (OSError, ValueError) as error:
        print(f"plot_curves: error: {error}", file=sys.stderr)
        return 2
    figure, (psnr_axes, loss_axes) = plt.subplots(1, 2, figsize=(11, 4))
    for name, (_, rows) in curves.items():
        validated = [r for r in rows if r["val_psnr"]]
        # Steps, not seconds: train_seconds is wall time, which depends on what else shares the machine.
        psnr_axes.plot([int(r["step"]) for r in validated], [float(r["val_psnr"]) for r in validated],
                       marker="o", markersize=3, label=name)
        watched = [r for r in validated if r.get("heldout_psnr")]
        if watched:
            psnr_axes.plot([int(r["step"]) for r in watched], [float(r["heldout_psnr"]) for r in watched],
                           marker="s", markersize=3, linestyle="--", label=f"{name}, held-out (--watch)")
        loss_axes.plot([int(r["step"]) for r in rows], [float(r["loss"]) for r in rows], label=name)
    psnr_axes.set(xlabel="step", ylabel="PSNR (dB)", title=args.psnr_title)
    loss_axes.set(xlabel="step", ylabel="training MSE", yscale="log",
                  title="training loss (mean over the steps since the previous row)")
    for axes in (psnr_axes, loss_axes):
        axes.grid(alpha=0.3)
        axes.legend()
    figure.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(args.out, dpi=110)
    for name, (path, _) in curves.items():
        shutil.copyfile(path, args.out.parent / f"{path.parent.name}.csv")
    print(f"wrote {args.out} and {len(curves)} curves beside it")
    return 0


if __name__ == "__main__":
    sys.exit(main())
