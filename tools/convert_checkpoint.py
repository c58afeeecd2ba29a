"""Converts an official RayPatchQuerying Lightning checkpoint (SRT / RP-SRT, OSRT / RP-OSRT or DeFiNe / RP-DeFiNe:
config base srt, osrt or define) into a raypatch model file (docs/FORMATS.md).

    python tools/convert_checkpoint.py IN.ckpt OUT.safetensors

Keeps the `encoder.`, `decoder_att.` and `decoder_rp.` tensors (DeFiNe: `decoder_att_rgb.`, `decoder_att_d.`,
`decoder_rp_rgb.`, `decoder_rp_d.`) as float32, drops `num_batches_tracked` and everything else (`val_metrics.…`,
`loss_colour.…`), checks every name and shape against the reference model built from the checkpoint's config, and
stores the config's model section as metadata. Exit code 2 and no output file on any error.
"""

import argparse
import json
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from raypatch_reference import build_model  # noqa: E402
from safetensors_io import save_safetensors  # noqa: E402

MODEL_FORMAT = "raypatch-model/1"
KEPT_PREFIXES = ("encoder.", "decoder_att.", "decoder_rp.",
                 "decoder_att_rgb.", "decoder_att_d.", "decoder_rp_rgb.", "decoder_rp_d.")
MAX_PROBLEM_LINES = 20


class ConversionError(Exception):
    """A one-line, user-facing reason why a checkpoint cannot be converted."""


def to_plain(value):
    """Recursively turns mappings (dict, omegaconf DictConfig, …) into dicts and sequences into lists."""
    if isinstance(value, Mapping):
        return {str(key): to_plain(item) for key, item in value.items()}
    if isinstance(value, Sequence) and not isinstance(value, (str, bytes)):
        return [to_plain(item) for item in value]
    return value


def model_config_from_checkpoint(checkpoint):
    """The run's config.yaml model section. The official train.py builds the model as Model(cfg["model"]) and
    GenericModel.save_hyperparameters() stores that argument, so Lightning holds the model section itself as
    hyper_parameters["cfg"]; a whole run config there (hyper_parameters["cfg"]["model"]) is taken too."""
    try:
        cfg = checkpoint["hyper_parameters"]["cfg"]
        model_cfg = cfg if "base" in cfg else cfg["model"]
        if not isinstance(model_cfg, Mapping):
            raise TypeError
    except (KeyError, TypeError):
        raise ConversionError('no model section in hyper_parameters["cfg"] (not a RayPatchQuerying checkpoint?)')
    return to_plain(model_cfg)


def inference_tensors(state_dict):
    """The model tensors of a Lightning state_dict, without num_batches_tracked, as contiguous float32."""
    return {name: tensor.detach().to(torch.float32).contiguous()
            for name, tensor in state_dict.items()
            if name.startswith(KEPT_PREFIXES) and not name.endswith("num_batches_tracked")}


def expected_shapes(model_cfg):
    """Name -> shape of every tensor the reference model built from model_cfg holds (num_batches_tracked aside)."""
    with torch.device("meta"):  # shapes only, no memory or init cost
        model = build_model(model_cfg)
    return {name: list(tensor.shape) for name, tensor in model.state_dict().items()
            if not name.endswith("num_batches_tracked")}


def shape_problems(tensors, model_cfg):
    """One line per missing, unexpected or wrongly shaped tensor."""
    expected = expected_shapes(model_cfg)
    problems = [f"missing tensor {name!r} (expected shape {shape})"
                for name, shape in expected.items() if name not in tensors]
    for name, tensor in tensors.items():
        if name not in expected:
            problems.append(f"unexpected tensor {name!r} (shape {list(tensor.shape)})")
        elif list(tensor.shape) != expected[name]:
            problems.append(f"tensor {name!r} has shape {list(tensor.shape)}, expected {expected[name]}")
    return problems


def write_model(path, state_dict, model_cfg, extra_metadata=None):
    """Writes a raypatch model file (float32 tensors, format and config metadata) atomically."""
    metadata = {"format": MODEL_FORMAT, "config": json.dumps(model_cfg)}
    metadata.update(extra_metadata or {})
    save_safetensors(path, {name: tensor.to(torch.float32) for name, tensor in state_dict.items()}, metadata)


def convert(in_path, out_path):
    try:
        checkpoint = torch.load(in_path, map_location="cpu", weights_only=False)
    except Exception as error:  # any unreadable or unpicklable file ends up here
        raise ConversionError(f"cannot load checkpoint: {type(error).__name__}: {error}")
    if not isinstance(checkpoint, Mapping) or not isinstance(checkpoint.get("state_dict"), Mapping):
        raise ConversionError("no state_dict (not a Lightning checkpoint?)")
    model_cfg = model_config_from_checkpoint(checkpoint)
    tensors = inference_tensors(checkpoint["state_dict"])
    try:
        problems = shape_problems(tensors, model_cfg)
    except ValueError as error:
        raise ConversionError(str(error))
    if problems:
        shown = problems[:MAX_PROBLEM_LINES]
        if len(problems) > len(shown):
            shown.append(f"... and {len(problems) - len(shown)} more problems")
        raise ConversionError("\n".join(shown))
    try:
        write_model(out_path, tensors, model_cfg, {"source": Path(in_path).name})
    except OSError as error:
        raise ConversionError(f"cannot write {out_path}: {error}")
    return len(tensors)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint", help="official Lightning .ckpt file")
    parser.add_argument("output", help="raypatch model .safetensors file to write")
    args = parser.parse_args(argv)
    try:
        count = convert(args.checkpoint, args.output)
    except ConversionError as error:
        for line in str(error).splitlines():
            print(f"convert_checkpoint: {args.checkpoint}: {line}", file=sys.stderr)
        return 2
    print(f"wrote {args.output}: {count} tensors")
    return 0


if __name__ == "__main__":
    sys.exit(main())
