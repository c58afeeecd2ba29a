#!/usr/bin/env python3
"""Issue 41's "done when" criteria, checked from what tools/bench/gpu_bench.sh's host step measured: a table
with one row per criterion (the figure, its bound, PASS / FAIL / NOT MEASURED, the file it comes from), then
the rows behind each figure. Reads the raypatch-bench results.json files and the test exit codes (tests.tsv)
under HOST_DIR; writes the table to --out (default HOST_DIR/host-check.md). Standard library only: the GPU
machine has no package registry.

    python3 tools/bench/host_check.py HOST_DIR [--quick] [--out FILE]

--quick: the host step's quick run (RAYPATCH_GPU_BENCH_QUICK=1), small random models standing in for the
official ones, fewer sizes; the bounds are the same. A criterion is PASS when every figure it needs was
measured within its bound, FAIL when one measured figure is out of it, NOT MEASURED otherwise (a run cut
short, a size that did not fit, a render timed by the wall clock alone).
"""
import argparse
import json
import os
import sys

VIEWS = (1, 8, 32)
# The models of each criterion as the sweep names them: (model, k), with each sweep's sizes (harness/sweep.rs:
# Ray-Patch sizes divide by k, the official OSRT runs at 120x160 only) and a title.
FULL = {
    "rpsrt": (("official", 8), "RP-SRT k=8", ("120x160", "240x320", "480x640", "960x1280")),
    "osrt": (("official-osrt", 8), "RP-OSRT k=8", ("120x160",)),
    "define": (("official-define", 16), "RP-DeFiNe k=16", ("240x320", "480x640", "960x1280")),
    "first_size": "120x160",
    "define_size": "480x640",
}
QUICK = {
    "rpsrt": (("small", 8), "small k=8 (for RP-SRT k=8)", ("120x160",)),
    "osrt": None,
    "define": (("small", 4), "small k=4 (for RP-DeFiNe k=16)", ("120x160",)),
    "first_size": "120x160",
    "define_size": "120x160",
}
# Which results folder under HOST_DIR holds which model's sweep.
FOLDERS = {"rpsrt": "rpsrt", "osrt": "families", "define": "families"}
CRITERION_TESTS = ("api", "golden", "kernels")

PASS, FAIL, NOT_MEASURED = "PASS", "FAIL", "NOT MEASURED"


def load(host, folder):
    """(HOST_DIR/folder/results.json as read, None) or (None, why there is none)."""
    path = os.path.join(host, folder, "results.json")
    try:
        with open(path) as f:
            results = json.load(f)
    except FileNotFoundError:
        return None, f"{folder}/results.json missing (not run, or cut short before its first size)"
    except (OSError, ValueError) as e:
        return None, f"{folder}/results.json unreadable: {e}"
    return results, None


def median(record, field):
    """The median time of a record's field (a stats object), or None where the record or the field has none."""
    stats = record.get(field) if record else None
    return stats["median_ms"] if isinstance(stats, dict) else None


def find(results, key, views, size, group="sweep"):
    """The f32 record of model `key` (model, k) rendering `views` views of `size` in `group`, or None."""
    for r in results["results"] if results else []:
        if ((r["model"], r["k"]) == key and r["target_views"] == views and r["target_size"] == size
                and r["group"] == group and r["precision"] == "f32"
                and (group != "sweep" or r["variant"] == "")):
            return r
    return None


def verdict(rows):
    """PASS / FAIL / NOT MEASURED of rows [(ok, or None where not measured, ...)]: FAIL on any failure, PASS
    when every row was measured and passed."""
    if any(row[0] is False for row in rows):
        return FAIL
    return PASS if rows and all(row[0] for row in rows) else NOT_MEASURED


def unmeasured(record, why_missing):
    """Why a record gives no figure: its note (skipped, does not fit, banded), or that it is missing."""
    if record is None:
        return why_missing
    return record.get("note") or "no time recorded"


def sweep_sizes(profile, loaded):
    """Each size of each swept model the profile has: (bench model key, title, size, its results, why missing)."""
    for name in ("rpsrt", "osrt", "define"):
        if profile[name] is None:
            continue
        key, title, sizes = profile[name]
        results, why = loaded[FOLDERS[name]]
        for size in sizes:
            yield key, title, size, results, why


def criterion1(profile, loaded):
    rows = []
    for key, title, size, results, why in sweep_sizes(profile, loaded):
        for views in VIEWS:
            r = find(results, key, views, size)
            wall, gpu = (median(r, "render_wall_ms"), median(r, "render_gpu_ms")) if r else (None, None)
            label = f"{title} {views}x{size}"
            if wall is None or gpu is None:
                rows.append((None, label, "-", "-", "-", unmeasured(r, why or "not in the results")))
                continue
            bound = 1.15 * gpu + 0.3
            rows.append((wall <= bound, label, f"{wall:.2f}", f"{gpu:.2f}", f"{bound:.2f}", ""))
    measured = [row for row in rows if row[0] is not None]
    worst = max(measured, key=lambda row: float(row[2]) / float(row[4]), default=None)
    figure = f"{len(measured)} of {len(rows)} measured"
    if worst:
        figure += f"; worst {worst[1]}: wall {worst[2]} ms, GPU {worst[3]} ms (bound {worst[4]} ms)"
    detail = ["| render | wall ms | GPU ms | bound ms | within | note |", "|---|---|---|---|---|---|"]
    detail += [f"| {row[1]} | {row[2]} | {row[3]} | {row[4]} | {yes_no(row[0])} | {row[5]} |" for row in rows]
    return verdict(rows), figure, detail


def yes_no(ok):
    return "-" if ok is None else ("yes" if ok else "**no**")


def criterion2(profile, loaded):
    key, title, _ = profile["rpsrt"]
    results, why = loaded["rpsrt"]
    r = find(results, key, 1, profile["first_size"])
    wall, gpu = (median(r, "render_wall_ms"), median(r, "render_gpu_ms")) if r else (None, None)
    if wall is None or gpu is None:
        return NOT_MEASURED, f"{title} 1x{profile['first_size']}: {unmeasured(r, why or 'not in the results')}"
    host = wall - gpu
    status = PASS if host <= 0.15 else FAIL
    size = profile["first_size"]
    return status, f"{title} 1x{size}: wall {wall:.3f} ms, GPU {gpu:.3f} ms, wall − GPU {host:.3f} ms"


def criterion3(profile, loaded):
    key, title, _ = profile["define"]
    results, why = loaded["define-pytorch"]
    size = profile["define_size"]
    r = find(results, key, 1, size)
    ours, theirs = (median(r, "render_wall_ms"), median(r, "pytorch_render_ms")) if r else (None, None)
    if ours is None:
        return NOT_MEASURED, f"{title} 1x{size}: {unmeasured(r, why or 'not in the results')}"
    if theirs is None:
        return NOT_MEASURED, f"{title} 1x{size}: PyTorch not timed ({r.get('note') or results.get('pytorch')})"
    speedup = theirs / ours
    status = PASS if speedup >= 2.0 else FAIL
    return status, (f"{title} 1x{size}: PyTorch eager {theirs:.2f} ms / engine wall {ours:.2f} ms = {speedup:.2f}x "
                    f"(PyTorch: {results.get('pytorch', '?')})")


def criterion4(profile, loaded):
    """The first frame (the first record of the rpsrt run, a fresh process with empty caches) and the
    pipelines every later shape of the same model compiled."""
    key, title, _ = profile["rpsrt"]
    results, why = loaded["rpsrt"]
    if results is None:
        return NOT_MEASURED, why, []
    same = [r for r in results["results"] if (r["model"], r["k"]) == key and r["precision"] == "f32"]
    first = same[0] if same else None
    parts = [first.get(f) for f in ("load_wall_ms", "first_encode_wall_ms", "first_render_wall_ms")] if first else []
    later = [r for r in same[1:] if r.get("first_render_pipelines") is not None]
    compiled = [r for r in later if r["first_render_pipelines"] > 0]
    detail = ["| later shape | group | pipelines compiled by its first render | first render ms |", "|---|---|---|---|"]
    for r in later:
        shape = f"{r['target_views']}x{r['target_size']}" + (f": {r['variant']}" if r["variant"] else "")
        detail.append(f"| {shape} | {r['group']} | {r['first_render_pipelines']} | "
                      f"{r.get('first_render_wall_ms') or 0:.1f} |")
    if not parts or any(p is None for p in parts):
        return NOT_MEASURED, f"{title}: no first frame recorded (load, first encode, first render)", detail
    total = sum(parts)
    figure = (f"{title} first frame: load {parts[0]:.0f} + encode {parts[1]:.0f} + first render "
              f"{parts[2]:.0f} ({first['target_views']}x{first['target_size']}) = {total:.0f} ms; "
              f"{len(compiled)} of {len(later)} later shapes compiled pipelines"
              + (f" ({sum(r['first_render_pipelines'] for r in compiled)} in all)" if compiled else ""))
    if total > 1000 or compiled:
        return FAIL, figure, detail
    return (PASS if later else NOT_MEASURED), figure + ("" if later else "; no later shape measured"), detail


def criterion5(profile, loaded):
    rows = []
    for key, title, size, results, why in sweep_sizes(profile, loaded):
        batched, path = find(results, key, 32, size), find(results, key, 32, size, group="views")
        label = f"{title} 32x{size}"
        one = median(batched, "render_wall_ms") if batched else None
        each = median(path, "render_wall_ms") if path else None
        if one is None or each is None:
            missing = unmeasured(path if one else batched, why or "not in the results")
            rows.append((None, label, "-", "-", "-", missing))
            continue
        ratio = each / one
        rows.append((ratio <= 1.3, label, f"{one:.2f}", f"{each:.2f}", f"{ratio:.2f}", path.get("note", "")))
    measured = [row for row in rows if row[0] is not None]
    worst = max(measured, key=lambda row: float(row[4]), default=None)
    figure = f"{len(measured)} of {len(rows)} measured"
    if worst:
        figure += f"; worst {worst[1]}: --view all {worst[3]} ms, batched {worst[2]} ms = {worst[4]}x"
    detail = ["| views | one batched call wall ms | a frame per view wall ms | ratio | within | note |",
              "|---|---|---|---|---|---|"]
    detail += [f"| {row[1]} | {row[2]} | {row[3]} | {row[4]} | {yes_no(row[0])} | {row[5]} |" for row in rows]
    return verdict(rows), figure, detail


def criterion6(host):
    """The test binaries' exit codes (tests.tsv: test, exit code or -1 where not run, seconds, limit)."""
    path = os.path.join(host, "tests.tsv")
    runs = {}
    try:
        with open(path) as f:
            for line in f:
                fields = line.rstrip("\n").split("\t")
                if len(fields) == 4:
                    runs[fields[0]] = (int(fields[1]), fields[2], fields[3])
    except FileNotFoundError:
        pass
    def said(test):
        if test not in runs:
            return f"{test} not run"
        code, seconds, limit = runs[test]
        if code == -1:
            return f"{test} not run (the step's deadline had passed)"
        outcome = {0: "pass", 124: f"cut at its {limit} s limit", 137: f"killed at its {limit} s limit"}
        return f"{test} {outcome.get(code, f'fails (exit {code})')} in {seconds} s"
    wanted = [runs.get(t, (None,))[0] for t in CRITERION_TESTS]
    if any(code not in (None, -1, 0, 124, 137) for code in wanted):
        status = FAIL
    elif all(code == 0 for code in wanted):
        status = PASS
    else:
        status = NOT_MEASURED
    figure = "; ".join(said(t) for t in CRITERION_TESTS)
    others = [t for t in runs if t not in CRITERION_TESTS]
    if others:
        figure += " (also " + "; ".join(said(t) for t in others) + ")"
    return status, figure


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("host", help="the host step's results folder (rpsrt/, families/, define-pytorch/, tests.tsv)")
    parser.add_argument("--quick", action="store_true", help="the quick run's small stand-in models and sizes")
    parser.add_argument("--out", help="where to write the table (default HOST_DIR/host-check.md)")
    args = parser.parse_args()
    profile = QUICK if args.quick else FULL
    loaded = {folder: load(args.host, folder) for folder in ("rpsrt", "families", "define-pytorch")}
    adapters = sorted({r.get("adapter", "?") for results, _ in loaded.values() if results for r in results["results"]})

    c1, figure1, detail1 = criterion1(profile, loaded)
    c2, figure2 = criterion2(profile, loaded)
    c3, figure3 = criterion3(profile, loaded)
    c4, figure4, detail4 = criterion4(profile, loaded)
    c5, figure5, detail5 = criterion5(profile, loaded)
    c6, figure6 = criterion6(args.host)
    families = "rpsrt/results.json, families/results.json"
    rows = [
        ("1", "wall vs GPU time at every size and view count (1, 8, 32) of the rpsrt and families sweeps", figure1,
         "wall ≤ 1.15 × GPU + 0.3 ms", c1, families),
        ("2", "RP-SRT k=8, 1 view 120x160", figure2, "wall ≤ GPU + 0.15 ms", c2, "rpsrt/results.json"),
        ("3", "RP-DeFiNe k=16 480x640 against PyTorch fp32 eager, wall time", figure3, "≥ 2x", c3,
         "define-pytorch/results.json"),
        ("4", "fresh process, empty pipeline and driver caches: load + encode + first render of RP-SRT k=8; "
         "later shapes compile nothing", figure4, "≤ 1000 ms; 0 pipelines", c4, "rpsrt/results.json"),
        ("5", "`render-frame --view all` path on 32 views against one batched call, wall time", figure5,
         "≤ 1.3x", c5, families),
        ("6", "the API, golden and kernel tests on the GPU", figure6, "all pass", c6, "tests.tsv, host.log"),
    ]
    text = "# Issue 41's \"done when\", as measured (tools/bench/gpu_bench.sh OUT host)\n\n"
    text += f"Adapter: {', '.join(adapters) or 'none recorded'}. "
    text += ("Quick run: small random models stand in for the official ones; the figures are not the issue's.\n\n"
             if args.quick else "Official-size models, random weights.\n\n")
    text += "| # | criterion | measured | bound | status | from |\n|---|---|---|---|---|---|\n"
    text += "".join(f"| {' | '.join(row)} |\n" for row in rows)
    for title, detail in (("1: wall against GPU time", detail1), ("4: pipelines compiled by later shapes", detail4),
                          ("5: a frame per view against one batched call", detail5)):
        text += f"\n## Criterion {title}\n\n" + "\n".join(detail) + "\n"
    out = args.out or os.path.join(args.host, "host-check.md")
    with open(out + ".partial", "w") as f:
        f.write(text)
    os.replace(out + ".partial", out)


if __name__ == "__main__":
    sys.exit(main())
