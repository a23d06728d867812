"""JSON: an object of equal-length arrays of numbers, or the same under ``"columns"``.

Parsing is bounded: nesting deeper than ``max_json_depth`` and numbers longer than
``max_number_chars`` are refused before Python builds them (a 10 000-deep ``[`` or a
5 000-digit integer is an attack, not a recording).  Rows count from 0.
"""
from __future__ import annotations

import json as _json
from typing import Any, Mapping

import numpy as np

from ._base import (ColumnSelector, Columns, Format, ReadLimits, RecordingError, RecordLike,
                    register_format)

_SCAN_BLOCK = 1 << 20


def json_depth(raw: bytes) -> int:
    """Deepest nesting of ``[``/``{`` outside strings; vectorised, in 1 MiB blocks."""
    raw = raw.replace(b"\\\\", b"__").replace(b'\\"', b"__")
    depth = 0
    deepest = 0
    in_string = False
    for start in range(0, len(raw), _SCAN_BLOCK):
        block = np.frombuffer(raw, np.uint8, count=min(_SCAN_BLOCK, len(raw) - start),
                              offset=start)
        idx = np.flatnonzero((block == 34) | (block == 91) | (block == 123)
                             | (block == 93) | (block == 125))
        if not idx.size:
            continue
        ch = block[idx]
        quotes = np.cumsum(ch == 34) + int(in_string)
        outside = (quotes % 2 == 0) & (ch != 34)
        step = np.where(outside & ((ch == 91) | (ch == 123)), 1,
                        np.where(outside & ((ch == 93) | (ch == 125)), -1, 0))
        levels = depth + np.cumsum(step)
        deepest = max(deepest, int(levels.max()))
        depth = int(levels[-1])
        in_string = bool(quotes[-1] % 2)
    return deepest


def loads_bounded(raw: bytes | str, name: str, limits: ReadLimits) -> Any:
    """``json.loads`` with depth and number-length limits (RecordingError on breach)."""
    data = raw.encode() if isinstance(raw, str) else bytes(raw)
    depth = json_depth(data)
    if depth > limits.max_json_depth:
        raise RecordingError(f"{name}: JSON nested {depth} levels deep, at most "
                             f"{limits.max_json_depth} allowed")

    def number(text: str) -> float:
        if len(text) > limits.max_number_chars:
            raise RecordingError(f"{name}: JSON number with {len(text)} characters "
                                 f"({text[:20]}...), at most {limits.max_number_chars}")
        return float(text)

    try:
        return _json.loads(data, parse_int=number, parse_float=number)
    except (_json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise RecordingError(f"{name}: invalid JSON ({exc})") from None


def columns_from_object(data: Any, name: str, select: ColumnSelector) -> dict[str, np.ndarray]:
    """The columns of a decoded JSON recording (object of lists, optionally under "columns")."""
    if isinstance(data, Mapping) and isinstance(data.get("columns"), Mapping):
        data = data["columns"]
    if not isinstance(data, Mapping):
        raise RecordingError(f"{name}: JSON must be an object of columns {{name: [values]}}")
    if not data:
        raise RecordingError(f"{name}: no columns (empty JSON object)")
    columns = {}
    for k, v in data.items():
        target = select.target(k)
        if target is None:
            continue
        if isinstance(v, np.ndarray) and v.ndim == 1:
            v = v.tolist()
        if not isinstance(v, list):
            raise RecordingError(f"{name}: column {k!r} must be a list of numbers")
        bad = next((i for i, x in enumerate(v)
                    if x is not None and (isinstance(x, bool)
                                          or not isinstance(x, (int, float)))), None)
        if bad is not None:
            raise RecordingError(f"{name}: column {k!r}, row {bad}: "
                                 f"{str(v[bad])[:40]!r} is not a number")
        columns[target] = np.array([np.nan if x is None else x for x in v], dtype=float)
    return columns


def read_json(raw: bytes, name: str, select: ColumnSelector, limits: ReadLimits) -> Columns:
    return Columns(columns_from_object(loads_bounded(raw, name, limits), name, select))


def write_json(rec: RecordLike) -> bytes:
    """Round-trips exactly (Python floats print their shortest exact repr)."""
    cols = {"time": rec.time.tolist(), **{k: v.tolist() for k, v in rec.channels.items()}}
    return _json.dumps(cols).encode()


def looks_like_json(raw: bytes) -> bool:
    return raw[:4096].lstrip(b"\xef\xbb\xbf \t\r\n").startswith(b"{")


FORMAT = register_format(Format(
    "json", (".json",), read_json, write_json,
    media_types=("application/json", "text/json"), sniff=looks_like_json,
    description="object of equal-length number arrays"))
