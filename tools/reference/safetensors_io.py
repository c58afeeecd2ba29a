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
    """Writes float32, float64 or uint8 tensors and string metadata to path atomically (a new temporary file in
    its folder, renamed into place)."""
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
    temporary = temporary_path(path)
    # Created here (O_EXCL: never an existing file or a symlink planted at that name), removed unless renamed.
    descriptor = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0), 0o666)
    try:
        with os.fdopen(descriptor, "wb") as file:
            file.write(struct.pack("<Q", len(header_bytes)))
            file.write(header_bytes)
            for data in chunks:
                file.write(data)
        os.replace(temporary, path)
    finally:
        temporary.unlink(missing_ok=True)


def temporary_path(path):
    """`.NAME.PID.tmp` beside path, NAME shortened so that the temporary's name fits in its folder (255 bytes on
    most file systems) whenever path's own name does."""
    try:
        name_max = os.pathconf(path.parent, "PC_NAME_MAX")
    except (OSError, ValueError, AttributeError):
        name_max = 255
    suffix = f".{os.getpid()}.tmp"
    name = path.name
    while name and len(os.fsencode(f".{name}{suffix}")) > name_max:
        name = name[:-1]
    return path.with_name(f".{name}{suffix}")

