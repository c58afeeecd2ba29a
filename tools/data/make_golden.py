"""Writes the golden test cases of raypatch: small random-weight models, synthetic scenes and the outputs of the
PyTorch reference (tools/reference/raypatch_reference.py).

    python3 tools/data/make_golden.py --out assets/golden
    python3 tools/data/make_golden.py --out assets/golden --cases srt_k1_in60x80,rpsrt_k4_in40x60_2views
    python3 tools/data/make_golden.py --full-size --out target/golden-full

--cases writes only the named cases (what the full run writes for them) and the README table of all cases, leaving
the other case folders as they are. Weights and scenes are the same everywhere; PyTorch builds on other machines
round float32 sums differently, so regenerating a case elsewhere changes its outputs and calibrated output
layers by float32 rounding (~1e-6), which is why adding a case should not regenerate the others.

Over 600 lines on purpose: every case (config, scene, calibration, expected outputs) in one script, so that one
command writes them all and a case reads as one entry of golden_cases().

Each case is a folder <out>/<case>/ with model.safetensors, scene.safetensors and expected.safetensors
(docs/FORMATS.md). `latent`, `rgb` (and `logdepth`) are the float32 CPU outputs, computed as the official model
computes them, and `patch_rays` the patch rays made from full-resolution target rays; `latent_f64`, `rgb_f64`
(`logdepth_f64`) are float64 tensors from a float64 copy of the same model on the same float32 inputs, for error
analysis. OSRT cases (base osrt) add `set_latent`, `segmentation` (with their `_f64`) and `fg_ari`. DeFiNe cases
(base define) have ScanNet-like scenes (make_define_scene) and always `logdepth`.
"""

import argparse
import copy
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tools/, whose packages this imports
from conversion.convert_checkpoint import write_model  # noqa: E402
from reference.cameras import get_camera_rays, look_at_positions  # noqa: E402
from reference.official_configs import RPSRT_MDBN_4_32  # noqa: E402
from reference.raypatch_reference import OSRT, build_model, foreground_ari  # noqa: E402
from reference.reference_define import DeFiNe  # noqa: E402
from reference.safetensors_io import save_safetensors  # noqa: E402

SCENE_FORMAT = "raypatch-scene/1"
GOLDEN_FORMAT = "raypatch-golden/1"


def small_config(decoder="lightfield", encoder_norm="Batch", rp_kwargs=None, out_dims=3, width=32):
    """The official structure (3 conv blocks, 2+2 attention layers here, 15+15 octaves, MSN octave starts) at small
    widths: tokens and latents `width` wide (4 heads), conv_hidden width/4, FF hidden 2·width.
    width 32 gives ~170k parameters, width 16 ~80k (the query width is 180 either way)."""
    cfg = {
        "base": "srt",
        "encoder_kwargs": {"pos_start_octave": -5, "num_att_blocks": 2, "num_conv_blocks": 3, "norm": encoder_norm,
                           "latent_dim": width, "conv_hidden": width // 4, "token_dim": width, "heads": 4,
                           "dim_head": width // 4},
        "decoder": decoder,
        "decoder_kwargs": {"num_att_blocks": 2, "pos_octaves": 15, "ray_octaves": 15, "pos_start_octave": -5,
                           "pos_end_octave": None, "ray_start_octave": 0, "ray_end_octave": None, "latent_dim": width,
                           "mode": "efficient", "out_dims": out_dims, "heads": 4, "input_mlp_hidden": 24,
                           "out_mlp_hidden": 48},
        # Training keys the engine must ignore, as in the official configs.
        "lr_config": "linear",
        "lr": 0.0001,
    }
    if rp_kwargs is not None:
        cfg["rp_kwargs"] = rp_kwargs
        # What an official checkpoint stores: SRT.__init__ writes the patch feature width here.
        cfg["decoder_kwargs"]["out_dims"] = rp_kwargs["conv_features"]
    return cfg


def small_osrt_config(decoder="lightfield", encoder_norm="Batch", num_slots=5, slot_iters=1, layer_norm=False,
                      rp_kwargs=None, out_dims=True):
    """The official OSRT structure (3 conv blocks, 15 + 15 octaves, MSN octave starts) at small widths: tokens 16
    wide (4 heads of 4, FF hidden 2·latent_dim = 32), slots 32 wide (slot MLP hidden 48), allocation transformer
    with 4 heads of 8 over the slots, mixing attention 24 wide, render MLP hidden 40; 2 encoder and 2 decoder
    attention layers. out_dims: store decoder_kwargs.out_dims as an official checkpoint does (3 for a light
    field, conv_features for Ray-Patch), otherwise leave it out as config.yaml does."""
    cfg = {
        "base": "osrt",
        "encoder_kwargs": {"num_conv_blocks": 3, "num_att_blocks": 2, "num_octaves": 15, "pos_start_octave": -5,
                           "num_slots": num_slots, "slot_dim": 32, "slot_iters": slot_iters, "max_pooling": False,
                           "norm": encoder_norm, "randomize_initial_slots": False, "latent_dim": 16,
                           "conv_hidden": 4, "token_dim": 16, "heads": 4, "dim_head": 4, "slot_hidden": 48},
        "decoder": decoder,
        "decoder_kwargs": {"num_att_blocks": 2, "pos_start_octave": -5, "layer_norm": layer_norm, "mode": "efficient",
                           "latent_dim": 32, "heads": 4, "input_mlp_hidden": 24, "att_dim": 24,
                           "render_mlp_hidden": 40},
        # Training keys the engine must ignore, as in the official configs.
        "lr_config": "linear",
        "lr": 0.0001,
        "gamma": 0.16,
    }
    if rp_kwargs is not None:
        cfg["rp_kwargs"] = rp_kwargs
    if out_dims:
        cfg["decoder_kwargs"]["out_dims"] = rp_kwargs["conv_features"] if rp_kwargs is not None else 3
    return cfg


def small_define_config(decoder="lightfield", rp_kwargs=None, explicit=False):
    """The official DeFiNe structure (ResNet-18, Perceiver with 1 cross-attention and num_att_blocks
    self-attention layers, official octaves: pos 20 and ray 10 linspace(1, 30), token width 306, query width 186)
    at small widths: ResNet width 8 (8, 16, 32, 64 channels), 64 latents 32 wide, 4 self-attention heads, 2
    self-attention layers. explicit: also write the keys that have official defaults (a config.yaml leaves them
    out). The model section of an official checkpoint also holds training keys and `wandb` (train.py adds it);
    the engine must ignore them."""
    cfg = {
        "base": "define",
        "encoder_kwargs": {"pos_start_octave": 1, "num_att_blocks": 2, "num_latents": 64, "resnet_width": 8,
                           "latent_dim": 32, "heads": 4},
        "decoder": decoder,
        "decoder_kwargs": {"pos_start_octave": 1, "latent_dim": 32},
        "lr_config": "step",
        "lr": 0.0002,
        "lr_warmup": 2500,
        "wandb": False,
    }
    if explicit:
        octaves = {"pos_octaves": 20, "pos_end_octave": 30, "ray_octaves": 10, "ray_start_octave": 1,
                   "ray_end_octave": 30}
        cfg["encoder_kwargs"].update(octaves)
        cfg["decoder_kwargs"].update(octaves)
    if rp_kwargs is not None:
        cfg["rp_kwargs"] = rp_kwargs
    return cfg


@dataclass
class Case:
    name: str
    seed: int  # weights, cameras and images
    model_cfg: dict
    input_size: tuple  # (H, W)
    target_size: tuple  # (Ht, Wt)
    num_inputs: int = 1
    num_targets: int = 2
    patch_rays: bool = False  # store target rays at patch resolution (and the target size as metadata)
    target_images: bool = False
    target_masks: bool = False  # scene target_masks (instance ids) and, for OSRT, the expected fg_ari
    description: str = ""


def golden_cases():
    # Width 32 for srt_k1 and rpsrt_k2, 16 elsewhere to keep assets/golden small.
    k2 = small_config("featurefield", rp_kwargs=dict(upsample=1, h_in=8, w_in=12, conv_features=16, norm="Batch"))
    del k2["decoder_kwargs"]["out_dims"]  # the config.yaml form, without the checkpoint's out_dims
    # h_in/w_in are the training grid (30x40 as in the official run), not the 8x12 grid of these targets.
    k4 = small_config("featurefield", width=16,
                      rp_kwargs=dict(upsample=2, h_in=30, w_in=40, conv_features=16, norm="Batch"))
    k8 = small_config("featurefield", encoder_norm=None, width=16,
                      rp_kwargs=dict(upsample=3, h_in=4, w_in=6, h_out=32, w_out=48, conv_features=16, norm="Batch"))
    # The old repo's k=8 at 60x80: 60 rows are 7 patches (56 pixels), nearest-resized to 60 (h_out/w_out).
    k8_resize = small_config("featurefield", width=16,
                             rp_kwargs=dict(upsample=3, h_in=7, w_in=10, h_out=60, w_out=80, conv_features=16,
                                            norm="Batch"))
    k16 = small_config("featurefield", width=16,
                       rp_kwargs=dict(upsample=4, h_in=2, w_in=4, conv_features=32, norm="Batch"))
    k2_in60x80 = small_config("featurefield", width=16,
                              rp_kwargs=dict(upsample=1, h_in=8, w_in=12, conv_features=16, norm="Batch"))
    # OSRT: slot widths 32, 5 slots (the official MSN count) unless said otherwise.
    osrt_k8 = small_osrt_config("featurefield", rp_kwargs=dict(
        upsample=3, h_in=4, w_in=6, h_out=32, w_out=48, conv_features=16, norm="Batch", out_dims=3))
    osrt_k4 = small_osrt_config("featurefield", num_slots=6, out_dims=False, rp_kwargs=dict(
        upsample=2, h_in=30, w_in=40, conv_features=16, norm="Batch"))
    # Keys left out take the official defaults: here num_slots 6 and the ones equal to the values above.
    for key in ("num_slots", "num_octaves", "max_pooling", "randomize_initial_slots", "slot_iters"):
        del osrt_k4["encoder_kwargs"][key]
    for key in ("mode", "layer_norm"):
        del osrt_k4["decoder_kwargs"][key]
    osrt_cases = [
        Case("osrt", 13, small_osrt_config("lightfield"), (24, 32), (16, 24), target_images=True, target_masks=True,
             description="OSRT light field, 5 slots, 1 slot-attention iteration, encoder BatchNorm"),
        Case("osrt_iters3_ln", 14, small_osrt_config("lightfield", encoder_norm=None, num_slots=4, slot_iters=3,
                                                     layer_norm=True), (24, 32), (16, 24), num_inputs=2,
             num_targets=1, target_images=True, target_masks=True,
             description="OSRT light field, 2 input views, 4 slots, 3 slot-attention iterations, mixing-block "
                         "LayerNorms, encoder without norm"),
        Case("rposrt_k8", 15, osrt_k8, (24, 32), (32, 48), target_images=True, target_masks=True,
             description="RP-OSRT k=8, 5 slots, rp h_out/w_out set (identity resize), segmentation bilinearly "
                         "upsampled from the 4x6 patch grid"),
        Case("rposrt_k4_patchrays", 16, osrt_k4, (24, 32), (32, 48), num_inputs=2, patch_rays=True,
             target_images=True, target_masks=True,
             description="RP-OSRT k=4, 2 input views, target rays given at patch resolution with target_size "
                         "metadata, rp h_in/w_in 30x40 differ from the 8x12 grid; config leaves out keys with "
                         "official defaults (6 slots, no decoder_kwargs.out_dims)"),
    ]
    # DeFiNe: 2 input views (the ScanNet stereo setting), k = 16 with 32 conv features.
    define_cases = [
        Case("define", 21, small_define_config("lightfield"), (64, 96), (16, 24), num_inputs=2,
             description="DeFiNe light field (rgb and log-depth heads), 2 input views, config.yaml keys only"),
        Case("rpdefine_k16", 22, small_define_config("featurefield", explicit=True, rp_kwargs=dict(
            upsample=4, h_in=2, w_in=3, conv_features=32, norm="Batch")), (64, 96), (32, 48), num_inputs=2,
            description="RP-DeFiNe k=16, conv_features 32, full-resolution target rays (patch rays by bilinear "
                        "resize), official octave keys written out"),
        Case("rpdefine_k16_patchrays_in60x88", 23, small_define_config("featurefield", rp_kwargs=dict(
            upsample=4, h_in=30, w_in=40, conv_features=32, norm="Batch")), (60, 88), (32, 48), num_inputs=2,
            patch_rays=True,
            description="RP-DeFiNe k=16, 2 input views of 60x88 (not multiples of 32: ResNet 15x22, 8x11, 4x6, "
                        "2x3), target rays given at patch resolution, rp h_in/w_in 30x40 differ from the 2x3 grid"),
    ]
    return [
        Case("srt_k1", 1, small_config("lightfield"), (32, 32), (16, 24),
             description="light field, 1 input view"),
        Case("srt_k1_depth", 2, small_config("lightfield", out_dims=4, width=16), (24, 32), (16, 24), num_targets=1,
             description="light field with decoder out_dims 4 (rgb + log-depth)"),
        Case("rpsrt_k2", 3, k2, (24, 32), (16, 24), target_images=True,
             description="Ray-Patch k=2, config without decoder_kwargs.out_dims, scene with target_images"),
        Case("rpsrt_k4", 4, k4, (24, 32), (32, 48), num_inputs=2,
             description="Ray-Patch k=4, 2 input views, rp h_in/w_in 30x40 differ from the 8x12 target grid"),
        Case("rpsrt_k4_patchrays", 4, copy.deepcopy(k4), (24, 32), (32, 48), num_inputs=2, patch_rays=True,
             description="rpsrt_k4 (same weights and scene) with target rays given at patch resolution "
                         "and target_size metadata: the same expected rgb"),
        Case("rpsrt_k8", 5, k8, (24, 32), (32, 48), num_targets=1,
             description="Ray-Patch k=8, encoder without norm, rp h_out/w_out set (identity resize)"),
        # Patch rays given: for a ratio that is not a power of two PyTorch's bilinear weights round, and its
        # x86 build fuses them into fmas, which the engine's kernel cannot promise to reproduce bit for bit.
        Case("rpsrt_k8_resize", 8, k8_resize, (24, 32), (60, 80), num_targets=1, patch_rays=True,
             description="Ray-Patch k=8 at 60x80 (not divisible by k): 7x10 patches (rays given), output "
                         "nearest-resized to 60x80 as rp h_out/w_out ask"),
        Case("rpsrt_k16", 6, k16, (24, 32), (32, 64), num_targets=1,
             description="Ray-Patch k=16, conv_features 32"),
        # Input sizes that 2^3 does not divide, as PyTorch takes them: each stride-2 conv (padding 1) maps a side s
        # to ceil(s / 2), so 60x80 gives 30x40, 15x20, 8x10 tokens per view and 40x60 gives 20x30, 10x15, 5x8.
        Case("srt_k1_in60x80", 9, small_config("lightfield", width=16), (60, 80), (16, 24),
             description="light field, 1 input view of 60x80 (8 does not divide its 60 rows): 8x10 = 80 tokens"),
        Case("srt_k1_in40x60", 10, small_config("lightfield", width=16), (40, 60), (16, 24), num_targets=1,
             description="light field, 1 input view of 40x60 (8 does not divide its 60 columns): 5x8 = 40 tokens"),
        Case("rpsrt_k2_in60x80_2views", 11, k2_in60x80, (60, 80), (16, 24), num_inputs=2,
             description="Ray-Patch k=2, 2 input views of 60x80: 2·8x10 = 160 tokens"),
        Case("rpsrt_k4_in40x60_2views", 12, copy.deepcopy(k4), (40, 60), (32, 48), num_inputs=2,
             description="Ray-Patch k=4, 2 input views of 40x60: 2·5x8 = 80 tokens"),
    ] + osrt_cases + define_cases


def full_size_case():
    cfg = copy.deepcopy(RPSRT_MDBN_4_32)
    cfg["decoder_kwargs"]["out_dims"] = 128  # as the official checkpoint stores it
    return Case("rpsrt_k4_full", 7, cfg, (120, 160), (60, 80),
                description="official rpsrt_MDBN_4_32 config (random weights), MSN-Easy input size")


def randomize_weights(model):
    """He-style random weights (activations stay O(1) through the ReLUs), random biases, and non-trivial
    LayerNorm and BatchNorm parameters and statistics. Default PyTorch init would shrink the activations layer by
    layer and make the outputs insensitive to mistakes."""
    def normal(tensor, std):
        tensor.copy_(torch.randn(tensor.shape) * std)

    def uniform(tensor, low, high):
        tensor.copy_(low + (high - low) * torch.rand(tensor.shape))

    with torch.no_grad():
        for name, module in model.named_modules():
            if isinstance(module, (nn.Linear, nn.Conv2d)):
                fan_in = module.weight[0].numel()
                # Attention projections keep unit gain so the attention logits stay O(1); the rest feed (Leaky)ReLUs.
                gain = 1.0 if any(part in name for part in ("to_q", "to_kv", "to_qkv", "to_out")) else math.sqrt(2)
                normal(module.weight, gain / math.sqrt(fan_in))
                if module.bias is not None:
                    normal(module.bias, 0.1)
            elif isinstance(module, nn.LayerNorm):
                uniform(module.weight, 0.5, 1.5)
                normal(module.bias, 0.1)
            elif isinstance(module, nn.BatchNorm2d):
                uniform(module.weight, 0.5, 1.5)
                normal(module.bias, 0.1)
                normal(module.running_mean, 0.2)
                uniform(module.running_var, 0.5, 2.0)


def randomize_osrt_weights(model):
    """randomize_weights, then unit gain for the slot-attention and mixing projections (their logits stay O(1)),
    random GRU weights (std slot_dim^-1/2) and biases, random initial slots."""
    randomize_weights(model)
    slot_attention = model.encoder.slot_attention
    mixing = model.decoder_att.mixing_block
    with torch.no_grad():
        for linear in (slot_attention.to_q, slot_attention.to_k, slot_attention.to_v, mixing.to_q, mixing.to_k):
            linear.weight.copy_(torch.randn(linear.weight.shape) / math.sqrt(linear.in_features))
        gru = slot_attention.gru
        for weight in (gru.weight_ih, gru.weight_hh):
            weight.copy_(torch.randn(weight.shape) / math.sqrt(gru.hidden_size))
        for bias in (gru.bias_ih, gru.bias_hh):
            bias.copy_(torch.randn(bias.shape) * 0.1)
        slot_attention.initial_slots.copy_(torch.randn(slot_attention.initial_slots.shape))


def calibrate_mixing(model, scene, target_size, logit_std=2.0):
    """Spreads the segmentation over the slots: random mixing weights give every pixel nearly the same query
    direction (the mean query), so one slot wins everywhere. On this scene, to_q is projected off the mean of its
    inputs (each slot's mean logit over the pixels is then 0) and to_k rescaled so that the logits have standard
    deviation logit_std."""
    mixing = model.decoder_att.mixing_block
    captured = {}
    hooks = [mixing.to_q.register_forward_hook(lambda module, inputs, output: captured.update(x=inputs[0])),
             mixing.to_k.register_forward_hook(lambda module, inputs, output: captured.update(k=output))]
    run_model(model, scene, target_size, torch.float32)
    for hook in hooks:
        hook.remove()
    with torch.no_grad():
        mean = captured["x"].flatten(0, 1).mean(0)
        mixing.to_q.weight.sub_(torch.outer(mixing.to_q.weight @ mean, mean) / mean.dot(mean))
        logits = torch.einsum("bpd,bsd->bps", mixing.to_q(captured["x"]), captured["k"]) * mixing.scale
        mixing.to_k.weight.mul_(logit_std / logits.std())


def calibrate_output(model, scene, target_size, logit_std=1.5):
    """Rescales the output layers so that on this scene the pre-sigmoid outputs have per-channel mean 0 and
    standard deviation logit_std: random weights otherwise saturate many pixels at 0 or 1, hiding errors."""
    decoder_rp = model.decoder_rp
    osrt = isinstance(model, OSRT)
    captured = []
    hook = (decoder_rp if model.patch_size > 1 else model.decoder_att.render_mlp if osrt
            else model.decoder_att).register_forward_hook(
        lambda module, inputs, output: captured.append(output))
    run_model(model, scene, target_size, torch.float32)
    hook.remove()
    logits = captured[0].flatten(0, -2)
    mean, scale = logits.mean(0), logit_std / logits.std(0)
    with torch.no_grad():
        if model.patch_size > 1:
            # The output is a sum of conv_0 and every conv_out, bilinearly upsampled: linear in all of them,
            # and the last conv_out adds to it directly.
            convs = [decoder_rp.conv_decoder.conv_0] + [out for _, out in decoder_rp.conv_decoder.conv_blocks]
        elif osrt:
            convs = [model.decoder_att.render_mlp.net[8]]
        else:
            convs = [model.decoder_att.out_mlp[-1]]
        for conv in convs:
            conv.weight.mul_(scale.view(-1, *[1] * (conv.weight.dim() - 1)))
            conv.bias.mul_(scale)
        convs[-1].bias.sub_(scale * mean)


def randomize_define_weights(model):
    """randomize_weights, then unit gain for the Perceiver attention projections (query, key, value, the output
    dense) and the final layers, and N(0, 1) latents."""
    randomize_weights(model)
    unit_gain = ("attention.self.query", "attention.self.key", "attention.self.value", "attention.output.dense",
                 "final_layer")
    with torch.no_grad():
        for name, module in model.named_modules():
            if isinstance(module, nn.Linear) and name.endswith(unit_gain):
                module.weight.copy_(torch.randn(module.weight.shape) / math.sqrt(module.in_features))
        latents = model.encoder.transformer.embeddings.latents
        latents.copy_(torch.randn(latents.shape))


def calibrate_batchnorm(model, scene, target_size):
    """Random BatchNorm statistics near the ones of this scene: each BatchNorm2d, as the model runs, gets running_mean
    = the batch mean of its input + 0.2 batch std · N(0, 1) and running_var = the batch variance · U(0.5, 2) per
    channel. Stored statistics drawn independently of the activations would let the ResNet's residual sums grow
    block by block until its features swamp the ray features in the tokens."""
    def set_statistics(module, inputs):
        x = inputs[0].detach().transpose(0, 1).flatten(1)
        mean, var = x.mean(1), x.var(1, unbiased=False)
        module.running_mean.copy_(mean + 0.2 * var.sqrt() * torch.randn(mean.shape))
        module.running_var.copy_(var * (0.5 + 1.5 * torch.rand(var.shape)))

    hooks = [module.register_forward_pre_hook(set_statistics) for module in model.modules()
             if isinstance(module, nn.BatchNorm2d)]
    run_model(model, scene, target_size, torch.float32)
    for hook in hooks:
        hook.remove()


def calibrate_define_output(model, scene, target_size, logit_std=1.5):
    """calibrate_output for both DeFiNe heads: the rgb and the depth pre-sigmoid outputs get per-channel mean 0
    and standard deviation logit_std on this scene (log-depth then spreads over the 0.1..10 range)."""
    ray_patch = model.patch_size > 1
    heads = []
    for att, rp in ((model.decoder_att_rgb, model.decoder_rp_rgb), (model.decoder_att_d, model.decoder_rp_d)):
        if ray_patch:
            convs = [rp.conv_decoder.conv_0] + [out for _, out in rp.conv_decoder.conv_blocks]
        else:
            convs = [att.transformer.final_layer]
        heads.append((rp if ray_patch else att, convs))
    captured = {}
    hooks = [module.register_forward_hook(lambda module, inputs, output, i=i: captured.update({i: output}))
             for i, (module, _) in enumerate(heads)]
    run_model(model, scene, target_size, torch.float32)
    for hook in hooks:
        hook.remove()
    with torch.no_grad():
        for i, (_, convs) in enumerate(heads):
            logits = captured[i].flatten(0, -2)
            mean, scale = logits.mean(0), logit_std / logits.std(0)
            for conv in convs:
                conv.weight.mul_(scale.view(-1, *[1] * (conv.weight.dim() - 1)))
                conv.bias.mul_(scale)
            convs[-1].bias.sub_(scale * mean)


def structured_image(height, width, rng):
    """A smooth colour gradient with a few flat discs and rectangles, values in [0, 1], [H, W, 3] float32."""
    y, x = np.meshgrid(np.linspace(0, 1, height), np.linspace(0, 1, width), indexing="ij")
    phase = rng.uniform(0, 2 * np.pi, 3)
    image = np.stack([0.5 + 0.25 * np.sin(2 * np.pi * (rng.uniform(0.3, 1.2) * x + rng.uniform(0.3, 1.2) * y)
                                          + phase[c]) for c in range(3)], -1)
    for _ in range(3):
        cy, cx = rng.uniform(0.15, 0.85, 2)
        radius = rng.uniform(0.08, 0.25)
        image[(y - cy) ** 2 + (x - cx) ** 2 < radius**2] = rng.uniform(0, 1, 3)
    for _ in range(2):
        y0, x0 = rng.uniform(0, 0.7, 2)
        h, w = rng.uniform(0.1, 0.3, 2)
        image[(y >= y0) & (y < y0 + h) & (x >= x0) & (x < x0 + w)] = rng.uniform(0, 1, 3)
    return np.clip(image, 0, 1).astype(np.float32)


def instance_masks(height, width, rng):
    """Instance ids [H, W] uint8: background 0 and 3 or 4 overlapping discs and rectangles with ids 1, 2, …"""
    y, x = np.meshgrid(np.linspace(0, 1, height), np.linspace(0, 1, width), indexing="ij")
    masks = np.zeros((height, width), np.uint8)
    for instance in range(1, rng.integers(3, 5) + 1):
        cy, cx = rng.uniform(0.2, 0.8, 2)
        if rng.uniform() < 0.5:
            radius = rng.uniform(0.12, 0.3)
            region = (y - cy) ** 2 + (x - cx) ** 2 < radius**2
        else:
            h, w = rng.uniform(0.15, 0.4, 2)
            region = (abs(y - cy) < h / 2) & (abs(x - cx) < w / 2)
        masks[region] = instance
    return masks


def make_scene(case, rng):
    """Input cameras on one side of the origin, targets elsewhere, all 5 to 12 units away."""
    input_pos = look_at_positions(rng.uniform(0, 360) + 70.0 * np.arange(case.num_inputs),
                                  rng.uniform(5, 12, case.num_inputs), rng.uniform(15, 50, case.num_inputs))
    target_pos = look_at_positions(rng.uniform(0, 360, case.num_targets), rng.uniform(5, 12, case.num_targets),
                                   rng.uniform(10, 60, case.num_targets))
    (h, w), (ht, wt) = case.input_size, case.target_size
    scene = {
        "input_images": np.stack([structured_image(h, w, rng) for _ in range(case.num_inputs)]),
        "input_camera_pos": input_pos,
        "input_rays": np.stack([get_camera_rays(p, w, h) for p in input_pos]),
        "target_camera_pos": target_pos,
        "target_rays": np.stack([get_camera_rays(p, wt, ht) for p in target_pos]),
    }
    if case.target_images:
        scene["target_images"] = np.stack([structured_image(ht, wt, rng) for _ in range(case.num_targets)])
    if case.target_masks:
        scene["target_masks"] = np.stack([instance_masks(ht, wt, rng) for _ in range(case.num_targets)])
    return {name: torch.from_numpy(array) for name, array in scene.items()}


# Depth intrinsics of the kind ScanNet's intrinsic_depth.txt holds (640x480, fx ~ fy ~ 578); the official loader
# scales them to h_rgb_un x w_rgb_un = 480x640, i.e. leaves them as they are.
SCANNET_K = np.array([[577.590698, 0.0, 318.905426], [0.0, 578.729797, 242.683609], [0.0, 0.0, 1.0]])
SCANNET_SIZE = (480, 640)


def rotation(yaw, pitch, roll):
    """Rotation matrix (camera to world) from angles in degrees about the camera's y (down), x (right), z (forward)
    axes (OpenCV camera: x right, y down, z forward)."""
    a, b, c = np.radians([yaw, pitch, roll])
    ry = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    rx = np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
    rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    return ry @ rx @ rz


def scannet_rays(rotation_matrix, position, height, width):
    """The official ScanNet loader's "rays": world points at unit depth, R·K⁻¹[u + 0.5, v + 0.5, 1] + t on the
    480x640 grid, bilinearly resized (align_corners=False, no antialiasing) to height x width; [H, W, 3] float32.
    Computed in float64 (the loader: float32)."""
    rows, cols = SCANNET_SIZE
    u, v = np.meshgrid(np.linspace(0.5, cols - 0.5, cols), np.linspace(0.5, rows - 0.5, rows), indexing="xy")
    pixels = np.stack((u, v, np.ones_like(u)), -1)
    points = pixels @ np.linalg.inv(SCANNET_K).T @ rotation_matrix.T + position
    points = torch.from_numpy(points).permute(2, 0, 1)[None]
    resized = torch.nn.functional.interpolate(points, size=(height, width), mode="bilinear", align_corners=False,
                                              antialias=False)
    return resized[0].permute(1, 2, 0).numpy().astype(np.float32)


def make_define_scene(case, rng):
    """A ScanNet-like scene in the canonical frame of input camera 0 (at the origin, identity rotation; the
    official loader picks the canonical camera at random): the other input cameras and the targets turned by up
    to 20 degrees and moved by up to about half a metre. Target 0 is input camera 1 (the stereo setting renders
    the input views), the others are new views. Camera positions are the translations t."""
    def random_pose():
        return rotation(*rng.uniform(-20, 20, 2), rng.uniform(-5, 5)), rng.uniform(-0.5, 0.5, 3)

    input_poses = [(np.eye(3), np.zeros(3))] + [random_pose() for _ in range(case.num_inputs - 1)]
    target_poses = input_poses[1:2] + [random_pose() for _ in range(case.num_targets - 1)]
    (h, w), (ht, wt) = case.input_size, case.target_size
    scene = {
        "input_images": np.stack([structured_image(h, w, rng) for _ in range(case.num_inputs)]),
        "input_camera_pos": np.stack([t for _, t in input_poses]).astype(np.float32),
        "input_rays": np.stack([scannet_rays(r, t, h, w) for r, t in input_poses]),
        "target_camera_pos": np.stack([t for _, t in target_poses]).astype(np.float32),
        "target_rays": np.stack([scannet_rays(r, t, ht, wt) for r, t in target_poses]),
    }
    return {name: torch.from_numpy(array) for name, array in scene.items()}


def run_model(model, scene, target_size, dtype):
    """Encodes the input views and renders the target views; batch dimension dropped from the results."""
    def batch(name):
        return scene[name].to(dtype)[None]

    inputs = (batch("input_images").permute(0, 1, 4, 2, 3), batch("input_camera_pos"), batch("input_rays"))
    targets = (batch("target_camera_pos"), batch("target_rays"), target_size)
    with torch.no_grad():
        if isinstance(model, OSRT):
            z, set_latent = model.encode(*inputs, return_set_latent=True)
            rgb, logdepth, segmentation = model.render_views(z, *targets)
        else:
            z = model.encode(*inputs)
            rgb, logdepth = model.render_views(z, *targets)
    out = {"latent": z[0], "rgb": rgb[0]}
    if isinstance(model, OSRT):
        out.update(set_latent=set_latent[0], segmentation=segmentation[0])
    if logdepth is not None:
        out["logdepth"] = logdepth[0]
    return out


def patch_rays_of(model, scene):
    """The scene with its target rays replaced by the patch rays the model makes from them."""
    k = model.patch_size
    rays = scene["target_rays"].permute(0, 3, 1, 2)
    rays = torch.nn.functional.interpolate(rays, size=(rays.shape[2] // k, rays.shape[3] // k), mode="bilinear",
                                           align_corners=False, antialias=False)
    return {**scene, "target_rays": rays.permute(0, 2, 3, 1).contiguous()}


def fg_ari(segmentation, masks):
    """FG-ARI [1] (float64) of a segmentation [T, H, W, S] against instance ids [T, H, W], the T views pooled."""
    return foreground_ari(segmentation[None], masks[None])


def write_case(case, out_dir, generator_command):
    seed = case.seed
    torch.manual_seed(seed)
    model = build_model(case.model_cfg).eval()
    osrt = isinstance(model, OSRT)
    define = isinstance(model, DeFiNe)
    if osrt:
        randomize_osrt_weights(model)
    elif define:
        randomize_define_weights(model)
    else:
        randomize_weights(model)
    if define:
        scene = make_define_scene(case, np.random.default_rng(seed))
        calibrate_batchnorm(model, scene, case.target_size)
        calibrate_define_output(model, scene, case.target_size)
    else:
        scene = make_scene(case, np.random.default_rng(seed))
    if osrt:
        calibrate_mixing(model, scene, case.target_size)
    if not define:
        calibrate_output(model, scene, case.target_size)
    scene_metadata = {"format": SCENE_FORMAT}
    if case.patch_rays:
        from_full_rays = run_model(model, scene, case.target_size, torch.float32)
        scene = patch_rays_of(model, scene)
        scene_metadata["target_size"] = "{}x{}".format(*case.target_size)

    expected = run_model(model, scene, case.target_size, torch.float32)
    if model.patch_size > 1 and not case.patch_rays:
        # For debugging an engine's ray resize in isolation.
        expected["patch_rays"] = patch_rays_of(model, scene)["target_rays"]
    expected_f64 = run_model(copy.deepcopy(model).double(), scene, case.target_size, torch.float64)
    expected.update({f"{name}_f64": tensor for name, tensor in expected_f64.items()})
    if case.patch_rays:
        # Patch rays given as such must render exactly what the model makes of the full-resolution rays.
        assert torch.equal(expected["rgb"], from_full_rays["rgb"])
        if "logdepth" in expected:
            assert torch.equal(expected["logdepth"], from_full_rays["logdepth"])
        if osrt:
            assert torch.equal(expected["segmentation"], from_full_rays["segmentation"])
    if osrt and case.target_masks:
        expected["fg_ari"] = fg_ari(expected["segmentation"], scene["target_masks"])

    case_dir = out_dir / case.name
    case_dir.mkdir(parents=True, exist_ok=True)
    state_dict = {name: tensor for name, tensor in model.state_dict().items()
                  if not name.endswith("num_batches_tracked")}
    write_model(case_dir / "model.safetensors", state_dict, case.model_cfg,
                {"source": f"random weights (seed {seed}) from {generator_command}"})
    save_safetensors(case_dir / "scene.safetensors", scene, scene_metadata)
    save_safetensors(case_dir / "expected.safetensors", expected,
                     {"format": GOLDEN_FORMAT, "case": case.name, "generator": generator_command})
    return scene, expected


README_HEADER = """# Golden test cases

Written by `{command}` (tools/data/make_golden.py); do not edit by hand, regenerate instead. Each folder holds
`model.safetensors` (random weights, raypatch-model/1), `scene.safetensors` (raypatch-scene/1) and
`expected.safetensors` (raypatch-golden/1), see docs/FORMATS.md.

`latent`, `rgb` and `logdepth` are float32 outputs of the PyTorch reference (tools/reference/raypatch_reference.py)
on CPU, computed as the official model computes them. Ray-Patch cases with full-resolution target rays also hold
`patch_rays` [T, Ht/k, Wt/k, 3], the patch rays the model made from them. `latent_f64`, `rgb_f64` and
`logdepth_f64` are **F64** tensors from a float64 copy of the same model on the same float32 inputs. The float32 and
float64 rgb differ by up to about 1e-3, because float32 rounds the arguments of the top sin/cos octaves (up to about
2^14·π·|d| for rays, 2^9·π·|p| for positions).

Sizes are height x width, rows first as the paper writes them: an input of 60x80 is 60 rows by 80 columns (the
engine's messages write width x height). Input views of any size are taken, as PyTorch takes them: each conv
block ends in a stride-2 3x3 convolution with padding 1, which maps a side s to ceil(s / 2), so n input views of
HxW give n·ceil(H/8)·ceil(W/8) latent tokens (60x80: 30x40, 15x20, 8x10 = 80 tokens a view; 40x60: 20x30, 10x15,
5x8 = 40). The `_in60x80` and `_in40x60` cases have input sizes that 8 does not divide.

Models are small SRT configs with the raypatch width extensions and the official MSN-Easy runs' geometry: 3 conv
blocks, encoder BatchNorm (none in rpsrt_k8), pos_start_octave -5; 2 encoder and 2 decoder attention layers,
15 + 15 octaves, 4 heads, token width 32 (srt_k1, rpsrt_k2) or 16 (the others). rpsrt_k2 stores
decoder_kwargs without `out_dims` like a config.yaml; the other Ray-Patch cases store `out_dims` = conv_features
like an official checkpoint. Output layers are rescaled so that the pre-sigmoid outputs have mean 0 and standard
deviation 1.5 on the case's own scene.

OSRT cases (`osrt`, `osrt_iters3_ln`, `rposrt_k8`, `rposrt_k4_patchrays`; base osrt) are small OSRT / RP-OSRT
configs (tools/data/make_golden.py `small_osrt_config`): the SRT encoder above at token width 16 (4 heads of 4, FF
hidden 32), slot attention with slots 32 wide (slot MLP hidden 48), allocation transformer of 2 layers with 4
heads of 8 over the slots, mixing attention 24 wide, render MLP hidden 40. Their random weights include random
GRU parameters and initial slots. On the case's scene the mixing block's to_q is projected off the mean of its
inputs and its to_k rescaled so that the mixing logits have standard deviation 2 (random weights otherwise let one
slot win every pixel), then the output layer (render_mlp.net.8, or the Ray-Patch convolutions) is rescaled as
above. Mixing weights can come close: the smallest gap between a pixel's two largest slot weights is about 1e-5
in the Ray-Patch cases, so an engine's argmax, and its FG-ARI, may differ on a few pixels.
Their scenes hold `target_images` and `target_masks` (U8 [T, Ht, Wt] instance ids, 0 = background), and their
expected files `set_latent` [tokens, token_dim] (the SRT-encoder output), `latent` = the slots [S, slot_dim],
`segmentation` [T, Ht, Wt, S] (slot weights per pixel; for Ray-Patch those of the patch rays bilinearly resized,
align_corners=False, to Ht x Wt, not renormalised), their `_f64` versions, and `fg_ari` (F64 [1]): the official
compute_adjusted_rand_index of the float32 segmentation against the one-hot target_masks without channel 0, all
target views of the scene pooled into one set of points, as the official OSRT test_step does.

DeFiNe cases (`define`, `rpdefine_k16`, `rpdefine_k16_patchrays_in60x88`; base define) are small DeFiNe / RP-DeFiNe
configs (tools/data/make_golden.py `small_define_config`): a ResNet-18 of width 8 (raypatch `resnet_width`: 8, 16,
32, 64 channels), a Perceiver with 64 latents 32 wide (`num_latents`, `latent_dim`), 2 self-attention layers of 4 heads
(`heads`), and the official octaves (position 20 and ray 10, linspace(1, 30)), so tokens are 15·8 + 186 = 306 wide
and decoder queries 186; Ray-Patch k=16 with 32 conv features. Their scenes are ScanNet-like (make_define_scene):
2 input views in the frame of input camera 0 (at the origin, identity rotation); `input_rays` and `target_rays`
are world points at unit depth, R·K⁻¹[u + 0.5, v + 0.5, 1] + t computed on the 480x640 grid (ScanNet-like depth
intrinsics) and bilinearly resized (align_corners=False, no antialiasing) to the stored size, as the official
ScanNet loader makes them; camera positions are t; target 0 is input camera 1. `input_images` are in [0, 1]: the
model ImageNet-normalises them itself, (x - mean) / std with mean (0.485, 0.456, 0.406) and std (0.229, 0.224,
0.225) in float32, where the official loader does it before the model. Input sides must be multiples of 4 (the
official code fails otherwise); 60x88 views give ResNet features of 15x22, 8x11, 4x6 and 2x3, bilinearly resized
(align_corners=False) to 15x22 = 330 tokens a view. Random weights have unit-gain Perceiver attention projections,
BatchNorm statistics drawn near those of the case's scene, and both heads' output layers rescaled as above, so
`logdepth` = log(sigmoid(x)·(10 - 0.1) + 0.1) spans most of 0.1..10 (every DeFiNe expected file holds it).
`latent` is the Perceiver's last_hidden_state [num_latents, latent_dim] = [64, 32].

| case | decoder | input views (n x HxW) | targets (n x HxW) | scene target_rays | what it covers |
|---|---|---|---|---|---|
"""


def patch_size(case):
    return 2 ** case.model_cfg["rp_kwargs"]["upsample"] if "rp_kwargs" in case.model_cfg else 1


def target_rays_shape(case):
    """The shape of the case's scene target_rays: full resolution, or the patch grid with patch_rays."""
    k = patch_size(case) if case.patch_rays else 1
    return [case.num_targets, case.target_size[0] // k, case.target_size[1] // k, 3]


def readme_row(case):
    k = patch_size(case)
    decoder = "lightfield" if k == 1 else f"Ray-Patch k={k}"
    if case.model_cfg["base"] == "osrt":
        decoder = "OSRT lightfield" if k == 1 else f"RP-OSRT k={k}"
    if case.model_cfg["base"] == "define":
        decoder = "DeFiNe lightfield" if k == 1 else f"RP-DeFiNe k={k}"
    inputs = "{} x {}x{}".format(case.num_inputs, *case.input_size)
    targets = "{} x {}x{}".format(case.num_targets, *case.target_size)
    return f"| `{case.name}` | {decoder} | {inputs} | {targets} | {target_rays_shape(case)} | {case.description} |"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", required=True, type=Path, help="folder to write the case folders into")
    parser.add_argument("--full-size", action="store_true",
                        help="write only the official-size case rpsrt_k4_full (about 170 MB)")
    parser.add_argument("--cases", help="comma-separated case names: write only these (and the README table)")
    args = parser.parse_args(argv)

    # The command that writes every case; files written with --cases are the same as its, so they name it.
    arguments = (" --full-size" if args.full_size else "") + f" --out {args.out}"
    command = "python3 tools/data/make_golden.py" + arguments
    all_cases = [full_size_case()] if args.full_size else golden_cases()
    cases = all_cases
    if args.cases is not None:
        names = [name.strip() for name in args.cases.split(",") if name.strip()]
        unknown = [name for name in names if name not in {case.name for case in all_cases}]
        if unknown or not names:
            parser.error(("unknown case(s) " + ", ".join(unknown) if unknown else "--cases names no case")
                         + "; the cases are " + ", ".join(case.name for case in all_cases))
        cases = [case for case in all_cases if case.name in names]
    for case in cases:
        start = time.perf_counter()
        scene, expected = write_case(case, args.out, command)
        assert list(scene["target_rays"].shape) == target_rays_shape(case), case.name
        rgb = expected["rgb"]
        shapes = ", ".join(f"{name} {list(tensor.shape)}" for name, tensor in {**scene, **expected}.items()
                           if not name.endswith("_f64"))
        print(f"{case.name}: {shapes}\n    rgb mean {rgb.mean():.3f} std {rgb.std():.3f}, "
              f"max |rgb - rgb_f64| {(rgb.double() - expected['rgb_f64']).abs().max():.2e}, "
              f"{time.perf_counter() - start:.1f} s")
        if "segmentation" in expected:
            top2 = expected["segmentation"].topk(2, -1)[0]
            print(f"    fg_ari {expected['fg_ari'].item():.6f}, smallest top-2 slot-weight gap "
                  f"{(top2[..., 0] - top2[..., 1]).min():.2e}, max |segmentation - segmentation_f64| "
                  f"{(expected['segmentation'].double() - expected['segmentation_f64']).abs().max():.2e}")
    if not args.full_size:
        rows = [readme_row(case) for case in all_cases]
        (args.out / "README.md").write_text(README_HEADER.format(command=command) + "\n".join(rows) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
