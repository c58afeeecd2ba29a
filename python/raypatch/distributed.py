"""Evaluate or render many scenes across machines with Ray (`pip install ./python[ray]`).

    python -m raypatch.distributed evaluate --model M --scenes DIR_OR_GLOB --out results.csv \\
        [--address ray://HOST:10001] [--workers N] [--gpus-per-worker G] [--adapter NAME]
    python -m raypatch.distributed render --model M --scenes DIR_OR_GLOB --out DIR [...]

Ray Data maps the scene list over a pool of N stateful actors (`map_batches` with a class): each loads the model
once and then encodes every scene it is handed once and renders all its target views (raypatch.evaluate). Without
--address Ray starts locally (`ray.init()`, a laptop); with it the same code runs on a cluster. `evaluate` writes
one row per target view (scene, view, psnr, ssim, and an OSRT model's fg_ari, a depth model's abs_rel, sq_rel,
rmse and depth_pixels), sorted by scene and view: the same figures as a single process, and as
`render-frame --metrics`. Any bad input: one line naming it on stderr, exit code 2, nothing written.
"""

from __future__ import annotations

import argparse
import csv
import os
import sys
import tempfile
from typing import List

from . import Engine, Error
from .evaluate import COLUMNS, SceneWorker, scene_paths


def run(task: str, model: str, paths: List[str], out: str, address: str = None, workers: int = 2,
        gpus_per_worker: float = 0.0, adapter: str = None) -> List[dict]:
    """Runs `task` ("evaluate" or "render") over `paths` on Ray and returns the rows, errors included."""
    import logging

    import ray

    if not ray.is_initialized():
        ray.init(address=address, logging_level="ERROR", log_to_driver=False)
    # Ray Data's progress lines would bury the one-line errors and the summary.
    logging.getLogger("ray.data").setLevel(logging.WARNING)
    ray.data.DataContext.get_current().enable_progress_bars = False
    dataset = ray.data.from_items([{"path": p} for p in paths], override_num_blocks=len(paths))
    results = dataset.map_batches(
        SceneWorker,
        fn_constructor_kwargs={"model": model, "task": task, "out": out, "adapter": adapter},
        batch_size=1,
        concurrency=workers,
        num_gpus=gpus_per_worker,
        batch_format="default",
    )
    rows = []
    for row in results.iter_rows():
        rows.append({k: (v.item() if hasattr(v, "item") else v) for k, v in row.items()
                     if not (isinstance(v, float) and v != v)})
    return rows


def write_csv(rows: List[dict], out: str) -> None:
    """The rows as CSV, sorted by scene and view, written beside `out` and renamed into place."""
    rows = sorted(rows, key=lambda r: (r["scene"], r["view"]))
    columns = [c for c in COLUMNS if any(c in r for r in rows)]
    folder = os.path.dirname(os.path.abspath(out))
    with tempfile.NamedTemporaryFile("w", dir=folder, prefix=".results.", suffix=".tmp", delete=False,
                                     newline="") as file:
        writer = csv.DictWriter(file, fieldnames=columns)
        writer.writeheader()
        for row in rows:
            writer.writerow({c: repr(v) if isinstance(v, float) else v for c, v in row.items() if c in columns})
    os.replace(file.name, out)


def main(argv: List[str] = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m raypatch.distributed", description=__doc__.split("\n\n")[0])
    parser.add_argument("task", choices=("evaluate", "render"))
    parser.add_argument("--model", required=True, help="model .safetensors file")
    parser.add_argument("--scenes", required=True, help="folder of scene files / frames folders, or a glob")
    parser.add_argument("--out", required=True, help="results.csv (evaluate) or a folder (render)")
    parser.add_argument("--address", help="Ray cluster, e.g. ray://HOST:10001 (default: start Ray locally)")
    parser.add_argument("--workers", type=int, default=2, help="actors, each with the model loaded (default 2)")
    parser.add_argument("--gpus-per-worker", type=float, default=0.0, help="GPUs Ray reserves per actor")
    parser.add_argument("--adapter", help="GPU adapter name each worker uses (default: its best)")
    args = parser.parse_args(argv)
    try:
        if args.workers < 1:
            raise Error(f"--workers {args.workers}: expected at least 1")
        paths = scene_paths(args.scenes)
        if args.task == "evaluate":
            folder = os.path.dirname(os.path.abspath(args.out))
            if not os.path.isdir(folder) or os.path.isdir(args.out):
                raise Error(f"--out {args.out}: expected a file in an existing folder")
        Engine(args.adapter).load(args.model)  # the model's errors here, before any worker starts
    except Error as e:
        print(f"raypatch.distributed: {e}", file=sys.stderr)
        return 2
    try:
        import ray  # noqa: F401
    except ImportError:
        print("raypatch.distributed: needs Ray: pip install './python[ray]'", file=sys.stderr)
        return 2
    rows = run(args.task, os.path.abspath(args.model), [os.path.abspath(p) for p in paths], args.out, args.address,
               args.workers, args.gpus_per_worker, args.adapter)
    errors = [r["error"] for r in rows if "error" in r]
    if errors:
        for line in errors:
            print(f"raypatch.distributed: {line}", file=sys.stderr)
        return 2
    if args.task == "evaluate":
        write_csv(rows, args.out)
    print(f"{len(rows)} view(s) of {len(paths)} scene(s) -> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
