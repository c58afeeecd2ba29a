"""python -m raypatch.distributed on a local Ray with 2 workers (lavapipe): the same figures as one process and
as render-frame --metrics, scene by scene; bad inputs exit 2 with one line and write nothing."""

import csv
import re
import subprocess
import sys
from pathlib import Path

import pytest

import raypatch
from raypatch.evaluate import evaluate_scene, scene_paths

pytest.importorskip("ray")

ROOT = Path(__file__).resolve().parents[2]
MODEL = ROOT / "assets" / "models" / "fitted_scene-2000000_rpsrt_k4.safetensors"
SCENES = ROOT / "assets" / "scenes"
RENDER_FRAME = ROOT / "target" / "release" / "render-frame"


def distributed(*args):
    return subprocess.run([sys.executable, "-m", "raypatch.distributed", *map(str, args)], capture_output=True,
                          text=True, timeout=600)


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    out = tmp_path_factory.mktemp("eval") / "results.csv"
    run = distributed("evaluate", "--model", MODEL, "--scenes", SCENES, "--out", out, "--workers", 2)
    assert run.returncode == 0, run.stderr
    with open(out, newline="") as file:
        return list(csv.DictReader(file))


def test_two_workers_equal_one_process(results):
    model = raypatch.load(MODEL)
    want = [row for path in scene_paths(str(SCENES)) for row in evaluate_scene(model, path)]
    assert [(r["scene"], int(r["view"])) for r in results] == [(r["scene"], r["view"]) for r in want]
    for got, row in zip(results, want):
        assert (float(got["psnr"]), float(got["ssim"])) == (row["psnr"], row["ssim"]), row


@pytest.mark.skipif(not RENDER_FRAME.exists(), reason="needs target/release/render-frame (cargo build --release)")
def test_equal_render_frame_metrics_scene_by_scene(results, tmp_path):
    for scene in sorted(SCENES.glob("*.safetensors")):
        run = subprocess.run([str(RENDER_FRAME), "--model", str(MODEL), "--scene", str(scene), "--view", "all",
                              "--metrics", "--out", str(tmp_path / scene.stem)], capture_output=True, text=True,
                             check=True)
        lines = re.findall(r"target view (\d+): PSNR ([\d.]+) dB, SSIM ([\d.]+)", run.stdout)
        rows = [r for r in results if r["scene"] == scene.stem]
        assert len(lines) == len(rows) > 0, scene
        for (view, p, s), row in zip(lines, rows):
            assert int(view) == int(row["view"])
            assert f"{float(row['psnr']):.3f}" == p and f"{float(row['ssim']):.4f}" == s, (scene, view)


def test_render_writes_every_view(tmp_path):
    run = distributed("render", "--model", MODEL, "--scenes", SCENES / "scene-200000[01].safetensors", "--out",
                      tmp_path, "--workers", 2)
    assert run.returncode == 0, run.stderr
    assert sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*.png")) == [
        "scene-2000000/view_000.png", "scene-2000000/view_001.png",
        "scene-2000001/view_000.png", "scene-2000001/view_001.png"]


def test_bad_inputs_exit_2_with_one_line(tmp_path):
    out = tmp_path / "results.csv"
    broken = tmp_path / "scenes"
    broken.mkdir()
    (broken / "good.safetensors").write_bytes((SCENES / "scene-2000000.safetensors").read_bytes())
    (broken / "bad.safetensors").write_bytes(b"not a scene")
    for args, named in [(("--scenes", broken), "bad.safetensors"),
                        (("--scenes", tmp_path / "nothing-*.safetensors"), "no scene file"),
                        (("--scenes", SCENES, "--workers", 0), "--workers")]:
        run = distributed("evaluate", "--model", MODEL, "--out", out, *args)
        assert run.returncode == 2, run.stderr
        errors = [line for line in run.stderr.splitlines() if line.startswith("raypatch.distributed:")]
        assert len(errors) == 1 and named in errors[0], run.stderr
        assert not out.exists()
    run = distributed("evaluate", "--model", tmp_path / "missing.safetensors", "--scenes", SCENES, "--out", out)
    assert run.returncode == 2 and "missing.safetensors" in run.stderr and not out.exists()
