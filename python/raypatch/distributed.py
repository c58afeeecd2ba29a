"""Evaluate or render many scenes across machines with Ray (`pip install ./python[ray]`).

    python -m raypatch.distributed evaluate --model M --scenes DIR_OR_GLOB --out results.csv \\
        [--address ray://HOST:10001] [--workers N] [--gpus-per-worker G] [--adapter NAME]
    python -m raypatch.distributed render --model M --scenes DIR_OR_GLOB --out DIR [...]

Ray Data maps the scene list over a pool of N stateful actors (`map_batches` with a class): each loads the model
once and then encodes every scene it is handed once and renders all its target views (raypatch.evaluate). Without
--address Ray starts locally (`ray.init()`, a laptop); with it the same code runs on a cluster. `evaluate` writes
one row per target view (scene, view, psnr, ssim, and an OSRT model's fg_ari, a depth model's abs_rel, sq_rel,
rmse and depth_pixels), sorted by scene and view: the same figures as a single process, and as
`render-frame --metrics`. `render` writes DIR/<scene>/view_000.png, ... for every scene. Every argument and
output is checked before Ray starts; any bad input: one line naming it on stderr, exit code 2, nothing written
(3: a GPU error, 70: anything else, such as Ray failing). Outputs are written all or none by render-frame's
writer (raypatch.output): a failed scene, SIGINT or SIGTERM (exit 130 or 143) leaves nothing behind.
"""

from __future__ import annotations

import argparse
import csv
import io
import math
import os
import re
import signal
import sys
from typing import List, Optional

import raypatch

from . import Engine, Error, FileError, GpuError, InputError, output
from ._text import excerpt, path_text, quoted
from .evaluate import COLUMNS, SceneWorker, scene_name, scene_paths

PROG = "raypatch.distributed"
# Ray's addresses: ray://HOST:PORT (Ray Client), HOST:PORT (a cluster's GCS), "auto" (a cluster started on this
# machine), "local" (a new local one). HOST: a name of at most 253 characters, an IPv4 address or an [IPv6] one.
_ADDRESS = re.compile(r"(ray://)?(\[[0-9A-Fa-f:.]{2,45}\]|[A-Za-z0-9]([A-Za-z0-9.-]{0,251}[A-Za-z0-9])?):([0-9]{1,5})")
# The names render gives views: an input with such a name in a scene's output folder would be overwritten.
_VIEW_FILE = re.compile(r"view_[0-9]{3,}\.png")


def _task(text: str) -> str:
    if text not in ("evaluate", "render"):
        raise argparse.ArgumentTypeError(f"{quoted(text)}: expected evaluate or render")
    return text


def _address(text: str) -> str:
    match = _ADDRESS.fullmatch(text)
    if text not in ("auto", "local") and (match is None or not 1 <= int(match.group(4)) <= 65535):
        raise argparse.ArgumentTypeError(f"{quoted(text)}: expected ray://HOST:PORT, HOST:PORT, auto or local")
    return text


def _workers(text: str) -> int:
    if not re.fullmatch(r"[0-9]{1,6}", text.strip()) or int(text) < 1:
        raise argparse.ArgumentTypeError(f"{quoted(text)}: expected a whole number of actors, at least 1")
    return int(text)


def _gpus(text: str) -> float:
    try:
        gpus = float(text)
    except ValueError:
        gpus = math.nan
    if not (math.isfinite(gpus) and gpus >= 0):
        raise argparse.ArgumentTypeError(f"{quoted(text)}: expected a finite number of GPUs, 0 or more")
    return gpus


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:
        # One line, bounded (argparse quotes what it could not parse), where argparse prints its usage first.
        self.exit(2, f"{PROG}: {excerpt(message, 300)} (see --help)\n")


def _parser() -> argparse.ArgumentParser:
    parser = _Parser(prog=f"python -m {PROG}", description=__doc__.split("\n\n")[0])
    parser.add_argument("task", type=_task, help="evaluate or render")
    parser.add_argument("--model", required=True, help="model .safetensors file")
    parser.add_argument("--scenes", required=True, help="folder of scene files / frames folders, or a glob")
    parser.add_argument("--out", required=True, help="results.csv (evaluate) or a folder (render)")
    parser.add_argument("--address", type=_address, help="Ray cluster, e.g. ray://HOST:10001 (default: start Ray locally)")
    parser.add_argument("--workers", type=_workers, default=2, help="actors, each with the model loaded (default 2)")
    parser.add_argument("--gpus-per-worker", type=_gpus, default=0.0, help="GPUs Ray reserves per actor")
    parser.add_argument("--adapter", help="GPU adapter name each worker uses (default: its best)")
    return parser


def check_outputs(task: str, out: str, model: str, paths: List[str]) -> None:
    """Refuses an --out that cannot be written or that would replace an input (raypatch.output.check_outputs):
    the model, a scene file, a file of a frames folder; for render also two scenes of one name (one output
    folder)."""
    inputs = [("--model", model)] + [("--scenes", p) for p in paths]
    if task == "evaluate":
        if os.path.isdir(out):
            raise FileError(f"--out {path_text(out)}: is a folder; evaluate writes a CSV file")
        output.check_outputs([("--out", out)], [], inputs)
        return
    # Where views go: view_000.png, and any input's name that a view could have.
    views = {"view_000.png"} | {os.path.basename(os.path.realpath(p)) for _, p in inputs}
    views = sorted(v for v in views if _VIEW_FILE.fullmatch(v))
    folders, files, by_name = [("--out", out)], [], {}
    for path in paths:
        name = scene_name(path)
        other = by_name.setdefault(name, path)
        folder = os.path.join(out, name)
        if other != path:
            raise InputError(f"--scenes: {path_text(other)} and {path_text(path)} would both render into {path_text(folder)}")
        folders.append(("--out", folder))
        files += [("--out", os.path.join(folder, view)) for view in views]
    output.check_outputs(files, folders, inputs)


def run(task: str, model: str, paths: List[str], out: str, address: Optional[str] = None, workers: int = 2,
        gpus_per_worker: float = 0.0, adapter: Optional[str] = None) -> List[dict]:
    """Runs `task` ("evaluate" or "render", into the folder `out`) over `paths` on Ray and returns the rows,
    errors included. Ray's own failures (no cluster at `address`, an actor that died) raise Error."""
    import logging

    import ray

    if not ray.is_initialized():
        try:
            ray.init(address=address, logging_level="ERROR", log_to_driver=False)
        except SystemExit as e:  # Ray's own SIGTERM handler, in place while it starts: ends as ours would
            if e.code == signal.SIGTERM:
                output.stop(signal.SIGTERM)
            raise
        except Exception as e:  # whatever Ray raises for a cluster it cannot reach or start
            raise Error(f"--address {excerpt(address or 'local')}: cannot start Ray: {_first_line(e)}") from None
        output.stop_on_signals(PROG, ray.shutdown)  # again: ray.init sets its own SIGTERM handler
    # Ray Data's progress and log lines would bury the one-line errors and the summary (set after ray.data is
    # first used, which configures its logger).
    ray.data.DataContext.get_current().enable_progress_bars = False
    logging.getLogger("ray.data").setLevel(logging.ERROR)
    dataset = ray.data.from_items([{"path": p} for p in paths], override_num_blocks=len(paths))
    results = dataset.map_batches(
        SceneWorker,
        fn_constructor_kwargs={"model": model, "task": task, "out": out, "adapter": adapter},
        batch_size=1,
        compute=ray.data.ActorPoolStrategy(size=workers),
        num_gpus=gpus_per_worker,
        batch_format="default",
    )
    rows = []
    try:
        for row in results.iter_rows():
            rows.append({k: (v.item() if hasattr(v, "item") else v) for k, v in row.items()
                         if not (isinstance(v, float) and v != v)})
    except Exception as e:  # an actor that could not start or died: Ray's error, one line
        raise Error(f"Ray: {_first_line(e)}") from None
    return rows


def _first_line(error: Exception) -> str:
    lines = [line for line in str(error).splitlines() if line.strip()]
    return excerpt(lines[0] if lines else type(error).__name__, 300)


def csv_bytes(rows: List[dict]) -> bytes:
    """The rows as CSV, sorted by scene and view."""
    rows = sorted(rows, key=lambda r: (r["scene"], r["view"]))
    columns = [c for c in COLUMNS if any(c in r for r in rows)]
    text = io.StringIO(newline="")
    writer = csv.DictWriter(text, fieldnames=columns)
    writer.writeheader()
    for row in rows:
        writer.writerow({c: repr(v) if isinstance(v, float) else v for c, v in row.items() if c in columns})
    return text.getvalue().encode()


# The exit code of each class of error, the first that matches: a bad input or file 2, the GPU 3, anything else
# (Ray's own failures included) 70.
_EXIT_CODES = ((InputError, 2), (FileError, 2), (GpuError, 3), (Error, 70))


def _fail(error: Error) -> int:
    print(f"{PROG}: {error}", file=sys.stderr)
    return next(code for kind, code in _EXIT_CODES if isinstance(error, kind))


def _worker_error(row: dict) -> Error:
    """A scene's error as its worker raised it: the class (one of raypatch's, by name) and the line."""
    kind = getattr(raypatch, str(row.get("error_class")), Error)
    return (kind if isinstance(kind, type) and issubclass(kind, Error) else Error)(row["error"])


def main(argv: Optional[List[str]] = None) -> int:
    args = _parser().parse_args(argv)
    try:
        paths = scene_paths(args.scenes)
        check_outputs(args.task, args.out, args.model, paths)
        Engine(args.adapter).load(args.model)  # the model's errors here, before any worker starts
    except Error as e:
        return _fail(e)
    try:
        import ray
    except ImportError:
        print(f"{PROG}: needs Ray: pip install './python[ray]'", file=sys.stderr)
        return 2
    # A stopped run ends Ray's processes too (those of a local Ray that is still starting included).
    output.stop_on_signals(PROG, ray.shutdown)
    paths = [os.path.abspath(p) for p in paths]
    with output.Staged() as staged:
        try:
            # render: the scenes' folders are made in a temporary folder merged into --out at the commit.
            folder = staged.folder(args.out) if args.task == "render" else ""
            rows = run(args.task, os.path.abspath(args.model), paths, folder, args.address, args.workers,
                       args.gpus_per_worker, args.adapter)
            errors = [_worker_error(r) for r in rows if "error" in r]
            if errors:
                return [_fail(e) for e in errors][0]
            if args.task == "evaluate":
                staged.write(args.out, csv_bytes(rows))
            staged.commit()
        except Error as e:
            return _fail(e)
    print(f"{len(rows)} view(s) of {len(paths)} scene(s) -> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
