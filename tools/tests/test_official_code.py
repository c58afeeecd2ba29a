"""The PyTorch reference against the official code of tberriel/RayPatchQuerying: skipped, saying why, unless
RAYPATCH_OFFICIAL_REPO names a checkout of it.

    RAYPATCH_OFFICIAL_REPO=<checkout> python3 -m pytest -s tools/tests/test_official_code.py

With it, the official modules run (einops, transformers and torchvision stubbed) on the reference's weights and are
compared with it: SRT and RP-SRT with the official encoder and decoders and get_camera_rays, OSRT and RP-OSRT with
the official `OSRT.decoder` and `compute_adjusted_rand_index` (`-s` prints the measured differences). The DeFiNe
comparison runs the official modules with the real transformers 4.24.0 and torchvision (installed beside the
project's packages, e.g. `pip install --no-deps --target DIR transformers==4.24.0 torchvision tqdm
huggingface-hub==0.10.1` and PYTHONPATH=DIR); it is skipped, saying why, where they cannot be imported.
"""

import ast
import copy
import functools
import importlib
import inspect
import json
import os
import sys
import textwrap
import types
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from safetensors import safe_open
from safetensors.torch import load_file
from torch import nn

from data import make_golden
from data.random_models import random_define, random_model
from reference import reference_define
from reference.cameras import get_camera_rays, look_at_positions
from reference.official_configs import (OSRT_MDBN_64, RPDEFINE_16_32_STEREO_ACC, RPOSRT_MDBN_8_64, RPSRT_MDBN_4_32,
                                        SRT_MDBN_32, official_keys)
from reference.raypatch_reference import OSRTEncoder, SlotMixerDecoder, build_model, foreground_ari
from reference.reference_define import DeFiNe
from reference_helpers import (DEFINE_CASES, DEFINE_KEY_LISTS, GOLDEN, OSRT_CASES, define_case, osrt_case, random_osrt,
                               scene_tensors)


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


def test_matches_official_code():
    repo = os.environ.get("RAYPATCH_OFFICIAL_REPO")
    if not repo:
        pytest.skip("set RAYPATCH_OFFICIAL_REPO to a checkout of tberriel/RayPatchQuerying")
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


def narrowed_srt_encoder(official_encoder, layers, enc):
    """The official SRTEncoder (its class and forward) with the widths it hard-codes (conv hidden 96, 768-wide
    tokens, 12 heads of 64) taken from `enc`, encoder_kwargs completed with the reference's defaults."""
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
    return srt


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
        encoder = bare(official_encoder.OSRTEncoder)
        encoder.srt_encoder = narrowed_srt_encoder(official_encoder, layers, enc)
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


def test_matches_official_osrt():
    """Reference OSRT / RP-OSRT against the official modules and the official OSRT.decoder and
    compute_adjusted_rand_index: set latent, slots, rgb, segmentation and FG-ARI of the four golden OSRT configs
    (on their scenes) and of the official osrt_MDBN_64 and rposrt_MDBN_8_64 configs (random weights)."""
    repo = os.environ.get("RAYPATCH_OFFICIAL_REPO")
    if not repo:
        pytest.skip("set RAYPATCH_OFFICIAL_REPO to a checkout of tberriel/RayPatchQuerying")
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
        print(f"{name}: max |reference - official| " + ", ".join(f"{key} {value:.2e}"
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
        pytest.skip(f"the official DeFiNe needs transformers 4.24.0 and torchvision: {error}")
    if transformers.__version__ != "4.24.0":
        pytest.skip(f"the official DeFiNe runs on transformers 4.24.0, found {transformers.__version__}")
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


def test_matches_official_define():
    """Reference DeFiNe / RP-DeFiNe against the official modules (transformers 4.24.0 Perceiver, torchvision ResNet)
    and the official DeFiNe.decoder: latent, rgb and log-depth of the three golden DeFiNe cases (their model and
    scene files) and of the official rpdefine_16_32_stereo_acc config (random weights, the rpdefine_k16 scene);
    the engine key lists are the official modules' state_dict names and shapes, in order."""
    repo = os.environ.get("RAYPATCH_OFFICIAL_REPO")
    if not repo:
        pytest.skip("set RAYPATCH_OFFICIAL_REPO to a checkout of tberriel/RayPatchQuerying")
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
        print(f"{name}: max |reference - official| " + ", ".join(f"{key} {value:.2e}"
                                                                  for key, value in differences.items())
              + f" (latent up to {z.abs().max():.1f}, {num_targets} x {target_size[0]}x{target_size[1]} targets)")
        assert rgb_official.shape == (1, num_targets * target_size[0] * target_size[1], 3), rgb_official.shape
        assert differences["latent"] < 1e-5 * max(1.0, z.abs().max().item()), (name, differences)
        assert differences["rgb"] < 1e-5 and differences["logdepth"] < 1e-5, (name, differences)
