"""Checks of the Python tools: the reference model and the cameras (converter: test_convert_checkpoint.py).

    python3 tools/test_reference.py

Exits with status 1 if any check fails. With RAYPATCH_OFFICIAL_REPO set to a checkout of
tberriel/RayPatchQuerying, it also runs the official modules (with einops, transformers and torchvision stubbed)
and compares them with the reference, SRT and OSRT (`python3 tools/test_reference.py -v` prints the measured
differences); without it those checks are reported as skipped. The DeFiNe comparison runs the official modules
with the real transformers 4.24.0 and torchvision (installed beside the project's packages, e.g.
`pip install --no-deps --target DIR transformers==4.24.0 torchvision tqdm huggingface-hub==0.10.1` and
PYTHONPATH=DIR); it is skipped, saying why, where they cannot be imported.
"""

import ast
import copy
import functools
import importlib
import inspect
import json
import math
import os
import sys
import textwrap
import types
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from safetensors import safe_open

TOOLS = Path(__file__).resolve().parent
sys.path.insert(0, str(TOOLS))
import make_golden  # noqa: E402
import reference_define  # noqa: E402
from cameras import get_camera_rays, look_at_positions  # noqa: E402
from official_configs import (DEFINE_32_STEREO_ACC, OSRT_MDBN_64, RPDEFINE_16_32_STEREO_ACC,  # noqa: E402
                              RPOSRT_MDBN_8_64, RPSRT_MDBN_4_32, SRT_MDBN_32, official_keys)
from random_models import k4_config, random_define, random_model  # noqa: E402
from raypatch_reference import (OSRT, SRT, Attention, MixingBlock, OSRTEncoder, SlotAttention,  # noqa: E402
                                SlotMixerDecoder, adjusted_rand_index, build_model, foreground_ari)
from reference_define import (DeFiNe, PerceiverBasicDecoder, PerceiverLayer, ResNetSkip,  # noqa: E402
                              imagenet_normalize)
from safetensors.torch import load_file  # noqa: E402
from torch import nn  # noqa: E402

GOLDEN = TOOLS.parent / "assets" / "golden"
OSRT_CASES = ("osrt", "osrt_iters3_ln", "rposrt_k8", "rposrt_k4_patchrays")
DEFINE_CASES = ("define", "rpdefine_k16", "rpdefine_k16_patchrays_in60x88")
# The official DeFiNe runs (key lists written from the official modules) and their parameter totals.
DEFINE_KEY_LISTS = (("define_32_stereo_acc", DEFINE_32_STEREO_ACC, 30_759_058),
                    ("rpdefine_16_32_stereo_acc", RPDEFINE_16_32_STEREO_ACC, 31_011_690))
CHECKS = []
VERBOSE = False


def report(line):
    """Measured figures, printed with -v."""
    if VERBOSE:
        print(f"     {line}")


class Skip(Exception):
    pass


def check(function):
    CHECKS.append(function)
    return function


def scene_tensors(case_name="rpsrt_k4"):
    case = next(case for case in make_golden.golden_cases() if case.name == case_name)
    return case, make_golden.make_scene(case, np.random.default_rng(0))


# --- reference model ----------------------------------------------------------------------------------------


def compare_with_official_keys(runs):
    """Each (run, config, parameter total): the config's model has the official run's names, order and shapes."""
    for run, model_cfg, total in runs:
        with torch.device("meta"):
            model = build_model(model_cfg)
        ours = [(name, list(tensor.shape)) for name, tensor in model.state_dict().items()]
        official = official_keys(run)
        missing = sorted({n for n, _ in official} - {n for n, _ in ours})
        unexpected = sorted({n for n, _ in ours} - {n for n, _ in official})
        assert not missing and not unexpected, f"{run}: missing {missing}, unexpected {unexpected}"
        for (name, shape), (official_name, official_shape) in zip(ours, official):
            assert (name, shape) == (official_name, official_shape), \
                f"{run}: {name} {shape} where the official model has {official_name} {official_shape}"
        parameters = sum(p.numel() for p in model.parameters())
        assert parameters == total, f"{run}: {parameters} parameters, official {total}"


@check
def official_state_dict_keys():
    """Official-size srt_MDBN_32 and rpsrt_MDBN_4_32: the same names, order and shapes as the official model."""
    compare_with_official_keys((("srt_MDBN_32", SRT_MDBN_32, 41_037_615),
                                ("rpsrt_MDBN_4_32", RPSRT_MDBN_4_32, 41_328_245)))


@check
def official_osrt_state_dict_keys():
    """Official-size osrt_MDBN_64 and rposrt_MDBN_8_64: the same names, order, shapes and parameter totals as the
    official key lists (num_batches_tracked included, as the lists have them)."""
    compare_with_official_keys((("osrt_MDBN_64", OSRT_MDBN_64, 94_917_423),
                                ("rposrt_MDBN_8_64", RPOSRT_MDBN_8_64, 95_213_144)))


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


# --- OSRT ---------------------------------------------------------------------------------------------------


def random_osrt(model_cfg, seed=0):
    torch.manual_seed(seed)
    model = build_model(model_cfg).eval()
    make_golden.randomize_osrt_weights(model)
    return model


@check
def osrt_config_errors_are_clear():
    small = make_golden.small_osrt_config()

    def edited(section, **changes):
        cfg = copy.deepcopy(small)
        cfg[section].update(changes)
        return cfg

    for cfg, message in ((edited("encoder_kwargs", slot_heads=2), "unknown key encoder_kwargs.slot_heads"),
                         (edited("decoder_kwargs", pos_octaves=15), "unknown key decoder_kwargs.pos_octaves"),
                         (edited("encoder_kwargs", randomize_initial_slots=True), "randomize_initial_slots"),
                         (edited("decoder_kwargs", latent_dim=64), "must equal encoder_kwargs.slot_dim 32"),
                         (edited("decoder_kwargs", heads=5), "not a multiple of heads 5"),
                         ({**small, "decoder": "featurefield"}, "needs section rp_kwargs"),
                         ({**small, "decoder": "nerf"}, "decoder must be"),
                         ({**small, "base": "nerf"}, "base must be one of")):
        try:
            with torch.device("meta"):
                build_model(cfg)
        except ValueError as error:
            assert message in str(error), str(error)
        else:
            raise AssertionError(f"no error for {message}")
    # The official OSRT overwrites decoder_kwargs.out_dims: 3 for a light field, conv_features for Ray-Patch.
    with torch.device("meta"):
        lightfield = build_model(edited("decoder_kwargs", out_dims=128))
        rp = build_model(make_golden.small_osrt_config("featurefield", out_dims=False, rp_kwargs=dict(
            upsample=2, conv_features=16)))
    assert lightfield.decoder_att.render_mlp.net[8].out_features == 3
    assert isinstance(lightfield.decoder_att.render_mlp.net[9], nn.Identity)
    assert rp.decoder_att.render_mlp.net[8].out_features == 16 and rp.patch_size == 4
    assert isinstance(rp.decoder_att.render_mlp.net[9], nn.LeakyReLU)
    with torch.device("meta"):
        assert isinstance(build_model(small), OSRT) and isinstance(build_model(SRT_MDBN_32), SRT)


@check
def slot_attention_maths():
    """SlotAttention against its definition written out in float64: softmax over the slots + 1e-8, weighted mean
    over the inputs, PyTorch GRUCell equations (gates r, z, n stacked in that order), residual MLP."""
    torch.manual_seed(1)
    module = SlotAttention(num_slots=3, input_dim=6, slot_dim=8, hidden_dim=10, iters=2).double()
    with torch.no_grad():
        for parameter in module.parameters():
            parameter.copy_(torch.randn(parameter.shape, dtype=torch.float64) * 0.5)
    inputs = torch.randn(2, 7, 6, dtype=torch.float64)

    def layer_norm(x, norm):
        return (x - x.mean(-1, keepdim=True)) / torch.sqrt(x.var(-1, unbiased=False, keepdim=True) + 1e-5) \
            * norm.weight + norm.bias

    x = layer_norm(inputs, module.norm_input)
    k, v = x @ module.to_k.weight.T, x @ module.to_v.weight.T
    slots = module.initial_slots.expand(2, -1, -1)
    gru = module.gru
    for _ in range(2):
        q = layer_norm(slots, module.norm_slots) @ module.to_q.weight.T
        attn = torch.softmax(q @ k.transpose(1, 2) / math.sqrt(8), dim=1) + 1e-8
        updates = (attn / attn.sum(-1, keepdim=True)) @ v
        gi = updates @ gru.weight_ih.T + gru.bias_ih
        gh = slots @ gru.weight_hh.T + gru.bias_hh
        r = torch.sigmoid(gi[..., :8] + gh[..., :8])
        z = torch.sigmoid(gi[..., 8:16] + gh[..., 8:16])
        n = torch.tanh(gi[..., 16:] + r * gh[..., 16:])
        slots = (1 - z) * n + z * slots
        hidden = torch.relu(layer_norm(slots, module.norm_pre_mlp) @ module.mlp[0].weight.T + module.mlp[0].bias)
        slots = slots + hidden @ module.mlp[2].weight.T + module.mlp[2].bias
    with torch.no_grad():
        assert torch.allclose(module(inputs), slots, atol=1e-12)


@check
def mixing_block_maths():
    torch.manual_seed(2)
    block = MixingBlock(input_dim=5, slot_dim=4, att_dim=6, layer_norm=False).double()
    x, slots = torch.randn(2, 9, 5, dtype=torch.float64), torch.randn(2, 3, 4, dtype=torch.float64)
    weights = torch.softmax((x @ block.to_q.weight.T) @ (slots @ block.to_k.weight.T).transpose(1, 2) / math.sqrt(6),
                            -1)
    with torch.no_grad():
        mix, w = block(x, slots)
    assert torch.allclose(w, weights, atol=1e-12) and torch.allclose(mix, weights @ slots, atol=1e-12)


def osrt_case(name):
    case = next(case for case in make_golden.golden_cases() if case.name == name)
    return case, make_golden.make_scene(case, np.random.default_rng(case.seed))


@check
def osrt_render_paths():
    """Full-resolution and patch rays render the same rgb and segmentation; light-field slot weights sum to 1 and
    render_views is decode on the flattened rays; the Ray-Patch segmentation is the bilinear resize of the
    patch rays' slot weights; float32 and float64 agree."""
    case, scene = osrt_case("rposrt_k4_patchrays")
    model = random_osrt(case.model_cfg)
    full = make_golden.run_model(model, scene, case.target_size, torch.float32)
    patches = make_golden.run_model(model, make_golden.patch_rays_of(model, scene), case.target_size, torch.float32)
    assert torch.equal(full["rgb"], patches["rgb"]) and torch.equal(full["segmentation"], patches["segmentation"])
    assert full["segmentation"].shape == (2, 32, 48, 6) and full["latent"].shape == (6, 32)
    assert full["set_latent"].shape == (2 * 3 * 4, 16)
    double = make_golden.run_model(copy.deepcopy(model).double(), scene, case.target_size, torch.float64)
    assert (full["rgb"].double() - double["rgb"]).abs().max() < 5e-3
    assert (full["segmentation"].double() - double["segmentation"]).abs().max() < 5e-3

    with torch.no_grad():
        slots = full["latent"][None]
        rays = make_golden.patch_rays_of(model, scene)["target_rays"]
        positions = scene["target_camera_pos"][:, None].expand(2, 8 * 12, 3).reshape(1, -1, 3)
        _, weights = model.decoder_att(slots, positions, rays.reshape(1, -1, 3))
        resized = F.interpolate(weights.reshape(2, 8, 12, 6).permute(0, 3, 1, 2), size=(32, 48), mode="bilinear",
                                align_corners=False).permute(0, 2, 3, 1)
    assert torch.allclose(resized, full["segmentation"], atol=1e-6)

    case, scene = osrt_case("osrt")
    model = random_osrt(case.model_cfg)
    out = make_golden.run_model(model, scene, case.target_size, torch.float32)
    assert torch.allclose(out["segmentation"].sum(-1), torch.ones(2, 16, 24), atol=1e-5)
    with torch.no_grad():
        positions = scene["target_camera_pos"][:, None].expand(2, 16 * 24, 3).reshape(1, -1, 3)
        rgb, logdepth, segmentation = model.decode(out["latent"][None], positions,
                                                   scene["target_rays"].reshape(1, -1, 3))
    assert logdepth is None and torch.equal(rgb.reshape(out["rgb"].shape), out["rgb"])
    assert torch.equal(segmentation.reshape(out["segmentation"].shape), out["segmentation"])


def pair_counting_ari(true_ids, pred_ids):
    """Adjusted Rand index by counting point pairs (Hubert and Arabie), float64."""
    n = len(true_ids)
    pairs = n * (n - 1) / 2
    same_true = sum(math.comb(int(c), 2) for c in np.bincount(true_ids))
    same_pred = sum(math.comb(int(c), 2) for c in np.bincount(pred_ids))
    same_both = sum(math.comb(int(c), 2) for c in np.unique(np.stack([true_ids, pred_ids]), axis=1,
                                                            return_counts=True)[1])
    expected = same_true * same_pred / pairs
    return (same_both - expected) / ((same_true + same_pred) / 2 - expected)


@check
def fg_ari_definition():
    """FG-ARI: pair-counting ARI over the foreground points, labels and slots permutation-invariant, background
    ignored, 1 for a single group on both sides, all views pooled."""
    rng = np.random.default_rng(3)
    masks = torch.from_numpy(rng.integers(0, 4, (1, 2, 6, 7)).astype(np.uint8))
    segmentation = torch.from_numpy(rng.random((1, 2, 6, 7, 5))).float()
    ari = foreground_ari(segmentation, masks)
    fg = masks.flatten() > 0
    expected = pair_counting_ari(masks.flatten()[fg].numpy(), segmentation.argmax(-1).flatten()[fg].numpy())
    assert ari.dtype == torch.float64 and abs(ari.item() - expected) < 1e-12, (ari, expected)
    assert torch.equal(foreground_ari(segmentation[..., [3, 0, 4, 1, 2]], masks), ari)
    relabelled = torch.tensor([0, 3, 1, 2], dtype=torch.uint8)[masks.long()]
    assert torch.equal(foreground_ari(segmentation, relabelled), ari)
    perfect = F.one_hot(masks.long(), 5).float() + 0.01 * segmentation
    background_noise = torch.where((masks == 0)[..., None], segmentation, perfect)
    assert foreground_ari(perfect, masks).item() == 1.0 and foreground_ari(background_noise, masks).item() == 1.0
    single = torch.ones_like(masks)
    assert foreground_ari(segmentation, single).item() != 1.0
    assert foreground_ari(torch.ones(1, 2, 6, 7, 5), single).item() == 1.0
    # [B, G, N] form with two scenes at once.
    true = F.one_hot(masks.long().flatten(1), 4).transpose(1, 2)[:, 1:].expand(2, -1, -1)
    assert torch.equal(adjusted_rand_index(true, segmentation.flatten(1, 3).transpose(1, 2).expand(2, -1, -1)),
                       ari.expand(2))


@check
def osrt_golden_files():
    """The committed OSRT golden cases are what the reference computes from their model and scene files (to
    float32 rounding across PyTorch builds), and their fg_ari that of their segmentation."""
    for name in OSRT_CASES:
        folder = GOLDEN / name
        with safe_open(str(folder / "model.safetensors"), "pt") as file:
            model_cfg = json.loads(file.metadata()["config"])
        with safe_open(str(folder / "scene.safetensors"), "pt") as file:
            target_size = file.metadata().get("target_size")
        model = build_model(model_cfg).eval()
        missing, unexpected = model.load_state_dict(load_file(str(folder / "model.safetensors")), strict=False)
        assert not unexpected and all(key.endswith("num_batches_tracked") for key in missing), (missing, unexpected)
        scene, expected = load_file(str(folder / "scene.safetensors")), load_file(str(folder / "expected.safetensors"))
        size = tuple(map(int, target_size.split("x"))) if target_size else tuple(scene["target_masks"].shape[1:])
        out = make_golden.run_model(model, scene, size, torch.float32)
        for key, value in out.items():
            difference = (value - expected[key]).abs().max().item()
            assert difference < 1e-4, (name, key, difference)
        assert torch.equal(make_golden.fg_ari(expected["segmentation"], scene["target_masks"]), expected["fg_ari"])
        assert expected["fg_ari"].dtype == torch.float64 and expected["fg_ari"].shape == (1,)

# --- DeFiNe -------------------------------------------------------------------------------------------------


def define_case(name):
    case = next(case for case in make_golden.golden_cases() if case.name == name)
    return case, make_golden.make_define_scene(case, np.random.default_rng(case.seed))


@check
def official_define_state_dict_keys():
    """Official-size define_32_stereo_acc and rpdefine_16_32_stereo_acc: the names and shapes of the key lists
    written from the official modules, and their parameter totals (30,759,058 and 31,011,690). The official
    FeatureDecoder registers conv_blocks before conv_0, so the order within decoder_rp_* differs; everything else
    is in the official order."""
    for file, model_cfg, total in DEFINE_KEY_LISTS:
        official = official_keys(file)
        with torch.device("meta"):
            model = build_model(model_cfg)
        ours = [(name, list(tensor.shape)) for name, tensor in model.state_dict().items()]
        assert sorted(ours) == sorted(official), (file, sorted(set(map(str, ours)) ^ set(map(str, official)))[:5])
        assert [n for n, _ in ours if "conv_decoder" not in n] == [n for n, _ in official if "conv_decoder" not in n]
        parameters = sum(p.numel() for p in model.parameters())
        from_list = sum(math.prod(shape) for name, shape in official
                        if not name.endswith(("running_mean", "running_var", "num_batches_tracked")))
        report(f"{file}: {len(official)} tensors, {parameters:,} parameters "
               f"(encoder {sum(p.numel() for n, p in model.named_parameters() if n.startswith('encoder.')):,})")
        assert parameters == from_list == total, (file, parameters, from_list, total)


@check
def define_config_rules():
    """Config checks of base define: unknown keys, rp_kwargs.out_dims, latent widths and heads are errors;
    decoder_kwargs.out_dims is ignored (the heads emit 3 and 1, or conv_features with Ray-Patch)."""
    small = make_golden.small_define_config()

    def edited(section, **changes):
        cfg = copy.deepcopy(small)
        cfg[section].update(changes)
        return cfg

    rp = make_golden.small_define_config("featurefield", rp_kwargs=dict(upsample=4, conv_features=32))
    for cfg, message in ((edited("encoder_kwargs", num_conv_blocks=3), "unknown key encoder_kwargs.num_conv_blocks"),
                         (edited("decoder_kwargs", heads=2), "unknown key decoder_kwargs.heads"),
                         (edited("decoder_kwargs", latent_dim=64), "must equal encoder_kwargs.latent_dim 32"),
                         (edited("encoder_kwargs", heads=5), "not a multiple of heads 5"),
                         ({**rp, "rp_kwargs": {**rp["rp_kwargs"], "out_dims": 3}}, "rp_kwargs.out_dims must be absent"),
                         ({**small, "decoder": "featurefield"}, "needs section rp_kwargs")):
        try:
            with torch.device("meta"):
                build_model(cfg)
        except ValueError as error:
            assert message in str(error), str(error)
        else:
            raise AssertionError(f"no error for {message}")
    with torch.device("meta"):
        lightfield = build_model(edited("decoder_kwargs", out_dims=128))
        ray_patch = build_model(rp)
    assert isinstance(lightfield, DeFiNe) and lightfield.patch_size == 1 and ray_patch.patch_size == 16
    heads = [model.transformer.final_layer.out_features
             for model in (lightfield.decoder_att_rgb, lightfield.decoder_att_d, ray_patch.decoder_att_rgb,
                           ray_patch.decoder_att_d)]
    assert heads == [3, 1, 32, 32], heads
    assert ray_patch.decoder_rp_rgb.conv_decoder.conv_0.out_channels == 3
    assert ray_patch.decoder_rp_d.conv_decoder.conv_0.out_channels == 1
    assert lightfield.encoder.transformer.d_model == 306 and lightfield.decoder_att_rgb.transformer.final_layer \
        .in_features == 186


@check
def perceiver_maths():
    """The HF Perceiver layers against their equations written out in float64: LayerNorm eps 1e-5, scores divided
    by sqrt(q/k head width), exact GELU, the query residual in the encoder cross-attention and the self-attention
    layers, none in the decoder cross-attention."""
    torch.manual_seed(3)

    def randomized(module):
        with torch.no_grad():
            for parameter in module.parameters():
                parameter.copy_(torch.randn(parameter.shape, dtype=torch.float64) * 0.4 + (parameter.dim() == 1) * 0.3)
        return module

    def layer_norm(x, norm):
        return (x - x.mean(-1, keepdim=True)) / torch.sqrt(x.var(-1, unbiased=False, keepdim=True) + 1e-5) \
            * norm.weight + norm.bias

    def linear(x, module):
        return x @ module.weight.T + module.bias

    def gelu(x):
        return 0.5 * x * (1 + torch.erf(x / math.sqrt(2)))

    def expected(layer, x, inputs, heads, residual):
        attention = layer.attention.self
        q = linear(layer_norm(x, attention.layernorm1), attention.query)
        source = layer_norm(x, attention.layernorm1) if inputs is None else layer_norm(inputs, attention.layernorm2)
        k, v = linear(source, attention.key), linear(source, attention.value)
        split = [t.unflatten(-1, (heads, -1)).transpose(1, 2) for t in (q, k, v)]
        weights = torch.softmax(split[0] @ split[1].transpose(-1, -2) / math.sqrt(split[0].shape[-1]), -1)
        a = linear((weights @ split[2]).transpose(1, 2).flatten(2), layer.attention.output.dense)
        if residual:
            a = a + x
        mlp = layer.mlp
        return a + linear(gelu(linear(layer_norm(a, layer.layernorm), mlp.dense1)), mlp.dense2)

    latents, inputs = torch.randn(2, 6, 8, dtype=torch.float64), torch.randn(2, 11, 10, dtype=torch.float64)
    cross = randomized(PerceiverLayer(True, 1, 8, 10).double())
    self_attention = randomized(PerceiverLayer(False, 4, 8, 8).double())
    decoder = randomized(PerceiverBasicDecoder(num_channels=7, d_latents=8, output_num_channels=3).double())
    queries = torch.randn(2, 5, 7, dtype=torch.float64)
    assert cross.attention.self.query.out_features == 10 and cross.attention.output.dense.out_features == 8
    assert isinstance(self_attention.attention.self.layernorm2, nn.Identity)
    with torch.no_grad():
        assert torch.allclose(cross(latents, inputs), expected(cross, latents, inputs, 1, True), atol=1e-12)
        assert torch.allclose(self_attention(latents), expected(self_attention, latents, None, 4, True), atol=1e-12)
        layer = decoder.decoding_cross_attention
        assert layer.attention.self.query.out_features == 8 and layer.attention.output.dense.out_features == 7
        want = linear(expected(layer, queries, latents, 1, False), decoder.final_layer)
        assert torch.allclose(decoder(queries, latents), want, atol=1e-12)


@check
def define_encoder_sizes():
    """ResNet-18 feature sizes (conv1 and maxpool stride 2, then each layer ceil(s/2)), ImageNet normalisation as
    torchvision's Normalize computes it, token counts, and input sides that 4 does not divide refused (the official
    code fails on them)."""
    resnet = ResNetSkip(8).eval()
    with torch.no_grad():
        sizes = [tuple(x.shape[1:]) for x in resnet(torch.randn(1, 3, 60, 88))]
    assert sizes == [(8, 15, 22), (16, 8, 11), (32, 4, 6), (64, 2, 3)], sizes
    images = torch.rand(2, 3, 4, 5)
    mean, std = torch.tensor([0.485, 0.456, 0.406]), torch.tensor([0.229, 0.224, 0.225])
    assert torch.equal(imagenet_normalize(images), images.sub(mean.view(-1, 1, 1)).div(std.view(-1, 1, 1)))

    model = random_define(make_golden.small_define_config())
    for height, width, error in ((64, 96, False), (60, 88, False), (4, 8, False), (60, 90, True), (62, 88, True)):
        views = torch.rand(1, 2, 3, height, width), torch.randn(1, 2, 3), torch.randn(1, 2, height, width, 3)
        try:
            with torch.no_grad():
                z = model.encode(*views)
        except ValueError as failure:
            assert error and "divisible by 4" in str(failure), (height, width, failure)
        else:
            assert not error and z.shape == (1, 64, 32), (height, width)
            tokens = model.encoder.transformer
            captured = []
            hook = tokens.register_forward_pre_hook(lambda module, inputs: captured.append(inputs[0]))
            with torch.no_grad():
                model.encode(*views)
            hook.remove()
            assert captured[0].shape == (1, 2 * (height // 4) * (width // 4), 306), captured[0].shape


@check
def define_render_paths():
    """Full-resolution and patch target rays give the same rgb and log-depth; render_views is decode on the
    flattened rays; float32 and float64 agree; the scene's rays are unit-depth points of its cameras."""
    case, scene = define_case("rpdefine_k16")
    model = random_define(case.model_cfg, case.seed, scene, case.target_size)
    full = make_golden.run_model(model, scene, case.target_size, torch.float32)
    patches = make_golden.run_model(model, make_golden.patch_rays_of(model, scene), case.target_size, torch.float32)
    assert torch.equal(full["rgb"], patches["rgb"]) and torch.equal(full["logdepth"], patches["logdepth"])
    assert full["rgb"].shape == (2, 32, 48, 3) and full["logdepth"].shape == (2, 32, 48)
    assert full["latent"].shape == (64, 32)
    assert math.log(0.1) <= full["logdepth"].min() and full["logdepth"].max() <= math.log(10.0)
    double = make_golden.run_model(copy.deepcopy(model).double(), scene, case.target_size, torch.float64)
    for key in ("rgb", "logdepth"):
        assert (full[key].double() - double[key]).abs().max() < 1e-4, key

    case, scene = define_case("define")
    model = random_define(case.model_cfg, case.seed, scene, case.target_size)
    out = make_golden.run_model(model, scene, case.target_size, torch.float32)
    with torch.no_grad():
        positions = scene["target_camera_pos"][:, None].expand(2, 16 * 24, 3).reshape(1, -1, 3)
        rgb, logdepth = model.decode(out["latent"][None], positions, scene["target_rays"].reshape(1, -1, 3))
    assert torch.equal(rgb.reshape(out["rgb"].shape), out["rgb"])
    assert torch.equal(logdepth.reshape(out["logdepth"].shape), out["logdepth"])

    # Input camera 0 is the canonical frame: its points have z = 1 and its position is the origin.
    assert torch.equal(scene["input_camera_pos"][0], torch.zeros(3))
    assert torch.allclose(scene["input_rays"][0, ..., 2], torch.ones(64, 96), atol=1e-6)
    assert torch.equal(scene["target_camera_pos"][0], scene["input_camera_pos"][1])
    # The resize of an affine function of the pixel is exact: the 2x2 central points are around pixel (320, 240).
    centre = scene["input_rays"][0, 31:33, 47:49].mean((0, 1))
    want = torch.from_numpy(np.linalg.inv(make_golden.SCANNET_K) @ [320.0, 240.0, 1.0]).float()
    assert torch.allclose(centre, want, atol=1e-6), (centre, want)


@check
def define_golden_files():
    """The committed DeFiNe golden cases are what the reference computes from their model and scene files (to
    float32 rounding across PyTorch builds), with the documented names and shapes."""
    for name in DEFINE_CASES:
        folder = GOLDEN / name
        with safe_open(str(folder / "model.safetensors"), "pt") as file:
            model_cfg = json.loads(file.metadata()["config"])
        with safe_open(str(folder / "scene.safetensors"), "pt") as file:
            target_size = file.metadata().get("target_size")
        model = build_model(model_cfg).eval()
        missing, unexpected = model.load_state_dict(load_file(str(folder / "model.safetensors")), strict=False)
        assert not unexpected and all(key.endswith("num_batches_tracked") for key in missing), (missing, unexpected)
        scene, expected = load_file(str(folder / "scene.safetensors")), load_file(str(folder / "expected.safetensors"))
        size = tuple(map(int, target_size.split("x"))) if target_size else tuple(scene["target_rays"].shape[1:3])
        num_targets = scene["target_rays"].shape[0]
        assert expected["rgb"].shape == (num_targets, *size, 3) and expected["logdepth"].shape == (num_targets, *size)
        assert expected["latent"].shape == (64, 32) and expected["logdepth_f64"].dtype == torch.float64
        out = make_golden.run_model(model, scene, size, torch.float32)
        for key, value in out.items():
            difference = (value - expected[key]).abs().max().item()
            assert difference < 1e-4, (name, key, difference)
        report(f"{name}: max |f32 - f64| rgb {(expected['rgb'].double() - expected['rgb_f64']).abs().max():.1e}, "
               f"logdepth {(expected['logdepth'].double() - expected['logdepth_f64']).abs().max():.1e}")


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


def defaults_of(module_cls, kwargs):
    """kwargs completed with the constructor defaults of module_cls."""
    parameters = inspect.signature(module_cls.__init__).parameters
    return {**{name: p.default for name, p in parameters.items() if p.default is not inspect.Parameter.empty},
            **kwargs}


def bare(module_cls):
    """An official module object without its __init__ (submodules are assigned by the caller)."""
    module = module_cls.__new__(module_cls)
    nn.Module.__init__(module)
    return module


def official_osrt_modules(official_encoder, official_decoder, layers, model_cfg, targets):
    """The official OSRT modules for model_cfg, loaded later with the reference's weights.

    Official-width configs use the official constructors as they are. Small configs keep the official classes
    and forward code and build the modules whose widths the official code hard-codes (SRTEncoder: conv hidden 96,
    768-wide tokens, 12 heads; RayPredictor: 12 heads, input MLP 360; OSRTEncoder: SlotAttention input 768, hidden
    3072) from the official Transformer, SRTConvBlock, RayEncoder, SlotAttention and SRTLinear at the config's
    widths. The official RayPatchDecoder gets the targets' patch grid as h_in/w_in and their size as h_out/w_out.
    """
    enc = defaults_of(OSRTEncoder, model_cfg["encoder_kwargs"])
    dec = defaults_of(SlotMixerDecoder, model_cfg["decoder_kwargs"])
    featurefield = model_cfg["decoder"] == "featurefield"
    dec["out_dims"] = model_cfg["rp_kwargs"].get("conv_features", 128) if featurefield else 3
    official_widths = all(enc[key] == value for key, value in
                          dict(conv_hidden=96, token_dim=768, heads=12, dim_head=64, slot_hidden=3072).items()) \
        and all(dec[key] == value for key, value in dict(latent_dim=1536, heads=12, input_mlp_hidden=360,
                                                         att_dim=1536, render_mlp_hidden=1536).items())
    if official_widths:
        encoder = official_encoder.OSRTEncoder(**model_cfg["encoder_kwargs"])
        decoder_att = official_decoder.SlotMixerDecoder(**{**model_cfg["decoder_kwargs"], "out_dims": dec["out_dims"]})
    else:
        srt = bare(official_encoder.SRTEncoder)
        srt.ray_encoder = layers.RayEncoder(pos_octaves=enc["num_octaves"], pos_start_octave=enc["pos_start_octave"],
                                            ray_octaves=enc["num_octaves"])
        blocks, channels = [official_encoder.SRTConvBlock(idim=12 * enc["num_octaves"] + 3, hdim=enc["conv_hidden"],
                                                          norm=enc["norm"])], 2 * enc["conv_hidden"]
        for _ in range(1, enc["num_conv_blocks"]):
            blocks.append(official_encoder.SRTConvBlock(idim=channels, odim=None, norm=enc["norm"]))
            channels *= 2
        srt.conv_blocks = nn.Sequential(*blocks)
        srt.pooling = nn.MaxPool2d(2) if enc["max_pooling"] else nn.Identity()
        srt.per_patch_linear = nn.Conv2d(channels, enc["token_dim"], kernel_size=1)
        srt.transformer = layers.Transformer(enc["token_dim"], depth=enc["num_att_blocks"], heads=enc["heads"],
                                             dim_head=enc["dim_head"], latent_dim=enc["latent_dim"],
                                             mlp_dim=int(enc["latent_dim"] * 2), selfatt=True)
        encoder = bare(official_encoder.OSRTEncoder)
        encoder.srt_encoder = srt
        encoder.slot_attention = layers.SlotAttention(enc["num_slots"], input_dim=enc["token_dim"],
                                                      slot_dim=enc["slot_dim"], hidden_dim=enc["slot_hidden"],
                                                      iters=enc["slot_iters"])
        allocation = official_decoder.RayPredictor(num_att_blocks=dec["num_att_blocks"],
                                                   pos_start_octave=dec["pos_start_octave"], input_mlp=True,
                                                   latent_dim=dec["latent_dim"], mode=dec["mode"], output_mlp=False,
                                                   return_queries=True)
        allocation.transformer = layers.Transformer(180, depth=dec["num_att_blocks"], heads=dec["heads"],
                                                    dim_head=dec["latent_dim"] // dec["heads"],
                                                    latent_dim=dec["latent_dim"], mlp_dim=int(dec["latent_dim"] * 2),
                                                    selfatt=False, mode=dec["mode"])
        allocation.input_mlp = nn.Sequential(layers.SRTLinear(180, dec["input_mlp_hidden"]), nn.ReLU(),
                                             layers.SRTLinear(dec["input_mlp_hidden"], 180))
        decoder_att = bare(official_decoder.SlotMixerDecoder)
        decoder_att.allocation_transformer = allocation
        decoder_att.mixing_block = official_decoder.MixingBlock(180, dec["latent_dim"], dec["att_dim"],
                                                                dec["layer_norm"])
        decoder_att.render_mlp = official_decoder.RenderMLP(dec["latent_dim"] + 180, dec["render_mlp_hidden"],
                                                            dec["out_dims"])
    decoder_rp = nn.Identity()
    if featurefield:
        k = 2 ** model_cfg["rp_kwargs"]["upsample"]
        (_, height, width) = targets
        decoder_rp = official_decoder.RayPatchDecoder(**{**model_cfg["rp_kwargs"], "h_in": height // k,
                                                         "w_in": width // k, "h_out": height, "w_out": width})
    return encoder, decoder_att, decoder_rp


def official_function(path, name, class_name=None, replacements=(), namespace=None):
    """A function (or a method of class_name) taken out of an official source file and compiled on its own."""
    source = Path(path).read_text()
    nodes = ast.parse(source).body
    if class_name is not None:
        nodes = next(node for node in nodes if isinstance(node, ast.ClassDef) and node.name == class_name).body
    node = next(node for node in nodes if isinstance(node, ast.FunctionDef) and node.name == name)
    text = textwrap.dedent(ast.get_source_segment(source, node, padded=True))
    for old, new in replacements:
        assert text.count(old) == 1, (name, old)
        text = text.replace(old, new)
    namespace = dict(namespace or {})
    exec(compile(text, str(path), "exec"), namespace)
    return namespace[name], namespace


@check
def matches_official_osrt():
    """Reference OSRT / RP-OSRT against the official modules and the official OSRT.decoder and
    compute_adjusted_rand_index: set latent, slots, rgb, segmentation and FG-ARI of the four golden OSRT configs
    (on their scenes) and of the official osrt_MDBN_64 and rposrt_MDBN_8_64 configs (random weights)."""
    repo = os.environ.get("RAYPATCH_OFFICIAL_REPO")
    if not repo:
        raise Skip("set RAYPATCH_OFFICIAL_REPO to a checkout of tberriel/RayPatchQuerying")
    official_encoder, official_decoder = import_official(repo)
    # The src.layers classes, as the official encoder.py and decoder.py import them.
    layers = types.SimpleNamespace(RayEncoder=official_encoder.RayEncoder, Transformer=official_encoder.Transformer,
                                   SlotAttention=official_encoder.SlotAttention, SRTLinear=official_decoder.SRTLinear)
    # OSRT.decoder hard-codes 5 slots and 2 target views in its Ray-Patch segmentation reshape; they become
    # parameters here (the text is otherwise the official one).
    decoder_function, decoder_namespace = official_function(
        Path(repo) / "src" / "model.py", "decoder", "OSRT",
        replacements=(("w_in,5]", "w_in,NUM_SLOTS]"), ("[-1,2,", "[-1,NUM_TARGETS,"), ("w_out,5]", "w_out,NUM_SLOTS]")),
        namespace={"torch": torch, "RayPatchDecoder": official_decoder.RayPatchDecoder})
    official_ari, _ = official_function(Path(repo) / "src" / "utils" / "common.py", "compute_adjusted_rand_index",
                                        namespace={"torch": torch})

    runs = [(name, osrt_case(name)) for name in OSRT_CASES]
    runs.append(("osrt_MDBN_64", (copy.deepcopy(OSRT_MDBN_64), osrt_case("osrt")[1])))
    runs.append(("rposrt_MDBN_8_64", (copy.deepcopy(RPOSRT_MDBN_8_64), osrt_case("rposrt_k8")[1])))
    for name, (case_or_cfg, scene) in runs:
        golden = not isinstance(case_or_cfg, dict)
        model_cfg = case_or_cfg.model_cfg if golden else case_or_cfg
        if golden:
            torch.manual_seed(case_or_cfg.seed)
            model = make_golden.build_model(model_cfg).eval()
            make_golden.randomize_osrt_weights(model)
            make_golden.calibrate_mixing(model, scene, case_or_cfg.target_size)
            make_golden.calibrate_output(model, scene, case_or_cfg.target_size)
        else:
            model = random_osrt(model_cfg)
        targets = tuple(scene["target_masks"].shape)
        encoder, decoder_att, decoder_rp = official_osrt_modules(official_encoder, official_decoder, layers,
                                                                 model_cfg, targets)
        state = model.state_dict()
        for prefix, module in (("encoder.", encoder), ("decoder_att.", decoder_att), ("decoder_rp.", decoder_rp)):
            module.load_state_dict({n[len(prefix):]: t for n, t in state.items() if n.startswith(prefix)})
            module.eval()
        # Same names and shapes (the official FeatureDecoder registers conv_blocks before conv_0, so the order
        # within decoder_rp differs; names are what checkpoints and model files go by).
        official_shapes = {f"{prefix}{n}": list(t.shape) for prefix, module in
                           (("encoder.", encoder), ("decoder_att.", decoder_att), ("decoder_rp.", decoder_rp))
                           for n, t in module.state_dict().items()}
        assert official_shapes == {n: list(t.shape) for n, t in state.items()}, name

        images = scene["input_images"].permute(0, 3, 1, 2)[None]
        inputs = (images, scene["input_camera_pos"][None], scene["input_rays"][None])
        num_targets, height, width = targets
        with torch.no_grad():
            slots, set_latent = model.encode(*inputs, return_set_latent=True)
            rgb, _, segmentation = model.render_views(slots, scene["target_camera_pos"][None],
                                                      scene["target_rays"][None], (height, width))
            set_latent_official = encoder.srt_encoder(*inputs)
            slots_official = encoder(*inputs)
            rays = scene["target_rays"]
            if model.patch_size > 1 and rays.shape[1] == height:
                rays = make_golden.patch_rays_of(model, scene)["target_rays"]
            positions = scene["target_camera_pos"][:, None].expand(-1, rays.shape[1] * rays.shape[2], 3)
            decoder_namespace.update(NUM_SLOTS=slots.shape[1], NUM_TARGETS=num_targets)
            official_self = types.SimpleNamespace(decoder_att=decoder_att, decoder_rp=decoder_rp, training=False)
            rgb_official, extras = decoder_function(official_self, slots_official, positions.reshape(1, -1, 3),
                                                    rays.reshape(1, -1, 3))
        segmentation_official = extras["segmentation"].reshape(1, -1, slots.shape[1])
        masks = F.one_hot(scene["target_masks"].long(), int(scene["target_masks"].max()) + 1)[None].float()
        true_seg = masks.flatten(1, 3)
        fg_ari_official = official_ari(true_seg.transpose(1, 2)[:, 1:], segmentation_official.transpose(1, 2))
        ours_on_official = foreground_ari(segmentation_official.reshape(segmentation.shape),
                                          scene["target_masks"][None])
        fg_ari = foreground_ari(segmentation, scene["target_masks"][None])
        differences = {"set_latent": (set_latent - set_latent_official).abs().max().item(),
                       "slots": (slots - slots_official).abs().max().item(),
                       "rgb": (rgb.reshape(1, -1, 3) - rgb_official).abs().max().item(),
                       "segmentation": (segmentation.reshape(1, -1, slots.shape[1])
                                        - segmentation_official).abs().max().item(),
                       "fg_ari": abs(fg_ari.item() - fg_ari_official.item())}
        report(f"{name}: max |reference - official| " + ", ".join(f"{key} {value:.2e}"
                                                                   for key, value in differences.items())
               + f" (slots up to {slots.abs().max():.1f}, fg_ari {fg_ari.item():.6f})")
        assert torch.equal(ours_on_official, fg_ari_official), (name, ours_on_official, fg_ari_official)
        scale = max(1.0, slots.abs().max().item())
        assert differences["set_latent"] < 1e-5 * max(1.0, set_latent.abs().max().item()), (name, differences)
        assert differences["slots"] < 1e-5 * scale, (name, differences)
        assert differences["rgb"] < 1e-5 and differences["segmentation"] < 1e-5, (name, differences)
        assert differences["fg_ari"] < 1e-3, (name, differences)


def import_official_define(repo):
    """src.resnet, src.encoder and src.decoder of the official checkout with the real transformers (4.24.0, the
    version the official pt2.yml pins) and torchvision, einops stubbed where it is missing (DeFiNe does not use it),
    and src.encoder's resnet18 built with pretrained=False (the official default downloads ImageNet weights)."""
    try:
        import torchvision
        import transformers
    except ImportError as error:
        raise Skip(f"the official DeFiNe needs transformers 4.24.0 and torchvision: {error}")
    if transformers.__version__ != "4.24.0":
        raise Skip(f"the official DeFiNe runs on transformers 4.24.0, found {transformers.__version__}")
    stubs = {}
    try:
        import einops  # noqa: F401
    except ImportError:
        stubs["einops"] = types.SimpleNamespace(rearrange=_rearrange, repeat=_unused)
    package = types.ModuleType("src")
    package.__path__ = [str(Path(repo) / "src")]
    names = [*stubs, "src", "src.layers", "src.resnet", "src.encoder", "src.decoder"]
    saved = {name: sys.modules.get(name) for name in names}
    sys.modules.update(stubs)
    sys.modules["src"] = package
    try:
        resnet = importlib.import_module("src.resnet")
        encoder = importlib.import_module("src.encoder")
        decoder = importlib.import_module("src.decoder")
    finally:
        for name, module in saved.items():
            if module is None:
                sys.modules.pop(name, None)
            else:
                sys.modules[name] = module
    encoder.resnet18 = functools.partial(resnet.resnet18, pretrained=False)
    return types.SimpleNamespace(resnet=resnet, encoder=encoder, decoder=decoder, transformers=transformers,
                                 normalize=torchvision.transforms.Normalize(reference_define.IMAGENET_MEAN,
                                                                           reference_define.IMAGENET_STD))


def narrowed(module, width):
    """The official ResNetSkip (torchvision's ResNet, BasicBlock and forward code) with every convolution and
    BatchNorm width scaled from 64 to `width` (torchvision hard-codes 64, 128, 256, 512)."""
    for name, child in module.named_children():
        if isinstance(child, nn.Conv2d):
            in_channels = 3 if child.in_channels == 3 else child.in_channels * width // 64
            setattr(module, name, nn.Conv2d(in_channels, child.out_channels * width // 64, child.kernel_size,
                                            child.stride, child.padding, bias=False))
        elif isinstance(child, nn.BatchNorm2d):
            setattr(module, name, nn.BatchNorm2d(child.num_features * width // 64))
        else:
            narrowed(child, width)
    return module


def official_define(official, model_cfg, grid=None):
    """The official DeFiNe modules for model_cfg, registered in DeFiNe.__init__'s order (encoder, decoder_rp_rgb,
    decoder_rp_d, decoder_att_rgb, decoder_att_d), with d_min and d_max read from DeFiNe.__init__.

    Official widths use DeFiNeEncoder as it is. Small widths keep the official DeFiNeEncoder class and forward,
    official RayEncoder, the official ResNetSkip narrowed, and the transformers PerceiverModel of the official
    PerceiverConfig with d_latents, d_model, num_latents, num_self_attends_per_block and num_self_attention_heads
    of the config (the official code hard-codes 512 wide latents and 8 heads). The official RayPatchDecoders get
    `grid` (the targets' patch grid) as h_in/w_in: they only know their configured grid.
    """
    enc = defaults_of(reference_define.DeFiNeEncoder, model_cfg["encoder_kwargs"])
    extensions = ("resnet_width", "latent_dim", "heads")
    official_kwargs = {key: value for key, value in model_cfg["encoder_kwargs"].items() if key not in extensions}
    model = nn.Module()
    if [enc[key] for key in extensions] == [64, 512, 8]:
        model.encoder = official.encoder.DeFiNeEncoder(**official_kwargs)
    else:
        encoder = bare(official.encoder.DeFiNeEncoder)
        encoder.ray_encoder = official.encoder.RayEncoder(
            pos_octaves=enc["pos_octaves"], pos_start_octave=enc["pos_start_octave"],
            pos_end_octave=enc["pos_end_octave"], ray_octaves=enc["ray_octaves"],
            ray_start_octave=enc["ray_start_octave"], ray_end_octave=enc["ray_end_octave"])
        encoder.conv_blocks = narrowed(official.resnet.resnet18(pretrained=False), enc["resnet_width"])
        encoder.config = official.transformers.PerceiverConfig(
            d_latents=enc["latent_dim"], d_model=15 * enc["resnet_width"] + 6 + 6 * (enc["pos_octaves"]
                                                                                  + enc["ray_octaves"]),
            num_latents=enc["num_latents"], hidden_act="gelu", hidden_dropout_prob=0.25, initializer_range=0.02,
            layer_norm_eps=1e-12, num_blocks=1, num_cross_attention_heads=1,
            num_self_attends_per_block=enc["num_att_blocks"], num_self_attention_heads=enc["heads"],
            qk_channels=None, v_channels=None)
        encoder.transformer = official.transformers.PerceiverModel(encoder.config)
        model.encoder = encoder
    decoder_kwargs = {key: value for key, value in model_cfg["decoder_kwargs"].items() if key != "out_dims"}
    if model_cfg["decoder"] == "featurefield":
        rp_kwargs = dict(model_cfg["rp_kwargs"])
        if grid is not None:
            rp_kwargs.update(h_in=grid[0], w_in=grid[1])
        model.decoder_rp_rgb = official.decoder.RayPatchDecoder(out_dims=3, **rp_kwargs)
        model.decoder_rp_d = official.decoder.RayPatchDecoder(out_dims=1, **rp_kwargs)
        out_rgb = out_d = rp_kwargs.get("conv_features", 128)
    else:
        model.decoder_rp_rgb = model.decoder_rp_d = nn.Identity()
        out_rgb, out_d = 3, 1
    model.decoder_att_rgb = official.decoder.DeFiNeDecoder(**decoder_kwargs, out_dims=out_rgb)
    model.decoder_att_d = official.decoder.DeFiNeDecoder(**decoder_kwargs, out_dims=out_d)
    source = (Path(os.environ["RAYPATCH_OFFICIAL_REPO"]) / "src" / "model.py").read_text()
    define_class = next(node for node in ast.parse(source).body
                        if isinstance(node, ast.ClassDef) and node.name == "DeFiNe")
    for node in ast.walk(define_class):
        if isinstance(node, ast.Assign) and isinstance(node.targets[0], ast.Attribute) \
                and node.targets[0].attr in ("d_min", "d_max"):
            setattr(model, node.targets[0].attr, ast.literal_eval(node.value))
    return model


@check
def matches_official_define():
    """Reference DeFiNe / RP-DeFiNe against the official modules (transformers 4.24.0 Perceiver, torchvision ResNet)
    and the official DeFiNe.decoder: latent, rgb and log-depth of the three golden DeFiNe cases (their model and
    scene files) and of the official rpdefine_16_32_stereo_acc config (random weights, the rpdefine_k16 scene);
    the engine key lists are the official modules' state_dict names and shapes, in order."""
    repo = os.environ.get("RAYPATCH_OFFICIAL_REPO")
    if not repo:
        raise Skip("set RAYPATCH_OFFICIAL_REPO to a checkout of tberriel/RayPatchQuerying")
    official = import_official_define(repo)
    decoder_function, _ = official_function(Path(repo) / "src" / "model.py", "decoder", "DeFiNe",
                                            namespace={"torch": torch})
    for file, model_cfg, total in DEFINE_KEY_LISTS:
        with torch.device("meta"):
            module = official_define(official, copy.deepcopy(model_cfg))
        keys = [(name, list(tensor.shape)) for name, tensor in module.state_dict().items()]
        assert keys == official_keys(file), file
        assert sum(p.numel() for p in module.parameters()) == total, file
        assert (module.d_min, module.d_max) == (DeFiNe.d_min, DeFiNe.d_max) == (0.1, 10), (module.d_min, module.d_max)

    runs = []
    for name in DEFINE_CASES:
        folder = GOLDEN / name
        with safe_open(str(folder / "model.safetensors"), "pt") as file:
            model_cfg = json.loads(file.metadata()["config"])
        model = build_model(model_cfg).eval()
        model.load_state_dict(load_file(str(folder / "model.safetensors")), strict=False)
        case, _ = define_case(name)
        runs.append((name, model_cfg, model, load_file(str(folder / "scene.safetensors")), case.patch_rays))
    _, scene = define_case("rpdefine_k16")
    runs.append(("rpdefine_16_32_stereo_acc", RPDEFINE_16_32_STEREO_ACC, random_define(RPDEFINE_16_32_STEREO_ACC),
                 scene, False))
    for name, model_cfg, model, scene, patch_rays_given in runs:
        k = model.patch_size
        rays = scene["target_rays"]
        if k > 1 and not patch_rays_given:  # full-resolution rays: the loader's resize to patch rays
            rays = make_golden.patch_rays_of(model, scene)["target_rays"]
        num_targets, grid_h, grid_w = rays.shape[:3]
        target_size = (grid_h * k, grid_w * k)
        module = official_define(official, model_cfg, (grid_h, grid_w))
        state = model.state_dict()
        for prefix in ("encoder", "decoder_rp_rgb", "decoder_rp_d", "decoder_att_rgb", "decoder_att_d"):
            part = {n[len(prefix) + 1:]: t for n, t in state.items() if n.startswith(prefix + ".")}
            if part:
                getattr(module, prefix).load_state_dict(part)
        module.eval()

        images = scene["input_images"].permute(0, 3, 1, 2)
        inputs = (images[None], scene["input_camera_pos"][None], scene["input_rays"][None])
        with torch.no_grad():
            z = model.encode(*inputs)
            rgb, logdepth = model.render_views(z, scene["target_camera_pos"][None], scene["target_rays"][None],
                                               target_size)
            # The official loader hands the model ImageNet-normalised images.
            z_official = module.encoder(official.normalize(images)[None], *inputs[1:])
            positions = scene["target_camera_pos"][:, None].expand(-1, grid_h * grid_w, 3).reshape(1, -1, 3)
            rgb_official, extras = decoder_function(module, z_official, positions, rays.reshape(1, -1, 3))
        differences = {"latent": (z - z_official).abs().max().item(),
                       "rgb": (rgb.reshape(1, -1, 3) - rgb_official).abs().max().item(),
                       "logdepth": (logdepth.reshape(1, -1) - extras["logdepth"]).abs().max().item()}
        report(f"{name}: max |reference - official| " + ", ".join(f"{key} {value:.2e}"
                                                                   for key, value in differences.items())
               + f" (latent up to {z.abs().max():.1f}, {num_targets} x {target_size[0]}x{target_size[1]} targets)")
        assert rgb_official.shape == (1, num_targets * target_size[0] * target_size[1], 3), rgb_official.shape
        assert differences["latent"] < 1e-5 * max(1.0, z.abs().max().item()), (name, differences)
        assert differences["rgb"] < 1e-5 and differences["logdepth"] < 1e-5, (name, differences)


def main():
    global VERBOSE
    VERBOSE = "-v" in sys.argv[1:]
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
