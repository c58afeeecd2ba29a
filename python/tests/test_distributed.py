"""python -m raypatch.distributed on a local Ray with 2 workers (lavapipe): the same figures as one process and
as render-frame --metrics, scene by scene; bad arguments refused before Ray starts, bad inputs exit 2 with one
line and write nothing (render too: all scenes or none); SIGINT and SIGTERM leave nothing behind."""

import csv
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

import raypatch
from raypatch import output
from raypatch import distributed as ray_cli
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


def one_error_line(stderr, ray_started=False):
    """Our one error line; once Ray started, it may log lines of its own beside it."""
    lines = stderr.splitlines()
    ours = [line for line in lines if line.startswith("raypatch.distributed: ")]
    assert len(ours) == 1 and (ray_started or len(lines) == 1), stderr
    return ours[0]


def ours(folder):
    return [name for _, dirs, files in os.walk(folder) for name in dirs + files if output.TEMP_MARK in name]


def listing(folder):
    return sorted((p.relative_to(folder).as_posix(), p.read_bytes() if p.is_file() else None)
                  for p in Path(folder).rglob("*"))


@pytest.fixture
def inputs(tmp_path):
    """A model, scene files and a frames folder in tmp_path, and an existing --out folder holding a file."""
    scenes = tmp_path / "scenes"
    scenes.mkdir()
    for name in ("a", "b"):
        (scenes / f"{name}.safetensors").symlink_to(SCENES / "scene-2000000.safetensors")
    (tmp_path / "frames" / "a").mkdir(parents=True)
    (tmp_path / "frames" / "a" / "transforms.json").write_text("{}")
    model = tmp_path / "model.safetensors"
    model.symlink_to(MODEL)
    (tmp_path / "views" / "a").mkdir(parents=True)
    (tmp_path / "views" / "a" / "view_000.png").write_bytes(b"the user's")
    return tmp_path


@pytest.mark.parametrize("task, args, named", [
    ("evaluate", ["--address", "not an address"], "--address"),
    ("evaluate", ["--address", "ray://head:99999"], "--address"),
    ("evaluate", ["--address", "ray://" + "h" * 100_000 + ":10001"], "--address"),
    ("evaluate", ["--gpus-per-worker", "nan"], "--gpus-per-worker"),
    ("evaluate", ["--gpus-per-worker", "inf"], "--gpus-per-worker"),
    ("evaluate", ["--gpus-per-worker", "-1"], "--gpus-per-worker"),
    ("evaluate", ["--workers", "0"], "--workers"),
    ("evaluate", ["--workers", "9" * 100_000], "--workers"),
    ("x" * 100_000, [], "evaluate or render"),
    ("evaluate", ["--bogus"], "unrecognized arguments"),
    ("render", ["--out", "{tmp}/scenes/a.safetensors"], "is not a folder"),
    ("render", ["--out", "{tmp}/missing/views"], "does not exist"),
    ("render", ["--out", "{tmp}/frames", "--scenes", "{tmp}/frames"], "would write into"),
    ("render", ["--scenes", "{tmp}/[sf]*/a*"], "would both render into"),
    ("render", ["--model", "{tmp}/views/a/view_000.png"], "would overwrite the input given by --model"),
    ("evaluate", ["--out", "{tmp}/views"], "is a folder"),
    ("evaluate", ["--out", "{tmp}/model.safetensors"], "would overwrite the input given by --model"),
    ("evaluate", ["--out", "{tmp}/scenes/b.safetensors"], "would overwrite the input given by --scenes"),
    ("evaluate", ["--out", "{tmp}/frames/a/transforms.json", "--scenes", "{tmp}/frames"], "would write into"),
    ("evaluate", ["--out", "/dev/null"], "a device"),
    ("evaluate", ["--scenes", "{tmp}/nothing-" + "*" * 100_000], "no scene file"),
])
def test_arguments_and_outputs_are_checked_before_ray_starts(inputs, monkeypatch, capsys, task, args, named):
    """One bounded line on stderr, exit code 2, nothing written, and Ray never started (run() fails the test)."""
    monkeypatch.setattr(ray_cli, "run", lambda *a, **k: pytest.fail("Ray started"))
    # The test's arguments after the defaults: argparse keeps an option's last value.
    argv = [task, "--model", str(inputs / "model.safetensors"), "--scenes", str(inputs / "scenes"), "--out",
            str(inputs / "views")] + [a.replace("{tmp}", str(inputs)) for a in args]
    before = listing(inputs)
    try:
        code = ray_cli.main(argv)
    except SystemExit as e:  # argparse
        code = e.code
    line = one_error_line(capsys.readouterr().err)
    assert code == 2 and named in line and len(line) < 1200, line[:1200]
    assert listing(inputs) == before and not ours(inputs)


def test_render_writes_all_scenes_or_none(tmp_path):
    """A bad scene among good ones: exit 2, and neither a new --out folder nor anything in an existing one."""
    scenes = tmp_path / "scenes"
    scenes.mkdir()
    (scenes / "good.safetensors").symlink_to(SCENES / "scene-2000000.safetensors")
    (scenes / "bad.safetensors").write_bytes(b"not a scene")
    existing = tmp_path / "existing"
    (existing / "good").mkdir(parents=True)
    (existing / "good" / "view_000.png").write_bytes(b"the user's")
    before = listing(tmp_path)
    for out in (tmp_path / "new", existing):
        run = distributed("render", "--model", MODEL, "--scenes", scenes, "--out", out, "--workers", 2)
        assert run.returncode == 2 and "bad.safetensors" in one_error_line(run.stderr, True), run.stderr
        assert listing(tmp_path) == before and not ours(tmp_path)


def _forty_scenes(tmp_path):
    scenes = tmp_path / "scenes"
    scenes.mkdir()
    for i in range(40):
        (scenes / f"s{i:02}.safetensors").symlink_to(SCENES / "scene-2000000.safetensors")
    return scenes


def _stop_mid_views(tmp_path, scenes, out, signum) -> str:
    """Renders `scenes` into `out` on one worker and sends `signum` once a view is being written; checks the run
    exits 128 + the signal and returns its stderr."""
    run = subprocess.Popen([sys.executable, "-m", "raypatch.distributed", "render", "--model", str(MODEL), "--scenes",
                            str(scenes), "--out", str(out), "--workers", "1"], stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 300
        while not any(p.suffix == ".png" for p in tmp_path.glob(f".{out.name}{output.TEMP_MARK}*/*/*")):
            assert run.poll() is None, run.communicate()
            assert time.monotonic() < deadline, "no view rendered"
            time.sleep(0.1)
        run.send_signal(signum)
        assert run.wait(timeout=60) == 128 + signum, run.communicate()
        return run.stderr.read()
    finally:
        run.kill()


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_mid_run_exits_128_plus_it_and_leaves_nothing(tmp_path, signum):
    _stop_mid_views(tmp_path, _forty_scenes(tmp_path), tmp_path / "views", signum)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scenes"], list(tmp_path.rglob("*"))


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_mid_run_keeps_the_users_files(tmp_path, signum):
    """As render-frame's signal tests: an --out folder holding a view the run would replace and a file beside it;
    stopped while views are written, the run exits 128 + the signal and leaves both as they were, and nothing
    of its own."""
    scenes = _forty_scenes(tmp_path)
    out = tmp_path / "views"
    (out / "s00").mkdir(parents=True)
    (out / "s00" / "view_000.png").write_bytes(b"the user's")
    (out / "notes.txt").write_bytes(b"mine")
    before = listing(tmp_path)
    stderr = _stop_mid_views(tmp_path, scenes, out, signum)
    assert f"stopped by {signal.Signals(signum).name}" in stderr
    assert listing(tmp_path) == before and not ours(tmp_path)


def test_an_output_hard_linked_to_an_input_is_refused(inputs, capsys):
    """The same file by another name: a hard link to the model, a path through a symlinked folder."""
    os.link(inputs / "views" / "a" / "view_000.png", inputs / "linked.png")
    (inputs / "through").symlink_to(inputs / "views")
    for out, model in ((inputs / "linked.png", inputs / "views" / "a" / "view_000.png"),
                       (inputs / "through" / "a" / "view_000.png", inputs / "linked.png")):
        code = ray_cli.main(["evaluate", "--model", str(model), "--scenes", str(inputs / "scenes"), "--out", str(out)])
        line = one_error_line(capsys.readouterr().err)
        assert code == 2 and "would overwrite the input given by --model" in line, line
