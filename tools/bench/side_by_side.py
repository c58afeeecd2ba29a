"""A labelled side-by-side PNG of scenes' target views: input view | ground truth | one column per model, each
model's views rendered by the engine (render-frame) and captioned with its PSNR and SSIM.

    python3 tools/bench/side_by_side.py --scene assets/scenes/scene-2000000.safetensors \\
        --model "fitted to this scene (RP-SRT k=4)=assets/models/fitted_scene-2000000_rpsrt_k4.safetensors" \\
        --model "generalising RP-SRT k=4=assets/models/rpsrt_k4.safetensors" --out docs/quality/fitted_side_by_side.png

--render-frame is the binary (default target/release/render-frame, built by cargo build --release). Rows are the
target views of each --scene in turn (with --first-view-only, target view 0 of each); the metrics are those
render-frame --metrics prints (PSNR with data range 1, SSIM as torchmetrics 1.x), recomputed here from the written
8-bit PNGs with tools/bench/evaluate.py (equal to 0.01 dB).
"""

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch
from PIL import Image, ImageDraw, ImageFont
from safetensors.numpy import load_file

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tools/, whose packages this imports
from bench.evaluate import psnr, ssim  # noqa: E402

GAP = 6
BACKGROUND = (255, 255, 255)
TEXT = (20, 20, 20)


def font(size):
    for name in ("DejaVuSans.ttf", "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf"):
        try:
            return ImageFont.truetype(name, size)
        except OSError:
            continue
    return ImageFont.load_default()


def render(binary, model, scene, folder):
    """The engine's renders of all target views of scene with model: uint8 [T, H, W, 3]."""
    folder.mkdir(parents=True)
    command = [str(binary), "--model", str(model), "--scene", str(scene), "--view", "all", "--out", f"{folder}/"]
    result = subprocess.run(command, capture_output=True, text=True)
    if result.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed:\n{result.stderr}")
    paths = sorted(folder.glob("*.png"))
    return np.stack([np.asarray(Image.open(p).convert("RGB")) for p in paths])


def metrics(pred, target):
    """Per-view PSNR and SSIM of uint8 renders against float targets in [0, 1]."""
    p = torch.from_numpy(pred).double() / 255
    t = torch.from_numpy(target).double()
    return psnr(p, t).numpy(), ssim(p, t).numpy()


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", type=Path, action="append", required=True,
                        help="scene file with target images (repeatable: the rows of each in turn)")
    parser.add_argument("--first-view-only", action="store_true", help="only target view 0 of each scene")
    parser.add_argument("--model", action="append", required=True, help="LABEL=MODEL.safetensors (repeatable)")
    parser.add_argument("--out", type=Path, required=True, help="PNG to write")
    parser.add_argument("--scale", type=int, default=4, help="pixels per image pixel (nearest, default 4)")
    parser.add_argument("--render-frame", type=Path, default=Path("target/release/render-frame"))
    args = parser.parse_args(argv)
    # One entry per row: the input view (on a scene's first row only), the ground truth and its caption, and
    # per model (render, PSNR, SSIM).
    rows = []
    try:
        models = []
        for spec in args.model:
            label, sep, path = spec.rpartition("=")
            if not sep:
                raise ValueError(f"--model {spec!r}: expected LABEL=MODEL.safetensors")
            models.append((label, path))
        with tempfile.TemporaryDirectory() as folder:
            for s, scene in enumerate(args.scene):
                tensors = load_file(scene)
                targets = tensors["target_images"]
                if rows and targets.shape[1:] != rows[0]["truth"].shape[:2] + (3,):
                    raise ValueError(f"{scene}: target views {targets.shape[1:3]}, but the first --scene's are "
                                     f"{rows[0]['truth'].shape[:2]} (one picture needs one size)")
                input_view = np.round(tensors["input_images"][0] * 255).astype(np.uint8)
                renders = []
                for m, (_, path) in enumerate(models):
                    views = render(args.render_frame, path, scene, Path(folder) / f"{s}-{m}")
                    renders.append((views, *metrics(views, targets)))
                for v in range(1 if args.first_view_only else len(targets)):
                    caption = f"target view {v}" if len(args.scene) == 1 else f"{scene.stem}, view {v}"
                    rows.append({"input": input_view if v == 0 else None,
                                 "truth": np.round(targets[v] * 255).astype(np.uint8), "caption": caption,
                                 "models": [(views[v], p[v], q[v]) for views, p, q in renders]})
    except (ValueError, OSError, KeyError, RuntimeError) as error:
        print(f"side_by_side: error: {error}", file=sys.stderr)
        return 2

    height, width = rows[0]["truth"].shape[0] * args.scale, rows[0]["truth"].shape[1] * args.scale
    labels = ["input view 0", "ground truth"] + [label for label, _ in models]
    title_font, caption_font = font(15), font(13)
    column_width = max(width, 40 + max(int(title_font.getlength(label)) for label in labels) // 2)
    header, caption = 44, 20
    canvas = Image.new("RGB", (len(labels) * (column_width + GAP) + GAP,
                               header + len(rows) * (height + caption + GAP) + GAP), BACKGROUND)
    draw = ImageDraw.Draw(canvas)
    for c, label in enumerate(labels):
        x = GAP + c * (column_width + GAP)
        words, lines = label.split(), [""]
        for word in words:  # wrap the label onto at most two lines of the column's width
            trial = (lines[-1] + " " + word).strip()
            if title_font.getlength(trial) <= column_width or not lines[-1]:
                lines[-1] = trial
            else:
                lines.append(word)
        for n, line in enumerate(lines[:2]):
            draw.text((x + (column_width - title_font.getlength(line)) / 2, 4 + 18 * n), line, fill=TEXT,
                      font=title_font)
        for r, row in enumerate(rows):
            y = header + r * (height + caption + GAP)
            if c == 0:
                view, text = row["input"], ""
            elif c == 1:
                view, text = row["truth"], row["caption"]
            else:
                view, psnr_value, ssim_value = row["models"][c - 2]
                text = f"{psnr_value:.2f} dB, SSIM {ssim_value:.3f}"
            if view is None:
                continue
            image = Image.fromarray(view).resize((width, height), Image.NEAREST)
            canvas.paste(image, (x + (column_width - width) // 2, y))
            draw.text((x + (column_width - caption_font.getlength(text)) / 2, y + height + 3), text, fill=TEXT,
                      font=caption_font)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    canvas.save(args.out)
    for m, (label, _) in enumerate(models):
        values = np.array([(row["models"][m][1], row["models"][m][2]) for row in rows])
        print(f"{label}: PSNR {', '.join(f'{v:.2f}' for v in values[:, 0])} dB (mean {values[:, 0].mean():.2f}), "
              f"SSIM {', '.join(f'{v:.3f}' for v in values[:, 1])} (mean {values[:, 1].mean():.3f})")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
