"""Checks of the Python tools: the reference model, the cameras, the checkpoint converter.

    python3 tools/test_reference.py

Exits with status 1 if any check fails. With RAYPATCH_OFFICIAL_REPO set to a checkout of
tberriel/RayPatchQuerying, it also runs the official modules (with einops, transformers and torchvision stubbed)
and compares them with the reference; without it that check is reported as skipped.
"""

import ast
import contextlib
import copy
import importlib
import io
import json
import os
import subprocess
import sys
import tempfile
import types
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from safetensors import safe_open

TOOLS = Path(__file__).resolve().parent
sys.path.insert(0, str(TOOLS))
import convert_checkpoint  # noqa: E402
import make_golden  # noqa: E402
from cameras import get_camera_rays, look_at_positions  # noqa: E402
from official_configs import RPSRT_MDBN_4_32, SRT_MDBN_32  # noqa: E402
from raypatch_reference import SRT, Attention  # noqa: E402

OFFICIAL_KEYS = TOOLS / "testdata" / "official_srt_keys.txt"
CHECKS = []


class Skip(Exception):
    pass


def check(function):
    CHECKS.append(function)
    return function


def random_model(model_cfg, seed=0):
    torch.manual_seed(seed)
    model = SRT.from_config(model_cfg).eval()
    make_golden.randomize_weights(model)
    return model


def k4_config(**rp_overrides):
    rp_kwargs = dict(upsample=2, h_in=8, w_in=12, conv_features=16, norm="Batch", **rp_overrides)
    return make_golden.small_config("featurefield", rp_kwargs=rp_kwargs, width=16)


def scene_tensors(case_name="rpsrt_k4"):
    case = next(case for case in make_golden.golden_cases() if case.name == case_name)
    return case, make_golden.make_scene(case, np.random.default_rng(0))


# --- reference model ----------------------------------------------------------------------------------------


def read_official_keys():
    """{section title: [(name, shape)]} and {section title: parameter total} from the testdata copy."""
    sections, totals, current = {}, {}, None
    for line in OFFICIAL_KEYS.read_text().splitlines():
        if line.startswith("### "):
            current = sections.setdefault(line[4:], [])
        elif line.startswith("## "):
            title, rest = line[3:].split(": ", 1)
            totals[title] = int(rest.split(" tensors, ")[1].split(" params")[0].replace(",", ""))
        elif line and not line.startswith("#"):
            name, shape = line.split(" ", 1)
            current.append((name, json.loads(shape)))
    return sections, totals


@check
def official_state_dict_keys():
    """Official-size srt_MDBN_32 and rpsrt_MDBN_4_32: the same names, order and shapes as the official model."""
    sections, totals = read_official_keys()
    for title, model_cfg in (("srt (lightfield, srt_MDBN_32)", SRT_MDBN_32),
                             ("rp-srt k=4 (rpsrt_MDBN_4_32)", RPSRT_MDBN_4_32)):
        with torch.device("meta"):
            model = SRT.from_config(model_cfg)
        ours = [(name, list(tensor.shape)) for name, tensor in model.state_dict().items()]
        official = sections[title]
        missing = sorted({n for n, _ in official} - {n for n, _ in ours})
        unexpected = sorted({n for n, _ in ours} - {n for n, _ in official})
        assert not missing and not unexpected, f"{title}: missing {missing}, unexpected {unexpected}"
        for (name, shape), (official_name, official_shape) in zip(ours, official):
            assert (name, shape) == (official_name, official_shape), \
                f"{title}: {name} {shape} where the official model has {official_name} {official_shape}"
        parameters = sum(p.numel() for p in model.parameters())
        assert parameters == totals[title], f"{title}: {parameters} parameters, official {totals[title]}"


@check
def config_errors_are_clear():
    bad = copy.deepcopy(SRT_MDBN_32)
    bad["encoder_kwargs"]["num_heads"] = 4
    for cfg, message in ((bad, "unknown key encoder_kwargs.num_heads"),
                         ({**SRT_MDBN_32, "base": "osrt"}, "base must be 'srt'"),
                         ({**RPSRT_MDBN_4_32, "rp_kwargs": None}, "needs section rp_kwargs")):
        try:
            with torch.device("meta"):
                SRT.from_config(cfg)
        except ValueError as error:
            assert message in str(error), str(error)
        else:
            raise AssertionError(f"no error for {message}")


@check
def attention_is_scaled_softmax():
    torch.manual_seed(0)
    attention = Attention(dim=20, heads=4, dim_head=8, kv_dim=12).double()
    x, z = torch.randn(2, 7, 20, dtype=torch.float64), torch.randn(2, 5, 12, dtype=torch.float64)
    q = attention.to_q(x).view(2, 7, 4, 8).transpose(1, 2)
    k, v = (t.view(2, 5, 4, 8).transpose(1, 2) for t in attention.to_kv(z).chunk(2, -1))
    weights = torch.softmax(q @ k.transpose(-1, -2) * 8**-0.5, -1)
    expected = attention.to_out((weights @ v).transpose(1, 2).reshape(2, 7, 32))
    assert torch.allclose(attention(x, z), expected, atol=1e-12)


@check
def patch_rays_average_the_central_pixels():
    """Bilinear resize by 1/k (align_corners=False) = mean of the 2x2 central rays of each kxk patch."""
    rays = torch.randn(2, 3, 32, 48)
    for k in (2, 4, 8, 16):
        resized = F.interpolate(rays, size=(32 // k, 48 // k), mode="bilinear", align_corners=False,
                                antialias=False)
        centre = rays[:, :, k // 2 - 1::k, k // 2 - 1::k] + rays[:, :, k // 2 - 1::k, k // 2::k] \
            + rays[:, :, k // 2::k, k // 2 - 1::k] + rays[:, :, k // 2::k, k // 2::k]
        assert torch.allclose(resized, centre / 4, atol=1e-6), f"k={k}"


@check
def render_paths_agree():
    """Full-resolution rays and given patch rays render the same; float32 and float64 agree; flat decode agrees."""
    case, scene = scene_tensors("rpsrt_k4")
    model = random_model(case.model_cfg)
    full = make_golden.run_model(model, scene, case.target_size, torch.float32)
    patches = make_golden.run_model(model, make_golden.patch_rays_of(model, scene), case.target_size,
                                    torch.float32)
    assert torch.equal(full["rgb"], patches["rgb"])
    assert full["rgb"].shape == (2, 32, 48, 3) and full["latent"].shape == (2 * 3 * 4, 16)
    double = make_golden.run_model(copy.deepcopy(model).double(), scene, case.target_size, torch.float64)
    assert (full["rgb"].double() - double["rgb"]).abs().max() < 5e-3

    # Light field: render_views is decode on the flattened rays.
    lightfield = random_model(make_golden.small_config("lightfield", width=16))
    with torch.no_grad():
        z = lightfield.encode(scene["input_images"].permute(0, 3, 1, 2)[None], scene["input_camera_pos"][None],
                              scene["input_rays"][None])
        rgb, logdepth = lightfield.render_views(z, scene["target_camera_pos"][None], scene["target_rays"][None])
        positions = scene["target_camera_pos"][:, None].expand(2, 32 * 48, 3).reshape(1, -1, 3)
        flat, _ = lightfield.decode(z, positions, scene["target_rays"].reshape(1, -1, 3))
    assert logdepth is None and torch.equal(rgb.reshape(1, -1, 3), flat)


@check
def target_size_rules():
    """Sizes not divisible by k need rp h_out/w_out (nearest resize to the target size); bad grids are errors."""
    case, scene = scene_tensors("rpsrt_k4")
    rays = scene["target_rays"][:, :30, :46]  # 30x46: patch grid 7x11 -> 28x44
    model = random_model(k4_config())
    with torch.no_grad():
        z = model.encode(scene["input_images"].permute(0, 3, 1, 2)[None], scene["input_camera_pos"][None],
                         scene["input_rays"][None])
        for bad_rays, target_size in ((rays, None), (scene["target_rays"], (32, 40))):
            try:
                model.render_views(z, scene["target_camera_pos"][None], bad_rays[None], target_size)
            except ValueError:
                pass
            else:
                raise AssertionError(f"no error for a {list(bad_rays.shape[1:3])} ray grid, target {target_size}")
        resizing = random_model(k4_config(h_out=120, w_out=160))
        rgb, _ = resizing.render_views(z, scene["target_camera_pos"][None], rays[None])
    assert rgb.shape == (1, 2, 30, 46, 3)


@check
def input_sizes_give_ceil_tokens():
    """Inputs of any size encode, as in PyTorch: 3 stride-2 convs (padding 1) give ceil(H/8) x ceil(W/8) tokens a
    view (60x80: 8x10, 40x60: 5x8, height x width)."""
    model = random_model(make_golden.small_config("lightfield", width=16))
    for num_views, height, width in ((1, 60, 80), (2, 40, 60), (1, 7, 9), (1, 1, 1)):
        position = look_at_positions(np.full(num_views, 30.0), np.full(num_views, 8.0), np.full(num_views, 20.0))
        rays = torch.from_numpy(np.stack([get_camera_rays(p, width, height) for p in position]))
        images = torch.rand(num_views, 3, height, width)
        with torch.no_grad():
            z = model.encode(images[None], torch.from_numpy(position)[None], rays[None])
        assert z.shape == (1, num_views * -(-height // 8) * -(-width // 8), 16), (num_views, height, width, z.shape)


@check
def depth_channel():
    case, scene = scene_tensors("srt_k1_depth")
    out = make_golden.run_model(random_model(case.model_cfg), scene, case.target_size, torch.float32)
    assert out["rgb"].shape == (1, 16, 24, 3) and out["logdepth"].shape == (1, 16, 24)


# --- cameras ------------------------------------------------------------------------------------------------


@check
def camera_rays():
    position = look_at_positions(35.0, 9.0, 30.0)[0]
    assert abs(np.linalg.norm(position) - 9.0) < 1e-5 and abs(position[2] - 4.5) < 1e-5
    height, width = 12, 16
    rays = get_camera_rays(position, width, height)
    assert rays.shape == (height, width, 3) and rays.dtype == np.float32
    assert np.allclose(np.linalg.norm(rays, axis=-1), 1, atol=1e-6)

    forward = -position / np.linalg.norm(position)
    right = np.cross(forward, (0, 0, 1))
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    # Pixel (0, 0) is the top-left pixel centre of a 32 mm wide sensor at 35 mm focal length.
    half_width, half_height = 0.016, 0.032 / width * height / 2
    corner = 0.035 * forward + (-half_width + half_width / width) * right + (-half_height + half_height / height) * down
    assert np.allclose(rays[0, 0], corner / np.linalg.norm(corner), atol=1e-6)
    centre = rays[height // 2 - 1:height // 2 + 1, width // 2 - 1:width // 2 + 1].mean((0, 1))
    assert np.allclose(centre / np.linalg.norm(centre), forward, atol=1e-6)
    assert rays[0, :, 2].mean() > rays[-1, :, 2].mean(), "row 0 must be the top row"


# --- converter ----------------------------------------------------------------------------------------------


class ConfigNode(Mapping):
    """Stands in for omegaconf's DictConfig: a mapping that is not a dict."""

    def __init__(self, items):
        self._items = {key: ConfigNode(value) if isinstance(value, dict) else value for key, value in items.items()}

    def __getitem__(self, key):
        return self._items[key]

    def __iter__(self):
        return iter(self._items)

    def __len__(self):
        return len(self._items)


class ConfigList(Sequence):
    """Stands in for omegaconf's ListConfig."""

    def __init__(self, items):
        self._items = list(items)

    def __getitem__(self, index):
        return self._items[index]

    def __len__(self):
        return len(self._items)


def fake_checkpoint(model, model_cfg, cfg_type=dict):
    """A Lightning checkpoint as the official training writes it, with metric and loss modules in the state_dict."""
    state_dict = dict(model.state_dict())
    state_dict["val_metrics.psnr.total"] = torch.tensor(3.0)
    state_dict["loss_colour.net.0.weight"] = torch.zeros(2, 2)
    cfg = {"data": {"dataset": "msn_easy", "kwargs": {"h": 120, "w": 160}}, "model": model_cfg,
           "training": {"batch_size": 32}}
    return {"epoch": 3, "global_step": 1000, "state_dict": state_dict,
            "hyper_parameters": {"cfg": cfg_type(cfg), "lr": 1e-4, "log_id": None}}


def run_converter(checkpoint, directory, name="run.ckpt"):
    """Saves the checkpoint, converts it in-process; returns (exit code, stderr, output path)."""
    in_path, out_path = Path(directory) / name, Path(directory) / (name + ".safetensors")
    torch.save(checkpoint, in_path)
    stderr = io.StringIO()
    with contextlib.redirect_stderr(stderr), contextlib.redirect_stdout(io.StringIO()):
        code = convert_checkpoint.main([str(in_path), str(out_path)])
    return code, stderr.getvalue(), out_path


@check
def converter_roundtrip():
    model_cfg = k4_config()
    model = random_model(model_cfg)
    expected = {name: tensor for name, tensor in model.state_dict().items()
                if not name.endswith("num_batches_tracked")}
    with tempfile.TemporaryDirectory() as directory:
        for cfg_type in (dict, ConfigNode):
            code, stderr, out_path = run_converter(fake_checkpoint(model, model_cfg, cfg_type), directory)
            assert code == 0, stderr
            with safe_open(str(out_path), "pt") as converted:
                metadata = converted.metadata()
                assert sorted(converted.keys()) == sorted(expected)
                for name, tensor in expected.items():
                    assert torch.equal(converted.get_tensor(name), tensor), name
            assert metadata["format"] == "raypatch-model/1" and metadata["source"] == "run.ckpt"
            assert json.loads(metadata["config"]) == model_cfg
            assert not [p for p in Path(directory).iterdir() if p.name.endswith(".tmp")]
    nested = ConfigNode({"a": ConfigList([1, ConfigNode({"b": None})]), "c": "text"})
    assert convert_checkpoint.to_plain(nested) == {"a": [1, {"b": None}], "c": "text"}


@check
def converter_rejects_bad_tensors():
    model_cfg = k4_config()
    checkpoint = fake_checkpoint(random_model(model_cfg), model_cfg)
    wrong, missing = "encoder.conv_blocks.0.layers.0.weight", "decoder_rp.conv_decoder.conv_0.bias"
    checkpoint["state_dict"][wrong] = torch.zeros(4, 180, 3, 3)
    del checkpoint["state_dict"][missing]
    with tempfile.TemporaryDirectory() as directory:
        code, stderr, out_path = run_converter(checkpoint, directory)
        assert code == 2 and not out_path.exists(), (code, stderr)
        lines = stderr.splitlines()
        assert len(lines) == 2, stderr
        assert any(wrong in line and "[4, 180, 3, 3]" in line and "[4, 183, 3, 3]" in line for line in lines), stderr
        assert any(missing in line and "missing" in line and "[3]" in line for line in lines), stderr
        assert all(line.startswith(f"convert_checkpoint: {Path(directory) / 'run.ckpt'}: ") for line in lines)

        no_rp = fake_checkpoint(random_model(model_cfg), {k: v for k, v in model_cfg.items() if k != "rp_kwargs"})
        code, stderr, out_path = run_converter(no_rp, directory, "no_rp.ckpt")
        assert code == 2 and "rp_kwargs" in stderr and len(stderr.splitlines()) == 1 and not out_path.exists()


@check
def converter_command_line():
    model_cfg = make_golden.small_config("lightfield", width=16)
    with tempfile.TemporaryDirectory() as directory:
        in_path, out_path = Path(directory) / "lf.ckpt", Path(directory) / "lf.safetensors"
        torch.save(fake_checkpoint(random_model(model_cfg), model_cfg), in_path)
        result = subprocess.run([sys.executable, str(TOOLS / "convert_checkpoint.py"), str(in_path), str(out_path)],
                                capture_output=True, text=True)
        assert result.returncode == 0 and out_path.exists(), result.stderr
        result = subprocess.run([sys.executable, str(TOOLS / "convert_checkpoint.py"), str(Path(directory) / "none"),
                                 str(Path(directory) / "none.safetensors")], capture_output=True, text=True)
        assert result.returncode == 2 and "cannot load checkpoint" in result.stderr, result.stderr


# --- against the official code ------------------------------------------------------------------------------


def _rearrange(tensor, pattern, **sizes):
    if pattern == "b n (h d) -> b h n d":
        return tensor.unflatten(-1, (sizes["h"], -1)).transpose(1, 2)
    if pattern == "b h n d -> b n (h d)":
        return tensor.transpose(1, 2).flatten(2)
    raise NotImplementedError(pattern)


def _unused(*args, **kwargs):
    raise NotImplementedError("stubbed out: not part of SRT")


def import_official(repo):
    """src.encoder and src.decoder of the official checkout, with their SRT-irrelevant imports stubbed."""
    stubs = {
        "einops": types.SimpleNamespace(rearrange=_rearrange, repeat=_unused),
        "transformers": types.SimpleNamespace(PerceiverModel=_unused, PerceiverConfig=_unused),
        "transformers.models.perceiver.modeling_perceiver": types.SimpleNamespace(PerceiverBasicDecoder=_unused),
        "src.resnet": types.SimpleNamespace(resnet18=_unused),
    }
    package = types.ModuleType("src")
    package.__path__ = [str(Path(repo) / "src")]
    saved = {name: sys.modules.get(name) for name in [*stubs, "src", "src.layers", "src.encoder", "src.decoder"]}
    sys.modules.update(stubs)
    sys.modules["src"] = package
    try:
        return importlib.import_module("src.encoder"), importlib.import_module("src.decoder")
    finally:
        for name, module in saved.items():
            if module is None:
                sys.modules.pop(name, None)
            else:
                sys.modules[name] = module


def official_get_camera_rays(repo):
    """The official get_camera_rays function, taken out of src/data/multishapenetEasy.py (whose imports need
    torchvision and imageio)."""
    source = (Path(repo) / "src" / "data" / "multishapenetEasy.py").read_text()
    function = next(node for node in ast.parse(source).body
                    if isinstance(node, ast.FunctionDef) and node.name == "get_camera_rays")
    namespace = {"np": np}
    exec(compile(ast.Module(body=[function], type_ignores=[]), "multishapenetEasy.py", "exec"), namespace)
    return namespace["get_camera_rays"]


@check
def matches_official_code():
    repo = os.environ.get("RAYPATCH_OFFICIAL_REPO")
    if not repo:
        raise Skip("set RAYPATCH_OFFICIAL_REPO to a checkout of tberriel/RayPatchQuerying")
    official_encoder, official_decoder = import_official(repo)

    official_rays = official_get_camera_rays(repo)
    for position in look_at_positions([10.0, 130.0, 250.0], [5.0, 8.0, 12.0], [15.0, 40.0, 70.0]):
        assert np.array_equal(get_camera_rays(position, 40, 30), official_rays(position, width=40, height=30))

    # rpsrt_k4's 2 views of 24x32, and input sizes that 8 does not divide (2 views of 40x60, 1 of 60x80).
    for case_name, model_cfg in [("rpsrt_k4", SRT_MDBN_32), ("rpsrt_k4", RPSRT_MDBN_4_32),
                                 ("rpsrt_k4_in40x60_2views", RPSRT_MDBN_4_32), ("srt_k1_in60x80", SRT_MDBN_32)]:
        _, scene = scene_tensors(case_name)
        images = scene["input_images"].permute(0, 3, 1, 2)[None]
        model_cfg = copy.deepcopy(model_cfg)
        featurefield = model_cfg["decoder"] == "featurefield"
        if featurefield:  # the official decoder only knows its configured grid: the patch grid of the targets
            model_cfg["rp_kwargs"].update(h_in=scene["target_rays"].shape[1] // 4,
                                          w_in=scene["target_rays"].shape[2] // 4)
        model = random_model(model_cfg)
        encoder = official_encoder.SRTEncoder(**model_cfg["encoder_kwargs"])
        decoder_att = official_decoder.SRTDecoder(**{**model_cfg["decoder_kwargs"],
                                                     "out_dims": 128 if featurefield else 3})
        encoder.load_state_dict({n[8:]: t for n, t in model.state_dict().items() if n.startswith("encoder.")})
        decoder_att.load_state_dict({n[12:]: t for n, t in model.state_dict().items()
                                     if n.startswith("decoder_att.")})
        official_modules = [encoder.eval(), decoder_att.eval()]
        if featurefield:
            decoder_rp = official_decoder.RayPatchDecoder(**model_cfg["rp_kwargs"])
            decoder_rp.load_state_dict({n[11:]: t for n, t in model.state_dict().items()
                                        if n.startswith("decoder_rp.")})
            official_modules.append(decoder_rp.eval())

        with torch.no_grad():
            z_official = encoder(images, scene["input_camera_pos"][None], scene["input_rays"][None])
            z = model.encode(images, scene["input_camera_pos"][None], scene["input_rays"][None])
            rgb, _ = model.render_views(z, scene["target_camera_pos"][None], scene["target_rays"][None])
            rays = scene["target_rays"]
            if featurefield:
                rays = make_golden.patch_rays_of(model, scene)["target_rays"]
            positions = scene["target_camera_pos"][:, None].expand(-1, rays.shape[1] * rays.shape[2], 3)
            out = decoder_att(z_official, positions.reshape(1, -1, 3), rays.reshape(1, -1, 3))
            if featurefield:
                out = decoder_rp(out).flatten(1, 3)
            rgb_official = torch.sigmoid(out)
        num_views, height, width = images.shape[1], images.shape[3], images.shape[4]
        assert z.shape[1] == num_views * -(-height // 8) * -(-width // 8), (case_name, z.shape)
        assert torch.allclose(z, z_official, atol=1e-5, rtol=1e-5), (z - z_official).abs().max()
        assert torch.allclose(rgb.reshape(1, -1, 3), rgb_official, atol=1e-5), \
            (rgb.reshape(1, -1, 3) - rgb_official).abs().max()


def main():
    failures = 0
    for function in CHECKS:
        try:
            function()
        except Skip as reason:
            print(f"skip {function.__name__}: {reason}")
        except Exception as error:  # report every failing check, not just the first
            failures += 1
            print(f"FAIL {function.__name__}: {type(error).__name__}: {error}")
        else:
            print(f"ok   {function.__name__}")
    print(f"{len(CHECKS) - failures}/{len(CHECKS)} checks passed" if failures else "all checks passed")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
