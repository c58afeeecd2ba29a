"""Times PyTorch's linear layer (torch.nn.functional.linear with bias, float32, on the CPU or, on a CUDA GPU,
cuBLAS without TF32) on the shapes raypatch-bench --gemm measures, for the GMAC/s table of docs/PERFORMANCE.md:

    python3 tools/bench/bench_gemm_pytorch.py --shape 300x1536x1536 [--shape MxKxN ...] [--repeats N] [--device cuda]
                                              [--dtype float32|float16|bfloat16]

--dtype float16 or bfloat16: x, weight and bias in that type (cuBLAS's tensor-core GEMMs on a GPU; the tensor
step of tools/bench/gpu_bench.sh compares them with the engine's tensor GEMM).

Prints one JSON object: the torch version, its thread count, the device, and per shape (M x K x N: x [M, K],
weight [N, K]) the median, min and max wall time in ms over the runs after one warm-up, each run waited for.
Exit code 3 when PyTorch cannot be imported or has no such device, 2 on a bad shape.
"""

import argparse
import json
import sys
from pathlib import Path

try:
    import torch
except ImportError as error:
    print(f"PyTorch is not available: {error}", file=sys.stderr)
    sys.exit(3)

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tools/, whose packages this imports
from bench.bench_pytorch import device_name, device_of, summary, timed  # noqa: E402


def shape(text):
    try:
        m, k, n = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--shape {text!r}: expected MxKxN, e.g. 300x1536x1536")
    if min(m, k, n) < 1:
        raise argparse.ArgumentTypeError(f"--shape {text!r}: every side must be at least 1")
    return m, k, n


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--shape", type=shape, action="append", required=True)
    parser.add_argument("--repeats", type=int, default=10)
    parser.add_argument("--device", choices=["cpu", "cuda"], default="cpu")
    parser.add_argument("--dtype", choices=["float32", "float16", "bfloat16"], default="float32")
    args = parser.parse_args()
    if args.repeats < 1:
        parser.error("--repeats must be at least 1")
    device = device_of(args.device)
    torch.manual_seed(0)
    results = []
    for m, k, n in args.shape:
        dtype = getattr(torch, args.dtype)
        x, w, b = (torch.randn(*shape).to(device, dtype) for shape in ((m, k), (n, k), (n,)))
        with torch.no_grad():
            _, times = timed(lambda: torch.nn.functional.linear(x, w, b), args.repeats, device)
        results.append({"m": m, "k": k, "n": n, **summary(times)})
    print(json.dumps({"torch": torch.__version__, "threads": torch.get_num_threads(), "device": device_name(device),
                      "dtype": args.dtype, "shapes": results}))


if __name__ == "__main__":
    main()
