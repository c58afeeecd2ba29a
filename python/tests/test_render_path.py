"""Scene.render_path: sequences of cameras (poses, camera path files, motion presets, interpolation) rendered
frame by frame, the same frames as render and as render-frame's."""

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest

import raypatch
from conftest import look_at

ROOT = Path(__file__).resolve().parents[2]
RENDER_FRAME = ROOT / "target" / "release" / "render-frame"


@pytest.fixture(scope="module")
def bundled():
    with raypatch.Engine() as engine:
        yield engine.bundled("fitted").encode_scene(raypatch.bundled_scene())


def test_poses_render_as_render_does(bundled):
    poses = np.stack([look_at((7.0, -2.0, 3.0)), look_at((-5.0, 5.0, 2.0)), look_at((2.0, 8.0, 4.0))])
    k, size = (105.0, 105.0, 40.0, 30.0), (80, 60)
    frames = bundled.render_path(poses, k, size, outputs="rgb", batch=2)
    assert not isinstance(frames, list), "frames come one at a time"
    frames = list(frames)
    assert len(frames) == 3
    for pose, frame in zip(poses, frames):
        alone = bundled.render(pose, k, size)
        assert frame["rgb"].shape == (60, 80, 3)
        assert np.abs(frame["rgb"] - alone["rgb"]).max() < 1e-5


@pytest.mark.skipif(not RENDER_FRAME.exists(), reason="needs target/release/render-frame (cargo build --release)")
@pytest.mark.parametrize("motion", ["orbit", "spiral", "zoom", "closeup", "eyeroll"])
def test_motions_are_render_frames(bundled, motion, tmp_path):
    subprocess.run([str(RENDER_FRAME), "--motion", motion, "--frames", "3", "--out", str(tmp_path / "cli")],
                   check=True, capture_output=True)
    frames = list(bundled.render_path(motion=motion, frames=3))
    assert len(frames) == 3
    for i, frame in enumerate(frames):
        frame.save(tmp_path / f"api_{i}.png")
        assert (tmp_path / f"api_{i}.png").read_bytes() == (tmp_path / "cli" / f"frame_{i:03d}.png").read_bytes()


def test_camera_paths_and_interpolation(bundled, tmp_path):
    poses = [look_at((9.0 * np.cos(a), 9.0 * np.sin(a), 5.0)) for a in (0.0, 0.5, 1.0)]
    path = {"camera_type": "perspective", "render_width": 80, "render_height": 60, "fps": 24,
            "camera_path": [{"camera_to_world": p.reshape(-1).tolist(), "fov": 40.0} for p in poses]}
    (tmp_path / "camera_path.json").write_text(json.dumps(path))
    keys = list(bundled.render_path(camera_path=tmp_path / "camera_path.json"))
    assert [f["rgb"].shape for f in keys] == [(60, 80, 3)] * 3
    smooth = list(bundled.render_path(camera_path=tmp_path / "camera_path.json", interpolate=True, frames=5))
    assert len(smooth) == 5
    for key, frame in ((0, 0), (2, 4)):
        assert np.abs(smooth[frame]["rgb"] - keys[key]["rgb"]).max() < 1e-4
    between = list(bundled.render_path(interpolate=True, frames=4))
    assert len(between) == 4


@pytest.mark.parametrize("kwargs, message", [
    (dict(motion="twirl"), "twirl"),
    (dict(motion="orbit", frames=0), "frames 0"),
    (dict(motion="orbit", elevation=120.0), "elevation 120"),
    (dict(motion="orbit", poses=np.eye(4)), "not poses and motion"),
    (dict(), "give poses, a camera_path or a motion"),
    (dict(camera_path="absent.json"), "absent.json"),
    (dict(motion="orbit", batch=0), "batch 0"),
])
def test_bad_paths_raise_one_line(bundled, kwargs, message):
    with pytest.raises(raypatch.Error) as error:
        list(bundled.render_path(**kwargs))
    assert message in str(error.value) and "\n" not in str(error.value)
