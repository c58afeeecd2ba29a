"""The PyTorch reference's DeFiNe / RP-DeFiNe (tools/reference/reference_define.py, config base define): official
key names, shapes and parameter totals, config rules, the Perceiver maths, ResNet-18 feature sizes and ImageNet
normalisation, rendering paths, and the committed DeFiNe golden files.

    python3 -m pytest tools/tests/test_reference_define.py      (-s prints the measured figures)
"""

import copy
import json
import math

import numpy as np
import torch
from safetensors import safe_open
from safetensors.torch import load_file
from torch import nn

from data import make_golden
from data.random_models import random_define
from reference.official_configs import official_keys
from reference.raypatch_reference import build_model
from reference.reference_define import DeFiNe, PerceiverBasicDecoder, PerceiverLayer, ResNetSkip, imagenet_normalize
from reference_helpers import DEFINE_CASES, DEFINE_KEY_LISTS, GOLDEN, assert_refused, define_case


def test_official_define_state_dict_keys():
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
        print(f"{file}: {len(official)} tensors, {parameters:,} parameters "
              f"(encoder {sum(p.numel() for n, p in model.named_parameters() if n.startswith('encoder.')):,})")
        assert parameters == from_list == total, (file, parameters, from_list, total)


def test_define_config_rules():
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
        assert_refused(build_model, cfg, message)
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


def test_perceiver_maths():
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


def test_define_encoder_sizes():
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


def test_define_render_paths():
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


def test_define_golden_files():
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
        print(f"{name}: max |f32 - f64| rgb {(expected['rgb'].double() - expected['rgb_f64']).abs().max():.1e}, "
              f"logdepth {(expected['logdepth'].double() - expected['logdepth_f64']).abs().max():.1e}")
