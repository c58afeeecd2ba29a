"""Procedural scenes in the spirit of MultiShapeNet-Easy, ray-traced with numpy.

    python3 tools/data/make_scenes.py --split test --count 200 --size 60x80 --out /work/data/scenes-test
    python3 tools/data/make_scenes.py --split train --count 50000 --size 60x80 --shard-size 1000 --out /work/data/train

Each scene holds 2 to 4 objects (sphere, box, cylinder, cone, capsule; random size, colour, material and yaw) resting
on an infinite floor, lit by a point light with hard shadows (shadow rays), ambient light and, for specular and
metallic materials, Blinn-Phong highlights and an environment reflection. Three views at 120° steps on a circle
around the scene centre (the world origin) look at it, with the MSN-Easy camera of tools/reference/cameras.py (z up,
focal 0.035, sensor width 0.032, unit rays through pixel centres). Per view: RGB (8-bit, like the MSN-Easy PNGs), depth
(distance from the camera centre along the unit ray, the official zs_to_depths convention; 0 where a ray hits
nothing) and instance masks (0 = floor, 1..n = objects in generation order).

Over 600 lines on purpose: the scene sampler, the ray tracer and the file writers are one generator whose
determinism (a seed gives the same bytes) is easiest to keep, and to review, in one file.

A scene is a pure function of its seed (numpy PCG64): it renders to the same bytes alone or in any batch. Seeds
select the split (SPLITS); docs/FORMATS.md describes the scene and shard files.

For per-scene fitting, --extra-views N writes instead, per seed, views-SEED.safetensors: the scene's view 0 and N
views from other cameras drawn from the scenes' own camera distribution, none within --exclude-deg of the cameras
of --exclude-views (default: the scene's target views 1 and 2, which stay held out):

    python3 tools/data/make_scenes.py --seed 2000000 --count 1 --extra-views 2000 --out /work/data/fit-2000000/train
"""

import argparse
import json
import shlex
import struct
import sys
import time
import zlib
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
from safetensors import safe_open
from safetensors.numpy import load_file

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tools/, whose packages this imports
from reference.cameras import get_camera_rays, look_at_positions  # noqa: E402
from reference.safetensors_io import save_safetensors  # noqa: E402

SCENE_FORMAT = "raypatch-scene/1"
SHARD_FORMAT = "raypatch-shard/1"
# Disjoint seed ranges [start, end) of the splits.
SPLITS = {"train": (0, 1_000_000), "val": (1_000_000, 1_010_000), "test": (2_000_000, 2_010_000)}
VIEWS = 3
MAX_OBJECTS = 4
KINDS = ("sphere", "box", "cylinder", "cone", "capsule")
MATERIALS = ("diffuse", "specular", "metal")
MATERIAL_WEIGHTS = (0.4, 0.35, 0.25)
SCENE_RADIUS = 3.0  # object centres lie in this disc around the origin
EPSILON = 1e-4  # minimum hit distance, world units
SHADOW_OFFSET = 1e-3  # shadow rays start this far off the surface, along the normal
AMBIENT = 0.22
SKY_COLOUR = np.array((0.75, 0.8, 0.88), np.float32)
GAMMA = 2.2
CAMERA_RADIUS = (9.5, 11.5)  # the scenes' camera distance range (uniform)
CAMERA_ELEVATION = (28.0, 42.0)  # and elevation range in degrees (uniform); azimuths go round the circle
VIEWS_FORMAT = "raypatch-views/1"


# ---------------------------------------------------------------------------------------------------------------
# Scene sampling


@dataclass
class SceneSpec:
    """Everything random about one scene. Sizes: sphere (r), box (half extents x, y, z), cylinder (r, half
    height), cone (base r, half height), capsule (r, half length along its local x); unused entries are 0."""

    seed: int
    kinds: list  # per object, an index into KINDS
    centres: np.ndarray  # [n, 3]; z is the half height, so objects rest on the floor
    yaws: np.ndarray  # [n], radians about +z
    sizes: np.ndarray  # [n, 3]
    colours: np.ndarray  # [n, 3], display (sRGB-like) values in [0, 1]
    materials: list  # per object, an index into MATERIALS
    floor_colour: np.ndarray  # [3], display values
    light_pos: np.ndarray  # [3]
    camera_pos: np.ndarray  # [VIEWS, 3] float32

    def describe(self):
        """JSON-able description (stored in the scene files' metadata)."""
        return {"objects": [{"kind": KINDS[k], "centre": np.round(c, 4).tolist(), "yaw": round(float(y), 4),
                             "size": np.round(s, 4).tolist(), "colour": np.round(col, 4).tolist(),
                             "material": MATERIALS[m]}
                            for k, c, y, s, col, m in zip(self.kinds, self.centres, self.yaws, self.sizes,
                                                          self.colours, self.materials)],
                "floor_colour": np.round(self.floor_colour, 4).tolist(),
                "light_pos": np.round(self.light_pos, 4).tolist()}


def hsv_to_rgb(h, s, v):
    i = int(h * 6) % 6
    f = h * 6 - int(h * 6)
    p, q, t = v * (1 - s), v * (1 - f * s), v * (1 - (1 - f) * s)
    return np.array([(v, t, p), (q, v, p), (p, v, t), (p, q, v), (t, p, v), (v, p, q)][i])


def sample_size(rng, kind, scale):
    """Shape parameters and the footprint radius (for placement) of one object."""
    name = KINDS[kind]
    if name == "sphere":
        size = (scale, 0.0, 0.0)
        return size, scale, scale
    if name == "box":
        size = scale * rng.uniform((0.5, 0.5, 0.45), (0.95, 0.95, 1.0))
        return tuple(size), float(np.hypot(size[0], size[1])), size[2]
    if name == "cylinder":
        size = (scale * rng.uniform(0.45, 0.85), scale * rng.uniform(0.5, 1.1), 0.0)
        return size, size[0], size[1]
    if name == "cone":
        size = (scale * rng.uniform(0.6, 1.0), scale * rng.uniform(0.7, 1.2), 0.0)
        return size, size[0], size[1]
    size = (scale * rng.uniform(0.3, 0.5), scale * rng.uniform(0.45, 0.85), 0.0)  # capsule
    return size, size[0] + size[1], size[0]


def sample_scene(seed):
    rng = np.random.default_rng(seed)
    count = int(rng.integers(2, MAX_OBJECTS + 1))
    kinds, centres, yaws, sizes, colours, materials, footprints = [], [], [], [], [], [], []
    while len(kinds) < count:
        kind = int(rng.integers(len(KINDS)))
        size, footprint, half_height = sample_size(rng, kind, rng.uniform(0.55, 1.05))
        for _ in range(100):  # rejection sampling of a position that does not overlap the others
            radius, angle = SCENE_RADIUS * np.sqrt(rng.uniform()), rng.uniform(0, 2 * np.pi)
            xy = radius * np.array((np.cos(angle), np.sin(angle)))
            if all(np.hypot(*(xy - c[:2])) > footprint + f + 0.1 for c, f in zip(centres, footprints)):
                break
        else:
            continue  # no room: draw another object
        kinds.append(kind)
        centres.append(np.array((xy[0], xy[1], half_height)))
        footprints.append(footprint)
        yaws.append(rng.uniform(0, 2 * np.pi))
        sizes.append(size)
        colours.append(hsv_to_rgb(rng.uniform(), rng.uniform(0.45, 0.95), rng.uniform(0.5, 0.95)))
        materials.append(int(rng.choice(len(MATERIALS), p=MATERIAL_WEIGHTS)))
    grey = rng.uniform(0.55, 0.8)
    floor_colour = hsv_to_rgb(rng.uniform(), rng.uniform(0.0, 0.15), grey)
    light_pos = look_at_positions(rng.uniform(0, 360), rng.uniform(10, 14), rng.uniform(40, 70))[0]
    first_azimuth = rng.uniform(0, 360)
    camera_pos = look_at_positions(first_azimuth + 120.0 * np.arange(VIEWS), rng.uniform(*CAMERA_RADIUS),
                                   rng.uniform(*CAMERA_ELEVATION))
    return SceneSpec(seed, kinds, np.array(centres), np.array(yaws), np.array(sizes), np.array(colours), materials,
                     floor_colour, light_pos.astype(np.float64), camera_pos)


class ObjectTable:
    """The objects of a batch of scenes as flat float32 arrays, indexed by object."""

    def __init__(self, specs):
        self.scene = np.concatenate([np.full(len(s.kinds), b) for b, s in enumerate(specs)])
        self.slot = np.concatenate([np.arange(len(s.kinds)) for s in specs])
        self.kind = np.concatenate([s.kinds for s in specs])
        self.material = np.concatenate([s.materials for s in specs])
        self.centre = np.concatenate([s.centres for s in specs]).astype(np.float32)
        yaw = np.concatenate([s.yaws for s in specs])
        self.cos, self.sin = np.cos(yaw).astype(np.float32), np.sin(yaw).astype(np.float32)
        self.size = np.concatenate([s.sizes for s in specs]).astype(np.float32)
        self.albedo = (np.concatenate([s.colours for s in specs]) ** GAMMA).astype(np.float32)
        self.index = np.full((len(specs), MAX_OBJECTS), -1)  # [scene, slot] -> object
        self.index[self.scene, self.slot] = np.arange(len(self.scene))


# ---------------------------------------------------------------------------------------------------------------
# Ray tracing: each shape in its local frame (centre at the origin, yaw undone), vectorised over objects and rays.
# All shapes are convex, so the nearest valid surface crossing is the entry point and a shadow ray leaving a
# surface point cannot hit its own object again.


def rotate(x, y, cos, sin):
    """Rotation by -yaw (world to local); pass -sin for local to world."""
    return cos * x + sin * y, cos * y - sin * x


def nearest(*candidates):
    """Smallest t > EPSILON among (t, valid) pairs; inf where none."""
    best = None
    for t, valid in candidates:
        t = np.where(valid & (t > EPSILON), t, np.inf)
        best = t if best is None else np.minimum(best, t)
    return best


def quadratic_roots(a, half_b, c):
    """Both roots of a t² + 2 half_b t + c = 0 and whether they are real."""
    disc = half_b * half_b - a * c
    root = np.sqrt(np.maximum(disc, 0))
    with np.errstate(divide="ignore", invalid="ignore"):
        return (-half_b - root) / a, (-half_b + root) / a, disc >= 0


def hit_sphere(o, d, size):
    r = size[:, 0:1]
    t0, _, real = quadratic_roots(np.float32(1), o[0] * d[0] + o[1] * d[1] + o[2] * d[2],
                                  o[0] * o[0] + o[1] * o[1] + o[2] * o[2] - r * r)
    return nearest((t0, real))


def hit_box(o, d, size):
    t_near, t_far = np.float32(-np.inf), np.float32(np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        for axis in range(3):
            inverse = 1 / d[axis]
            t1 = (-size[:, axis:axis + 1] - o[axis]) * inverse
            t2 = (size[:, axis:axis + 1] - o[axis]) * inverse
            t_near = np.maximum(t_near, np.minimum(t1, t2))
            t_far = np.minimum(t_far, np.maximum(t1, t2))
    return nearest((t_near, t_near <= t_far))


def caps(o, d, z_levels, radius):
    """Crossings of horizontal discs at the given local heights."""
    out = []
    with np.errstate(divide="ignore", invalid="ignore"):
        for z in z_levels:
            t = (z - o[2]) / d[2]
            x, y = o[0] + t * d[0], o[1] + t * d[1]
            out.append((t, x * x + y * y <= radius * radius))
    return out


def hit_cylinder(o, d, size):
    r, h = size[:, 0:1], size[:, 1:2]
    t0, _, real = quadratic_roots(d[0] * d[0] + d[1] * d[1], o[0] * d[0] + o[1] * d[1],
                                  o[0] * o[0] + o[1] * o[1] - r * r)
    side = (t0, real & (np.abs(o[2] + t0 * d[2]) <= h))
    return nearest(side, *caps(o, d, (h, -h), r))


def hit_cone(o, d, size):
    """Apex at z = +h, base of radius r at z = -h: x² + y² = (r (h - z) / 2h)²."""
    r, h = size[:, 0:1], size[:, 1:2]
    slope2 = (r / (2 * h)) ** 2
    w = h - o[2]
    t0, t1, real = quadratic_roots(d[0] * d[0] + d[1] * d[1] - slope2 * d[2] * d[2],
                                   o[0] * d[0] + o[1] * d[1] + slope2 * w * d[2],
                                   o[0] * o[0] + o[1] * o[1] - slope2 * w * w)
    sides = [(t, real & (np.abs(o[2] + t * d[2]) <= h)) for t in (t0, t1)]  # excludes the mirrored cone
    return nearest(*sides, *caps(o, d, (-h,), r))


def hit_capsule(o, d, size):
    """Segment from x = -L to x = +L, radius r."""
    r, half_length = size[:, 0:1], size[:, 1:2]
    t0, _, real = quadratic_roots(d[1] * d[1] + d[2] * d[2], o[1] * d[1] + o[2] * d[2],
                                  o[1] * o[1] + o[2] * o[2] - r * r)
    candidates = [(t0, real & (np.abs(o[0] + t0 * d[0]) <= half_length))]
    for end in (half_length, -half_length):
        ox = o[0] - end
        t_end, _, real_end = quadratic_roots(np.float32(1), ox * d[0] + o[1] * d[1] + o[2] * d[2],
                                             ox * ox + o[1] * o[1] + o[2] * o[2] - r * r)
        candidates.append((t_end, real_end))
    return nearest(*candidates)


HIT = {"sphere": hit_sphere, "box": hit_box, "cylinder": hit_cylinder, "cone": hit_cone, "capsule": hit_capsule}


def local_normals(kind, p, size):
    """Unit outward normals at local surface points p (3 arrays [n]) of objects with sizes [n, 3]."""
    x, y, z = p
    zero = np.zeros_like(x)
    if kind == "sphere":
        n = (x, y, z)
    elif kind == "box":
        scaled = np.abs(np.stack(p)) / size.T
        axis = np.argmax(scaled, 0)
        n = tuple(np.where(axis == a, np.sign(p[a]), zero) for a in range(3))
    elif kind == "cylinder":
        r, h = size[:, 0], size[:, 1]
        rho = np.hypot(x, y) + 1e-12
        cap = h - np.abs(z) < r - rho
        n = (np.where(cap, zero, x / rho), np.where(cap, zero, y / rho), np.where(cap, np.sign(z), zero))
    elif kind == "cone":
        r, h = size[:, 0], size[:, 1]
        slope = r / (2 * h)
        rho = np.hypot(x, y) + 1e-12
        base = np.abs(z + h) < np.abs(rho - slope * (h - z))
        n = (np.where(base, zero, x / rho), np.where(base, zero, y / rho), np.where(base, -1, slope))
    else:  # capsule
        half_length = size[:, 1]
        n = (x - np.clip(x, -half_length, half_length), y, z)
    length = np.sqrt(n[0] ** 2 + n[1] ** 2 + n[2] ** 2) + 1e-12
    return tuple(c / length for c in n)


def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def trace_objects(objects, origins, dirs):
    """Hit distances [B, MAX_OBJECTS, R] (inf: no hit or no object) of rays origins, dirs [3, B, R]."""
    batch, rays = origins.shape[1:]
    t = np.full((batch, MAX_OBJECTS, rays), np.inf, np.float32)
    for kind, name in enumerate(KINDS):
        idx = np.flatnonzero(objects.kind == kind)
        if len(idx) == 0:
            continue
        scene = objects.scene[idx]
        o = origins[:, scene] - objects.centre[idx].T[:, :, None]
        d = dirs[:, scene]
        cos, sin = objects.cos[idx, None], objects.sin[idx, None]
        ox, oy = rotate(o[0], o[1], cos, sin)
        dx, dy = rotate(d[0], d[1], cos, sin)
        t[scene, objects.slot[idx]] = HIT[name]((ox, oy, o[2]), (dx, dy, d[2]), objects.size[idx])
    return t


def trace(objects, origins, dirs):
    """Nearest hits of rays [3, B, R]: distance [B, R] (inf: none) and id [B, R] (-1 nothing, 0 floor, 1.. object
    slot + 1)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t_floor = np.where(dirs[2] < 0, -origins[2] / dirs[2], np.inf).astype(np.float32)
    t_all = np.concatenate((t_floor[:, None], trace_objects(objects, origins, dirs)), 1)
    hit = np.argmin(t_all, 1)
    t = np.take_along_axis(t_all, hit[:, None], 1)[:, 0]
    return t, np.where(np.isinf(t), -1, hit)


def shade(objects, specs, origins, dirs, t, hit):
    """Linear RGB [3, B, R] of the primary hits of rays [3, B, R]."""
    found = hit >= 0
    points = origins + np.where(found, t, 0) * dirs
    normals = np.zeros_like(points)
    normals[2] = 1  # floor
    floor = (np.stack([s.floor_colour for s in specs]).T ** GAMMA).astype(np.float32)[:, :, None]
    albedo = np.repeat(floor, t.shape[1], 2)
    material = np.full(t.shape, MATERIALS.index("diffuse"))

    b_idx, r_idx = np.nonzero(hit >= 1)
    obj = objects.index[b_idx, hit[b_idx, r_idx] - 1]
    albedo[:, b_idx, r_idx] = objects.albedo[obj].T
    material[b_idx, r_idx] = objects.material[obj]
    for kind, name in enumerate(KINDS):
        sel = objects.kind[obj] == kind
        if not sel.any():
            continue
        o, bs, rs = obj[sel], b_idx[sel], r_idx[sel]
        p = points[:, bs, rs] - objects.centre[o].T
        x, y = rotate(p[0], p[1], objects.cos[o], objects.sin[o])
        nx, ny, nz = local_normals(name, (x, y, p[2]), objects.size[o])
        nx, ny = rotate(nx, ny, objects.cos[o], -objects.sin[o])
        normals[:, bs, rs] = np.stack((nx, ny, nz))

    light = np.stack([s.light_pos for s in specs]).T.astype(np.float32)[:, :, None]
    starts = points + SHADOW_OFFSET * normals
    to_light = light - starts
    light_dist = np.sqrt(dot(to_light, to_light))
    to_light /= light_dist
    occluded = trace_objects(objects, starts, to_light).min(1) < light_dist
    falloff = (np.sqrt(dot(light, light)) / light_dist) ** 1.5  # 1 at the scene centre
    direct = np.where(occluded, 0, falloff)
    ambient = AMBIENT * (0.7 + 0.3 * normals[2])
    rgb = albedo * (ambient + direct * np.maximum(dot(normals, to_light), 0))

    # Specular and metallic surfaces: Blinn-Phong highlight; metal also tints it and reflects the environment.
    b_idx, r_idx = np.nonzero(material != MATERIALS.index("diffuse"))
    n, d, l = normals[:, b_idx, r_idx], dirs[:, b_idx, r_idx], to_light[:, b_idx, r_idx]
    half = l - d
    n_dot_h = np.maximum(dot(n, half) / (np.sqrt(dot(half, half)) + 1e-12), 0)
    metal = material[b_idx, r_idx] == MATERIALS.index("metal")
    colour = albedo[:, b_idx, r_idx]
    highlight = direct[b_idx, r_idx] * np.where(metal, 0.9 * n_dot_h ** 90, 0.5 * n_dot_h ** 40)
    reflected = d - 2 * dot(d, n) * n
    environment = np.where(reflected[2] > 0, (SKY_COLOUR ** GAMMA)[:, None] * (0.6 + 0.4 * reflected[2]),
                           0.5 * floor[:, b_idx, 0])
    rgb[:, b_idx, r_idx] = np.where(metal, 0.35 * rgb[:, b_idx, r_idx] + highlight * colour
                                    + 0.55 * colour * environment, rgb[:, b_idx, r_idx] + highlight)
    return np.where(found, rgb, (SKY_COLOUR ** GAMMA)[:, None, None])


def camera_rays(specs, height, width):
    """Unit rays [3, B, V·height·width] (views, rows, columns) and per-ray origins, float32; V is the number of
    camera positions of each scene (VIEWS for sampled scenes; all scenes of a batch must have the same V)."""
    rays = np.stack([np.stack([get_camera_rays(pos, width, height) for pos in s.camera_pos]) for s in specs])
    origins = np.stack([s.camera_pos for s in specs]).astype(np.float32)
    origins = np.broadcast_to(origins[:, :, None, None, :], rays.shape)
    return (np.ascontiguousarray(np.moveaxis(rays.reshape(len(specs), -1, 3), -1, 0)),
            np.ascontiguousarray(np.moveaxis(origins.reshape(len(specs), -1, 3), -1, 0)))


def render(specs, height, width, supersample=1):
    """Renders the views of each scene (one per row of its camera_pos: VIEWS for sampled scenes, any V for
    with_cameras). Returns images uint8 [B, V, H, W, 3], depth float32 [B, V, H, W], masks uint8 [B, V, H, W] and
    camera_pos float32 [B, V, 3].

    With supersample S > 1 the colour of a pixel is the mean over the centres of its S×S sub-pixels (rays of an
    S-times finer camera); depth and masks always come from the pixel-centre rays.
    """
    objects = ObjectTable(specs)
    batch = len(specs)
    views = len(specs[0].camera_pos)
    dirs, origins = camera_rays(specs, height, width)
    t, hit = trace(objects, origins, dirs)
    depth = np.where(hit >= 0, t, 0).reshape(batch, views, height, width)
    masks = np.where(hit > 0, hit, 0).astype(np.uint8).reshape(batch, views, height, width)
    if supersample > 1:
        dirs, origins = camera_rays(specs, height * supersample, width * supersample)
        t, hit = trace(objects, origins, dirs)
    rgb = np.moveaxis(shade(objects, specs, origins, dirs, t, hit), 0, -1)
    rgb = rgb.reshape(batch, views, height, supersample, width, supersample, 3).mean((3, 5))
    display = np.clip(rgb, 0, 1) ** (1 / GAMMA)
    images = np.round(display * 255).astype(np.uint8)
    camera_pos = np.stack([s.camera_pos for s in specs]).astype(np.float32)
    return images, depth.astype(np.float32), masks, camera_pos


# ---------------------------------------------------------------------------------------------------------------
# Extra views of one scene (per-scene fitting)


def angle_between_deg(a, b):
    """Angles in degrees between the directions from the origin of positions a [n, 3] and b [m, 3] -> [n, m]."""
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    return np.degrees(np.arccos(np.clip(a @ b.T, -1, 1)))


def extra_cameras(spec, count, camera_seed, exclude_views, exclude_deg, exclude_positions=()):
    """count camera positions float32 [count, 3] drawn from the scenes' own camera distribution (azimuth uniform
    round the circle, distance uniform in CAMERA_RADIUS, elevation uniform in CAMERA_ELEVATION), rejecting every
    one whose direction from the scene centre lies within exclude_deg (> 0) of the scene's views exclude_views or
    of the cameras exclude_positions [m, 3], so that those views stay held out. A pure function of its arguments."""
    if exclude_deg <= 0:
        raise ValueError(f"--exclude-deg {exclude_deg}: must be > 0 (held-out cameras must differ from training ones)")
    rng = np.random.default_rng([camera_seed, spec.seed])
    excluded = np.concatenate((spec.camera_pos[list(exclude_views)], np.reshape(exclude_positions, (-1, 3))))
    chosen = []
    while len(chosen) < count:
        positions = look_at_positions(rng.uniform(0, 360, 256), rng.uniform(*CAMERA_RADIUS, 256),
                                      rng.uniform(*CAMERA_ELEVATION, 256))
        if len(excluded):
            positions = positions[angle_between_deg(positions, excluded).min(1) > exclude_deg]
        chosen.extend(positions[:count - len(chosen)])
    return np.stack(chosen).astype(np.float32)


def render_extra_views(spec, camera_pos, height, width, supersample=1, chunk=32):
    """The scene of spec seen from any cameras camera_pos [V, 3]: images [V, H, W, 3], depth, masks (as render)."""
    parts = [render([replace(spec, camera_pos=camera_pos[i:i + chunk])], height, width, supersample)
             for i in range(0, len(camera_pos), chunk)]
    return tuple(np.concatenate([part[n][0] for part in parts]) for n in range(3))


def write_views(path, spec, images, depth, masks, camera_pos, command, cameras):
    """A views file: one scene seen from V cameras (docs in tools/README.md), readable by load_views."""
    metadata = {"format": VIEWS_FORMAT, "seed": str(spec.seed), "split": split_of(spec.seed), "views": str(len(images)),
                "generator": command, "scene": json.dumps(spec.describe()), "cameras": json.dumps(cameras)}
    tensors = {"images": images[None], "depth": depth[None], "masks": masks[None], "camera_pos": camera_pos[None]}
    save_safetensors(path, {name: torch.from_numpy(np.ascontiguousarray(v)) for name, v in tensors.items()},
                     metadata)


def views_strip(images, count=8, scale=3):
    """The first count views side by side with 2-pixel white gaps."""
    images = images[:count]
    height, width = images.shape[1:3]
    strip = np.full((height, len(images) * (width + 2) - 2, 3), 255, np.uint8)
    for v, image in enumerate(images):
        strip[:, v * (width + 2):v * (width + 2) + width] = image
    return strip.repeat(scale, 0).repeat(scale, 1)


# ---------------------------------------------------------------------------------------------------------------
# Files


def split_of(seed):
    for name, (start, end) in SPLITS.items():
        if start <= seed < end:
            return name
    raise ValueError(f"seed {seed} is in no split (" +
                     ", ".join(f"{name} [{start}, {end})" for name, (start, end) in SPLITS.items()) + ")")


def scene_tensors(images, depth, masks, camera_pos, height, width):
    """One scene's views as scene-file tensors: view 0 is the input, views 1 and 2 the targets."""
    rays = np.stack([get_camera_rays(pos, width, height) for pos in camera_pos])
    as_float = images.astype(np.float32) / 255
    tensors = {"input_images": as_float[:1], "input_camera_pos": camera_pos[:1], "input_rays": rays[:1],
               "input_depth": depth[:1], "input_masks": masks[:1],
               "target_images": as_float[1:], "target_camera_pos": camera_pos[1:], "target_rays": rays[1:],
               "target_depth": depth[1:], "target_masks": masks[1:]}
    return {name: torch.from_numpy(np.ascontiguousarray(value)) for name, value in tensors.items()}


def write_scene(path, spec, images, depth, masks, camera_pos, command):
    height, width = images.shape[1:3]
    metadata = {"format": SCENE_FORMAT, "seed": str(spec.seed), "split": split_of(spec.seed),
                "generator": command, "scene": json.dumps(spec.describe())}
    save_safetensors(path, scene_tensors(images, depth, masks, camera_pos, height, width), metadata)


def write_shard(path, first_seed, images, depth, masks, camera_pos, command):
    metadata = {"format": SHARD_FORMAT, "first_seed": str(first_seed), "count": str(len(images)),
                "split": split_of(first_seed), "generator": command}
    tensors = {"images": images, "depth": depth, "masks": masks, "camera_pos": camera_pos}
    save_safetensors(path, {name: torch.from_numpy(np.ascontiguousarray(v)) for name, v in tensors.items()},
                     metadata)


def load_views(folder):
    """All scenes of a folder of scene files, shards or views files (--extra-views), as arrays over scenes and
    views: images uint8 [S, V, H, W, 3], camera_pos float32 [S, V, 3], seeds int64 [S]. Scene files give
    V = inputs + targets, shards V = VIEWS, views files their view count (all files must agree)."""
    folder = Path(folder)
    shards = sorted(folder.glob("shard-*.safetensors"))
    scenes = sorted(folder.glob("scene-*.safetensors"))
    views = sorted(folder.glob("views-*.safetensors"))
    if not shards and not scenes and not views:
        raise ValueError(f"{folder}: no shard-*.safetensors, scene-*.safetensors or views-*.safetensors files")
    images, camera_pos, seeds = [], [], []
    for path, expected in [(p, SHARD_FORMAT) for p in shards] + [(p, VIEWS_FORMAT) for p in views]:
        with safe_open(path, "np") as file:  # reads only the tensors asked for
            metadata = file.metadata()
            if metadata.get("format") != expected:
                raise ValueError(f"{path}: metadata format is {metadata.get('format')!r}, expected {expected!r}")
            images.append(file.get_tensor("images"))
            camera_pos.append(file.get_tensor("camera_pos"))
        first = int(metadata["first_seed"] if expected == SHARD_FORMAT else metadata["seed"])
        seeds.append(first + np.arange(len(images[-1])))
    for path in scenes:
        with safe_open(path, "np") as file:
            seed = int(file.metadata()["seed"])
        tensors = load_file(path)
        views = np.concatenate((tensors["input_images"], tensors["target_images"]))
        images.append(np.round(views * 255).astype(np.uint8)[None])
        camera_pos.append(np.concatenate((tensors["input_camera_pos"], tensors["target_camera_pos"]))[None])
        seeds.append(np.array([seed]))
    if len({image.shape[1:] for image in images}) > 1:
        raise ValueError(f"{folder}: files with different view counts or sizes "
                         f"{sorted({image.shape[1:4] for image in images})}")
    return np.concatenate(images), np.concatenate(camera_pos), np.concatenate(seeds)


def write_png(path, rgb):
    """8-bit RGB PNG from a uint8 [H, W, 3] array (no imaging library needed)."""
    height, width, _ = rgb.shape
    raw = b"".join(b"\x00" + row.tobytes() for row in rgb)

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    png = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
           + chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b""))
    Path(path).write_bytes(png)


# Viridis at 9 evenly spaced points.
VIRIDIS = np.array([(68, 1, 84), (71, 44, 122), (59, 81, 139), (44, 113, 142), (33, 144, 141), (39, 173, 129),
                    (92, 200, 99), (170, 220, 50), (253, 231, 37)], np.float64)
MASK_COLOURS = np.array([(40, 40, 40), (230, 25, 75), (60, 180, 75), (255, 225, 25), (0, 130, 200)], np.uint8)


def colour_depth(depth):
    """Viridis, near = yellow, scaled to the scene's depth range; black where there is no surface."""
    valid = depth > 0
    near, far = depth[valid].min(), depth[valid].max()
    x = 1 - (depth - near) / max(far - near, 1e-6)
    positions = np.linspace(0, 1, len(VIRIDIS))
    rgb = np.stack([np.interp(x, positions, VIRIDIS[:, c]) for c in range(3)], -1)
    return np.where(valid[..., None], np.round(rgb), 0).astype(np.uint8)


def preview(images, depth, masks, scale=3):
    """A sheet: rows RGB, depth, masks; columns view 0 (input), 1, 2 (targets); 2-pixel white gaps."""
    rows = [images, colour_depth(depth), MASK_COLOURS[masks]]
    height, width = images.shape[1:3]
    sheet = np.full((3 * height + 4, VIEWS * width + 2 * (VIEWS - 1), 3), 255, np.uint8)
    for r, row in enumerate(rows):
        for v in range(VIEWS):
            sheet[r * (height + 2):r * (height + 2) + height, v * (width + 2):v * (width + 2) + width] = row[v]
    return sheet.repeat(scale, 0).repeat(scale, 1)


def parse_size(text):
    try:
        height, width = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--size {text!r}: expected HEIGHTxWIDTH, e.g. 60x80")
    if height <= 0 or width <= 0:
        raise argparse.ArgumentTypeError(f"--size {text!r}: height and width must be positive")
    return height, width


def resolve_seeds(args):
    """First seed of the run; checks that all seeds lie in one split (the named one, if given)."""
    if args.count <= 0:
        raise ValueError(f"--count {args.count}: must be positive")
    first = args.seed if args.seed is not None else SPLITS[args.split or "train"][0]
    split = split_of(first)
    last = first + args.count - 1
    if split_of(last) != split or (args.split is not None and split != args.split):
        start, end = SPLITS[args.split or split]
        raise ValueError(f"seeds {first}..{last} are not all in split {args.split or split} [{start}, {end})")
    return first


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seed", type=int, help="first scene seed (default: the start of --split)")
    parser.add_argument("--split", choices=sorted(SPLITS), help="split whose seed range to use (default: train)")
    parser.add_argument("--count", type=int, required=True, help="number of scenes (seeds SEED .. SEED+COUNT-1)")
    parser.add_argument("--size", type=parse_size, default=(60, 80), help="HEIGHTxWIDTH of every view (60x80)")
    parser.add_argument("--out", type=Path, required=True, help="folder to write into (created)")
    parser.add_argument("--shard-size", type=int, default=0,
                        help="write scenes in shard files of this many scenes instead of one file per scene")
    parser.add_argument("--supersample", type=int, default=1, help="S×S colour samples per pixel (default 1)")
    parser.add_argument("--pngs", type=int, default=16, help="preview sheets for the first N scenes (default 16)")
    parser.add_argument("--batch", type=int, default=32, help="scenes rendered together (memory vs speed)")
    parser.add_argument("--extra-views", type=int, default=0,
                        help="instead of scene files: per seed a views file views-SEED.safetensors holding the "
                             "scene's view 0 and this many views from other cameras (per-scene fitting)")
    parser.add_argument("--camera-seed", type=int, default=0, help="seed of the --extra-views cameras")
    parser.add_argument("--exclude-views", default="1,2",
                        help="scene views whose cameras no extra view may come near (default 1,2: the targets)")
    parser.add_argument("--exclude-cameras", type=Path,
                        help="a views file whose extra cameras (views 1..) the extra views keep away from too "
                             "(a validation set held out like the targets)")
    parser.add_argument("--exclude-deg", type=float, default=5.0,
                        help="minimum angle at the scene centre between an extra camera and an excluded one")
    args = parser.parse_args(argv)
    try:
        first_seed = resolve_seeds(args)
        if args.supersample < 1 or args.batch < 1 or args.shard_size < 0 or args.pngs < 0 or args.extra_views < 0:
            raise ValueError("--supersample and --batch must be >= 1, --shard-size, --pngs and --extra-views >= 0")
        exclude_views = [int(v) for v in args.exclude_views.split(",") if v.strip()]
        if any(not 0 <= v < VIEWS for v in exclude_views):
            raise ValueError(f"--exclude-views {args.exclude_views!r}: views are 0 to {VIEWS - 1}")
        if args.extra_views and args.exclude_deg <= 0:
            raise ValueError(f"--exclude-deg {args.exclude_deg}: must be > 0")
        exclude_positions = np.zeros((0, 3), np.float32)
        if args.exclude_cameras:
            with safe_open(args.exclude_cameras, "np") as file:
                if file.metadata().get("format") != VIEWS_FORMAT:
                    raise ValueError(f"--exclude-cameras {args.exclude_cameras}: not a {VIEWS_FORMAT} file")
                exclude_positions = file.get_tensor("camera_pos")[0, 1:]
        args.out.mkdir(parents=True, exist_ok=True)
    except (ValueError, OSError) as error:
        print(f"make_scenes: error: {error}", file=sys.stderr)
        return 2
    command = "python3 tools/data/make_scenes.py " + " ".join(shlex.quote(a) for a in (argv or sys.argv[1:]))
    height, width = args.size
    if args.extra_views:
        start = time.perf_counter()
        for seed in range(first_seed, first_seed + args.count):
            spec = sample_scene(seed)
            extra = extra_cameras(spec, args.extra_views, args.camera_seed, exclude_views, args.exclude_deg,
                                  exclude_positions)
            camera_pos = np.concatenate((spec.camera_pos[:1], extra)).astype(np.float32)
            images, depth, masks = render_extra_views(spec, camera_pos, height, width, args.supersample)
            nearest = angle_between_deg(extra, spec.camera_pos[exclude_views]).min(0) if exclude_views else []
            cameras = {"view_0": "the scene's view 0 (its input view)",
                       "extra_views": f"views 1..{args.extra_views}: azimuth uniform in [0, 360), distance uniform "
                                      f"in {list(CAMERA_RADIUS)}, elevation uniform in {list(CAMERA_ELEVATION)} deg",
                       "camera_seed": args.camera_seed, "excluded_scene_views": exclude_views,
                       "exclude_deg": args.exclude_deg,
                       "nearest_extra_to_excluded_deg": [round(float(a), 3) for a in nearest]}
            if args.exclude_cameras:
                cameras["excluded_cameras_of"] = str(args.exclude_cameras)
                cameras["nearest_extra_to_those_deg"] = round(float(angle_between_deg(extra, exclude_positions).min()), 3)
            write_views(args.out / f"views-{seed:07d}.safetensors", spec, images, depth, masks, camera_pos, command,
                        cameras)
            if seed - first_seed < args.pngs:
                write_png(args.out / f"views-{seed:07d}.png", views_strip(images))
        seconds = time.perf_counter() - start
        print(f"wrote views of {args.count} scenes (view 0 and {args.extra_views} extra views each, {height}x{width}, "
              f"supersample {args.supersample}) to {args.out} in {seconds:.1f} s")
        return 0
    group = args.shard_size or args.batch  # scenes rendered and written together
    start = time.perf_counter()
    for group_start in range(first_seed, first_seed + args.count, group):
        seeds = range(group_start, min(group_start + group, first_seed + args.count))
        specs = [sample_scene(seed) for seed in seeds]
        parts = [render(specs[i:i + args.batch], height, width, args.supersample)
                 for i in range(0, len(specs), args.batch)]
        images, depth, masks, camera_pos = (np.concatenate(p) for p in zip(*parts))
        if args.shard_size:
            index = (group_start - first_seed) // args.shard_size
            write_shard(args.out / f"shard-{index:05d}.safetensors", group_start, images, depth, masks,
                        camera_pos, command)
        else:
            for i, spec in enumerate(specs):
                write_scene(args.out / f"scene-{spec.seed:07d}.safetensors", spec, images[i], depth[i], masks[i],
                            camera_pos[i], command)
        for i, spec in enumerate(specs):
            if spec.seed - first_seed < args.pngs:
                write_png(args.out / f"scene-{spec.seed:07d}.png", preview(images[i], depth[i], masks[i]))
    seconds = time.perf_counter() - start
    print(f"wrote {args.count} scenes ({height}x{width}, supersample {args.supersample}) to {args.out} "
          f"in {seconds:.1f} s ({args.count / seconds:.1f} scenes/s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
