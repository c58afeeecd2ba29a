"""Trivial baselines on a folder of scenes: what PSNR and SSIM a renderer gets without any model.

    python3 tools/bench/baselines.py --scenes assets/scenes [--grey 0.5 --grey 0.6]

For every target view of every scene (each scene's view 0 is the input, the other views the targets, as
tools/bench/evaluate.py renders them) it predicts
- input mean colour: every pixel the mean colour of the scene's input view;
- constant grey: every pixel (g, g, g) for each --grey g, 0.5 by default;
and prints, per baseline, the mean PSNR and SSIM over the target views (the metrics of tools/bench/evaluate.py and
render-frame --metrics: per-image PSNR with data range 1, then the mean; SSIM as torchmetrics 1.x), and with
--per-scene the means of each scene.
"""

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tools/, whose packages this imports
from bench.evaluate import psnr, ssim  # noqa: E402
from data.make_scenes import load_views  # noqa: E402


def baselines(images, greys=(0.5,)):
    """{name: (psnr [S, T], ssim [S, T])} of the baselines on images uint8 [S, V, H, W, 3] (view 0 the input)."""
    pixels = torch.from_numpy(images).double() / 255
    inputs, targets = pixels[:, 0], pixels[:, 1:]
    scenes, views = targets.shape[:2]
    predictions = {
        "input mean colour": inputs.mean((1, 2))[:, None, None, None, :].expand_as(targets),
    }
    for grey in greys:
        predictions[f"constant grey ({grey:g})"] = torch.full_like(targets, grey)
    out = {}
    for name, pred in predictions.items():
        flat_pred, flat_target = pred.reshape(-1, *targets.shape[2:]), targets.reshape(-1, *targets.shape[2:])
        out[name] = (psnr(flat_pred, flat_target).reshape(scenes, views).numpy(),
                     ssim(flat_pred.contiguous(), flat_target).reshape(scenes, views).numpy())
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", type=Path, required=True, help="folder of scene-*.safetensors, shards or views")
    parser.add_argument("--grey", type=float, action="append", help="value of a constant-grey prediction "
                        "(repeatable; default 0.5)")
    parser.add_argument("--per-scene", action="store_true", help="also print each scene's means")
    args = parser.parse_args(argv)
    try:
        images, _, seeds = load_views(args.scenes)
    except (ValueError, OSError, KeyError) as error:
        print(f"baselines: error: {error}", file=sys.stderr)
        return 2
    print(f"{len(images)} scenes, {len(images) * (images.shape[1] - 1)} target views, from {args.scenes}")
    print("| baseline | PSNR (dB) | SSIM |\n|---|---|---|")
    results = baselines(images, args.grey or [0.5])
    for name, (psnrs, ssims) in results.items():
        print(f"| {name} | {psnrs.mean():.2f} | {ssims.mean():.3f} |")
    if args.per_scene:
        for name, (psnrs, ssims) in results.items():
            for seed, p, s in zip(seeds, psnrs.mean(1), ssims.mean(1)):
                print(f"{name}: scene {seed}: PSNR {p:.2f} dB, SSIM {s:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
