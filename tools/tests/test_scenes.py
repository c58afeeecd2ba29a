"""Checks of the scene generator, the metrics and the training loop.

    python3 -m pytest tools/tests/test_scenes.py     (10 to 35 s; unittest classes, run by pytest)

Geometry is checked against signed distance functions written independently of the ray-shape intersections.
"""

import json
import tempfile
import unittest
from pathlib import Path

import numpy as np
import torch
from safetensors import safe_open
from safetensors.numpy import load_file

from bench import evaluate
from data import make_scenes, train
from reference.cameras import get_camera_rays

ROOT = Path(__file__).resolve().parents[2]  # the repository


def signed_distance(kind, p, size):
    """Signed distance (exact or a bound with the right sign and zero set) to a shape in its local frame."""
    x, y, z = p
    if kind == "sphere":
        return np.sqrt(x * x + y * y + z * z) - size[0]
    if kind == "box":
        q = np.abs(np.stack(p)) - np.asarray(size)[:, None]
        return np.linalg.norm(np.maximum(q, 0), axis=0) + np.minimum(q.max(0), 0)
    if kind == "cylinder":
        radial, axial = np.hypot(x, y) - size[0], np.abs(z) - size[1]
        return np.hypot(np.maximum(radial, 0), np.maximum(axial, 0)) + np.minimum(np.maximum(radial, axial), 0)
    if kind == "cone":
        r, h = size[0], size[1]
        # Side plane distance of the (rho, z) half-plane section, then the base plane.
        side = (np.hypot(x, y) - r * (h - z) / (2 * h)) * (2 * h) / np.hypot(2 * h, r)
        return np.maximum(side, -z - h)
    if kind == "capsule":
        return np.sqrt((x - np.clip(x, -size[1], size[1])) ** 2 + y * y + z * z) - size[0]
    raise ValueError(kind)


def distances_to_objects(spec, points):
    """[objects, n] signed distances of world points [n, 3] to every object of the scene."""
    out = []
    for kind, centre, yaw, size in zip(spec.kinds, spec.centres, spec.yaws, spec.sizes):
        p = points - centre
        c, s = np.cos(yaw), np.sin(yaw)
        local = (c * p[:, 0] + s * p[:, 1], c * p[:, 1] - s * p[:, 0], p[:, 2])
        out.append(signed_distance(make_scenes.KINDS[kind], local, size))
    return np.stack(out)


class SceneTests(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.seeds = list(range(40, 52))  # covers every shape kind and material
        cls.specs = [make_scenes.sample_scene(seed) for seed in cls.seeds]
        cls.height, cls.width = 30, 40
        cls.rendered = make_scenes.render(cls.specs, cls.height, cls.width)

    def test_scenes_cover_every_kind_and_material(self):
        self.assertEqual({k for s in self.specs for k in s.kinds}, set(range(len(make_scenes.KINDS))))
        self.assertEqual({m for s in self.specs for m in s.materials}, set(range(len(make_scenes.MATERIALS))))
        self.assertTrue(all(2 <= len(s.kinds) <= 4 for s in self.specs))

    def test_same_bytes_alone_or_in_a_batch(self):
        alone = make_scenes.render([make_scenes.sample_scene(self.seeds[5])], self.height, self.width)
        for batched, single in zip(self.rendered, alone):
            np.testing.assert_array_equal(batched[5], single[0])

    def test_depth_and_masks_lie_on_the_surfaces_that_are_hit_first(self):
        _, depth, masks, camera_pos = self.rendered
        for b, spec in enumerate(self.specs):
            for v in range(make_scenes.VIEWS):
                rays = get_camera_rays(camera_pos[b, v], self.width, self.height).reshape(-1, 3).astype(np.float64)
                t = depth[b, v].reshape(-1).astype(np.float64)
                mask = masks[b, v].reshape(-1)
                self.assertTrue((t > 0).all())  # the floor fills every view
                points = camera_pos[b, v] + t[:, None] * rays
                distances = distances_to_objects(spec, points)
                on_object = mask > 0
                hit = distances[mask[on_object] - 1, np.flatnonzero(on_object)]
                self.assertLess(np.abs(hit).max(), 2e-3)
                self.assertLess(np.abs(points[~on_object, 2]).max(), 2e-3)  # floor pixels are at z = 0
                self.assertGreater(distances[:, ~on_object].min(), -2e-3)  # and not inside an object
                for fraction in (0.3, 0.6, 0.9, 0.99):  # nothing is crossed before the hit
                    before = camera_pos[b, v] + (fraction * t)[:, None] * rays
                    self.assertGreater(distances_to_objects(spec, before).min(), -2e-3)
                    self.assertTrue((before[:, 2] > -2e-3).all())

    def test_images_are_shaded_and_objects_cast_shadows(self):
        images, _, masks, _ = self.rendered
        floor = images[masks == 0].astype(float).mean(-1)
        self.assertGreater(floor.std(), 3)  # light falloff and shadows
        for b, spec in enumerate(self.specs):
            # Floor points whose path to the light crosses an object get no direct light: darker than the
            # floor points next to them in the image.
            objects = make_scenes.ObjectTable([spec])
            _, depth, _, camera_pos = (x[b:b + 1] for x in self.rendered)
            rays = get_camera_rays(camera_pos[0, 0], self.width, self.height).reshape(-1, 3)
            points = camera_pos[0, 0] + depth[0, 0].reshape(-1, 1) * rays
            floor_pixels = masks[b, 0].reshape(-1) == 0
            to_light = spec.light_pos - points
            length = np.linalg.norm(to_light, axis=1, keepdims=True)
            starts = (points + 1e-3 * np.array((0, 0, 1))).T[:, None].astype(np.float32)
            blocked = make_scenes.trace_objects(objects, starts, (to_light / length).T[:, None].astype(np.float32))
            shadowed = (blocked[0].min(0) < length[:, 0]) & floor_pixels
            lit = ~shadowed & floor_pixels
            if shadowed.sum() > 5:
                brightness = images[b, 0].reshape(-1, 3).astype(float).mean(1)
                self.assertLess(brightness[shadowed].mean(), brightness[lit].mean() - 10)

    def test_files(self):
        with tempfile.TemporaryDirectory() as folder:
            folder = Path(folder)
            seed = make_scenes.SPLITS["test"][0]
            argv = ["--split", "test", "--count", "3", "--size", "20x24"]
            self.assertEqual(make_scenes.main(argv + ["--out", str(folder / "scenes")]), 0)
            self.assertEqual(make_scenes.main(argv + ["--out", str(folder / "shards"), "--shard-size", "2"]), 0)
            path = folder / "scenes" / f"scene-{seed:07d}.safetensors"
            tensors = load_file(path)
            with safe_open(path, "np") as file:
                metadata = file.metadata()
            self.assertEqual((metadata["format"], metadata["seed"], metadata["split"]),
                             ("raypatch-scene/1", str(seed), "test"))
            self.assertEqual(len(json.loads(metadata["scene"])["objects"]), len(make_scenes.sample_scene(seed).kinds))
            shapes = {name: (t.shape, t.dtype) for name, t in tensors.items()}
            self.assertEqual(shapes, {
                "input_images": ((1, 20, 24, 3), np.float32), "input_camera_pos": ((1, 3), np.float32),
                "input_rays": ((1, 20, 24, 3), np.float32), "input_depth": ((1, 20, 24), np.float32),
                "input_masks": ((1, 20, 24), np.uint8), "target_images": ((2, 20, 24, 3), np.float32),
                "target_camera_pos": ((2, 3), np.float32), "target_rays": ((2, 20, 24, 3), np.float32),
                "target_depth": ((2, 20, 24), np.float32), "target_masks": ((2, 20, 24), np.uint8)})
            np.testing.assert_array_equal(tensors["target_rays"][1],
                                          get_camera_rays(tensors["target_camera_pos"][1], 24, 20))
            self.assertTrue(((tensors["target_images"] >= 0) & (tensors["target_images"] <= 1)).all())
            self.assertTrue(sorted(p.name for p in (folder / "shards").iterdir() if p.suffix != ".png")
                            == ["shard-00000.safetensors", "shard-00001.safetensors"])
            from_scenes, from_shards = (make_scenes.load_views(folder / name) for name in ("scenes", "shards"))
            for a, b in zip(from_scenes, from_shards):
                np.testing.assert_array_equal(a, b)
            np.testing.assert_array_equal(from_scenes[2], seed + np.arange(3))
            self.assertTrue((folder / "scenes" / f"scene-{seed:07d}.png").read_bytes().startswith(b"\x89PNG"))

    def test_bundled_scenes_are_what_the_generator_renders(self):
        """Extending the generator must not change a scene: the bundled files' tensors are regenerated exactly."""
        bundled = sorted((ROOT / "assets" / "scenes").glob("scene-*.safetensors"))
        self.assertTrue(bundled)
        for path in bundled:
            with safe_open(path, "np") as file:
                metadata = file.metadata()
            spec = make_scenes.sample_scene(int(metadata["seed"]))
            self.assertEqual(json.loads(metadata["scene"]), json.loads(json.dumps(spec.describe())))
            stored = load_file(path)
            images, depth, masks, camera_pos = (x[0] for x in make_scenes.render([spec], 60, 80))
            fresh = make_scenes.scene_tensors(images, depth, masks, camera_pos, 60, 80)
            self.assertEqual(set(fresh), set(stored))
            for name, tensor in fresh.items():
                np.testing.assert_array_equal(tensor.numpy(), stored[name], err_msg=f"{path.name} {name}")

    def test_extra_views_of_one_scene(self):
        seed = make_scenes.SPLITS["test"][0] + 3
        spec = make_scenes.sample_scene(seed)
        with tempfile.TemporaryDirectory() as folder:
            folder = Path(folder)
            common = ["--seed", str(seed), "--count", "1", "--size", "20x24", "--pngs", "1"]
            self.assertEqual(make_scenes.main(common + ["--extra-views", "4", "--camera-seed", "1", "--exclude-deg",
                                                        "8", "--out", str(folder / "val")]), 0)
            val_file = folder / "val" / f"views-{seed:07d}.safetensors"
            argv = common + ["--extra-views", "50", "--exclude-deg", "8", "--exclude-cameras", str(val_file)]
            self.assertEqual(make_scenes.main(argv + ["--out", str(folder / "a")]), 0)
            self.assertEqual(make_scenes.main(argv + ["--out", str(folder / "b")]), 0)
            path = folder / "a" / f"views-{seed:07d}.safetensors"
            again = load_file(folder / "b" / path.name)
            for name, tensor in load_file(path).items():  # deterministic
                np.testing.assert_array_equal(tensor, again[name])
            self.assertTrue((folder / "a" / f"views-{seed:07d}.png").read_bytes().startswith(b"\x89PNG"))
            with safe_open(path, "np") as file:
                metadata = file.metadata()
            self.assertEqual((metadata["format"], metadata["seed"], metadata["views"]), ("raypatch-views/1", str(seed),
                                                                                         "51"))
            images, camera_pos, seeds = make_scenes.load_views(folder / "a")
            self.assertEqual((images.shape, camera_pos.shape, seeds.tolist()), ((1, 51, 20, 24, 3), (1, 51, 3), [seed]))
            # View 0 is the scene's own view 0, pixel for pixel; the others are the scene from other cameras.
            scene_images, _, _, scene_pos = make_scenes.render([spec], 20, 24)
            np.testing.assert_array_equal(images[0, 0], scene_images[0, 0])
            np.testing.assert_array_equal(camera_pos[0, 0], scene_pos[0, 0])
            alone = make_scenes.render([make_scenes.replace(spec, camera_pos=camera_pos[0, 7:8])], 20, 24)[0]
            np.testing.assert_array_equal(images[0, 7], alone[0, 0])
            # Extra cameras keep away from the held-out targets (views 1, 2) and the validation cameras, and
            # follow the scenes' camera distribution.
            extra = camera_pos[0, 1:].astype(np.float64)
            held_out = np.concatenate((scene_pos[0, 1:], load_file(val_file)["camera_pos"][0, 1:]))
            self.assertGreater(make_scenes.angle_between_deg(extra, held_out).min(), 8)
            radius = np.linalg.norm(extra, axis=1)
            elevation = np.degrees(np.arcsin(extra[:, 2] / radius))
            self.assertTrue(((radius > 9.5 - 1e-4) & (radius < 11.5 + 1e-4)).all())
            self.assertTrue(((elevation > 28 - 1e-3) & (elevation < 42 + 1e-3)).all())
            azimuth = np.degrees(np.arctan2(extra[:, 1], extra[:, 0])) % 360
            self.assertEqual(len(np.unique(azimuth // 90)), 4)  # all round the circle
            cameras = json.loads(metadata["cameras"])
            self.assertEqual(cameras["excluded_scene_views"], [1, 2])
            self.assertGreater(min(cameras["nearest_extra_to_excluded_deg"]), 8)
            self.assertEqual(make_scenes.main(common + ["--extra-views", "3", "--exclude-deg", "0", "--out",
                                                        str(folder / "c")]), 2)

    def test_splits_are_disjoint_and_enforced(self):
        ranges = sorted(make_scenes.SPLITS.values())
        self.assertTrue(all(a[1] <= b[0] for a, b in zip(ranges, ranges[1:])))
        end = make_scenes.SPLITS["val"][1]
        with tempfile.TemporaryDirectory() as folder:
            for argv in (["--seed", str(end - 1), "--count", "2"], ["--split", "test", "--seed", "0", "--count", "1"],
                         ["--seed", str(end), "--count", "1"], ["--count", "0"]):
                self.assertEqual(make_scenes.main(argv + ["--out", folder]), 2, argv)
            with self.assertRaises(SystemExit):
                make_scenes.main(["--count", "1", "--size", "0x4", "--out", folder])
            self.assertEqual(list(Path(folder).iterdir()), [])


def naive_ssim(pred, target, border):
    """SSIM of [H, W, C] float64 images, written from the definition: Gaussian 11x11 window, sigma 1.5, reflect
    padding, the mean over all pixels or over those at least 5 pixels from the border."""
    offsets = np.arange(11) - 5
    window = np.exp(-(offsets / 1.5) ** 2 / 2)
    window = (np.outer(window, window) / window.sum() ** 2)[..., None]
    height, width, _ = pred.shape
    padded = [np.pad(x, ((5, 5), (5, 5), (0, 0)), mode="reflect") for x in (pred, target)]
    skip = 5 if border else 0
    values = []
    for i in range(skip, height - skip):
        for j in range(skip, width - skip):
            a, b = (x[i:i + 11, j:j + 11] for x in padded)
            mu_a, mu_b = (window * a).sum((0, 1)), (window * b).sum((0, 1))
            var_a, var_b = (window * a * a).sum((0, 1)) - mu_a ** 2, (window * b * b).sum((0, 1)) - mu_b ** 2
            cov = (window * a * b).sum((0, 1)) - mu_a * mu_b
            c1, c2 = 0.01 ** 2, 0.03 ** 2
            values.append((2 * mu_a * mu_b + c1) * (2 * cov + c2)
                          / ((mu_a ** 2 + mu_b ** 2 + c1) * (var_a + var_b + c2)))
    return np.mean(values)


class MetricTests(unittest.TestCase):
    def test_ssim_and_psnr_match_their_definitions(self):
        rng = np.random.default_rng(3)
        target = rng.uniform(size=(2, 24, 30, 3))
        pred = np.clip(target * 0.8 + 0.2 * rng.uniform(size=target.shape), 0, 1)
        for definition, border in (("torchmetrics-1", False), ("torchmetrics-0.9.3", True)):
            ssim = evaluate.ssim(torch.from_numpy(pred), torch.from_numpy(target), definition).numpy()
            np.testing.assert_allclose(ssim, [naive_ssim(p, t, border) for p, t in zip(pred, target)], atol=1e-10)
            same = evaluate.ssim(torch.from_numpy(target), torch.from_numpy(target), definition)
            np.testing.assert_allclose(same.numpy(), 1, atol=1e-12)
        psnr = evaluate.psnr(torch.from_numpy(pred), torch.from_numpy(target)).numpy()
        np.testing.assert_allclose(psnr, -10 * np.log10(((pred - target) ** 2).mean((1, 2, 3))), rtol=1e-12)

    def test_metrics_equal_torchmetrics(self):
        """Runs where torchmetrics can be imported (see tools/README.md): 0.9.3 (the official code's) or 1.x."""
        try:
            import torchmetrics
            from torchmetrics.image import PeakSignalNoiseRatio, StructuralSimilarityIndexMeasure
        except ImportError:
            self.skipTest("torchmetrics is not installed")
        definition = "torchmetrics-0.9.3" if torchmetrics.__version__ == "0.9.3" else "torchmetrics-1"
        if definition == "torchmetrics-1" and not torchmetrics.__version__.startswith("1."):
            self.skipTest(f"torchmetrics {torchmetrics.__version__} is neither 0.9.3 nor 1.x")
        generator = torch.Generator().manual_seed(0)
        for shape in ((4, 60, 80, 3), (3, 17, 23, 3), (2, 120, 160, 3)):
            target = torch.rand(shape, generator=generator)
            pred = (target * 0.8 + 0.2 * torch.rand(shape, generator=generator)).clamp(0, 1)
            nchw = pred.permute(0, 3, 1, 2), target.permute(0, 3, 1, 2)
            ssim = StructuralSimilarityIndexMeasure(data_range=1.0)(*nchw)
            psnr = PeakSignalNoiseRatio(data_range=1.0, dim=(1, 2, 3))(*nchw)
            self.assertAlmostEqual(evaluate.ssim(pred, target, definition).mean().item(), ssim.item(), delta=1e-6)
            self.assertAlmostEqual(evaluate.psnr(pred, target).mean().item(), psnr.item(), delta=1e-5)


class TrainingTests(unittest.TestCase):
    def test_official_schedule(self):
        optimizer = torch.optim.Adam(torch.nn.Linear(1, 1).parameters(), lr=1e-4)
        factor = train.linear_schedule(optimizer, 2500, 500_000).lr_lambdas[0]
        # The official run: warmup from 0 over 2.5k steps, then 1e-4 decays linearly to 4e-5 at step 300k.
        np.testing.assert_allclose([factor(s) for s in (0, 1250, 2500, 300_000, 500_000, 600_000)],
                                   [0, 0.5, 1, 200_000 / 497_500, 0, 0], rtol=1e-12)

    def test_configs_fit_the_engine(self):
        for k in (1, 2, 4, 8):
            cfg = train.model_config(k, "cpu", 60, 80, 1e-4, 10, 100)
            self.assertEqual(cfg["encoder_kwargs"]["num_conv_blocks"], 2)
            model = train.SRT.from_config(cfg)
            self.assertEqual(model.patch_size, k)
            self.assertEqual("h_out" in cfg.get("rp_kwargs", {}), k == 8)  # 60 rows do not tile into 8x8 patches
        self.assertEqual(train.model_config(4, "cpu", 120, 160, 1e-4, 10, 100)["encoder_kwargs"]["num_conv_blocks"], 3)

    def test_training_learns_resumes_and_exports(self):
        with tempfile.TemporaryDirectory() as folder:
            folder = Path(folder)
            make_scenes.main(["--count", "6", "--size", "20x24", "--out", str(folder / "train"), "--shard-size", "6",
                              "--pngs", "0"])
            make_scenes.main(["--split", "val", "--count", "2", "--size", "20x24", "--out", str(folder / "val"),
                              "--pngs", "0"])
            common = ["--train", str(folder / "train"), "--val", str(folder / "val"), "--batch", "4", "--lr", "3e-3",
                      "--warmup", "1", "--decay-it", "100", "--log-every", "4", "--val-every", "8",
                      "--checkpoint-every", "4", "--threads", "1", "--num-points", "200"]
            for k in (1, 2):
                straight, resumed = folder / f"straight-{k}", folder / f"resumed-{k}"
                self.assertEqual(train.main(["--k", str(k), "--out", str(straight), "--steps", "8"] + common), 0)
                self.assertEqual(train.main(["--k", str(k), "--out", str(resumed), "--steps", "4"] + common), 0)
                self.assertEqual(train.main(["--k", str(k), "--out", str(resumed), "--steps", "8"] + common), 0)
                with safe_open(straight / "model.safetensors", "pt") as file:
                    metadata = file.metadata()
                    names = set(file.keys())
                record = json.loads(metadata["training"])
                self.assertEqual((record["steps"], record["k"], len(record["curve"])), (8, k, 1))
                curve = (straight / "curve.csv").read_text().splitlines()
                losses = [float(line.split(",")[3]) for line in curve[1:]]
                self.assertLess(losses[-1], losses[0])
                model, _, _ = evaluate.load_model(straight / "model.safetensors")
                self.assertEqual(names, {n for n in model.state_dict() if not n.endswith("num_batches_tracked")})
                for a, b in zip(torch.load(straight / "checkpoint.pt", weights_only=True)["model"].values(),
                                torch.load(resumed / "checkpoint.pt", weights_only=True)["model"].values()):
                    torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-6)

    def test_fitting_one_scene_learns_resumes_and_says_so(self):
        seed = make_scenes.SPLITS["test"][0]
        with tempfile.TemporaryDirectory() as folder:
            folder = Path(folder)
            common = ["--seed", str(seed), "--count", "1", "--size", "20x24", "--pngs", "0"]
            make_scenes.main(common + ["--extra-views", "4", "--camera-seed", "1", "--out", str(folder / "val")])
            make_scenes.main(common + ["--extra-views", "12", "--out", str(folder / "train")])
            make_scenes.main(["--seed", str(seed), "--count", "1", "--size", "20x24", "--pngs", "0", "--out",
                              str(folder / "heldout")])
            argv = ["--fit-scene", "--k", "2", "--train", str(folder / "train"), "--val", str(folder / "val"),
                    "--watch", str(folder / "heldout"), "--targets-per-step", "4", "--lr", "3e-3", "--warmup", "1",
                    "--decay-it", "100", "--log-every", "2", "--val-every", "4", "--checkpoint-every", "2",
                    "--threads", "1"]
            straight, resumed = folder / "straight", folder / "resumed"
            self.assertEqual(train.main(argv + ["--out", str(straight), "--steps", "8"]), 0)
            self.assertEqual(train.main(argv + ["--out", str(resumed), "--steps", "4"]), 0)
            self.assertEqual(train.main(argv + ["--out", str(resumed), "--steps", "8"]), 0)
            for a, b in zip(torch.load(straight / "checkpoint.pt", weights_only=True)["model"].values(),
                            torch.load(resumed / "checkpoint.pt", weights_only=True)["model"].values()):
                torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-6)
            rows = (straight / "curve.csv").read_text().splitlines()
            self.assertEqual(rows[0], "step,train_seconds,lr,loss,val_psnr,heldout_psnr")
            self.assertEqual(len([r for r in rows[1:] if r.split(",")[5]]), 2)  # steps 4 and 8
            with safe_open(straight / "model.safetensors", "pt") as file:
                metadata = file.metadata()
            record = json.loads(metadata["training"])
            self.assertEqual((record["fitted_to_scene"], record["train_views"], record["train_scenes"]), (seed, 12, 1))
            self.assertIn("does not generalise", record["note"])
            self.assertIn(f"fitted to scene {seed} only", metadata["source"])
            self.assertEqual([row[0] for row in record["heldout"]["curve"]], [4, 8])
            # A training folder of several scenes, or a batch above 1, is refused.
            self.assertEqual(train.main(argv + ["--out", str(folder / "bad"), "--steps", "2", "--batch", "2"]), 2)
            self.assertEqual(train.main(argv + ["--out", str(folder / "bad"), "--steps", "2", "--targets-per-step",
                                                "13"]), 2)


if __name__ == "__main__":
    unittest.main()
