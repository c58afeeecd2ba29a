"""Model sections of the official MSN-Easy and ScanNet run configs of tberriel/RayPatchQuerying (297afbc), read from
assets/official/configs.json, the one copy the Rust crates read too (raypatch_model::official). Each is
runs/<dataset>/<run>/config.yaml's model section (YAML Null -> None); the key lists of their state_dicts are
assets/official/keys/<run>.txt (official_keys).

A checkpoint stores these with one change: the official SRT.__init__ / OSRT.__init__ writes the attention decoder
width into decoder_kwargs.out_dims (128 for the Ray-Patch runs) before Lightning saves the hyper-parameters. The
official DeFiNe class writes nothing into the config (the heads' out_dims are passed beside it); a checkpoint's model
section also holds `wandb` (added by train.py). rpdefine's rp_kwargs.conv_features is left at its default, 128.
"""

import json
from pathlib import Path

OFFICIAL = Path(__file__).resolve().parents[2] / "assets" / "official"
CONFIGS = json.loads((OFFICIAL / "configs.json").read_text())

SRT_MDBN_32 = CONFIGS["srt_MDBN_32"]
RPSRT_MDBN_4_32 = CONFIGS["rpsrt_MDBN_4_32"]
OSRT_MDBN_64 = CONFIGS["osrt_MDBN_64"]
RPOSRT_MDBN_8_64 = CONFIGS["rposrt_MDBN_8_64"]
DEFINE_32_STEREO_ACC = CONFIGS["define_32_stereo_acc"]
RPDEFINE_16_32_STEREO_ACC = CONFIGS["rpdefine_16_32_stereo_acc"]


def official_keys(run):
    """[(name, shape)] of the official run's state_dict, in the official order (num_batches_tracked included)."""
    keys = []
    for line in (OFFICIAL / "keys" / f"{run}.txt").read_text().splitlines():
        if line and not line.startswith("#"):
            name, shape = line.split(" ", 1)
            keys.append((name, json.loads(shape)))
    return keys
