"""Quoting what a caller passed in a message: a bounded excerpt, so that a message stays one short line however
large the value (a 50 MB string or array quoted whole would be a 50 MB exception); the engine's messages quote
alike (raypatch_model::error::Quoted)."""

from __future__ import annotations

import reprlib

from ._raypatch import MAX_QUOTED_CHARS as QUOTED_CHARS  # as much as the engine's messages quote
# Longest path written whole in a message (longer than any a file system takes, short of a flooded one).
PATH_CHARS = 1000

# reprlib bounds the work as well as the text: a list of millions of numbers is never turned into one string.
_REPR = reprlib.Repr()
_REPR.maxstring = _REPR.maxother = _REPR.maxlong = QUOTED_CHARS


def excerpt(text, most: int = QUOTED_CHARS) -> str:
    """`text` (or str of it) as it is when short, else its first `most` characters and its length."""
    text = str(text)
    return text if len(text) <= most else f"{text[:most]}... ({len(text)} characters)"


def path_text(path) -> str:
    """A path for a message: whole up to PATH_CHARS characters."""
    return excerpt(path, PATH_CHARS)


def quoted(value) -> str:
    """`value` as Python writes it (repr), bounded: a string's first QUOTED_CHARS characters and its length,
    another value's repr cut at QUOTED_CHARS characters."""
    if isinstance(value, str):
        head = repr(value[:QUOTED_CHARS])
        return head if len(value) <= QUOTED_CHARS else f"{head}... ({len(value)} characters)"
    text = _REPR.repr(value)
    return text if len(text) <= QUOTED_CHARS else f"{text[:QUOTED_CHARS]}..."
