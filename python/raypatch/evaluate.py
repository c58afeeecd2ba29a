"""Evaluating and rendering scene files with one model, scene by scene: what `render-frame --metrics` computes,
as rows of a table. `raypatch.distributed` runs the same functions on Ray workers."""

from __future__ import annotations

import glob
import os
from pathlib import Path
from typing import List

from . import Engine, Error, InputError, Model, depth_errors, fg_ari, load_scene, psnr, ssim
from ._text import path_text
from .output import Staged

# Columns of the results table, in order; a family's metrics that do not apply are left out.
COLUMNS = ("scene", "view", "psnr", "ssim", "fg_ari", "abs_rel", "sq_rel", "rmse", "depth_pixels")


def scene_paths(scenes: str) -> List[str]:
    """Scene files and frames folders: a folder's `*.safetensors` files and subfolders holding transforms.json
    (or the folder itself when it holds one), or what a glob matches; sorted."""
    if os.path.isdir(scenes):
        if os.path.exists(os.path.join(scenes, "transforms.json")):
            return [scenes]
        entries = sorted(os.listdir(scenes))
        paths = [os.path.join(scenes, e) for e in entries if e.endswith(".safetensors")]
        paths += [os.path.join(scenes, e) for e in entries if os.path.exists(os.path.join(scenes, e, "transforms.json"))]
        found = sorted(paths)
    else:
        found = sorted(glob.glob(scenes))
    if not found:
        raise InputError(f"--scenes {path_text(scenes)}: no scene file (*.safetensors) or frames folder (transforms.json) there")
    return found


def scene_name(path: str) -> str:
    """The scene's name in results: the file's stem, or the frames folder's name."""
    return Path(path).stem if not os.path.isdir(path) else Path(path).name


def evaluate_scene(model: Model, path: str) -> List[dict]:
    """One row per target view: PSNR and SSIM against its ground-truth image, FG-ARI of an OSRT model's
    segmentation against `target_masks`, depth errors of a depth model against ground-truth depth; as
    `render-frame --scene PATH --view all --metrics` computes them (encode once, render every view)."""
    data = load_scene(path)
    views = range(data.target_count)
    outputs = ["rgb"]
    if "segmentation" in model.outputs and all(data.target_masks(v) is not None for v in views):
        outputs.append("segmentation")
    if "depth" in model.outputs and all(data.target_depth(v) is not None for v in views):
        outputs.append("depth")
    scene = model.encode_scene(data)
    rows = []
    for view in views:
        rendered = scene.render_view(view, outputs)
        row = {"scene": scene_name(path), "view": view}
        truth = data.target_image(view)
        if truth is not None:
            row["psnr"], row["ssim"] = psnr(rendered["rgb"], truth), ssim(rendered["rgb"], truth)
        if "segmentation" in rendered:
            row["fg_ari"] = fg_ari(data.target_masks(view), rendered["segmentation"])
        if "depth" in rendered:
            e = depth_errors(rendered["depth"], data.target_depth(view))
            row.update(abs_rel=e["abs_rel"], sq_rel=e["sq_rel"], rmse=e["rmse"], depth_pixels=e["pixels"])
        rows.append(row)
    return rows


def render_scene(model: Model, path: str, out: str) -> List[str]:
    """Renders every target view of a scene into `out/<scene>/view_000.png`, ..., all of them or, on an error,
    none (raypatch.output); returns the files written. `out` must exist."""
    data = load_scene(path)
    scene = model.encode_scene(data)
    folder = os.path.join(out, scene_name(path))
    files = [os.path.join(folder, f"view_{view:03}.png") for view in range(data.target_count)]
    with Staged.planned([("--out", f) for f in files], [("--out", folder)], [("--scenes", path)]) as staged:
        for view, file in enumerate(files):
            staged.write(file, scene.render_view(view).png())
        staged.commit()
    return files


def error_line(path: str, error: Exception) -> str:
    """One line naming the scene and what went wrong."""
    text = str(error).splitlines()[0] if str(error) else type(error).__name__
    return text if isinstance(error, Error) and path in text else f"{path}: {text}"


class SceneWorker:
    """A Ray actor (raypatch.distributed; here, in an importable module, so that Ray ships it by reference): the model loaded once, then every batch of scene paths evaluated or rendered with it. Errors
    come back as rows with an `error` column, so that the driver reports them all in one line each."""

    def __init__(self, model: str, task: str, out: str = "", adapter: str = None):
        self.engine = Engine(adapter)
        self.model = self.engine.load(model)
        self.task, self.out = task, out

    def __call__(self, batch: dict) -> dict:
        rows = []
        for path in batch["path"]:
            path = str(path)
            try:
                if self.task == "evaluate":
                    rows.extend(evaluate_scene(self.model, path))
                else:
                    rows.extend({"scene": path, "file": f} for f in render_scene(self.model, path, self.out))
            except Error as e:
                rows.append({"scene": path, "error": error_line(path, e), "error_class": type(e).__name__})
        columns = sorted({key for row in rows for key in row})
        return {key: [row.get(key, float("nan")) for row in rows] for key in columns}
