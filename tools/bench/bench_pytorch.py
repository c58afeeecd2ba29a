"""Times the PyTorch reference (tools/reference/raypatch_reference.py) on a raypatch model file and scene file, for
raypatch-bench, which runs it on the same weights and inputs as the engine in the same run:

    python3 tools/bench/bench_pytorch.py --model M.safetensors --scene S.safetensors [--repeats N] [--threads T]
                                   [--device cpu|cuda] [--compile] [--out-rgb O.safetensors]
                                   [--autocast-bf16 --out-autocast A.safetensors]

Prints one JSON object: the torch version, its thread count, the device, and the wall times in ms (median, min,
max over the runs after one warm-up) of encoding the input views and of rendering the target views, as the
official model computes them in float32 (eager), on the CPU or on a CUDA GPU (synchronised before each time is
read; TF32 off, so that the products are float32 as on the CPU). With --compile the same is timed again with
encode and render_views under torch.compile (the first, compiling, call is the warm-up), or why it failed. The
model is SRT / RP-SRT, OSRT / RP-OSRT or DeFiNe / RP-DeFiNe, by the config's `base`
(raypatch_reference.build_model); OSRT's render_views computes its segmentation beside rgb, as the official
OSRT.decoder does, and it is timed with it. With --out-rgb it also writes the (eager) rendered `rgb` [T, Ht, Wt, 3]
(and `logdepth` [T, Ht, Wt], `segmentation` [T, Ht, Wt, S] where the model returns them). With --autocast-bf16 the
eager model runs once more under `torch.autocast(device, dtype=torch.bfloat16)` (PyTorch's mixed precision: matrix
products and convolutions in bfloat16), timed as "autocast", its outputs (as float32) written to --out-autocast.
Exit code 3 when PyTorch cannot be imported or has no such device, 2 on a bad input.
"""

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

try:
    import torch
    from safetensors import safe_open
except ImportError as error:
    print(f"PyTorch is not available: {error}", file=sys.stderr)
    sys.exit(3)

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tools/, whose packages this imports
from reference.raypatch_reference import build_model  # noqa: E402
from reference.safetensors_io import save_safetensors  # noqa: E402


def read(path):
    with safe_open(str(path), "pt") as file:
        return {name: file.get_tensor(name) for name in file.keys()}, file.metadata() or {}


def load_model(path):
    tensors, metadata = read(path)
    if "config" not in metadata:
        raise ValueError(f"{path}: no `config` entry in the safetensors metadata")
    model = build_model(json.loads(metadata["config"])).eval()
    result = model.load_state_dict(tensors, strict=False)
    missing = [key for key in result.missing_keys if not key.endswith("num_batches_tracked")]
    if missing or result.unexpected_keys:
        raise ValueError(f"{path}: missing tensors {missing}, unexpected tensors {result.unexpected_keys}")
    return model


def target_size(scene, metadata):
    if "target_images" in scene:
        return tuple(scene["target_images"].shape[1:3])
    if "target_size" in metadata:
        height, width = metadata["target_size"].split("x")
        return int(height), int(width)
    return tuple(scene["target_rays"].shape[1:3])


def synchronize(device):
    """Waits for the device's queued work (CUDA runs asynchronously)."""
    if device.type == "cuda":
        torch.cuda.synchronize(device)


# Seconds of unrecorded runs before timing on a GPU, as the engine's harness does (measure::warm_for): a GPU
# idle between short runs holds its lowest clocks until it has been busy for a while.
GPU_WARM_SECONDS = 0.25


def timed(function, repeats, device=torch.device("cpu")):
    """(result, [wall ms per run]) after one warm-up run (on a GPU, as many as fill GPU_WARM_SECONDS), each run
    waited for on `device`."""
    warming = time.perf_counter()
    function()
    synchronize(device)
    while device.type == "cuda" and time.perf_counter() - warming < GPU_WARM_SECONDS:
        function()
        synchronize(device)
    times, result = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        result = function()
        synchronize(device)
        times.append((time.perf_counter() - start) * 1e3)
    return result, times


def device_of(name):
    """The torch device for --device, or exit code 3 when this PyTorch has none such."""
    if name == "cuda" and not torch.cuda.is_available():
        print("PyTorch has no CUDA device here", file=sys.stderr)
        sys.exit(3)
    if name == "cuda":
        # float32 products as on the CPU: no TF32 (PyTorch's default for matmul, set here for convolutions too).
        torch.backends.cuda.matmul.allow_tf32 = False
        torch.backends.cudnn.allow_tf32 = False
    return torch.device(name)


def device_name(device):
    return torch.cuda.get_device_name(device) if device.type == "cuda" else "cpu"


OUTPUT_NAMES = ("rgb", "logdepth", "segmentation")


def output_tensors(views):
    """The first batch item of render_views' (rgb, logdepth[, segmentation]) by name, float32 on the CPU, the
    outputs the model does not have (None) left out."""
    return {name: tensor[0].detach().float().cpu().contiguous()
            for name, tensor in zip(OUTPUT_NAMES, views) if tensor is not None}


def summary(times):
    return {"median_ms": statistics.median(times), "min_ms": min(times), "max_ms": max(times), "runs": len(times)}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", required=True, type=Path)
    parser.add_argument("--scene", required=True, type=Path)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)")
    parser.add_argument("--device", choices=["cpu", "cuda"], default="cpu")
    parser.add_argument("--compile", action="store_true", help="also time encode and render under torch.compile")
    parser.add_argument("--out-rgb", type=Path, default=None)
    parser.add_argument("--autocast-bf16", action="store_true",
                        help="also run (and time) the eager model under torch.autocast with bfloat16")
    parser.add_argument("--out-autocast", type=Path, default=None, help="where --autocast-bf16 writes its outputs")
    args = parser.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    device = device_of(args.device)
    try:
        model = load_model(args.model).to(device)
        scene, metadata = read(args.scene)
        size = target_size(scene, metadata)
    except (OSError, ValueError, KeyError) as error:
        print(f"bench_pytorch: {error}", file=sys.stderr)
        return 2

    def batch(name):
        return scene[name][None].to(device)

    def time_model(encode, render_views, autocast=False):
        """(outputs, encode times, render times) of one way of running the model."""
        with torch.no_grad(), torch.autocast(device.type, dtype=torch.bfloat16, enabled=autocast):
            z, encode_times = timed(lambda: encode(batch("input_images").permute(0, 1, 4, 2, 3),
                                                   batch("input_camera_pos"), batch("input_rays")), args.repeats, device)
            # SRT returns (rgb, logdepth), OSRT (rgb, logdepth, segmentation).
            views, render_times = timed(lambda: render_views(z, batch("target_camera_pos"), batch("target_rays"),
                                                             size), args.repeats, device)
        return output_tensors(views), summary(encode_times), summary(render_times)

    outputs, encode, render = time_model(model.encode, model.render_views)
    # The vector ISA PyTorch's CPU kernels use (AVX2, AVX512, ...): CPU ratios depend on it, as lavapipe's do not
    # in the same way (llvmpipe runs 256-bit vectors on both).
    result = {"torch_version": torch.__version__, "threads": torch.get_num_threads(),
              "cpu_capability": torch.backends.cpu.get_cpu_capability(), "device": device_name(device),
              "encode": encode, "render": render}
    if args.compile:
        try:
            _, encode, render = time_model(torch.compile(model.encode), torch.compile(model.render_views))
            result["compiled"] = {"encode": encode, "render": render}
        except Exception as error:  # noqa: BLE001 -- any failure of the compiler is reported, not fatal
            result["compile_error"] = f"{type(error).__name__}: {str(error).splitlines()[0] if str(error) else ''}"
    if args.autocast_bf16:
        autocast_outputs, encode, render = time_model(model.encode, model.render_views, autocast=True)
        result["autocast"] = {"dtype": "bfloat16", "encode": encode, "render": render}
        if args.out_autocast is not None:
            save_safetensors(args.out_autocast, autocast_outputs, {"format": "raypatch-bench-pytorch/1"})
    if args.out_rgb is not None:
        save_safetensors(args.out_rgb, outputs, {"format": "raypatch-bench-pytorch/1"})
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
