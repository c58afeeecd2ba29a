"""What the package's tests share: an engine per test module, OpenGL look-at poses, and a scene encoded from
posed images with the bundled RP-SRT k=4."""

import numpy as np
import pytest

import raypatch


@pytest.fixture(scope="module")
def engine():
    with raypatch.Engine() as engine:
        yield engine


def look_at(eye, target=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0)):
    """An OpenGL camera-to-world pose at eye looking at target."""
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    back = (eye - target) / np.linalg.norm(eye - target)
    right = np.cross(up, back) / np.linalg.norm(np.cross(up, back))
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = right, np.cross(back, right), back, eye
    return pose


@pytest.fixture(scope="module")
def posed_scene(engine):
    """(model, images [2, 60, 80, 3], OpenGL poses [2, 4, 4], K [3, 3], the scene they encode)."""
    model = engine.bundled("rpsrt_k4")
    images = np.random.default_rng(0).random((2, 60, 80, 3), dtype=np.float32)
    poses = np.stack([look_at((7.0, -2.0, 3.0)), look_at((-5.0, 5.0, 2.0))])
    k = np.array([[105.0, 0.0, 40.0], [0.0, 105.0, 30.0], [0.0, 0.0, 1.0]])
    return model, images, poses, k, model.encode(images, poses, k)
