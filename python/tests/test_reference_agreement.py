"""The package and the PyTorch reference (tools/reference: the official modules' names and maths) on the same
random-weight model of each family and the same inputs: the same rgb, log-depth and segmentation to float32
rounding. The reference runs here, live (tests/golden.rs compares the engine with its stored outputs)."""

import sys
from pathlib import Path

import numpy as np
import pytest

import raypatch

torch = pytest.importorskip("torch")
from safetensors.torch import load_file  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tools"))
from data.make_golden import run_model  # noqa: E402
from reference.raypatch_reference import build_model  # noqa: E402

# One Ray-Patch and one per-pixel model of each family: random weights, as tools/data/make_golden.py drew them.
CASES = ("srt_k1", "rpsrt_k4", "osrt", "rposrt_k8", "define", "rpdefine_k16")
MAX_ABS = 1e-4


@pytest.mark.parametrize("case", CASES)
def test_package_equals_pytorch_reference(case):
    folder = ROOT / "assets" / "golden" / case
    model = raypatch.load(folder / "model.safetensors")
    reference = build_model(model.config).eval()
    reference.load_state_dict(load_file(str(folder / "model.safetensors")), strict=False)
    scene = load_file(str(folder / "scene.safetensors"))
    ran = run_model(reference, scene, None, torch.float32)
    want = {name: ran[name].numpy() for name in ("rgb", "logdepth", "segmentation")
            if name in ran and (name != "logdepth" or "depth" in model.outputs)}
    encoded = model.encode_scene(raypatch.load_scene(folder / "scene.safetensors"))
    for view in range(scene["target_rays"].shape[0]):
        got = encoded.render_view(view, tuple(want))
        for name, values in want.items():
            error = np.abs(got[name] - values[view]).max()
            if name == "logdepth" and model.config["base"] != "define":
                error /= np.abs(values).max()  # SRT's raw depth channel: relative, as tests/golden.rs
            assert error <= MAX_ABS, (case, name, view, error)
