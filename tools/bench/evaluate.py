"""Quality and cost of a raypatch model file on a folder of test scenes, with the PyTorch reference.

    python3 tools/bench/evaluate.py --model MODEL.safetensors --scenes /work/data/scenes-test [--json OUT.json]

Renders both target views of every scene from its input view, and prints a markdown row in the layout of the
paper's Table 1: PSNR and SSIM (means over target images, data range 1: PSNR as torchmetrics
PeakSignalNoiseRatio(data_range=1, dim=(1,2,3)), per image then the mean; SSIM as torchmetrics
StructuralSimilarityIndexMeasure(data_range=1), Gaussian window 11, sigma 1.5, in the definition of torchmetrics 1.x
like render-frame --metrics, or with --ssim torchmetrics-0.9.3 the one the official code used, which leaves the
5-pixel border out of the mean), giga multiply-adds to encode one input view and render one target view (what the
paper calls FLOPs: it gives 48.2 G for the official SRT at 60x80, where this count gives 49.4 G), parameters, and
the training time recorded in the model's metadata.
"""

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from safetensors import safe_open
from safetensors.torch import load_file
from torch.utils.flop_counter import FlopCounterMode

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tools/, whose packages this imports
from data.make_scenes import load_views  # noqa: E402
from reference.cameras import get_camera_rays  # noqa: E402
from reference.raypatch_reference import SRT  # noqa: E402

SSIM_SIGMA = 1.5
SSIM_K1, SSIM_K2 = 0.01, 0.03
# torchmetrics StructuralSimilarityIndexMeasure(data_range=1) of two eras: 1.x (what render-frame --metrics
# computes) averages the SSIM map over the whole image and clamps the variances at 0; 0.9.3 (what the official code
# pinned) leaves the window radius (5 pixels) at each border out of the mean and does not clamp.
SSIM_DEFINITIONS = ("torchmetrics-1", "torchmetrics-0.9.3")


def psnr(pred, target):
    """Per-image PSNR [n] of images [n, ..] in [0, 1]."""
    mse = ((pred - target) ** 2).flatten(1).mean(1)
    return 10 * torch.log10(1 / mse)


def ssim(pred, target, definition="torchmetrics-1"):
    """Per-image SSIM [n] of images [n, H, W, C] in [0, 1]: Gaussian window 11, sigma 1.5, data range 1, the image
    extended by reflection (without repeating the edge), averaged over channels and pixels (SSIM_DEFINITIONS)."""
    if definition not in SSIM_DEFINITIONS:
        raise ValueError(f"SSIM definition {definition!r}, expected one of {SSIM_DEFINITIONS}")
    pred, target = pred.permute(0, 3, 1, 2), target.permute(0, 3, 1, 2)
    channels, dtype = pred.shape[1], pred.dtype
    size = int(3.5 * SSIM_SIGMA + 0.5) * 2 + 1  # 11
    pad = (size - 1) // 2
    dist = torch.arange((1 - size) / 2, (1 + size) / 2, 1, dtype=dtype, device=pred.device)
    gauss = torch.exp(-torch.pow(dist / SSIM_SIGMA, 2) / 2)
    gauss = (gauss / gauss.sum())[None]
    kernel = torch.matmul(gauss.t(), gauss).expand(channels, 1, size, size)
    pred = F.pad(pred, (pad, pad, pad, pad), mode="reflect")
    target = F.pad(target, (pad, pad, pad, pad), mode="reflect")
    stacked = torch.cat((pred, target, pred * pred, target * target, pred * target))
    mu_pred, mu_target, pred_sq, target_sq, pred_target = F.conv2d(stacked, kernel, groups=channels).split(
        pred.shape[0])
    mu_pred_sq, mu_target_sq, mu_pred_target = mu_pred.pow(2), mu_target.pow(2), mu_pred * mu_target
    var_pred, var_target = pred_sq - mu_pred_sq, target_sq - mu_target_sq
    if definition == "torchmetrics-1":
        var_pred, var_target = var_pred.clamp(min=0), var_target.clamp(min=0)
    c1, c2 = SSIM_K1 ** 2, SSIM_K2 ** 2
    upper = 2 * (pred_target - mu_pred_target) + c2
    lower = var_pred + var_target + c2
    index = ((2 * mu_pred_target + c1) * upper) / ((mu_pred_sq + mu_target_sq + c1) * lower)
    if definition == "torchmetrics-0.9.3":
        index = index[..., pad:-pad, pad:-pad]
    return index.flatten(1).mean(1)


def load_model(path, device="cpu"):
    """The reference model of a raypatch model file (eval mode), its config and its metadata."""
    with safe_open(path, "pt") as file:
        metadata = file.metadata() or {}
    if "config" not in metadata:
        raise ValueError(f"{path}: no 'config' metadata (not a raypatch model file?)")
    model_cfg = json.loads(metadata["config"])
    model = SRT.from_config(model_cfg)
    missing, unexpected = model.load_state_dict(load_file(path), strict=False)
    missing = [name for name in missing if not name.endswith("num_batches_tracked")]
    if missing or unexpected:
        raise ValueError(f"{path}: missing tensors {missing[:5]}, unexpected tensors {unexpected[:5]}")
    return model.to(device).eval(), model_cfg, metadata


def scene_batch(images, camera_pos, scenes, input_views, device):
    """Model inputs for the given scenes (arrays from make_scenes.load_views), one input view each and the other
    views as targets in order: input images [B, 1, 3, H, W], camera_pos [B, 1, 3], rays [B, 1, H, W, 3]; target
    images [B, T, H, W, 3], camera_pos [B, T, 3], rays [B, T, H, W, 3]."""
    height, width = images.shape[2:4]
    views = images.shape[1]
    order = np.array([[v] + [t for t in range(views) if t != v] for v in input_views])
    rows = np.asarray(scenes)[:, None]
    pixels = torch.from_numpy(images[rows, order]).to(device=device, dtype=torch.float32) / 255
    positions = camera_pos[rows, order]
    rays = np.stack([[get_camera_rays(pos, width, height) for pos in scene] for scene in positions])
    positions, rays = torch.from_numpy(positions).to(device), torch.from_numpy(rays).to(device)
    return {"input_images": pixels[:, :1].permute(0, 1, 4, 2, 3), "input_camera_pos": positions[:, :1],
            "input_rays": rays[:, :1], "target_images": pixels[:, 1:], "target_camera_pos": positions[:, 1:],
            "target_rays": rays[:, 1:]}


@torch.no_grad()
def render_targets(model, batch):
    """Whole target views [B, T, H, W, 3] rendered from the batch's input view."""
    z = model.encode(batch["input_images"], batch["input_camera_pos"], batch["input_rays"])
    return model.render_views(z, batch["target_camera_pos"], batch["target_rays"])[0]


def evaluate(model, images, camera_pos, batch_size=8, device="cpu", ssim_definition="torchmetrics-1"):
    """Mean PSNR and SSIM (None when ssim_definition is None) over all target images of the scenes, each rendered
    from its view 0."""
    psnrs, ssims = [], []
    for start in range(0, len(images), batch_size):
        scenes = np.arange(start, min(start + batch_size, len(images)))
        batch = scene_batch(images, camera_pos, scenes, np.zeros(len(scenes), int), device)
        # Metrics in float64, as render-frame --metrics computes them.
        pred = render_targets(model, batch).flatten(0, 1).double()
        target = batch["target_images"].flatten(0, 1).double()
        psnrs.append(psnr(pred, target))
        if ssim_definition:
            ssims.append(ssim(pred, target, ssim_definition))
    return torch.cat(psnrs).mean().item(), (torch.cat(ssims).mean().item() if ssim_definition else None)


def multiply_adds_per_frame(model_cfg, height, width):
    """Multiply-adds to encode one input view and render one target view of height x width."""
    with torch.device("meta"):
        model = SRT.from_config(model_cfg).eval()
        with FlopCounterMode(display=False) as counter:
            z = model.encode(torch.zeros(1, 1, 3, height, width), torch.zeros(1, 1, 3),
                             torch.zeros(1, 1, height, width, 3))
            model.render_views(z, torch.zeros(1, 1, 3), torch.zeros(1, 1, height, width, 3))
    return counter.get_total_flops() // 2  # the counter counts 2 FLOPs per multiply-add


def table_row(name, k, psnr_value, ssim_value, multiply_adds, parameters, training_hours):
    hours = "-" if training_hours is None else f"{training_hours:.2f} h"
    return (f"| {name} | {k} | {psnr_value:.2f} | {ssim_value:.3f} | {multiply_adds / 1e9:.3f} | "
            f"{parameters / 1e6:.3f} M | {hours} |")


TABLE_HEADER = ("| model | k | PSNR (dB) | SSIM | G multiply-adds / frame | parameters | training time |\n"
                "|---|---|---|---|---|---|---|")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", type=Path, required=True, help="raypatch model file (.safetensors)")
    parser.add_argument("--scenes", type=Path, required=True, help="folder of scene-*.safetensors or shards")
    parser.add_argument("--name", help="model name in the table (default: the file name)")
    parser.add_argument("--limit", type=int, help="evaluate only the first N scenes")
    parser.add_argument("--batch", type=int, default=8, help="scenes rendered together")
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--ssim", choices=SSIM_DEFINITIONS, default=SSIM_DEFINITIONS[0],
                        help="SSIM definition (default: torchmetrics-1, as render-frame --metrics)")
    parser.add_argument("--json", type=Path, help="also write the results as JSON here")
    args = parser.parse_args(argv)
    try:
        model, model_cfg, metadata = load_model(args.model, args.device)
        images, camera_pos, seeds = load_views(args.scenes)
    except (ValueError, OSError, KeyError) as error:
        print(f"evaluate: error: {error}", file=sys.stderr)
        return 2
    if args.limit:
        images, camera_pos, seeds = images[:args.limit], camera_pos[:args.limit], seeds[:args.limit]
    start = time.perf_counter()
    psnr_value, ssim_value = evaluate(model, images, camera_pos, args.batch, args.device, args.ssim)
    seconds = time.perf_counter() - start
    height, width = images.shape[2:4]
    multiply_adds = multiply_adds_per_frame(model_cfg, height, width)
    parameters = sum(p.numel() for p in model.parameters())
    training = json.loads(metadata["training"]) if "training" in metadata else {}
    hours = training["train_seconds"] / 3600 if "train_seconds" in training else None
    name = args.name or args.model.stem
    print(f"{len(images)} scenes ({2 * len(images)} target views, {height}x{width}) from {args.scenes}, "
          f"seeds {seeds.min()}..{seeds.max()}, rendered in {seconds:.1f} s on {args.device}")
    print(TABLE_HEADER)
    print(table_row(name, model.patch_size, psnr_value, ssim_value, multiply_adds, parameters, hours))
    if args.json:
        args.json.write_text(json.dumps({
            "model": str(args.model), "name": name, "k": model.patch_size, "scenes": str(args.scenes),
            "scene_count": len(images), "psnr": psnr_value, "ssim": ssim_value, "ssim_definition": args.ssim,
            "multiply_adds": multiply_adds,
            "parameters": parameters, "training_hours": hours}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
