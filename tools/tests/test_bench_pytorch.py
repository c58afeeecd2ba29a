"""tools/bench/bench_pytorch.py: the outputs it writes for raypatch-bench, eager float32 and under bf16 autocast."""

import json
from pathlib import Path

import pytest
import torch
from safetensors import safe_open

from bench import bench_pytorch

GOLDEN = Path(__file__).resolve().parents[2] / "assets" / "golden"


def tensors(path):
    with safe_open(str(path), "pt") as file:
        return {name: file.get_tensor(name) for name in file.keys()}


@pytest.mark.parametrize("case, names", [("srt_k1_depth", {"rgb", "logdepth"}),
                                         ("rposrt_k4_patchrays", {"rgb", "segmentation"})])
def test_eager_and_autocast_outputs(case, names, tmp_path, capsys):
    eager, autocast = tmp_path / "eager.safetensors", tmp_path / "autocast.safetensors"
    code = bench_pytorch.main(["--model", str(GOLDEN / case / "model.safetensors"),
                               "--scene", str(GOLDEN / case / "scene.safetensors"), "--repeats", "1",
                               "--out-rgb", str(eager), "--autocast-bf16", "--out-autocast", str(autocast)])
    assert code == 0
    result = json.loads(capsys.readouterr().out)
    assert result["autocast"]["dtype"] == "bfloat16" and result["autocast"]["render"]["runs"] == 1
    full, mixed = tensors(eager), tensors(autocast)
    assert set(full) == names and set(mixed) == names
    expected = tensors(GOLDEN / case / "expected.safetensors")["rgb"]
    for name in names:
        assert full[name].dtype == torch.float32 and mixed[name].dtype == torch.float32
        assert full[name].shape == mixed[name].shape
    assert full["rgb"].shape == expected.shape
    # Float32 eager is the golden output; bf16 products move it, within bf16's 8 bits of mantissa.
    assert (full["rgb"] - expected).abs().max() < 1e-4
    error = (mixed["rgb"] - full["rgb"]).abs().max()
    assert 0 < error < 0.2, error


def test_without_autocast_nothing_is_autocast(tmp_path, capsys):
    case = GOLDEN / "srt_k1"
    code = bench_pytorch.main(["--model", str(case / "model.safetensors"), "--scene", str(case / "scene.safetensors"),
                               "--repeats", "1", "--out-rgb", str(tmp_path / "rgb.safetensors")])
    assert code == 0
    assert "autocast" not in json.loads(capsys.readouterr().out)
    assert set(tensors(tmp_path / "rgb.safetensors")) == {"rgb"}
