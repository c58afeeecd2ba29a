"""Small models with make_golden's random weights, shared by the tests (tools/tests: test_reference_*.py,
test_convert_checkpoint.py)."""

import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tools/, whose packages this imports
from data import make_golden  # noqa: E402
from reference.raypatch_reference import SRT, build_model  # noqa: E402


def random_model(model_cfg, seed=0):
    """An SRT / RP-SRT with make_golden's random weights."""
    torch.manual_seed(seed)
    model = SRT.from_config(model_cfg).eval()
    make_golden.randomize_weights(model)
    return model


def k4_config(**rp_overrides):
    """A small RP-SRT k = 4 config (featurefield decoder, widths 16)."""
    rp_kwargs = dict(upsample=2, h_in=8, w_in=12, conv_features=16, norm="Batch", **rp_overrides)
    return make_golden.small_config("featurefield", rp_kwargs=rp_kwargs, width=16)


def random_define(model_cfg, seed=0, scene=None, target_size=None):
    """A DeFiNe with make_golden's random weights (and, given a scene, its BatchNorm and output calibration)."""
    torch.manual_seed(seed)
    model = build_model(model_cfg).eval()
    make_golden.randomize_define_weights(model)
    if scene is not None:
        make_golden.calibrate_batchnorm(model, scene, target_size)
        make_golden.calibrate_define_output(model, scene, target_size)
    return model
