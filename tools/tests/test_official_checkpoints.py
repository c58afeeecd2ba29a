"""Checkpoints made by the official code of tberriel/RayPatchQuerying, read by render-frame: skipped, saying why,
unless RAYPATCH_OFFICIAL_REPO names a checkout of it, pytorch_lightning and torchmetrics import, and
target/release/render-frame is built.

    RAYPATCH_OFFICIAL_REPO=<checkout> PYTHONPATH=<official deps> python3 -m pytest tools/tests/test_official_checkpoints.py

For each family (SRT, RP-SRT, OSRT, RP-OSRT, DeFiNe, RP-DeFiNe) the official Lightning module (src.model's SRT, OSRT or
DeFiNe, its own __init__: hyper-parameters, loss and metric modules, the decoder_kwargs it rewrites) is built as the
official train.py builds it, `Model(cfg["model"], lpips=False, ssim=False)` with cfg["model"]["wandb"] set, where
cfg["model"] is the official run's config.yaml model section with the golden model's architecture keys. Its
submodules are the official classes at the golden model's tiny widths (the official constructors hard-code the
official widths, so they build the narrowed official modules of test_official_code.py) and hold the golden weights.
Lightning's Trainer saves it (`trainer.save_checkpoint`), the Python converter converts it, and
`render-frame --model run.ckpt` renders the golden scene bit-equal to `--model converted.safetensors`;
`render-frame --save-model` writes the converter's bytes. DeFiNe needs the real transformers 4.24.0 and torchvision
(as in test_official_code.py); SRT and OSRT stub them (and einops) where they are missing.
"""

import copy
import importlib
import os
import sys
import types
from pathlib import Path

import numpy as np
import pytest
import torch
from torch import nn

from conversion import convert_checkpoint
from reference.raypatch_reference import SRTDecoder, SRTEncoder
from test_checkpoint_reader import FAMILIES, RENDER_FRAME, golden_model, render_frame, render_raw
from test_official_code import (_rearrange, _unused, bare, defaults_of, import_official_define, narrowed_srt_encoder,
                                official_define, official_osrt_modules)

REPO = os.environ.get("RAYPATCH_OFFICIAL_REPO")
# The official run whose training keys (lr schedule, warmup, decay) each golden family's checkpoint carries.
OFFICIAL_RUNS = {"srt_k1": "msn_easy/srt_MDBN_32", "rpsrt_k4": "msn_easy/rpsrt_MDBN_4_32",
                 "osrt": "msn_easy/osrt_MDBN_64", "rposrt_k8": "msn_easy/rposrt_MDBN_8_64",
                 "define": "scannet/define_32_stereo_acc", "rpdefine_k16": "scannet/rpdefine_16_32_stereo_acc"}

pytestmark = [pytest.mark.skipif(not REPO, reason="set RAYPATCH_OFFICIAL_REPO to a checkout of tberriel/RayPatchQuerying"),
              pytest.mark.skipif(not RENDER_FRAME.exists(),
                                 reason="needs target/release/render-frame (cargo build --release)")]


def stubs_for_missing():
    """Stand-ins for the official imports that SRT and OSRT do not use, where they cannot be imported."""
    stubs = {}
    try:
        import einops  # noqa: F401
    except ImportError:
        stubs["einops"] = types.SimpleNamespace(rearrange=_rearrange, repeat=_unused)
    try:
        import transformers  # noqa: F401
    except ImportError:
        stubs.update({"transformers": types.SimpleNamespace(PerceiverModel=_unused, PerceiverConfig=_unused),
                      "transformers.models.perceiver.modeling_perceiver":
                          types.SimpleNamespace(PerceiverBasicDecoder=_unused)})
    try:
        import torchvision  # noqa: F401
    except ImportError:
        stubs["src.resnet"] = types.SimpleNamespace(resnet18=_unused)
    return stubs


@pytest.fixture(scope="module")
def official():
    """pytorch_lightning and the official src.model, src.encoder, src.decoder and src.layers."""
    lightning = pytest.importorskip("pytorch_lightning", reason="the official train.py saves with pytorch_lightning")
    pytest.importorskip("torchmetrics", reason="the official src.model builds torchmetrics modules")
    yaml = pytest.importorskip("yaml", reason="the official train.py reads its config.yaml with PyYAML")
    stubs = stubs_for_missing()
    package = types.ModuleType("src")
    package.__path__ = [str(Path(REPO) / "src")]
    before = set(sys.modules)
    saved = {name: sys.modules.get(name) for name in [*stubs, "src"]}
    sys.modules.update(stubs)
    sys.modules["src"] = package
    try:
        modules = {name: importlib.import_module(f"src.{name}") for name in ("model", "encoder", "decoder", "layers")}
    except ImportError as error:
        pytest.skip(f"the official src.model does not import: {error}")
    finally:
        for name in set(sys.modules) - before:
            if name == "src" or name.startswith("src."):
                sys.modules.pop(name)
        for name, module in saved.items():
            if module is None:
                sys.modules.pop(name, None)
            else:
                sys.modules[name] = module
    return types.SimpleNamespace(lightning=lightning, yaml=yaml, **modules)


def narrowed_srt_decoder(official, dec):
    """The official SRTDecoder (class, RayPredictor, forward) with the widths it hard-codes (12 heads, input MLP 360,
    out MLP 1536) taken from `dec`, decoder_kwargs completed with the reference's defaults."""
    layers, idim = official.layers, 6 * (dec["pos_octaves"] + dec["ray_octaves"])
    predictor = bare(official.decoder.RayPredictor)
    predictor.return_queries = False
    predictor.query_encoder = layers.RayEncoder(
        pos_octaves=dec["pos_octaves"], pos_start_octave=dec["pos_start_octave"], pos_end_octave=dec["pos_end_octave"],
        ray_octaves=dec["ray_octaves"], ray_start_octave=dec["ray_start_octave"], ray_end_octave=dec["ray_end_octave"])
    predictor.transformer = layers.Transformer(idim, depth=dec["num_att_blocks"], heads=dec["heads"],
                                               dim_head=int(dec["latent_dim"] / dec["heads"]),
                                               latent_dim=dec["latent_dim"], mlp_dim=int(dec["latent_dim"] * 2),
                                               selfatt=False, mode=dec["mode"])
    predictor.input_mlp = nn.Sequential(layers.SRTLinear(idim, dec["input_mlp_hidden"]), nn.ReLU(),
                                        layers.SRTLinear(dec["input_mlp_hidden"], idim))
    predictor.output_mlp = nn.Identity()
    decoder = bare(official.decoder.SRTDecoder)
    decoder.resize_out = False
    decoder.ray_predictor = predictor
    widths = [idim] + [dec["out_mlp_hidden"]] * 4 + [dec["out_dims"]]
    mlp = []
    for index, (width_in, width_out) in enumerate(zip(widths, widths[1:])):
        mlp += [layers.SRTLinear(width_in, width_out)] + ([nn.LeakyReLU()] if index < 4 else [])
    decoder.out_mlp = nn.Sequential(*mlp)
    return decoder


def narrowed_constructors(official, model_cfg):
    """src.model's names of the constructors that hard-code official widths -> a stand-in building the official
    classes at model_cfg's widths (RayPatchDecoder takes its widths from rp_kwargs and stays as it is)."""
    if model_cfg["base"] == "srt":
        return {"SRTEncoder": lambda **kwargs: narrowed_srt_encoder(official.encoder, official.layers,
                                                                    defaults_of(SRTEncoder, kwargs)),
                "SRTDecoder": lambda **kwargs: narrowed_srt_decoder(official, defaults_of(SRTDecoder, kwargs))}
    if model_cfg["base"] == "osrt":
        rp_kwargs = model_cfg.get("rp_kwargs") or {}
        encoder, decoder_att, _ = official_osrt_modules(official.encoder, official.decoder, official.layers,
                                                        model_cfg, (None, rp_kwargs.get("h_out"), rp_kwargs.get("w_out")))
        return {"OSRTEncoder": lambda **kwargs: encoder, "SlotMixerDecoder": lambda **kwargs: decoder_att}
    define = official_define(import_official_define(REPO), copy.deepcopy(model_cfg))
    decoders = iter([define.decoder_att_rgb, define.decoder_att_d])  # DeFiNe.__init__ builds rgb, then depth
    return {"DeFiNeEncoder": lambda **kwargs: define.encoder, "DeFiNeDecoder": lambda **kwargs: next(decoders)}


def official_run_model(official, case, monkeypatch):
    """The official Lightning module of `case`, built as train.py builds it, holding the golden weights."""
    model_cfg, reference = golden_model(case)
    with open(Path(REPO) / "runs" / OFFICIAL_RUNS[case] / "config.yaml") as file:
        cfg = official.yaml.load(file, Loader=getattr(official.yaml, "CLoader", official.yaml.Loader))
    cfg["model"] = {**cfg["model"], **copy.deepcopy(model_cfg)}
    if "wandb" not in cfg["model"]:
        cfg["model"]["wandb"] = False
    for name, constructor in narrowed_constructors(official, model_cfg).items():
        monkeypatch.setattr(official.model, name, constructor)
    model_class = {"srt": official.model.SRT, "osrt": official.model.OSRT, "define": official.model.DeFiNe}
    module = model_class[model_cfg["base"]](cfg["model"], lpips=False, ssim=False)
    expected = {name: tuple(tensor.shape) for name, tensor in reference.state_dict().items()}
    assert {name: tuple(tensor.shape) for name, tensor in module.state_dict().items()} == expected, case
    module.load_state_dict(reference.state_dict())
    return module


def fake_batches(model_cfg, height=128, width=128, num_targets=2, num_rays=64):
    """One training example of the official loaders' keys and shapes (random values): the Ray-Patch decoders take
    their configured grid of rays per target view and give their output size in pixels."""
    generator = torch.Generator().manual_seed(0)
    rp_kwargs = model_cfg.get("rp_kwargs")
    if rp_kwargs:
        scale = 2 ** rp_kwargs["upsample"]
        num_rays = num_targets * rp_kwargs["h_in"] * rp_kwargs["w_in"]
        out_h, out_w = (rp_kwargs.get("h_out") or rp_kwargs["h_in"] * scale,
                        rp_kwargs.get("w_out") or rp_kwargs["w_in"] * scale)
        num_pixels = num_targets * out_h * out_w
    else:
        out_h, out_w, num_pixels = 1, num_rays // num_targets, num_rays
    example = {"input_images": torch.rand(1, 3, height, width, generator=generator),
               "input_camera_pos": torch.randn(1, 3, generator=generator),
               "input_rays": nn.functional.normalize(torch.randn(1, height, width, 3, generator=generator), dim=-1),
               "target_camera_pos": torch.randn(1, 3, generator=generator).expand(num_rays, 3).clone(),
               "target_rays": nn.functional.normalize(torch.randn(num_rays, 3, generator=generator), dim=-1),
               "target_pixels": torch.rand(num_pixels, 3, generator=generator),
               "target_vis_mask": torch.ones(num_pixels, dtype=torch.bool),
               "target_real_mask": torch.ones(num_pixels, dtype=torch.bool),
               "target_shape": torch.tensor([num_targets, out_h, out_w, 3])}
    return [example]


@pytest.mark.parametrize("case", FAMILIES)
def test_official_checkpoints_render_as_their_conversion(tmp_path, case, official, monkeypatch):
    module = official_run_model(official, case, monkeypatch)
    # As train.py: its ModelCheckpoint "model" saving every step, fit for one step (the official warm-up schedules
    # start at learning rate 0, so the weights stay; BatchNorm statistics move).
    from pytorch_lightning.callbacks import ModelCheckpoint
    monkeypatch.setattr(np, "Inf", np.inf, raising=False)  # the official Lightning 2.0.2 predates numpy 2
    checkpoint = ModelCheckpoint(every_n_train_steps=1, filename="model", dirpath=str(tmp_path),
                                 save_on_train_epoch_end=True)
    trainer = official.lightning.Trainer(accelerator="cpu", devices=1, max_steps=1, logger=False,
                                         enable_progress_bar=False, enable_model_summary=False, callbacks=[checkpoint])
    trainer.fit(module, train_dataloaders=torch.utils.data.DataLoader(fake_batches(module.hparams.cfg)))
    ckpt = tmp_path / "model.ckpt"

    python_out, rust_out = tmp_path / "py.safetensors", tmp_path / "rs.safetensors"
    assert convert_checkpoint.main([str(ckpt), str(python_out)]) == 0
    result = render_frame("--model", ckpt, "--save-model", rust_out)
    assert result.returncode == 0, result.stderr
    assert rust_out.read_bytes() == python_out.read_bytes()
    direct = render_raw(ckpt, case, tmp_path / "direct.safetensors")
    converted = render_raw(python_out, case, tmp_path / "converted.safetensors")
    assert direct.keys() == converted.keys()
    for name in direct:
        assert torch.equal(direct[name], converted[name]), name
