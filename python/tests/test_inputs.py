"""Refusals of the Python API at their roots: integers are numbers where floats are expected, negative or
non-integer sizes, indices and counts are InputErrors naming the argument, arrays too large for the engine are
refused before they are converted, the metrics refuse empty images alike, and messages quote a bounded excerpt
of what was passed. Every refusal is a raypatch.Error of one line."""

import tracemalloc

import numpy as np
import pytest

import raypatch
from conftest import look_at

# What a message may grow to when it quotes a huge value: the excerpt, its length, and the rest of the line.
SHORT = 400


@pytest.fixture(scope="module")
def from_file(engine):
    data = raypatch.bundled_scene()
    return data, engine.bundled("fitted").encode_scene(data)


def refused(kind, call, *named):
    """The one-line message of the `kind` of raypatch.Error that `call` raises, naming each of `named`."""
    with pytest.raises(raypatch.Error) as error:
        call()
    text = str(error.value)
    assert isinstance(error.value, kind), (type(error.value), text)
    assert "\n" not in text and len(text) < SHORT, text[:SHORT]
    for name in named:
        assert name in text, text
    return text


def test_bytes_paths_are_paths(tmp_path):
    refused(raypatch.FileError, lambda: raypatch.load(bytes(tmp_path / "absent.safetensors")), "absent.safetensors")


def test_integers_are_accepted_as_floats(posed_scene, from_file):
    model, images, poses, k, scene = posed_scene
    want = scene.render(poses[0])["rgb"]
    k_ints = np.array([[105, 0, 40], [0, 105, 30], [0, 0, 1]])
    assert np.array_equal(model.encode(images, poses, k_ints).render(poses[0])["rgb"], want)
    assert np.array_equal(model.encode(images, poses, (105, 105, 40, 30)).render(poses[0])["rgb"], want)
    assert np.array_equal(scene.render(poses[0], intrinsics=[105, 105, 40, 30], size=(80, 60))["rgb"], want)
    assert np.array_equal(scene.render(poses[0], size=(np.int64(80), 60.0))["rgb"], want)
    identity_pose = np.eye(4, dtype=np.int32)
    identity_pose[:3, 3] = (0, 0, 6)
    assert np.array_equal(scene.render(identity_pose)["rgb"], scene.render(identity_pose.astype(float))["rgb"])
    # docs/PYTHON.md's own example, integers and all.
    data, file_scene = from_file
    frames = list(file_scene.render_path(motion="orbit", frames=np.int64(2), elevation=40, radius=6,
                                         centre=(0, 0, 0.5), up=(0, 0, 1), fade=True))
    as_floats = list(file_scene.render_path(motion="orbit", frames=2, elevation=40.0, radius=6.0,
                                            centre=(0.0, 0.0, 0.5), up=(0.0, 0.0, 1.0), fade=True))
    assert all(np.array_equal(a["rgb"], b["rgb"]) for a, b in zip(frames, as_floats)) and len(frames) == 2
    assert np.array_equal(file_scene.render_view(np.int64(1))["rgb"], file_scene.render_view(1)["rgb"])


@pytest.mark.parametrize("call, named", [
    (lambda s, p: s.render(p, intrinsics=np.ones(4, dtype=bool)), "intrinsics: dtype bool"),
    (lambda s, p: s.render(p, size=(True, 60)), "width True: expected an integer, not a bool"),
    (lambda s, p: s.render(p.astype(bool)), "pose: dtype bool"),
    (lambda s, p: s.render(p, region=(0, 0, 8.5, 8)), "region width 8.5: expected an integer"),
    (lambda s, p: s.render(p, size="80x60"), "size '80x60': expected (width, height)"),
    (lambda s, p: raypatch.load(5), "path 5: expected a path"),
    (lambda s, p: s.render(p, outputs=None), "outputs None: expected"),
])
def test_nonsense_numbers_are_refused(posed_scene, call, named):
    model, images, poses, k, scene = posed_scene
    refused(raypatch.InputError, lambda: call(scene, poses[0]), named)


@pytest.mark.parametrize("call, named", [
    (lambda s, d, p: s.render_view(-1), "target view -1: expected 0 or more"),
    (lambda s, d, p: s.render_view(2 ** 70), "64 bits"),
    (lambda s, d, p: s.render_view("0"), "view '0': expected an integer"),
    (lambda s, d, p: d.target_image(-2), "target view -2"),
    (lambda s, d, p: d.target_size(-1), "target view -1"),
    (lambda s, d, p: s.render(p, (105, 105, 40, 30), size=(-80, 60)), "width -80: expected 0 or more"),
    (lambda s, d, p: s.render_view(0, region=(-1, 0, 8, 8)), "region x -1"),
    (lambda s, d, p: s.render_view(0, region=(0, 0, 8, -8)), "region height -8"),
    (lambda s, d, p: list(s.render_path(motion="orbit", frames=-3)), "frames -3"),
    (lambda s, d, p: list(s.render_path(interpolate=True, frames=-1)), "frames -1"),
    (lambda s, d, p: list(s.render_path(motion="orbit", frames=2, batch=-2)), "batch -2"),
    (lambda s, d, p: list(s.render_path(p[None], (105, 105, 40, 30), size=(80, -60))), "height -60"),
])
def test_negative_sizes_indices_and_counts_are_input_errors(from_file, call, named):
    data, scene = from_file
    refused(raypatch.InputError, lambda: call(scene, data, look_at((7.0, -2.0, 3.0))), named)


def test_too_large_arrays_are_refused_before_conversion(posed_scene):
    model, images, poses, k, scene = posed_scene
    one = np.zeros((1, 1, 1, 3), dtype=np.uint8)
    # Views of one pixel (no memory): converted, they would be 2 TB and 300 MB of float32.
    huge = np.broadcast_to(one, (10_000, 4096, 4096, 3))
    too_wide = np.broadcast_to(one, (1, 5000, 5000, 3))
    slots = np.broadcast_to(np.zeros((1, 1, 1), np.float32), (4096, 4096, 1000))
    ids = np.broadcast_to(np.zeros((1, 1), np.uint32), (4096, 4096))
    tracemalloc.start()
    try:
        refused(raypatch.InputError, lambda: model.encode(huge, poses, k), "images", "values accepted")
        refused(raypatch.InputError, lambda: model.encode(too_wide, poses[:1], k), "images", "5000x5000")
        refused(raypatch.InputError, lambda: raypatch.psnr(too_wide[0], too_wide[0]), "a: image size 5000x5000")
        refused(raypatch.InputError, lambda: raypatch.fg_ari(ids, slots), "weights")
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 16 << 20, peak


@pytest.mark.parametrize("shape", [(0, 0, 3), (0, 8, 3), (8, 0, 3)])
def test_metrics_refuse_empty_images_alike(shape):
    empty = np.zeros(shape, dtype=np.float32)
    assert refused(raypatch.InputError, lambda: raypatch.psnr(empty, empty), "empty") == \
        refused(raypatch.InputError, lambda: raypatch.ssim(empty, empty), "empty")
    refused(raypatch.InputError, lambda: raypatch.depth_errors(empty[..., 0], empty[..., 0]), "predicted", "empty")
    refused(raypatch.InputError, lambda: raypatch.fg_ari(empty[..., 0].astype(int), empty), "weights", "empty")


HUGE = "x" * 5_000_000


@pytest.mark.parametrize("call", [
    lambda m, s, p: m.encode(np.zeros((2, 60, 80, 3)), p, (105, 105, 40, 30), convention=HUGE),
    lambda m, s, p: s.render(p[0], convention=HUGE),
    lambda m, s, p: s.render(p[0], outputs=[HUGE]),
    lambda m, s, p: s.render(p[0], outputs=[0.5] * 1_000_000),
    lambda m, s, p: s.render(p[0], size=HUGE),
    lambda m, s, p: s.render(p[0], region=list(range(1_000_000))),
    lambda m, s, p: s.render(HUGE),
    lambda m, s, p: s.render([0.0] * 5_000_000),
    lambda m, s, p: s.render(p[0], intrinsics=HUGE),
    lambda m, s, p: list(s.render_path(motion=HUGE)),
    lambda m, s, p: list(s.render_path(motion=[0.0] * 5_000_000)),
    lambda m, s, p: list(s.render_path(motion="orbit", frames="9" * 100_000)),
    lambda m, s, p: raypatch.Engine(precision=HUGE),
    lambda m, s, p: raypatch.Engine(matmul=HUGE),
    lambda m, s, p: raypatch.bundled(HUGE),
    lambda m, s, p: raypatch.bundled_scene(HUGE),
    lambda m, s, p: raypatch.Rendered({HUGE: p}).save("x.png"),
])
def test_messages_quote_a_bounded_excerpt(posed_scene, call):
    model, images, poses, k, scene = posed_scene
    refused(raypatch.Error, lambda: call(model, scene, poses))


@pytest.mark.parametrize("call", [
    lambda: raypatch.load(HUGE),
    lambda: raypatch.load_scene("/" + HUGE),
    lambda: list(raypatch.bundled("fitted").encode_scene(raypatch.bundled_scene()).render_path(camera_path=HUGE)),
])
def test_engine_messages_are_bounded_too(call):
    """Messages the engine writes about a path it was given (cut by the binding if the engine quotes more)."""
    with pytest.raises(raypatch.Error) as error:
        call()
    assert "\n" not in str(error.value) and len(str(error.value)) <= 2000, str(error.value)[:2000]


def test_bad_sizes_and_poses_are_input_errors(posed_scene):
    """A size the model's patch size does not divide and a pose that is not rigid are InputErrors (checked by
    raypatch.input, as on the CLI and the viewer), never FileErrors."""
    model, images, poses, k, scene = posed_scene
    nearest = "nearest valid sizes: 48x28, 48x32, 52x28, 52x32"
    refused(raypatch.InputError, lambda: scene.render(poses[0], size=(50, 30)), "target size 50x30", nearest)
    refused(raypatch.InputError, lambda: scene.render_many(poses, size=(50, 30)), "target size 50x30", nearest)
    sheared = poses[0].copy()
    sheared[0, 1] += 0.3
    refused(raypatch.InputError, lambda: scene.render(sheared), "pose 0: pose rotation is not orthonormal")
    refused(raypatch.InputError, lambda: model.encode(images, np.stack([poses[0], sheared]), k), "poses 1: ")
    bottom = poses[0].copy()
    bottom[3, 0] = 1.0
    refused(raypatch.InputError, lambda: scene.render(bottom), "pose bottom row")


def test_a_new_size_resizes_input_view_0s_camera(posed_scene):
    """size= without intrinsics resizes input view 0's camera by raypatch's one policy: the focal lengths scale
    with the height, the principal point keeps its place relative to the image."""
    model, images, poses, k, scene = posed_scene
    doubled = scene.render(poses[0], intrinsics=(210, 210, 80, 60), size=(160, 120))["rgb"]
    assert np.array_equal(scene.render(poses[0], size=(160, 120))["rgb"], doubled)
    wider = scene.render(poses[0], intrinsics=(105, 105, 80, 30), size=(160, 60))["rgb"]
    assert np.array_equal(scene.render(poses[0], size=(160, 60))["rgb"], wider)
