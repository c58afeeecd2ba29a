"""A byte-stable safetensors writer.

safetensors.torch.save_file orders the header's metadata by hash, so regenerating an unchanged file changes its
bytes; this writer sorts metadata and tensor names, so committed golden files only change when their content does.
The layout is the standard one: u64 little-endian header length, JSON header padded with spaces to 8 bytes,
then the little-endian tensor data in header order.
"""

import json
import os
import struct
from pathlib import Path

import torch

DTYPE_NAMES = {torch.float32: "F32", torch.float64: "F64", torch.uint8: "U8"}


def save_safetensors(path, tensors, metadata):
    """Writes float32, float64 or uint8 tensors and string metadata to path atomically (temporary file, rename)."""
    header = {"__metadata__": dict(sorted(metadata.items()))}
    chunks, offset = [], 0
    for name in sorted(tensors):
        tensor = tensors[name].detach().cpu()
        array = tensor.contiguous().numpy()
        data = array.astype(array.dtype.newbyteorder("<"), copy=False).tobytes()
        header[name] = {"dtype": DTYPE_NAMES[tensor.dtype], "shape": list(tensor.shape),
                        "data_offsets": [offset, offset + len(data)]}
        chunks.append(data)
        offset += len(data)
    header_bytes = json.dumps(header, separators=(",", ":")).encode()
    header_bytes += b" " * (-len(header_bytes) % 8)

    path = Path(path)
    temporary = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(temporary, "wb") as file:
            file.write(struct.pack("<Q", len(header_bytes)))
            file.write(header_bytes)
            for data in chunks:
                file.write(data)
        os.replace(temporary, path)
    finally:
        temporary.unlink(missing_ok=True)

