"""raypatch: Light Field Transformers (SRT, OSRT, DeFiNe and their Ray-Patch variants) on any GPU.

Load a model (official PyTorch checkpoints converted with tools/conversion/convert_checkpoint.py, or a bundled
one), encode posed images into a scene once, render it from any camera: rgb, depth, log-depth and OSRT's
object masks as numpy arrays. The engine is raypatch's Rust one (WGSL kernels on wgpu: Vulkan, Metal, DX12, or
the CPU through Mesa lavapipe); this package wraps it and reimplements nothing.

    import raypatch
    model = raypatch.bundled("fitted")
    model.encode_scene(raypatch.bundled_scene()).render_view(0).save("view.png")

Arrays in: anything numpy can read (numpy arrays, CPU torch tensors, objects with ``__array__`` or
``__dlpack__``); images uint8 or float in [0, 1]. Arrays out: numpy float32. Every refusal raises a
``raypatch.Error`` subclass with a one-line message; the GIL is released while the GPU works.
"""

from __future__ import annotations

import json
import operator
import os
from typing import Iterable, Iterator, Optional, Sequence, Tuple, Union

import numpy as np

from . import _raypatch
from ._raypatch import BUNDLED_MODELS, BUNDLED_SCENES, EngineClosed, Error, FileError, GpuError, InputError
from ._text import excerpt, quoted

# Before any engine loads a driver (issue 50): where HOME's cache folder cannot be written, Mesa's shader cache
# goes to raypatch's cache folder, or is off, instead of Mesa saying so on stderr four times. Set through
# os.environ (under the GIL), so Python and the driver see one environment; a variable the user set is kept.
_DRIVER_CACHE_VARS, DRIVER_CACHE_NOTE = _raypatch.driver_cache_env()
os.environ.update(_DRIVER_CACHE_VARS)

__all__ = [
    "Engine", "Model", "Scene", "SceneData", "Rendered", "load", "bundled", "load_scene", "bundled_scene",
    "psnr", "ssim", "fg_ari", "depth_errors", "Error", "InputError", "FileError", "GpuError", "EngineClosed",
    "BUNDLED_MODELS", "BUNDLED_SCENES",
]

OUTPUTS = ("rgb", "logdepth", "depth", "segmentation")
PathLike = Union[str, "os.PathLike[str]"]
# Most values in one array converted for the engine: the largest any call takes is a scene's images or rays.
MAX_VALUES = 3 * _raypatch.MAX_SCENE_PIXELS
# render_path's batches per render_batch call: the GPU renders one while the last is read back, and at most
# these many batches of frames are held.
PATH_BATCHES = 4


def _array(name: str, value) -> np.ndarray:
    """`value` as a numpy array without a copy where numpy can (buffer protocol, __array__, __dlpack__)."""
    if isinstance(value, np.ndarray):
        return value
    try:
        if hasattr(value, "__array__") or not hasattr(value, "__dlpack__"):
            return np.asarray(value)
        return np.from_dlpack(value)
    except Exception as e:  # anything that is not an array of numbers
        raise InputError(f"{name}: cannot be read as an array ({type(value).__name__}: {excerpt(e)})") from None


def _floats(name: str, value, shape: Tuple[Optional[int], ...], dtype=np.float32, image: bool = False) -> np.ndarray:
    """A C-contiguous, finite `dtype` array (float32 by default) of `shape` (None: any size), from floats or
    integers, or for an `image` (`[..., H, W, 3]`) from floats or uint8 (divided by 255). Sizes are checked before
    anything is converted: an array too large for the engine is an InputError, not a MemoryError."""
    array = _array(name, value)
    if array.ndim != len(shape) or any(want is not None and got != want for got, want in zip(array.shape, shape)):
        wanted = "[" + ", ".join("*" if s is None else str(s) for s in shape) + "]"
        raise InputError(f"{name}: shape {list(array.shape)}, expected {wanted}")
    if array.size > MAX_VALUES:
        raise InputError(f"{name}: shape {list(array.shape)}, more than the {MAX_VALUES} values accepted")
    if image:
        height, width = array.shape[-3:-1]
        _raypatch.check_images(name, int(np.prod(array.shape[:-3])), width, height)
    if image and array.dtype == np.uint8:
        array = array.astype(np.float32) / np.float32(255.0)
    elif array.dtype.kind == "f" or (array.dtype.kind in ("i", "u") and not image):
        array = array.astype(dtype, copy=False)
    else:  # bool, complex, strings, objects; and integer images other than uint8, whose scale is unknown
        raise InputError(f"{name}: dtype {array.dtype}, expected {'uint8 or floating point' if image else 'numbers'}")
    if not np.isfinite(array).all():
        raise InputError(f"{name}: holds NaN or infinity")
    return np.ascontiguousarray(array)


def _integer(name: str, value) -> int:
    """A whole number from Python or numpy (a float only where whole; never a bool) within 64 bits: the binding
    refuses a negative one where it needs a size, count or index, naming `name`."""
    if isinstance(value, (bool, np.bool_)):
        raise InputError(f"{name} {value}: expected an integer, not a bool")
    try:
        number = operator.index(value)
    except TypeError:
        whole = isinstance(value, (float, np.floating)) and float(value).is_integer()
        if not whole:
            raise InputError(f"{name} {quoted(value)}: expected an integer") from None
        number = int(value)
    if not -(2 ** 63) <= number < 2 ** 63:
        raise InputError(f"{name}: an integer of {number.bit_length()} bits, expected one that fits 64 bits")
    return number


def _text(name: str, value, optional: bool = False) -> Optional[str]:
    """A string argument (or None where `optional`)."""
    if (value is None and optional) or isinstance(value, str):
        return value
    raise InputError(f"{name} {quoted(value)}: expected a string")


def _path(name: str, value) -> str:
    """A path argument: a string, bytes or os.PathLike."""
    try:
        return os.fsdecode(os.fspath(value))
    except TypeError:
        raise InputError(f"{name} {quoted(value)}: expected a path (str, bytes or os.PathLike)") from None


def _number(name: str, value) -> float:
    """A finite number from Python or numpy, integers included (not a bool)."""
    return _floats(name, value, (), np.float64).item()


def _bytes(array: np.ndarray) -> bytes:
    return array.astype("<f4", copy=False).tobytes()


def _opencv_poses(name: str, poses, convention, count: Optional[int] = None) -> list:
    """4x4 camera-to-world matrices ([4, 4] or [count, 4, 4], float64: a pose is never rounded to float32) with
    the axes `convention` names, as the binding's row-major OpenCV poses (raypatch.input checks each is rigid)."""
    array = _array(name, poses)
    if array.ndim == 2 and count is None:
        array = array[None]
    array = _floats(name, array, (count, 4, 4), np.float64)
    return _raypatch.opencv_poses(name, array.astype("<f8", copy=False).tobytes(), len(array),
                                  _text("convention", convention))


def _intrinsics(name: str, intrinsics, count: int) -> list:
    """(fx, fy, cx, cy) per view from 3x3 K matrices or (fx, fy, cx, cy) rows, one shared or one per view."""
    array = _floats(name, intrinsics, (None,) * np.ndim(_array(name, intrinsics)), np.float64)
    if array.shape in ((3, 3), (4,)):
        array = np.broadcast_to(array, (count,) + array.shape)
    if array.shape == (count, 3, 3):
        return [(k[0, 0], k[1, 1], k[0, 2], k[1, 2]) for k in array]
    if array.shape == (count, 4):
        return [tuple(k) for k in array]
    raise InputError(f"{name}: shape {list(array.shape)}, expected a 3x3 K, (fx, fy, cx, cy), or one per view")


class Engine:
    """One GPU adapter: a real GPU when there is one, else a CPU one (lavapipe). ``adapter`` picks by name
    (case-insensitive substring); ``matmul`` forces a kernel family ("rows", "tiled", "lanes"); ``precision`` is
    "f32" (default), "f16" (f16 linear weights) or "f16-act" (the tensor path: every GEMM on cooperative
    matrices where the device has them, operands rounded to f16, sums in f32; rgb within ~2e-2); f16 needs the
    adapter's shader-f16."""

    def __init__(self, adapter: Optional[str] = None, matmul: Optional[str] = None, precision: str = "f32"):
        self._inner = _raypatch.Engine(_text("adapter", adapter, True), _text("matmul", matmul, True),
                                       _text("precision", precision))

    @staticmethod
    def adapters() -> list:
        """Every adapter wgpu sees, the default first: dicts of name, kind, backend and driver."""
        return _raypatch.Engine.adapters()

    @property
    def adapter(self) -> str:
        return self._inner.adapter

    @property
    def closed(self) -> bool:
        return self._inner.closed

    def close(self) -> None:
        """Later calls on this engine, its models and their scenes raise EngineClosed; their GPU memory is freed
        once Python drops them."""
        self._inner.close()

    def __enter__(self) -> "Engine":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def load(self, path: PathLike) -> "Model":
        """A model file (safetensors with the official key names and the config in its metadata)."""
        return Model(self._inner.load(_path("path", path)))

    def bundled(self, name: str = "fitted") -> "Model":
        """A model shipped with the package (BUNDLED_MODELS): "fitted" is RP-SRT k=4 fitted to the bundled scene."""
        return Model(self._inner.load_bundled(_text("name", name)))

    def __repr__(self) -> str:
        return f"raypatch.Engine({self.adapter!r}{', closed' if self.closed else ''})"


_default_engine: Optional[Engine] = None


def default_engine() -> Engine:
    """The engine `load` and `bundled` use, made on first use."""
    global _default_engine
    if _default_engine is None or _default_engine.closed:
        _default_engine = Engine()
    return _default_engine


def load(path: PathLike) -> "Model":
    """A model file on the default engine."""
    return default_engine().load(path)


def bundled(name: str = "fitted") -> "Model":
    """A bundled model on the default engine."""
    return default_engine().bundled(name)


class SceneData:
    """Posed views from a scene file (docs/FORMATS.md) or a folder with transforms.json: inputs to encode and
    target views with their ground truth."""

    def __init__(self, inner):
        self._inner = inner

    @property
    def input_count(self) -> int:
        return self._inner.input_count

    @property
    def target_count(self) -> int:
        return self._inner.target_count

    def target_size(self, i: int) -> Tuple[int, int]:
        """(width, height) of target view i."""
        return self._inner.target_size(_integer("view", i))

    def target_image(self, i: int) -> Optional[np.ndarray]:
        """Ground truth [H, W, 3] float32 in [0, 1], or None."""
        data = self._inner.target_image(_integer("view", i))
        width, height = self.target_size(i)
        return None if data is None else np.frombuffer(data, "<f4").reshape(height, width, 3)

    def target_masks(self, i: int) -> Optional[np.ndarray]:
        """Object ids [H, W] uint32 (0: background), or None."""
        data = self._inner.target_masks(_integer("view", i))
        width, height = self.target_size(i)
        return None if data is None else np.frombuffer(data, "<u4").reshape(height, width)

    def target_depth(self, i: int) -> Optional[np.ndarray]:
        """Depth [H, W] float32 in metres (0 where unknown), or None."""
        data = self._inner.target_depth(_integer("view", i))
        width, height = self.target_size(i)
        return None if data is None else np.frombuffer(data, "<f4").reshape(height, width)


def load_scene(path: PathLike) -> SceneData:
    """A scene safetensors file or a folder holding transforms.json."""
    return SceneData(_raypatch.SceneData.load(_path("path", path)))


def bundled_scene(name: str = "scene-2000000") -> SceneData:
    """A scene shipped with the package (BUNDLED_SCENES): held-out views of a procedural MultiShapeNet-style scene."""
    return SceneData(_raypatch.SceneData.bundled(_text("name", name)))


class Rendered(dict):
    """One render: output name -> float32 array over the region: "rgb" [H, W, 3], "logdepth" and "depth" [H, W],
    "segmentation" [H, W, slots]. Batched renders (Scene.render_many) add a leading view axis."""

    def save(self, path: PathLike, output: str = "rgb") -> None:
        """Writes the rgb image as a PNG (written beside, then renamed into place)."""
        _raypatch.save_png(*self._rgb("save", output), _path("path", path))

    def png(self, output: str = "rgb") -> bytes:
        """The rgb image as the bytes of a PNG file (for raypatch.output.Staged.write)."""
        return _raypatch.encode_png(*self._rgb("png", output))

    def _rgb(self, what: str, output: str) -> tuple:
        """The rgb image as bytes, width, height."""
        if output != "rgb" or "rgb" not in self:
            raise InputError(f"{what}: needs the rgb output (rendered: {quoted(sorted(self))})")
        rgb = self["rgb"]
        if rgb.ndim != 3:
            raise InputError(f"{what}: a batched render holds several views; take one, e.g. Rendered(rgb=r['rgb'][0])")
        height, width, _ = rgb.shape
        return _bytes(rgb), width, height


def _rendered(raw: dict) -> Rendered:
    out = Rendered()
    for name, (data, (height, width, channels)) in raw.items():
        array = np.frombuffer(data, "<f4").reshape(height, width, channels)
        out[name] = array[..., 0] if name in ("logdepth", "depth") else array
    return out


def _output_names(outputs: Union[str, Iterable[str]]) -> list:
    try:
        names = [outputs] if isinstance(outputs, str) else list(outputs)
    except TypeError:
        raise InputError(f"outputs {quoted(outputs)}: expected a name or names of {OUTPUTS}") from None
    if not names or not all(isinstance(n, str) for n in names):
        raise InputError(f"outputs {quoted(names)}: expected some of {OUTPUTS}")
    return names


def _region(region: Optional[Sequence[int]]) -> Optional[tuple]:
    """(x, y, width, height) of the pixels to render, or None for all."""
    if region is None:
        return None
    if not isinstance(region, (tuple, list, np.ndarray)) or len(region) != 4:
        raise InputError(f"region {quoted(region)}: expected (x, y, width, height)")
    return tuple(_integer(f"region {n}", v) for n, v in zip(("x", "y", "width", "height"), region))


class Model:
    """A model with its weights on the GPU."""

    def __init__(self, inner):
        self._inner = inner

    @property
    def config(self) -> dict:
        """The model section of the run config, with the official defaults filled in."""
        return json.loads(self._inner.config_json)

    @property
    def name(self) -> str:
        """As the paper names it, e.g. "RP-SRT k=4"."""
        return self._inner.name

    @property
    def path(self) -> str:
        return self._inner.path

    @property
    def patch_size(self) -> int:
        """Ray-Patch's k (1 for a per-pixel decoder)."""
        return self._inner.patch_size

    @property
    def outputs(self) -> Tuple[str, ...]:
        return tuple(self._inner.outputs)

    @property
    def parameter_count(self) -> int:
        return self._inner.parameter_count

    def encode(self, images, poses=None, intrinsics=None, convention: str = "opengl", *, positions=None,
               rays=None) -> "Scene":
        """Encodes posed images [V, H, W, 3] (uint8, or float in [0, 1]) into a scene.

        Pinhole cameras: ``poses`` [V, 4, 4] camera-to-world (``convention`` "opengl": x right, y up, looking
        along -z, as transforms.json; or "opencv") and ``intrinsics`` (a 3x3 K or (fx, fy, cx, cy), shared or
        one per view). Or the rays scene files hold: ``positions`` [V, 3] camera centres and ``rays``
        [V, H, W, 3] (unit directions; unit-depth points for DeFiNe)."""
        images = _floats("images", images, (None, None, None, 3), image=True)
        count, height, width, _ = images.shape
        if rays is not None or positions is not None:
            if poses is not None or intrinsics is not None:
                raise InputError("encode: give poses and intrinsics, or positions and rays, not both")
            if rays is None or positions is None:
                raise InputError("encode: rays and positions go together")
            positions = _floats("positions", positions, (count, 3), np.float64)
            rays = _floats("rays", rays, (count, height, width, 3))
            scene = self._inner.encode_rays(_bytes(images), (count, height, width),
                                            [tuple(p) for p in positions], _bytes(rays))
            return Scene(scene, self, None)
        if poses is None or intrinsics is None:
            raise InputError("encode: needs poses and intrinsics (or positions and rays)")
        k = _intrinsics("intrinsics", intrinsics, count)
        poses = _opencv_poses("poses", poses, convention, count)
        scene = self._inner.encode_posed(_bytes(images), (count, height, width), poses, k)
        cameras = [(p, (*k_i, width, height)) for p, k_i in zip(poses, k)]
        return Scene(scene, self, (k[0], width, height), cameras=cameras)

    def encode_scene(self, data: SceneData) -> "Scene":
        """Encodes the input views of a scene file or frames folder (load_scene, bundled_scene)."""
        return Scene(self._inner.encode_data(data._inner), self, None, data)

    def __repr__(self) -> str:
        return f"raypatch.Model({self.name!r}, {self.path!r})"


class Scene:
    """A scene encoded by a model (its latent tokens, computed once): render it from any camera."""

    def __init__(self, inner, model: Model, camera, data: Optional[SceneData] = None, cameras=None):
        self._inner = inner
        self.model = model
        # (fx, fy, cx, cy) and the size of input view 0, for renders that give no intrinsics.
        self._camera = camera
        self._data = data
        # The input cameras as (row-major OpenCV pose, (fx, fy, cx, cy, width, height)), when encoded from poses.
        self._cameras = cameras

    def _camera_of(self, intrinsics, size) -> Tuple[float, float, float, float, int, int]:
        """(fx, fy, cx, cy, width, height): the intrinsics given at `size` (by default input view 0's size), or
        input view 0's camera, resized to `size` when given (raypatch.input's one policy: the vertical field of
        view and the principal point's relative position kept)."""
        if size is not None:
            if not isinstance(size, (tuple, list, np.ndarray)) or len(size) != 2:
                raise InputError(f"size {quoted(size)}: expected (width, height)")
            size = (_integer("width", size[0]), _integer("height", size[1]))
        if intrinsics is None:
            if self._camera is None:
                raise InputError("render: needs intrinsics (the scene was not encoded from pinhole cameras)")
            k, width, height = self._camera
            return (*k, width, height) if size is None else _raypatch.resized_camera((*k, width, height), *size)
        if size is None:
            if self._camera is None:
                raise InputError("render: needs size=(width, height)")
            size = self._camera[1:]
        return (*_intrinsics("intrinsics", intrinsics, 1)[0], *size)

    def render(self, pose, intrinsics=None, size: Optional[Sequence[int]] = None,
               outputs: Union[str, Iterable[str]] = ("rgb",), region: Optional[Sequence[int]] = None,
               convention: str = "opengl") -> Rendered:
        """Renders a 4x4 camera-to-world ``pose`` (intrinsics and size: by default input view 0's). ``region`` =
        (x, y, width, height) renders only those pixels (and decodes only the patches they need)."""
        camera = self._camera_of(intrinsics, size)
        pose = _opencv_poses("pose", pose, convention)
        if len(pose) != 1:
            raise InputError("render: one pose [4, 4]; render_many takes [T, 4, 4]")
        raw = self._inner.render_posed((pose[0], camera), _output_names(outputs), _region(region))
        return _rendered(raw)

    def render_many(self, poses, intrinsics=None, size: Optional[Sequence[int]] = None,
                    outputs: Union[str, Iterable[str]] = ("rgb",), region: Optional[Sequence[int]] = None,
                    convention: str = "opengl") -> Rendered:
        """Renders poses [T, 4, 4] as render does; each output gets a leading axis of T views. The views render
        as many at once as the engine's memory budget allows, each batch submitted before the last is read."""
        camera = self._camera_of(intrinsics, size)
        poses = _floats("poses", poses, (None, 4, 4), np.float64)
        cameras = [(p, camera) for p in _opencv_poses("poses", poses, convention)]
        if not cameras:
            return Rendered({})
        renders = [_rendered(raw) for raw in self._inner.render_batch(cameras, _output_names(outputs), _region(region))]
        return Rendered({name: np.stack([r[name] for r in renders]) for name in renders[0]})

    def render_view(self, i: int, outputs: Union[str, Iterable[str]] = ("rgb",),
                    region: Optional[Sequence[int]] = None) -> Rendered:
        """Renders target view i of the scene file this scene was encoded from (encode_scene)."""
        if self._data is None:
            raise InputError("render_view: the scene was not encoded from a scene file (use render)")
        view = _integer("view", i)
        return _rendered(self._inner.render_target(self._data._inner, view, _output_names(outputs), _region(region)))


    def render_path(self, poses=None, intrinsics=None, size: Optional[Sequence[int]] = None, *,
                    camera_path: Optional[PathLike] = None, motion: Optional[str] = None, frames: int = 36,
                    elevation: Optional[float] = None, radius: Optional[float] = None, centre=None, up=None,
                    fade: bool = False, interpolate: bool = False, outputs: Union[str, Iterable[str]] = ("rgb",),
                    convention: str = "opengl", batch: int = 4) -> Iterator[Rendered]:
        """Renders a sequence of cameras, yielding one Rendered per frame as it is rendered (``batch`` frames
        per render call, one plan for the whole sequence, each batch submitted before the last is read back; at
        most PATH_BATCHES batches are held).

        The cameras: ``poses`` [T, 4, 4] (intrinsics and size as render), the cameras of a ``camera_path`` file
        (nerfstudio's camera_path.json or raypatch's form, docs/CAMERA_PATHS.md), or a ``motion`` preset
        ("orbit", "spiral", "zoom", "closeup", "eyeroll") of ``frames`` frames from the scene's first target
        camera (scene files) or first input camera, about ``centre`` (default: the point nearest to the scene
        cameras' optical axes) and ``up`` (default: the world axis nearest their up), at ``elevation`` degrees
        and ``radius`` (default: the start camera's). ``interpolate=True``: ``frames`` cameras along a smooth
        path through the given poses, the camera path's cameras, or else the scene's cameras."""
        cameras = self._path_cameras(poses, intrinsics, size, camera_path, motion, frames, elevation, radius,
                                     centre, up, fade, interpolate, convention)
        names = _output_names(outputs)
        batch = _integer("batch", batch)
        if batch < 1:
            raise InputError(f"render_path: batch {batch}: expected at least 1")
        return self._frames(cameras, names, batch)

    def _frames(self, cameras: list, names: list, batch: int) -> Iterator[Rendered]:
        # PATH_BATCHES batches per call: within a call each batch is submitted before the last is read back.
        group = batch * PATH_BATCHES
        for start in range(0, len(cameras), group):
            chunk = cameras[start:start + group]
            real = len(chunk)
            if len(cameras) > batch and real % batch:  # a short last batch filled up: one plan for the sequence
                chunk = chunk + [chunk[-1]] * (batch - real % batch)
            for raw in self._inner.render_batch(chunk, names, None, batch)[:real]:
                yield _rendered(raw)

    def _scene_cameras(self) -> Tuple[list, int]:
        """The scene's cameras (inputs, then targets) and the index of the one motions start from."""
        if self._data is not None:
            return self._inner.fitted_cameras(self._data._inner), self._data.input_count
        if self._cameras is not None:
            return self._cameras, 0
        raise InputError("render_path: the scene was encoded from rays: give poses or a camera_path")

    def _path_cameras(self, poses, intrinsics, size, camera_path, motion, frames, elevation, radius, centre, up,
                      fade, interpolate, convention) -> list:
        given = [name for name, v in (("poses", poses), ("camera_path", camera_path), ("motion", motion)) if v is not None]
        if len(given) > 1:
            raise InputError(f"render_path: give one of poses, camera_path and motion, not {' and '.join(given)}")
        if poses is not None:
            camera = self._camera_of(intrinsics, size)
            cameras = [(p, camera) for p in _opencv_poses("poses", poses, convention)]
        elif camera_path is not None:
            cameras = _raypatch.camera_path_cameras(_path("camera_path", camera_path))[0]
        elif motion is not None:
            scene, first = self._scene_cameras()
            if centre is None:
                centre = _raypatch.scene_centre([pose for pose, _ in scene])
            if up is None:
                up = _raypatch.up_axis([pose for pose, _ in scene])
            if not isinstance(motion, str):
                raise InputError(f"motion {quoted(motion)}: expected a name such as \"orbit\"")
            point = lambda name, v: tuple(float(x) for x in _floats(name, v, (3,), np.float64))
            number = lambda name, v: None if v is None else _number(name, v)
            return _raypatch.motion_cameras(motion, scene[first], _integer("frames", frames), point("centre", centre),
                                            point("up", up), number("elevation", elevation), number("radius", radius),
                                            bool(fade))
        elif interpolate:
            cameras = self._scene_cameras()[0]
        else:
            raise InputError("render_path: give poses, a camera_path or a motion")
        return _raypatch.interpolate_cameras(cameras, _integer("frames", frames)) if interpolate else cameras


def _nonempty(name: str, value) -> np.ndarray:
    """An array with some values: a metric of none is refused (as psnr and ssim refuse empty images)."""
    array = _array(name, value)
    if array.size == 0:
        raise InputError(f"{name}: shape {list(array.shape)} is empty, expected at least one pixel")
    return array


def _image_pair(metric: str, a, b) -> tuple:
    """Two images of one shape, [H, W, 3], neither empty, as the binding's metrics take them."""
    a, b = _floats("a", a, (None, None, 3), image=True), _floats("b", b, (None, None, 3), image=True)
    if a.shape != b.shape:
        raise InputError(f"{metric}: images of shapes {list(a.shape)} and {list(b.shape)}")
    return _bytes(a), _bytes(b), a.shape[1], a.shape[0]


def psnr(a, b) -> float:
    """PSNR in dB of two [H, W, 3] images in [0, 1] (the engine's, as render-frame --metrics)."""
    return _raypatch.psnr(*_image_pair("psnr", a, b))


def ssim(a, b) -> float:
    """SSIM of two [H, W, 3] images in [0, 1], as the official evaluation computes it."""
    return _raypatch.ssim(*_image_pair("ssim", a, b))


def fg_ari(true_ids, weights) -> float:
    """FG-ARI of slot weights [H, W, slots] against object ids [H, W] (0: background, ignored)."""
    weights = _floats("weights", _nonempty("weights", weights), (None, None, None))
    ids = _array("true_ids", true_ids)
    if ids.shape != weights.shape[:2] or ids.dtype.kind not in "ui":
        raise InputError(f"true_ids: {ids.dtype} {list(ids.shape)}, expected integers {list(weights.shape[:2])}")
    if ids.size and (ids.min() < 0 or ids.max() > np.iinfo(np.uint32).max):
        raise InputError("true_ids: object ids must fit uint32")
    pixels = ids.size
    return _raypatch.fg_ari(ids.astype("<u4").tobytes(), _bytes(weights), pixels, weights.shape[2])


def depth_errors(predicted, truth) -> dict:
    """Abs.Rel, Sq.Rel and RMSE of predicted depth against ground truth (same shape; truth 0 = no data), over
    the pixels with ground truth, as the official DeFiNe test step computes them."""
    predicted = _floats("predicted", _nonempty("predicted", predicted), (None, None))
    truth = _floats("truth", truth, predicted.shape)
    abs_rel, sq_rel, rmse, pixels = _raypatch.depth_errors(_bytes(predicted), _bytes(truth), predicted.size)
    return {"abs_rel": abs_rel, "sq_rel": sq_rel, "rmse": rmse, "pixels": pixels}
