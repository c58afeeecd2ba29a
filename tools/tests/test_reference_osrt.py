"""The PyTorch reference's OSRT / RP-OSRT (tools/reference/raypatch_reference.py, config base osrt): official key
names, order, shapes and parameter totals, config rules, slot attention and mixing block maths, rendering paths and
segmentation, FG-ARI against its pair-counting definition, and the committed OSRT golden files.

    python3 -m pytest tools/tests/test_reference_osrt.py
"""

import copy
import json
import math

import numpy as np
import torch
import torch.nn.functional as F
from safetensors import safe_open
from safetensors.torch import load_file
from torch import nn

from data import make_golden
from reference.official_configs import OSRT_MDBN_64, RPOSRT_MDBN_8_64, SRT_MDBN_32
from reference.raypatch_reference import (OSRT, SRT, MixingBlock, SlotAttention, adjusted_rand_index, build_model,
                                          foreground_ari)
from reference_helpers import GOLDEN, OSRT_CASES, assert_refused, compare_with_official_keys, osrt_case, random_osrt


def test_official_osrt_state_dict_keys():
    """Official-size osrt_MDBN_64 and rposrt_MDBN_8_64: the same names, order, shapes and parameter totals as the
    official key lists (num_batches_tracked included, as the lists have them)."""
    compare_with_official_keys((("osrt_MDBN_64", OSRT_MDBN_64, 94_917_423),
                                ("rposrt_MDBN_8_64", RPOSRT_MDBN_8_64, 95_213_144)))


def test_osrt_config_errors_are_clear():
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
        assert_refused(build_model, cfg, message)
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


def test_slot_attention_maths():
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


def test_mixing_block_maths():
    torch.manual_seed(2)
    block = MixingBlock(input_dim=5, slot_dim=4, att_dim=6, layer_norm=False).double()
    x, slots = torch.randn(2, 9, 5, dtype=torch.float64), torch.randn(2, 3, 4, dtype=torch.float64)
    weights = torch.softmax((x @ block.to_q.weight.T) @ (slots @ block.to_k.weight.T).transpose(1, 2) / math.sqrt(6),
                            -1)
    with torch.no_grad():
        mix, w = block(x, slots)
    assert torch.allclose(w, weights, atol=1e-12) and torch.allclose(mix, weights @ slots, atol=1e-12)


def test_osrt_render_paths():
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


def test_fg_ari_definition():
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


def test_osrt_golden_files():
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
