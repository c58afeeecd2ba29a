"""Trains SRT or RP-SRT (tools/reference/raypatch_reference.py, the official architecture) on scenes of
tools/data/make_scenes.py, as the official tberriel/RayPatchQuerying training does, and exports a raypatch model file.

    python3 tools/data/train.py --k 4 --train /work/data/train --val /work/data/val --out target/runs/rpsrt-k4 \\
        --steps 3000 --batch 16

What follows the official code (train.py, src/model.py, src/data/multishapenetEasy.py):
- every (scene, input view) pair once per epoch in a shuffled order, the other two views as targets;
- loss: MSE on RGB. SRT (k = 1) decodes --num-points rays sampled without replacement from the pooled pixels of
  both target views (official: 8192 of 2·120·160; the default keeps that fraction); RP-SRT decodes the whole patch
  grid (the official --full-scale) with patch rays made by the official bilinear resize;
- Adam, the official linear schedule: warmup from 0, then linear decay towards 0 at decay_it. The official run
  (2.5k warmup steps, decay_it 500k, 300k steps, ending at 0.4 of the peak rate) is scaled to --steps.
- BatchNorm in the encoder and the Ray-Patch decoder (the official "MDBN" runs).
Differences: widths (--preset; raypatch config extensions, docs/FORMATS.md) and 2 conv blocks for 60x80 inputs
(15x20 tokens, as the official 3 blocks give at 120x160; the engine takes any input size).

Per-scene fitting (--fit-scene): --train holds one views file of tools/data/make_scenes.py --extra-views (one scene, its
view 0 and many views from other cameras). Every step encodes view 0, the view the scene's own renders condition on,
and renders --targets-per-step of the other views (each once per epoch, shuffled). The model learns that one scene,
not scenes in general: its metadata says so. --watch DIR renders a folder of scenes (e.g. the scene's own file,
whose target views the views file leaves out) at every validation into curve.csv's heldout_psnr column; it plays no
part in training.

The run folder holds checkpoint.pt (written every --checkpoint-every steps; a run restarts from it), curve.csv
(step, training seconds, learning rate, mean training loss since the previous row, validation PSNR) and, at the end,
model.safetensors: the weights, the config and a `training` JSON record in the metadata.
"""

import argparse
import csv
import functools
import json
import math
import shlex
import sys
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tools/, whose packages this imports
from bench.evaluate import evaluate, scene_batch  # noqa: E402
from conversion.convert_checkpoint import inference_tensors, write_model  # noqa: E402
from data.make_scenes import load_views  # noqa: E402
from reference.raypatch_reference import SRT  # noqa: E402

# Official run: 300k steps, warmup 2.5k, decay_it 500k, lr 1e-4, batch 32, 8192 sampled rays of 2·120·160.
OFFICIAL_STEPS, OFFICIAL_WARMUP, OFFICIAL_DECAY_IT = 300_000, 2_500, 500_000
OFFICIAL_POINTS_FRACTION = 8192 / (2 * 120 * 160)

# Widths (raypatch config extensions). token_dim is the encoder token width and the decoder latent_dim. At 60x80:
# cpu 0.46-0.49 M parameters, gpu 2.2-2.3 M (all four gpu models together 35 MB, within the assets budget).
PRESETS = {
    "cpu": {"token_dim": 64, "heads": 4, "conv_hidden": 16, "encoder_layers": 3, "decoder_layers": 2,
            "input_mlp_hidden": 180, "out_mlp_hidden": 128, "conv_features": 64},
    # Per-scene fitting (--fit-scene): the cpu preset with a wider patch decoder.
    "fit": {"token_dim": 64, "heads": 4, "conv_hidden": 16, "encoder_layers": 3, "decoder_layers": 2,
            "input_mlp_hidden": 180, "out_mlp_hidden": 256, "conv_features": 128},
    "gpu": {"token_dim": 160, "heads": 5, "conv_hidden": 32, "encoder_layers": 5, "decoder_layers": 2,
            "input_mlp_hidden": 360, "out_mlp_hidden": 320, "conv_features": 128},
}
CURVE_FIELDS = ("step", "train_seconds", "lr", "loss", "val_psnr")
WATCH_FIELD = "heldout_psnr"  # curve.csv column of --watch


def model_config(k, preset, height, width, lr, warmup, decay_it):
    """A config.yaml model section: the official MSN-Easy structure (MDBN runs) at the preset's widths."""
    p = PRESETS[preset]
    # 60x80 inputs get 2 blocks: 15x20 tokens, the official 3 blocks' count at the paper's 120x160.
    conv_blocks = 3 if height % 8 == 0 and width % 8 == 0 else 2
    cfg = {
        "base": "srt",
        "encoder_kwargs": {"pos_start_octave": -5, "num_att_blocks": p["encoder_layers"],
                           "num_conv_blocks": conv_blocks, "norm": "Batch", "latent_dim": p["token_dim"],
                           "conv_hidden": p["conv_hidden"], "token_dim": p["token_dim"], "heads": p["heads"],
                           "dim_head": p["token_dim"] // p["heads"]},
        "decoder": "lightfield" if k == 1 else "featurefield",
        "decoder_kwargs": {"num_att_blocks": p["decoder_layers"], "pos_octaves": 15, "ray_octaves": 15,
                           "pos_start_octave": -5, "pos_end_octave": None, "ray_start_octave": 0,
                           "ray_end_octave": None, "latent_dim": p["token_dim"], "mode": "efficient",
                           "heads": p["heads"], "input_mlp_hidden": p["input_mlp_hidden"],
                           "out_mlp_hidden": p["out_mlp_hidden"]},
        "lr_config": "linear", "gamma": None, "lr": lr, "decay_it": decay_it, "lr_warmup": warmup,
    }
    if k == 1:
        cfg["decoder_kwargs"]["out_dims"] = 3
    else:
        cfg["rp_kwargs"] = {"upsample": int(math.log2(k)), "h_in": height // k, "w_in": width // k,
                            "conv_features": p["conv_features"], "norm": "Batch"}
        if height % k or width % k:
            # The official way to train a patch grid that does not tile the image: nearest resize of the output.
            cfg["rp_kwargs"].update(h_out=height, w_out=width)
    return cfg


def linear_schedule(optimizer, warmup, decay_it):
    """The official get_linear_schedule_with_warmup (gamma None)."""
    def factor(step):
        if step < warmup:
            return step / max(1, warmup)
        return max(0.0, (decay_it - step) / max(1, decay_it - warmup))
    return torch.optim.lr_scheduler.LambdaLR(optimizer, factor)


def training_loss(model, batch, num_points, rng):
    """MSE on RGB: sampled rays of the pooled target pixels for SRT, whole target views for RP-SRT."""
    z = model.encode(batch["input_images"], batch["input_camera_pos"], batch["input_rays"])
    if model.patch_size > 1:
        pred = model.render_views(z, batch["target_camera_pos"], batch["target_rays"])[0]
        return F.mse_loss(pred, batch["target_images"])
    b, t, h, w, _ = batch["target_rays"].shape
    chosen = torch.from_numpy(np.stack([rng.choice(t * h * w, num_points, replace=num_points > t * h * w)
                                        for _ in range(b)])).to(z.device)
    rays = batch["target_rays"].reshape(b, -1, 3)
    positions = batch["target_camera_pos"][:, :, None].expand(b, t, h * w, 3).reshape(b, -1, 3)
    pixels = batch["target_images"].reshape(b, -1, 3)

    def pick(x):
        return torch.gather(x, 1, chosen[..., None].expand(b, num_points, 3))

    pred, _ = model.decode(z, pick(positions), pick(rays))
    return F.mse_loss(pred, pick(pixels))


@functools.lru_cache(maxsize=1)
def epoch_order(seed, epoch, scenes, views):
    """(scene, input view) pairs of one epoch, shuffled; a pure function so that a resumed run continues it."""
    order = np.random.default_rng([seed, epoch]).permutation(scenes * views)
    return order // views, order % views


@functools.lru_cache(maxsize=1)
def fit_order(seed, epoch, views):
    """Target views 1..views-1 of one epoch of per-scene fitting, shuffled; a pure function like epoch_order."""
    return np.random.default_rng([seed, epoch]).permutation(views - 1) + 1


def fit_batch(images, camera_pos, targets, device):
    """One step of per-scene fitting: input view 0 of the single scene, the given views as targets."""
    views = [0] + [int(t) for t in targets]
    return scene_batch(images[:1, views], camera_pos[:1, views], [0], [0], device)


def write_curve(path, rows):
    fields = CURVE_FIELDS + ((WATCH_FIELD,) if any(WATCH_FIELD in row for row in rows) else ())
    with open(path, "w", newline="") as file:
        writer = csv.DictWriter(file, fields)
        writer.writeheader()
        writer.writerows(rows)


def save_checkpoint(path, state):
    temporary = path.with_suffix(".tmp")
    torch.save(state, temporary)
    temporary.replace(path)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--k", type=int, choices=(1, 2, 4, 8, 16), required=True,
                        help="patch size: 1 = SRT (pixel queries), else RP-SRT")
    parser.add_argument("--train", type=Path, required=True, help="training scenes (shards or scene files)")
    parser.add_argument("--val", type=Path, required=True, help="validation scenes")
    parser.add_argument("--out", type=Path, required=True, help="run folder (created; an existing run resumes)")
    parser.add_argument("--steps", type=int, required=True, help="optimizer steps")
    parser.add_argument("--batch", type=int, help="scenes per step (official: 32; default 16, 1 with --fit-scene)")
    parser.add_argument("--fit-scene", action="store_true",
                        help="per-scene fitting: --train is one views file (make_scenes.py --extra-views); input "
                             "view 0, --targets-per-step of its other views as targets")
    parser.add_argument("--targets-per-step", type=int, default=8, help="target views per step with --fit-scene")
    parser.add_argument("--watch", type=Path,
                        help="scenes rendered at every validation into curve.csv's heldout_psnr (not trained on)")
    parser.add_argument("--preset", choices=sorted(PRESETS), default="cpu", help="model widths")
    parser.add_argument("--lr", type=float, default=1e-4, help="peak learning rate (official: 1e-4)")
    parser.add_argument("--warmup", type=int, help="warmup steps (default: the official fraction of --steps)")
    parser.add_argument("--decay-it", type=int, help="step where the rate would reach 0 (default: scaled)")
    parser.add_argument("--num-points", type=int, help="SRT rays per scene and step (default: official fraction)")
    parser.add_argument("--val-scenes", type=int, default=32, help="validation scenes used (first N)")
    parser.add_argument("--val-every", type=int, default=500, help="steps between validations")
    parser.add_argument("--log-every", type=int, default=50, help="steps between curve rows")
    parser.add_argument("--checkpoint-every", type=int, default=500, help="steps between checkpoints")
    parser.add_argument("--seed", type=int, default=0, help="weights, data order and ray sampling")
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--threads", type=int, default=2, help="CPU threads for PyTorch")
    args = parser.parse_args(argv)
    command = "python3 tools/data/train.py " + " ".join(shlex.quote(a) for a in (argv or sys.argv[1:]))

    torch.set_num_threads(args.threads)
    if args.batch is None:
        args.batch = 1 if args.fit_scene else 16
    try:
        train_images, train_pos, train_seeds = load_views(args.train)
        val_images, val_pos, val_seeds = load_views(args.val)
        watch = load_views(args.watch) if args.watch else None
        if args.steps < 1 or args.batch < 1 or args.batch > len(train_images) * train_images.shape[1]:
            raise ValueError(f"--steps must be >= 1 and --batch between 1 and the {len(train_images)} scenes' "
                             f"{len(train_images) * train_images.shape[1]} (scene, view) pairs")
        if args.fit_scene:
            if len(train_images) != 1 or args.batch != 1:
                raise ValueError(f"--fit-scene needs one scene in --train ({len(train_images)} found) and --batch 1")
            if not 1 <= args.targets_per_step <= train_images.shape[1] - 1:
                raise ValueError(f"--targets-per-step must be between 1 and the {train_images.shape[1] - 1} views "
                                 f"other than view 0")
            if args.watch and any(int(seed) != int(train_seeds[0]) for seed in watch[2]):
                raise ValueError(f"--watch holds seeds {watch[2].tolist()}, not only the fitted {train_seeds[0]}")
        for name, other in (("validation", val_images), ("--watch", watch[0] if watch else None)):
            if other is not None and other.shape[2:] != train_images.shape[2:]:
                raise ValueError(f"training views {train_images.shape[2:4]} and {name} views {other.shape[2:4]} "
                                 f"differ in size")
        if not args.fit_scene and train_images.shape[1:] != val_images.shape[1:]:
            raise ValueError(f"training views {train_images.shape[1:4]} and validation views "
                             f"{val_images.shape[1:4]} differ in count or size")
        height, width = train_images.shape[2:4]
        warmup = args.warmup if args.warmup is not None else round(args.steps * OFFICIAL_WARMUP / OFFICIAL_STEPS)
        decay_it = args.decay_it or round(args.steps * OFFICIAL_DECAY_IT / OFFICIAL_STEPS)
        model_cfg = model_config(args.k, args.preset, height, width, args.lr, warmup, decay_it)
        args.out.mkdir(parents=True, exist_ok=True)
    except (ValueError, OSError, KeyError) as error:
        print(f"train: error: {error}", file=sys.stderr)
        return 2
    views = train_images.shape[1]
    targets = args.targets_per_step if args.fit_scene else views - 1
    num_points = args.num_points or round(OFFICIAL_POINTS_FRACTION * targets * height * width)
    val_images, val_pos = val_images[:args.val_scenes], val_pos[:args.val_scenes]

    torch.manual_seed(args.seed)
    model = SRT.from_config(model_cfg).to(args.device)
    optimizer = torch.optim.Adam(model.parameters(), lr=args.lr)
    scheduler = linear_schedule(optimizer, warmup, decay_it)
    checkpoint_path = args.out / "checkpoint.pt"
    step, train_seconds, curve = 0, 0.0, []
    if checkpoint_path.exists():
        state = torch.load(checkpoint_path, map_location=args.device, weights_only=True)  # plain types only
        if state["config"] != model_cfg:
            print(f"train: error: {checkpoint_path} was trained with another config; use another --out",
                  file=sys.stderr)
            return 2
        model.load_state_dict(state["model"])
        optimizer.load_state_dict(state["optimizer"])
        scheduler.load_state_dict(state["scheduler"])
        step, train_seconds, curve = state["step"], state["train_seconds"], state["curve"]
        print(f"resuming {checkpoint_path} at step {step}")

    def checkpoint():
        save_checkpoint(checkpoint_path, {"model": model.state_dict(), "optimizer": optimizer.state_dict(),
                                          "scheduler": scheduler.state_dict(), "step": step,
                                          "train_seconds": train_seconds, "curve": curve, "config": model_cfg})

    def validate(images, camera_pos):
        model.eval()
        value, _ = evaluate(model, images, camera_pos, device=args.device, ssim_definition=None)
        model.train()
        return value

    parameters = sum(p.numel() for p in model.parameters())
    print(f"k={args.k} preset {args.preset}: {parameters / 1e6:.3f} M parameters; {len(train_images)} training "
          f"scenes, {len(val_images)} validation scenes, {height}x{width}; batch {args.batch}, {args.steps} steps, "
          f"lr {args.lr} (warmup {warmup}, decay_it {decay_it})" + (f", {num_points} rays" if args.k == 1 else "")
          + f" on {args.device}")
    if args.fit_scene:
        print(f"fitting scene {train_seeds[0]}: input view 0, {views - 1} other views, {args.targets_per_step} "
              f"targets per step" + (f"; watching {args.watch} (not trained on)" if args.watch else ""))
    batches_per_epoch = (views - 1) // args.targets_per_step if args.fit_scene else len(train_images) * views // args.batch
    model.train()
    losses = []
    cpu_seconds = 0.0  # this session's process CPU time in steps: less sensitive to other load than wall time
    steps_this_session = 0
    while step < args.steps:
        start, cpu_start = time.perf_counter(), time.process_time()
        epoch, position = divmod(step, batches_per_epoch)
        if args.fit_scene:
            order = fit_order(args.seed, epoch, views)
            chosen = order[position * args.targets_per_step:(position + 1) * args.targets_per_step]
            batch = fit_batch(train_images, train_pos, chosen, args.device)
        else:
            scenes, input_views = epoch_order(args.seed, epoch, len(train_images), views)
            chosen = slice(position * args.batch, (position + 1) * args.batch)
            batch = scene_batch(train_images, train_pos, scenes[chosen], input_views[chosen], args.device)
        loss = training_loss(model, batch, num_points, np.random.default_rng([args.seed, step]))
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        lr = optimizer.param_groups[0]["lr"]
        optimizer.step()
        scheduler.step()
        if args.device.startswith("cuda"):
            torch.cuda.synchronize()
        train_seconds += time.perf_counter() - start
        cpu_seconds += time.process_time() - cpu_start
        losses.append(loss.item())
        step += 1
        steps_this_session += 1
        if step % args.log_every == 0 or step % args.val_every == 0 or step == args.steps:
            validating = step % args.val_every == 0 or step == args.steps
            val_psnr = validate(val_images, val_pos) if validating else None
            curve.append({"step": step, "train_seconds": round(train_seconds, 2), "lr": lr,
                          "loss": float(np.mean(losses)), "val_psnr": val_psnr})
            if watch is not None:
                curve[-1][WATCH_FIELD] = validate(watch[0], watch[1]) if validating else None
            losses = []
            write_curve(args.out / "curve.csv", curve)
            print(f"step {step}: loss {curve[-1]['loss']:.5f}, lr {lr:.2e}, {train_seconds:.0f} s, "
                  f"{step / max(train_seconds, 1e-9):.2f} steps/s, {cpu_seconds / steps_this_session:.2f} CPU s/step"
                  + (f", val PSNR {val_psnr:.2f} dB" if val_psnr is not None else "")
                  + (f", held-out PSNR {curve[-1][WATCH_FIELD]:.2f} dB" if curve[-1].get(WATCH_FIELD) else ""),
                  flush=True)
        if step % args.checkpoint_every == 0 or step == args.steps:
            checkpoint()

    # The curve of the steps the model has seen (a run resumed to a checkpoint's own step rewrites it to that).
    write_curve(args.out / "curve.csv", curve)
    validated = [row for row in curve if row["val_psnr"] is not None]
    record = {
        "generator": command, "k": args.k, "preset": args.preset, "steps": step, "batch_size": args.batch,
        "optimizer": "Adam", "lr": args.lr, "lr_warmup": warmup, "decay_it": decay_it, "loss": "MSE on RGB",
        "rays_per_scene": num_points if args.k == 1 else "all patches", "train_scenes": len(train_images),
        "train_seeds": [int(train_seeds.min()), int(train_seeds.max())], "val_scenes": len(val_images),
        "val_seeds": [int(val_seeds.min()), int(val_seeds[:args.val_scenes].max())], "size": [height, width],
        "train_seconds": round(train_seconds, 1), "device": args.device, "threads": args.threads,
        "seed": args.seed, "final_val_psnr": validated[-1]["val_psnr"] if validated else None,
        "curve": [[row["step"], row["train_seconds"], round(row["loss"], 6), round(row["val_psnr"], 3)]
                  for row in validated],
    }
    if args.fit_scene:
        record.update({
            "fitted_to_scene": int(train_seeds[0]),
            "note": f"fitted to the one scene {int(train_seeds[0])} (per-scene fitting, like per-scene light-field "
                    f"methods): it renders that scene from new cameras and does not generalise to other scenes",
            "input_view": "view 0 of the scene", "train_views": views - 1,
            "targets_per_step": args.targets_per_step, "rays_per_scene": num_points if args.k == 1 else "all patches",
            "train_scenes": 1})
    if watch is not None:
        record["heldout"] = {"scenes": str(args.watch), "seeds": sorted({int(s) for s in watch[2]}),
                             "curve": [[row["step"], round(row[WATCH_FIELD], 3)] for row in validated]}
    model_path = args.out / "model.safetensors"
    source = f"trained by tools/data/train.py (run {args.out.name})"
    if args.fit_scene:
        source = f"fitted to scene {int(train_seeds[0])} only by tools/data/train.py --fit-scene (run {args.out.name})"
    write_model(model_path, inference_tensors(model.state_dict()), model_cfg,
                {"source": source, "training": json.dumps(record)})
    print(f"wrote {model_path} ({parameters / 1e6:.3f} M parameters, final validation PSNR "
          f"{record['final_val_psnr']:.2f} dB, {train_seconds / 60:.1f} min of training)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
