#!/usr/bin/env python3
"""Issue 47's tensor-path figures, checked from what tools/bench/gpu_bench.sh's tensor step measured: a table with
one row per figure (the figure, its bound, PASS / FAIL / NOT MEASURED, the file it comes from), then the
comparisons with PyTorch and cuBLAS, then the rows behind them. Reads, under TENSOR_DIR: tests.tsv (the tensor
tests' exit codes and counts), tune/coop-tune.json (raypatch-bench --coop-tune), srt/results.json and
rpsrt/results.json (raypatch-bench sweeps at f32 and f16-act, PyTorch beside the f32 records), cublas-float16.json
and cublas-bfloat16.json (tools/bench/bench_gemm_pytorch.py); writes the table to --out (default
TENSOR_DIR/tensor-check.md). Standard library only: the GPU machine has no package registry.

    python3 tools/bench/tensor_check.py TENSOR_DIR [--quick] [--out FILE]

--quick: the step's quick run (RAYPATCH_GPU_BENCH_QUICK=1): small random models stand in for the official ones,
the tuner's stand-in shapes and a 512³ GEMM for 4096³; the bounds are the same. A figure is PASS when it was
measured within its bound, FAIL when measured out of it, NOT MEASURED otherwise (not run, cut short, no such
record, PyTorch or CUDA missing).
"""
import argparse
import json
import os
import sys

# The host step's checker: the verdicts and how a record's time is read, or why it has none.
from host_check import FAIL, NOT_MEASURED, PASS, median, unmeasured

SIZE = "120x160"
VIEWS = 32
# The bounds of issue 47 (an H100 or H200).
GEMM_TFLOPS = 150.0
SRT_MS = 3.0
RPSRT_VIEWS_PER_S = 11500.0
# (model, k) of the two engine figures, as the sweeps name them, with titles; quick: small stand-ins.
FULL = {"srt": (("official", 1), "SRT"), "rpsrt": (("official", 8), "RP-SRT k=8"), "square": 4096}
QUICK = {"srt": (("small", 1), "small k=1 (for SRT)"), "rpsrt": (("small", 8), "small k=8 (for RP-SRT k=8)"),
         "square": 512}
# The tensor tests the step runs (tests.tsv names), each of which must run at least one test and pass.
TESTS = ("kernels coop", "golden tensor path")
# PyTorch's ways of rendering, by the record fields the harness fills (results.json), in the table's order.
TORCH = (("fp32 eager", ("pytorch_render_ms",)),
         ("fp32 compiled", ("pytorch_compiled_render_ms",)),
         ("bf16 autocast eager", ("pytorch_autocast_render_ms", "pytorch_bf16_render_ms")),
         ("bf16 autocast compiled", ("pytorch_autocast_compiled_render_ms", "pytorch_compiled_autocast_render_ms",
                                     "pytorch_bf16_compiled_render_ms")))


def load(folder, name):
    """(the JSON file TENSOR_DIR/name as read, None) or (None, why there is none)."""
    path = os.path.join(folder, name)
    try:
        with open(path) as f:
            return json.load(f), None
    except FileNotFoundError:
        return None, f"{name} missing (not run, or cut short)"
    except (OSError, ValueError) as e:
        return None, f"{name} unreadable: {e}"


def find(results, key, views, precision):
    """The sweep record of model `key` (model, k) rendering `views` views of 120x160 at `precision`, or None."""
    for r in (results or {}).get("results", []):
        if ((r["model"], r["k"]) == key and r["target_views"] == views and r["target_size"] == SIZE
                and r["group"] == "sweep" and r["precision"] == precision and r.get("variant", "") == ""):
            return r
    return None


def tests_row(folder):
    """The tensor tests (tests.tsv: name, exit code or -1 where not run, seconds, limit, tests passed)."""
    runs = {}
    try:
        with open(os.path.join(folder, "tests.tsv")) as f:
            for line in f:
                fields = line.rstrip("\n").split("\t")
                if len(fields) == 5:
                    runs[fields[0]] = (int(fields[1]), fields[2], fields[3], int(fields[4] or 0))
    except FileNotFoundError:
        pass
    said, statuses = [], []
    for test in TESTS:
        if test not in runs:
            said.append(f"{test}: not run")
            statuses.append(NOT_MEASURED)
            continue
        code, seconds, limit, passed = runs[test]
        if code == -1:
            said.append(f"{test}: not run (the step's deadline had passed)")
            statuses.append(NOT_MEASURED)
        elif code in (124, 137):
            said.append(f"{test}: cut at its {limit} s limit ({passed} passed)")
            statuses.append(NOT_MEASURED)
        elif code != 0:
            said.append(f"{test}: fails (exit {code}; {passed} passed) in {seconds} s")
            statuses.append(FAIL)
        elif passed == 0:
            said.append(f"{test}: no test ran (none of that name in the kit's binary)")
            statuses.append(NOT_MEASURED)
        else:
            said.append(f"{test}: {passed} pass in {seconds} s")
            statuses.append(PASS)
    status = FAIL if FAIL in statuses else (PASS if all(s == PASS for s in statuses) else NOT_MEASURED)
    return status, "; ".join(said)


def tune_rows(tune, why):
    """The tuner's row and the tensor GEMM's TFLOP/s row."""
    if tune is None:
        return (NOT_MEASURED, why), (NOT_MEASURED, why, None)
    picked = {c["class"]: c for c in tune["classes"]}
    parts = []
    for name in ("small", "large"):
        c = picked.get(name)
        if not c or not c.get("best"):
            parts.append(f"{name}: none timed")
            continue
        b = c["best"]
        total = next(x["total_ms"] for x in c["candidates"] if x["tiling"] == b)
        tried = sum(1 for x in c["candidates"] if x.get("total_ms") is not None)
        speedup = f", {c['default_total_ms'] / total:.2f}x the default" if c.get("default_total_ms") else ""
        parts.append(f"{name}: sg {b['sg_m']}x{b['sg_n']}, bk {b['bk']} (fastest of {tried}{speedup})")
    left_out = sum(1 for c in tune["classes"] for x in c["candidates"] if x.get("error"))
    figure = "; ".join(parts) + f"; {len(tune['tuning_lines'])} lines written"
    if left_out:
        figure += f"; {left_out} (tiling, class) pairs left out (wrong output or failed)"
    if tune.get("untried"):
        figure += f"; {tune['untried']} tilings untried (time budget)"
    status = PASS if len(tune["tuning_lines"]) == 2 else NOT_MEASURED
    square = tune.get("square")
    if square is None:
        gemm = (NOT_MEASURED, f"not measured: {tune.get('square_error') or 'no figure'}", None)
    else:
        n = square["size"]
        t = square["tiling"]
        gemm = (PASS if square["tflops"] >= GEMM_TFLOPS else FAIL,
                f"{n}³: {square['tflops']:.3f} TFLOP/s ({square['ms']:.3f} ms, sg {t['sg_m']}x{t['sg_n']}, bk {t['bk']})",
                square)
    return (status, figure), gemm


def engine_row(results, why, key, title, views):
    """(status, figure, f16-act record, f32 record) of one engine figure."""
    r = find(results, key, views, "f16-act")
    f32 = find(results, key, views, "f32")
    wall = median(r, "render_wall_ms")
    shape = f"{title} {views}x{SIZE} f16-act"
    if wall is None:
        missing = why or "no f16-act record in the results"
        if results and r is None and f32 is not None and views > 1:
            missing = (f"no f16-act record of {views} views (the sweep renders --views at f32 only: "
                       "harness/sweep.rs, many_views under f32_weights)")
        return NOT_MEASURED, f"{shape}: {unmeasured(r, missing)}", r, f32
    gpu = median(r, "render_gpu_ms")
    kernel = r.get("kernel")
    extra = (f", GPU {gpu:.3f} ms" if gpu is not None else "") + (f", GEMMs on {kernel}" if kernel else "")
    if views == 1:
        ok = wall <= SRT_MS
        return (PASS if ok else FAIL), f"{shape}: wall {wall:.3f} ms{extra}", r, f32
    rate = views / (wall * 1e-3)
    ok = rate >= RPSRT_VIEWS_PER_S
    return (PASS if ok else FAIL), f"{shape}: {rate:,.0f} views/s (wall {wall:.3f} ms{extra})", r, f32


def torch_rows(results, why, title, record, f32):
    """A comparison row per PyTorch mode: the engine's f16-act wall against PyTorch's render (on the f32 record)."""
    rows = []
    ours = median(record, "render_wall_ms")
    for mode, fields in TORCH:
        label = f"{title}: PyTorch {mode}"
        theirs = next((median(f32, f) for f in fields if median(f32, f) is not None), None)
        if f32 is None:
            rows.append((NOT_MEASURED, label, why or "no f32 record (PyTorch is timed beside it)"))
        elif theirs is None:
            if median(f32, "pytorch_render_ms") is not None:
                reason = "not timed: this bench has no such PyTorch mode"
            else:
                reason = (results or {}).get("pytorch") or f32.get("note") or "not timed"
            rows.append((NOT_MEASURED, label, reason))
        elif ours is None:
            rows.append((NOT_MEASURED, label, f"PyTorch {theirs:.3f} ms; the engine's f16-act not measured"))
        else:
            rows.append((PASS if ours <= theirs else FAIL, label,
                         f"PyTorch {theirs:.3f} ms, engine f16-act {ours:.3f} ms: {theirs / ours:.2f}x"))
    return rows


def cublas_rows(folder, square, side):
    rows, detail = [], []
    for dtype in ("float16", "bfloat16"):
        label = f"tensor GEMM {side}³: cuBLAS {dtype}"
        data, why = load(folder, f"cublas-{dtype}.json")
        if data is None:
            rows.append((NOT_MEASURED, label, why))
            continue
        shapes = data.get("shapes", [])
        for s in shapes:
            tflops = 2.0 * s["m"] * s["k"] * s["n"] / (s["median_ms"] * 1e-3) / 1e12
            detail.append(f"| {s['m']}x{s['k']}x{s['n']} | {dtype} | {s['median_ms']:.4f} | {tflops:.3f} |")
        hit = next((s for s in shapes if (s["m"], s["k"], s["n"]) == (side, side, side)), None)
        if hit is None:
            rows.append((NOT_MEASURED, label, f"no {side}³ shape in cublas-{dtype}.json"))
            continue
        theirs = 2.0 * side ** 3 / (hit["median_ms"] * 1e-3) / 1e12
        on = data.get("device", "?")
        figure = f"PyTorch {data.get('torch', '?')} on {on}: {theirs:.3f} TFLOP/s"
        if on == "cpu":
            rows.append((NOT_MEASURED, label, figure + " (the CPU: not cuBLAS)"))
            continue
        if square is None:
            rows.append((NOT_MEASURED, label, figure + "; the engine's not measured"))
            continue
        rows.append((PASS if square["tflops"] >= theirs else FAIL, label,
                     figure + f"; engine {square['tflops']:.3f} TFLOP/s = {square['tflops'] / theirs:.2f}x"))
    return rows, detail


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("tensor", help="the tensor step's results folder")
    parser.add_argument("--quick", action="store_true", help="the quick run's stand-in models and sizes")
    parser.add_argument("--out", help="where to write the table (default TENSOR_DIR/tensor-check.md)")
    args = parser.parse_args()
    profile = QUICK if args.quick else FULL
    folder = args.tensor
    tune, tune_why = load(folder, os.path.join("tune", "coop-tune.json"))
    srt, srt_why = load(folder, os.path.join("srt", "results.json"))
    rpsrt, rpsrt_why = load(folder, os.path.join("rpsrt", "results.json"))
    adapters = sorted({r.get("adapter", "?") for res in (srt, rpsrt) if res for r in res["results"]}
                      | ({tune["adapter"]} if tune else set()))

    tests = tests_row(folder)
    tuned, gemm = tune_rows(tune, tune_why)
    srt_status, srt_figure, srt_rec, srt_f32 = engine_row(srt, srt_why, *profile["srt"], 1)
    rp_status, rp_figure, rp_rec, rp_f32 = engine_row(rpsrt, rpsrt_why, *profile["rpsrt"], VIEWS)
    rows = [
        ("1", "the tensor tests on this adapter (kernels `coop`, golden renders on the tensor path)", tests[1],
         "all pass", tests[0], "tests.tsv, tensor.log"),
        ("2", "tilings tuned per shape class and written to the engine's tuning file", tuned[1],
         "a tiling per class (small, large)", tuned[0], "tune/coop-tune.json, coop-tuning.tsv"),
        ("3", f"the tensor GEMM (linear_coop, f16 in, f32 sums) at {profile['square']}³", gemm[1], f"≥ {GEMM_TFLOPS:.0f} TFLOP/s",
         gemm[0], "tune/coop-tune.json"),
        ("4", f"{profile['srt'][1]} {SIZE}, 1 view, --precision f16-act, wall time", srt_figure,
         f"≤ {SRT_MS} ms", srt_status, "srt/results.json"),
        ("5", f"{profile['rpsrt'][1]}, {VIEWS} views of {SIZE}, --precision f16-act, wall time", rp_figure,
         f"≥ {RPSRT_VIEWS_PER_S:,.0f} views/s", rp_status, "rpsrt/results.json"),
    ]
    side = gemm[2]["size"] if gemm[2] else profile["square"]
    comparisons = [(s, l, f, "srt/results.json") for s, l, f in
                   torch_rows(srt, srt_why, f"{profile['srt'][1]} 1x{SIZE}", srt_rec, srt_f32)]
    comparisons += [(s, l, f, "rpsrt/results.json") for s, l, f in
                    torch_rows(rpsrt, rpsrt_why, f"{profile['rpsrt'][1]} {VIEWS}x{SIZE}", rp_rec, rp_f32)]
    cublas, cublas_detail = cublas_rows(folder, gemm[2], side)
    comparisons += [(s, l, f, f"cublas-{l.split()[-1]}.json, tune/coop-tune.json") for s, l, f in cublas]

    text = "# Issue 47's tensor path, as measured (tools/bench/gpu_bench.sh OUT tensor)\n\n"
    text += f"Adapter: {', '.join(adapters) or 'none recorded'}. "
    text += ("Quick run: small random models stand in for the official ones, the tuner's stand-in shapes and "
             f"{profile['square']}³ for 4096³; the figures are not the issue's.\n\n"
             if args.quick else "Official-size models, random weights.\n\n")
    text += "| # | figure | measured | bound | status | from |\n|---|---|---|---|---|---|\n"
    text += "".join(f"| {' | '.join(row)} |\n" for row in rows)
    text += ("\n## Beside PyTorch and cuBLAS\n\nThe same renders in PyTorch (its official model code, same weights and "
             "inputs, on the f32 record) and cuBLAS's GEMM; bound: the engine at least as fast.\n\n"
             "| figure | measured | bound | status | from |\n|---|---|---|---|---|\n")
    text += "".join(f"| {label} | {figure} | engine as fast or faster | {status} | {source} |\n"
                    for status, label, figure, source in comparisons)
    if tune:
        text += "\n## The tuner's classes\n\n| class | tiling | total ms over the class's shapes |\n|---|---|---|\n"
        for c in tune["classes"]:
            for x in c["candidates"]:
                t = x["tiling"]
                mark = " (fastest)" if x["tiling"] == c.get("best") else ""
                total = f"{x['total_ms']:.4f}" if x.get("total_ms") is not None else (x.get("error") or "-")
                text += f"| {c['class']} | sg {t['sg_m']}x{t['sg_n']}, bk {t['bk']}{mark} | {total.replace('|', '/')} |\n"
    if cublas_detail:
        text += ("\n## cuBLAS (PyTorch F.linear, TF32 off)\n\n| M x K x N | dtype | ms | TFLOP/s |\n|---|---|---|---|\n"
                 + "\n".join(cublas_detail) + "\n")
    out = args.out or os.path.join(folder, "tensor-check.md")
    with open(out + ".partial", "w") as f:
        f.write(text)
    os.replace(out + ".partial", out)


if __name__ == "__main__":
    sys.exit(main())
