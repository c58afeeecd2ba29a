"""render-frame reads Lightning checkpoints itself (crates/raypatch-model/src/checkpoint), checked against the Python
converter (tools/conversion/convert_checkpoint.py), about 2 minutes on lavapipe:

    cargo build --release --bin render-frame && python3 -m pytest tools/tests/test_checkpoint_reader.py

For each family (SRT, RP-SRT, OSRT, RP-OSRT, DeFiNe, RP-DeFiNe: the golden models' weights and configs), a checkpoint
shaped as the official train.py's Lightning writes it (torch.save of state_dict with BatchNorm counters, metrics and
loss modules, hyper_parameters with the model section as `cfg`, optimizer and scheduler states, loops, callbacks)
is converted by the Python converter and saved by `render-frame --save-model`: the two model files are byte-equal,
and `render-frame --model run.ckpt` renders the same bits as `--model converted.safetensors`. Storages in f16, bf16
and f64, transposed and offset views, Lightning's AttributeDict and a whole run config under `cfg` read the same.
Hostile checkpoints (code-execution payloads, decompression bombs, wrong shapes, entries that are not tensors) are
refused with exit 2 and one line on stderr, nothing written. Skipped, saying why, without
target/release/render-frame.
"""

import os
import subprocess
import sys
import types
import zipfile
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file

from checkpoint_helpers import PAYLOAD_PLACES, with_payload
from conversion import convert_checkpoint
from reference.raypatch_reference import build_model

ROOT = Path(__file__).resolve().parents[2]
RENDER_FRAME = ROOT / "target" / "release" / "render-frame"
GOLDEN = ROOT / "assets" / "golden"
FAMILIES = ["srt_k1", "rpsrt_k4", "osrt", "rposrt_k8", "define", "rpdefine_k16"]

pytestmark = pytest.mark.skipif(not RENDER_FRAME.exists(),
                                reason="needs target/release/render-frame (cargo build --release)")


def golden_model(case):
    """The golden model of `case` as the official module would hold it: (model section, torch module)."""
    from safetensors import safe_open
    import json
    path = GOLDEN / case / "model.safetensors"
    with safe_open(str(path), "pt") as file:
        model_cfg = json.loads(file.metadata()["config"])
    model = build_model(model_cfg).eval()
    missing, unexpected = model.load_state_dict(load_file(str(path)), strict=False)
    assert not unexpected and all(name.endswith("num_batches_tracked") for name in missing), (missing, unexpected)
    return model_cfg, model


def attribute_dict():
    """A stand-in for Lightning's AttributeDict under its own module name (Lightning need not be installed)."""
    module = types.ModuleType("lightning_fabric.utilities.data")
    kind = type("AttributeDict", (dict,), {"__module__": module.__name__})
    module.AttributeDict = kind
    return kind, {"lightning_fabric": types.ModuleType("lightning_fabric"),
                  "lightning_fabric.utilities": types.ModuleType("lightning_fabric.utilities"),
                  module.__name__: module}


def lightning_checkpoint(model, model_cfg, variant):
    """The dict Lightning saves for the official GenericModel: `variant` picks how its tensors and config are held."""
    state_dict = dict(model.state_dict())
    if variant == "views":
        # The same values through other storages: f64 and f16-exact / bf16-exact values, a transposed view and a
        # view at an offset into a larger storage.
        names = [name for name, tensor in state_dict.items() if tensor.dim() == 2 and tensor.is_floating_point()]
        first, second, third, fourth = names[:4]
        state_dict[first] = state_dict[first].double()
        state_dict[second] = state_dict[second].t().contiguous().t()
        state_dict[third] = torch.cat([torch.zeros(7), state_dict[third].flatten()])[7:].view_as(state_dict[third])
        state_dict[fourth] = state_dict[fourth].half().float().half()
        biases = [name for name, tensor in state_dict.items() if name.endswith(".bias") and tensor.dim() == 1]
        state_dict[biases[0]] = state_dict[biases[0]].bfloat16()
    state_dict["val_metrics.psnr.total"] = torch.tensor(3.0)
    state_dict["loss_colour.net.0.weight"] = torch.zeros(2, 2, dtype=torch.float16)
    cfg = model_cfg if variant != "run-config" else {"data": {"dataset": "msn_easy"}, "model": model_cfg}
    parameters = [tensor for tensor in state_dict.values() if tensor.is_floating_point()][:3]
    return {
        "epoch": 3, "global_step": 1000, "pytorch-lightning_version": "2.0.2",
        "state_dict": state_dict,
        "loops": {"fit_loop": {"state_dict": {}, "epoch_progress": {"total": {"ready": 4, "completed": 3}}}},
        "callbacks": {"ModelCheckpoint{'monitor': 'val_psnr'}": {"best_model_score": torch.tensor(21.5),
                                                                "best_model_path": "/runs/model_best.ckpt"}},
        "optimizer_states": [{"state": {i: {"step": torch.tensor(1000.0), "exp_avg": torch.zeros_like(p)}
                                        for i, p in enumerate(parameters)},
                              "param_groups": [{"lr": 1e-4, "betas": (0.9, 0.999), "params": [0, 1, 2]}]}],
        "lr_schedulers": [{"base_lrs": [1e-4], "last_epoch": 1000, "lr_lambdas": [None]}],
        "hparams_name": "kwargs",
        "hyper_parameters": {"cfg": cfg, "log_id": None, "time_elapsed": 0.0, "lpips": False, "ssim": False},
    }


def render_frame(*args):
    return subprocess.run([str(RENDER_FRAME), *map(str, args)], capture_output=True, text=True, timeout=600)


def render_raw(model, case, out):
    # The pictures go beside the raw file (render-frame's default, render.png, would land in the working folder).
    pictures = Path(out).with_suffix("")
    result = render_frame("--model", model, "--scene", GOLDEN / case / "scene.safetensors", "--view", "all",
                          "--out-raw", out, "--out", pictures, "--quiet")
    assert result.returncode == 0, result.stderr
    return load_file(str(out))


@pytest.mark.parametrize("case", FAMILIES)
def test_checkpoints_render_as_their_conversion(tmp_path, case, monkeypatch):
    model_cfg, model = golden_model(case)
    kind, modules = attribute_dict()
    for name, module in modules.items():
        monkeypatch.setitem(sys.modules, name, module)
    for variant in ("plain", "views", "run-config"):
        checkpoint = lightning_checkpoint(model, model_cfg, variant)
        if variant == "plain":
            checkpoint["hyper_parameters"] = kind(checkpoint["hyper_parameters"])
        ckpt = tmp_path / f"{variant}.ckpt"
        torch.save(checkpoint, ckpt)
        python_out, rust_out = tmp_path / f"{variant}.py.safetensors", tmp_path / f"{variant}.rs.safetensors"
        assert convert_checkpoint.main([str(ckpt), str(python_out)]) == 0
        result = render_frame("--model", ckpt, "--save-model", rust_out)
        assert result.returncode == 0, result.stderr
        assert rust_out.read_bytes() == python_out.read_bytes(), variant
    # Rendering: the checkpoint itself (a name without .ckpt: told apart by content) and its conversion.
    os.replace(tmp_path / "views.ckpt", tmp_path / "views.model")
    direct = render_raw(tmp_path / "views.model", case, tmp_path / "direct.safetensors")
    converted = render_raw(tmp_path / "views.py.safetensors", case, tmp_path / "converted.safetensors")
    assert direct.keys() == converted.keys()
    for name in direct:
        assert torch.equal(direct[name], converted[name]), name


# --- hostile checkpoints ----------------------------------------------------------------------------------------


class RunsCode:
    """Unpickling it with pickle would call function(*args)."""

    def __init__(self, function, *args):
        self.function, self.args = function, args

    def __reduce__(self):
        return self.function, self.args


def hostile(tmp_path, model, model_cfg):
    """name -> (file bytes, a fragment of the refusal)."""
    marker = tmp_path / "MARKER"
    cases = {}

    def saved(checkpoint):
        path = tmp_path / "scratch.ckpt"
        torch.save(checkpoint, path)
        return path.read_bytes()

    for where in PAYLOAD_PLACES:
        evil = RunsCode(os.system, f"touch {marker}")
        checkpoint = with_payload(lightning_checkpoint(model, model_cfg, "plain"), where, evil)
        cases[f"system-{where}"] = (saved(checkpoint), "refusing to unpickle posix.system")
    checkpoint = lightning_checkpoint(model, model_cfg, "plain")
    checkpoint["optimizer_states"] = [{"state": {0: {"exp_avg": torch.zeros(25_000_000)}}}]  # 100 MB of zeros
    torch.save(checkpoint, tmp_path / "big.ckpt")
    with zipfile.ZipFile(tmp_path / "big.ckpt") as original, \
            zipfile.ZipFile(tmp_path / "bomb.ckpt", "w", zipfile.ZIP_DEFLATED, compresslevel=1) as packed:
        for info in original.infolist():
            packed.writestr(info.filename, original.read(info.filename))
    cases["bomb"] = ((tmp_path / "bomb.ckpt").read_bytes(), "decompression bomb")
    (tmp_path / "big.ckpt").unlink()
    (tmp_path / "bomb.ckpt").unlink()
    weight = next(name for name, tensor in model.state_dict().items() if tensor.dim() == 4)
    for name, value, fragment in [
        (weight, torch.zeros(3, 1, 2, 2), "has shape [3, 1, 2, 2]"),
        ("encoder.x", 3, "not a tensor but int 3"),
        (weight, torch.zeros(model.state_dict()[weight].shape, dtype=torch.int64), "torch.int64"),
        (weight, torch.zeros(1).expand(10 ** 12), "expanded or overlapping views"),
        (weight, torch.full(model.state_dict()[weight].shape, float("nan")), "NaN or infinity"),
    ]:
        checkpoint = lightning_checkpoint(model, model_cfg, "plain")
        checkpoint["state_dict"][name] = value
        cases[f"entry-{fragment.split()[-1]}"] = (saved(checkpoint), fragment)
    good = saved(lightning_checkpoint(model, model_cfg, "plain"))
    cases["truncated"] = (good[:len(good) // 2], "not a readable zip archive")
    (tmp_path / "scratch.ckpt").unlink()
    return marker, cases


def test_hostile_checkpoints_are_refused(tmp_path):
    model_cfg, model = golden_model("rpsrt_k4")
    marker, cases = hostile(tmp_path, model, model_cfg)
    for name, (data, fragment) in cases.items():
        path = tmp_path / f"{name}.ckpt"
        path.write_bytes(data)
        before = sorted(os.listdir(tmp_path))
        for args in (["--model", path, "--out", tmp_path / "out.png"],
                     ["--model", path, "--save-model", tmp_path / "out.safetensors"]):
            result = render_frame(*args)
            assert result.returncode == 2, (name, result.stderr)
            assert len(result.stderr.splitlines()) == 1 and fragment in result.stderr, (name, result.stderr)
            assert sorted(os.listdir(tmp_path)) == before, name
        assert not marker.exists(), "a pickle ran code"
        path.unlink()


def test_a_comment_full_of_directory_signatures_is_read_at_once(tmp_path):
    """Issue 50: an official-size checkpoint (150 MB: Adam's moments beside the weights) whose zip comment is 64 KB
    of end-of-central-directory signatures made the zip library retry from each one, scanning the file each time
    (over 120 s). Now it loads as the same checkpoint without the comment, in seconds."""
    import struct
    model_cfg, model = golden_model("rpsrt_k4")
    checkpoint = lightning_checkpoint(model, model_cfg, "plain")
    checkpoint["optimizer_states"] = [{"state": {0: {"exp_avg": torch.zeros(37_500_000)}}}]
    (tmp_path / "clean").mkdir()
    (tmp_path / "signed").mkdir()
    torch.save(checkpoint, tmp_path / "clean" / "run.ckpt")
    data = (tmp_path / "clean" / "run.ckpt").read_bytes()
    end = data.rfind(b"PK\x05\x06")
    assert end == len(data) - 22
    comment = b"PK\x05\x06" * (65532 // 4)
    (tmp_path / "signed" / "run.ckpt").write_bytes(data[:end + 20] + struct.pack("<H", len(comment)) + comment)
    del data
    for folder in ("clean", "signed"):
        result = subprocess.run([str(RENDER_FRAME), "--model", tmp_path / folder / "run.ckpt", "--save-model",
                                 tmp_path / folder / "model.safetensors"], capture_output=True, text=True, timeout=30)
        assert result.returncode == 0, result.stderr
    assert (tmp_path / "clean" / "model.safetensors").read_bytes() == \
        (tmp_path / "signed" / "model.safetensors").read_bytes()
