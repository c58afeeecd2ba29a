"""The Python package against the engine's own checks: the golden cases (PyTorch's outputs, tests/golden.rs's
tolerances), render-frame's raw outputs byte for byte, the metrics, bad inputs, and threads. Run with
`python3 -m pytest python/tests` after `pip install ./python` (and `cargo build --release` for render-frame)."""

import json
import subprocess
import threading
from pathlib import Path

import numpy as np
import pytest
from safetensors.numpy import load_file

import raypatch

ROOT = Path(__file__).resolve().parents[2]
GOLDEN = ROOT / "assets" / "golden"
RENDER_FRAME = ROOT / "target" / "release" / "render-frame"
# tests/golden.rs: rgb and segmentation max abs; the latent and SRT's log-depth relative to their largest value;
# DeFiNe's log-depth max abs.
OUTPUT_MAX_ABS = 1e-4
RELATIVE_MAX = 1e-4


def golden_cases():
    # rpsrt_k8_resize gives patch rays (10x7) that k = 8 does not divide into its 80x60 target: the engine-level
    # golden test reads them, the scene-file API (raypatch::SceneData) takes only grids of the size or size / k.
    names = sorted(p.name for p in GOLDEN.iterdir() if (p / "expected.safetensors").exists())
    return [pytest.param(n, marks=pytest.mark.skip(reason="patch rays SceneData refuses")) if n == "rpsrt_k8_resize"
            else n for n in names]


@pytest.mark.parametrize("case", golden_cases())
def test_golden_cases_match_pytorch(engine, case):
    folder = GOLDEN / case
    model = engine.load(folder / "model.safetensors")
    data = raypatch.load_scene(folder / "scene.safetensors")
    expected = load_file(str(folder / "expected.safetensors"))
    outputs = [o for o in ("rgb", "logdepth", "segmentation") if o in expected]
    scene = model.encode_scene(data)
    for view in range(data.target_count):
        rendered = scene.render_view(view, outputs)
        for output in outputs:
            want, got = expected[output][view], rendered[output]
            assert got.shape == want.shape, (case, output)
            error = np.abs(got - want).max()
            if output == "logdepth" and model.config["base"] != "define":
                error /= np.abs(expected[output]).max()
                assert error <= RELATIVE_MAX, (case, output, view, error)
            else:
                assert error <= OUTPUT_MAX_ABS, (case, output, view, error)


def test_bundled_three_lines_write_a_picture(tmp_path):
    out = tmp_path / "view.png"
    model = raypatch.bundled("fitted")
    model.encode_scene(raypatch.bundled_scene()).render_view(0).save(out)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.skipif(not RENDER_FRAME.exists(), reason="needs target/release/render-frame (cargo build --release)")
def test_the_same_bytes_as_render_frame(engine, tmp_path):
    folder = GOLDEN / "rposrt_k8"
    raw = tmp_path / "raw.safetensors"
    subprocess.run([str(RENDER_FRAME), "--model", str(folder / "model.safetensors"), "--scene",
                    str(folder / "scene.safetensors"), "--view", "all", "--outputs", "rgb,segmentation",
                    "--out-raw", str(raw), "--out", str(tmp_path / "views")], check=True, capture_output=True)
    cli = load_file(str(raw))
    data = raypatch.load_scene(folder / "scene.safetensors")
    scene = engine.load(folder / "model.safetensors").encode_scene(data)
    for view in range(data.target_count):
        ours = scene.render_view(view, ("rgb", "segmentation"))
        for output in ("rgb", "segmentation"):
            assert ours[output].tobytes() == cli[output][view].tobytes(), (output, view)


def test_a_transforms_json_folder_is_the_same_scene_as_its_arrays(posed_scene, tmp_path):
    """load_scene on a NeRF-style frames folder (OpenGL poses, fl_x/fl_y/cx/cy) and encode() on the same images,
    poses and K give the same pixels: the conventions agree."""
    model, images, poses, k, _ = posed_scene
    as_uint8 = np.round(images * 255).astype(np.uint8)
    frames = []
    for i, pose in enumerate(poses):
        raypatch.Rendered(rgb=as_uint8[i].astype(np.float32) / 255).save(tmp_path / f"frame_{i}.png")
        frames.append({"file_path": f"frame_{i}.png", "transform_matrix": pose.tolist()})
    meta = {"fl_x": k[0, 0], "fl_y": k[1, 1], "cx": k[0, 2], "cy": k[1, 2], "w": 80, "h": 60, "frames": frames}
    (tmp_path / "transforms.json").write_text(json.dumps(meta))
    data = raypatch.load_scene(tmp_path)
    assert (data.input_count, data.target_count) == (2, 2)
    assert np.array_equal(data.target_image(1), as_uint8[1].astype(np.float32) / 255)
    from_folder = model.encode_scene(data).render_view(1)["rgb"]
    from_arrays = model.encode(as_uint8, poses, k).render(poses[1])["rgb"]
    assert np.array_equal(from_folder, from_arrays)


def test_uint8_and_float_images_encode_alike(posed_scene):
    model, images, poses, k, scene = posed_scene
    as_uint8 = np.round(images * 255).astype(np.uint8)
    a = model.encode(as_uint8, poses, k).render(poses[0])["rgb"]
    b = model.encode(as_uint8.astype(np.float32) / 255, poses, k).render(poses[0])["rgb"]
    assert np.array_equal(a, b)


def test_renders_many_poses_and_regions(posed_scene):
    model, images, poses, k, scene = posed_scene
    many = scene.render_many(poses)
    assert many["rgb"].shape == (2, 60, 80, 3)
    for i, pose in enumerate(poses):
        assert np.array_equal(many["rgb"][i], scene.render(pose)["rgb"])
    part = scene.render(poses[0], region=(40, 8, 16, 12))["rgb"]
    assert part.shape == (12, 16, 3)
    assert np.abs(part - many["rgb"][0][8:20, 40:56]).max() < 1e-5
    parts = scene.render_many(poses, region=(40, 8, 16, 12))["rgb"]
    assert parts.shape == (2, 12, 16, 3) and np.array_equal(parts[0], part)
    assert scene.render_many(np.zeros((0, 4, 4))) == {}


def test_a_lightning_checkpoint_loads_as_its_model(engine, tmp_path):
    """raypatch.load reads an official Lightning checkpoint (a torch.save zip, told apart by content, whatever
    its name) as the model the Python converter would make of it."""
    torch = pytest.importorskip("torch")
    from safetensors import safe_open
    from safetensors.torch import load_file as load_tensors
    folder = GOLDEN / "rpsrt_k4"
    with safe_open(str(folder / "model.safetensors"), "pt") as file:
        cfg = json.loads(file.metadata()["config"])
    checkpoint = {"epoch": 3, "state_dict": load_tensors(str(folder / "model.safetensors")),
                  "hyper_parameters": {"cfg": cfg, "lpips": False, "ssim": False}}
    torch.save(checkpoint, tmp_path / "run.weights")
    data = raypatch.load_scene(folder / "scene.safetensors")
    renders = [engine.load(path).encode_scene(data).render_view(0)["rgb"]
               for path in (tmp_path / "run.weights", folder / "model.safetensors")]
    assert np.array_equal(renders[0], renders[1])


def test_non_contiguous_and_torch_inputs_give_the_same_scene(posed_scene):
    model, images, poses, k, scene = posed_scene
    want = scene.render(poses[1])["rgb"]
    strided = np.repeat(images, 2, axis=3)[..., ::2]
    assert not strided.flags["C_CONTIGUOUS"]
    assert np.array_equal(model.encode(strided, poses, k).render(poses[1])["rgb"], want)
    torch = pytest.importorskip("torch")
    got = model.encode(torch.from_numpy(images), torch.from_numpy(poses), k).render(poses[1])["rgb"]
    assert np.array_equal(got, want)


def test_opencv_poses_are_opengl_poses_flipped(posed_scene):
    model, images, poses, k, scene = posed_scene
    opencv = poses[0] @ np.diag([1.0, -1.0, -1.0, 1.0])
    assert np.array_equal(scene.render(opencv, convention="opencv")["rgb"], scene.render(poses[0])["rgb"])


@pytest.mark.parametrize("bad, message", [
    (lambda m, i, p, k: m.encode(i.astype(np.int64), p, k), "dtype int64"),
    (lambda m, i, p, k: m.encode(i, p.astype(bool), k), "poses: dtype bool"),
    (lambda m, i, p, k: m.encode(i[..., :2], p, k), "shape"),
    (lambda m, i, p, k: m.encode(np.where(i > 0.5, np.nan, i), p, k), "NaN"),
    (lambda m, i, p, k: m.encode(i * 2, p, k), "[0, 1]"),
    (lambda m, i, p, k: m.encode(i, p[:1], k), "poses"),
    (lambda m, i, p, k: m.encode(i, p @ np.diag([2.0, 2.0, 2.0, 1.0]), k), "orthonormal"),
    (lambda m, i, p, k: m.encode(i, p, k, convention="blender"), "convention"),
    (lambda m, i, p, k: m.encode(i, p, np.zeros((3, 3))), "focal"),
    (lambda m, i, p, k: m.encode(i, p, k).render(p[0], outputs=("rgb", "normals")), "normals"),
    (lambda m, i, p, k: m.encode(i, p, k).render(p[0], outputs=("segmentation",)), "segmentation"),
    (lambda m, i, p, k: m.encode(i, p, k).render(p[0], region=(70, 0, 20, 8)), "region"),
    (lambda m, i, p, k: m.encode(i, p, k).render_view(0), "scene file"),
    (lambda m, i, p, k: raypatch.load("no/such/model.safetensors"), "no/such/model.safetensors"),
    (lambda m, i, p, k: raypatch.bundled("nope"), "bundled"),
    (lambda m, i, p, k: raypatch.psnr(i[0], i[1, :10]), "shapes"),
])
def test_bad_inputs_raise_with_one_line(posed_scene, bad, message):
    model, images, poses, k, _ = posed_scene
    with pytest.raises(raypatch.Error) as error:
        bad(model, images, poses, k)
    text = str(error.value)
    assert message.lower() in text.lower() and "\n" not in text, text


def test_precisions():
    rgb = {}
    for precision in ("f32", "f16", "f16-act"):
        try:
            model = raypatch.Engine(precision=precision).bundled("fitted")
        except raypatch.Error as error:
            assert precision != "f32" and "shader-f16" in str(error), error
            continue
        rgb[precision] = model.encode_scene(raypatch.bundled_scene()).render_view(0)["rgb"]
    for precision in set(rgb) - {"f32"}:
        diff = float(np.abs(rgb[precision] - rgb["f32"]).max())
        assert 0.0 < diff < 1e-2, (precision, diff)
    with pytest.raises(raypatch.InputError, match='precision "f8"'):
        raypatch.Engine(precision="f8")


def test_a_closed_engine_refuses_work():
    engine = raypatch.Engine()
    model = engine.bundled("fitted")
    scene = model.encode_scene(raypatch.bundled_scene())
    engine.close()
    for work in (lambda: engine.bundled("fitted"), lambda: model.encode_scene(raypatch.bundled_scene()),
                 lambda: scene.render_view(0)):
        with pytest.raises(raypatch.EngineClosed):
            work()


def test_a_model_outlives_its_engine_object():
    model = raypatch.Engine().bundled("fitted")  # the engine object is dropped here; the model keeps the GPU
    assert model.encode_scene(raypatch.bundled_scene()).render_view(0)["rgb"].shape == (60, 80, 3)


def test_two_threads_render_one_scene(posed_scene):
    model, images, poses, k, scene = posed_scene
    want = [scene.render(pose)["rgb"] for pose in poses]
    got, failures = {}, []

    def render(i):
        try:
            for _ in range(5):
                got.setdefault(i, []).append(scene.render(poses[i])["rgb"])
        except Exception as e:  # reported below
            failures.append(e)

    threads = [threading.Thread(target=render, args=(i,)) for i in (0, 1)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not failures
    for i in (0, 1):
        assert all(np.array_equal(r, want[i]) for r in got[i])


def test_metrics_are_the_engines():
    data = raypatch.bundled_scene()
    truth = data.target_image(0)
    rendered = raypatch.bundled("fitted").encode_scene(data).render_view(0)["rgb"]
    assert raypatch.psnr(truth, truth) == float("inf")
    assert 10 < raypatch.psnr(rendered, truth) < 60 and 0 < raypatch.ssim(rendered, truth) <= 1
    weights = np.array([[[0.9, 0.1], [0.2, 0.8]], [[0.7, 0.3], [0.4, 0.6]]], dtype=np.float32)
    assert raypatch.fg_ari(np.array([[1, 2], [1, 0]]), weights) == pytest.approx(1.0)
    errors = raypatch.depth_errors(np.full((2, 2), 2.0), np.array([[1.0, 2.0], [4.0, 0.0]]))
    assert errors["pixels"] == 3 and errors["abs_rel"] == pytest.approx((1 + 0 + 0.5) / 3)
