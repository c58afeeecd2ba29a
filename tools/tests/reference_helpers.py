"""Shared by the reference tests (test_reference_srt.py, test_reference_osrt.py, test_reference_define.py,
test_official_code.py): the golden cases and scenes they run on, the comparison with the official key lists, the
check that a config is refused, and OSRT's random weights."""

from pathlib import Path

import numpy as np
import torch

from data import make_golden
from reference.official_configs import DEFINE_32_STEREO_ACC, RPDEFINE_16_32_STEREO_ACC, official_keys
from reference.raypatch_reference import build_model

GOLDEN = Path(__file__).resolve().parents[2] / "assets" / "golden"
OSRT_CASES = ("osrt", "osrt_iters3_ln", "rposrt_k8", "rposrt_k4_patchrays")
DEFINE_CASES = ("define", "rpdefine_k16", "rpdefine_k16_patchrays_in60x88")
# The official DeFiNe runs (key lists written from the official modules) and their parameter totals.
DEFINE_KEY_LISTS = (("define_32_stereo_acc", DEFINE_32_STEREO_ACC, 30_759_058),
                    ("rpdefine_16_32_stereo_acc", RPDEFINE_16_32_STEREO_ACC, 31_011_690))


def assert_refused(build, cfg, message):
    """build(cfg) (on the meta device) raises a ValueError whose text holds `message`."""
    try:
        with torch.device("meta"):
            build(cfg)
    except ValueError as error:
        assert message in str(error), str(error)
    else:
        raise AssertionError(f"no error for {message}")


def scene_tensors(case_name="rpsrt_k4"):
    case = next(case for case in make_golden.golden_cases() if case.name == case_name)
    return case, make_golden.make_scene(case, np.random.default_rng(0))


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


def random_osrt(model_cfg, seed=0):
    torch.manual_seed(seed)
    model = build_model(model_cfg).eval()
    make_golden.randomize_osrt_weights(model)
    return model


def osrt_case(name):
    case = next(case for case in make_golden.golden_cases() if case.name == name)
    return case, make_golden.make_scene(case, np.random.default_rng(case.seed))


def define_case(name):
    case = next(case for case in make_golden.golden_cases() if case.name == name)
    return case, make_golden.make_define_scene(case, np.random.default_rng(case.seed))
