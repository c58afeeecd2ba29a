"""tools/bench/tensor_check.py: tensor-check.md's rows from a tensor step's results (made up here: no GPU)."""

import json
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "bench" / "tensor_check.py"


def stats(ms):
    return {"median_ms": ms, "min_ms": ms, "max_ms": ms, "runs": 1}


def record(model, k, views, precision, wall, **extra):
    return {"model": model, "k": k, "target_views": views, "target_size": "120x160", "group": "sweep",
            "variant": "", "precision": precision, "adapter": "GPU X", "render_wall_ms": stats(wall),
            "render_gpu_ms": stats(wall * 0.9), "note": "", **extra}


def write(folder, name, value):
    path = folder / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(value))


def rows(folder, *args):
    subprocess.run([sys.executable, str(SCRIPT), str(folder), *args], check=True)
    text = (folder / "tensor-check.md").read_text()
    return {line.split(" | ")[0].lstrip("| "): line for line in text.splitlines() if line.startswith("| ")}, text


def test_an_empty_run_is_not_measured(tmp_path):
    table, _ = rows(tmp_path)
    for number in "12345":
        assert "NOT MEASURED" in table[number], table[number]


def test_figures_pass_and_fail_on_their_bounds(tmp_path):
    (tmp_path / "tests.tsv").write_text("kernels coop\t0\t12\t45\t9\ngolden tensor path\t0\t20\t45\t0\n")
    tiling = {"sg_m": 4, "sg_n": 2, "bk": 32}
    classes = [{"class": c, "shapes": [], "best": tiling, "default_total_ms": 2.0,
                "candidates": [{"tiling": tiling, "ms": [1.0], "total_ms": 1.0, "error": None}]}
               for c in ("small", "large")]
    write(tmp_path, "tune/coop-tune.json", {
        "adapter": "GPU X", "classes": classes, "untried": 0, "tuning_lines": ["a", "b"],
        "square": {"size": 4096, "tiling": tiling, "ms": 1.0, "tflops": 137.4}, "square_error": None})
    write(tmp_path, "srt/results.json", {"pytorch": "2.x", "results": [
        record("official", 1, 1, "f32", 9.0, pytorch_render_ms=stats(6.0), pytorch_compiled_render_ms=stats(2.0)),
        record("official", 1, 1, "f16-act", 2.5)]})
    write(tmp_path, "rpsrt/results.json", {"pytorch": "2.x", "results": [
        record("official", 8, 32, "f32", 5.0, pytorch_render_ms=stats(20.0),
               pytorch_autocast_render_ms=stats(8.0)),
        record("official", 8, 32, "f16-act", 3.2)]})
    write(tmp_path, "cublas-float16.json", {"torch": "2.x", "device": "NVIDIA H100", "shapes": [
        {"m": 4096, "k": 4096, "n": 4096, "median_ms": 0.2, "min_ms": 0.2, "max_ms": 0.2, "runs": 1}]})
    write(tmp_path, "cublas-bfloat16.json", {"torch": "2.x", "device": "cpu", "shapes": [
        {"m": 4096, "k": 4096, "n": 4096, "median_ms": 90.0, "min_ms": 90.0, "max_ms": 90.0, "runs": 1}]})
    table, text = rows(tmp_path)
    # The golden binary ran no test of that name: not measured, not passed.
    assert "NOT MEASURED" in table["1"] and "no test ran" in table["1"]
    assert "| PASS |" in table["2"]
    assert "| FAIL |" in table["3"] and "137.400 TFLOP/s" in table["3"]
    assert "| PASS |" in table["4"] and "wall 2.500 ms" in table["4"]
    # 32 views in 3.2 ms: 10,000 views/s, under 11,500.
    assert "| FAIL |" in table["5"] and "10,000 views/s" in table["5"]
    comparisons = [line for line in text.splitlines() if "PyTorch" in line or "cuBLAS" in line]
    srt_eager, srt_compiled = (next(l for l in comparisons if f"1x120x160: PyTorch fp32 {m}" in l)
                               for m in ("eager", "compiled"))
    assert "| PASS |" in srt_eager and "| FAIL |" in srt_compiled
    autocast = next(l for l in comparisons if "32x120x160: PyTorch bf16 autocast eager" in l)
    assert "| PASS |" in autocast and "2.50x" in autocast
    assert "no such PyTorch mode" in next(l for l in comparisons if "32x120x160: PyTorch bf16 autocast compiled" in l)
    assert "| FAIL |" in next(l for l in comparisons if "cuBLAS float16" in l)
    assert "not cuBLAS" in next(l for l in comparisons if "cuBLAS bfloat16" in l)
