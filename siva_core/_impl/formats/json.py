"""JSON: an object of equal-length arrays of numbers, or the same under ``"columns"``.

Parsing is bounded: nesting deeper than ``max_json_depth`` and numbers longer than
``max_number_chars`` are refused before Python builds them (a 10 000-deep ``[`` or a
5 000-digit integer is an attack, not a recording).  Rows count from 0.

Memory is bounded too (issue 19: a 60 MB body cost 740 MB as Python lists): every long
array of numbers is cut out of the text before ``json.loads`` sees it (:func:`loads_columns`
finds them with a vectorised scan of the brackets outside strings), and a column is parsed
straight into a float64 array in 256 KiB blocks, after its value count is checked against
``max_values``.  Arrays of columns the model does not use are never parsed.
"""
from __future__ import annotations

import json as _json
import re
from typing import Any, Iterator, Mapping

import numpy as np

from ._base import (ColumnSelector, Columns, Format, ReadLimits, RecordingError, RecordLike,
                    RecordingTooLarge, register_format)

_SCAN_BLOCK = 1 << 20
_PARSE_BLOCK = 1 << 18
#: arrays shorter than this (bytes) stay in the text json.loads parses
_SHORT_ARRAY = 256
#: at most this many [ ] { } outside strings: a recording is a few columns, not a tree
MAX_BRACKETS = 8192
_NUMBER = rb"-?(?:0|[1-9][0-9]*)(?:\.[0-9]+)?(?:[eE][+-]?[0-9]+)?|null|NaN|-?Infinity"
_TOKEN_RE = re.compile(rb"\s*(?:" + _NUMBER + rb")\s*")
_BLOCK_RE = re.compile(rb"\s*(?:" + _NUMBER + rb")\s*(?:,\s*(?:" + _NUMBER + rb")\s*)*")


def _bracket_blocks(raw: bytes) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
    """Per 1 MiB block: (block start, bytes of the [ ] { } outside strings, their offsets in
    the block), in order; vectorised, so a long body is scanned without a Python loop."""
    raw = raw.replace(b"\\\\", b"__").replace(b'\\"', b"__")
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
        in_string = bool(quotes[-1] % 2)
        yield start, ch[outside], idx[outside]


def _structure(raw: bytes, limits: ReadLimits, name: str) -> Iterator[tuple[int, int]]:
    """(position, byte) of every bracket outside strings, in order; bounded in count."""
    count = 0
    for start, ch, keep in _bracket_blocks(raw):
        count += keep.size
        if count > MAX_BRACKETS:
            raise RecordingTooLarge(f"{name}: JSON with more than {MAX_BRACKETS} arrays and "
                                    "objects; a recording is an object of number arrays")
        for i, c in zip((keep + start).tolist(), ch.tolist()):
            yield i, c


class NumberArray:
    """A JSON array of numbers left unparsed in the body: ``[start, end)`` is its inside."""

    def __init__(self, raw: bytes, start: int, end: int) -> None:
        self.raw, self.start, self.end = raw, start, end

    def count(self) -> int:
        """How many values (commas + 1), without parsing or copying."""
        commas = self.raw.count(b",", self.start, self.end)
        if not commas and not self.raw[self.start:self.end].strip():
            return 0
        return commas + 1

    def parse(self, name: str, column: str, limits: ReadLimits) -> np.ndarray:
        """float64 values (null -> NaN), in blocks; the first bad value is named by row."""
        out = np.empty(self.count())
        pos, row, raw, end = self.start, 0, self.raw, self.end
        while pos < end and row < out.size:
            cut = min(end, pos + _PARSE_BLOCK)
            if cut < end:
                cut = raw.find(b",", cut, end)
                cut = end if cut < 0 else cut
            block = raw[pos:cut]
            tokens = block.split(b",")
            longest = max(map(len, tokens))
            if longest > limits.max_number_chars or not _BLOCK_RE.fullmatch(block):
                self._explain(tokens, row, name, column, limits)
            out[row:row + len(tokens)] = np.array(block.replace(b"null", b"nan").split(b","),
                                                  dtype=np.bytes_).astype(np.float64)
            row += len(tokens)
            pos = cut + 1
        return out

    @staticmethod
    def _explain(tokens: list[bytes], row: int, name: str, column: str,
                 limits: ReadLimits) -> None:
        for i, tok in enumerate(tokens):
            text = tok.strip().decode("utf-8", "replace")
            if len(text) > limits.max_number_chars and _TOKEN_RE.fullmatch(tok):
                raise RecordingError(f"{name}: JSON number with {len(text)} characters "
                                     f"({text[:20]}...), at most {limits.max_number_chars}")
            if not _TOKEN_RE.fullmatch(tok):
                raise RecordingError(f"{name}: column {column!r}, row {row + i}: "
                                     f"{text[:40]!r} is not a number")
        raise RecordingError(f"{name}: column {column!r}: unreadable numbers near row {row}")


def loads_columns(raw: bytes | str, name: str, limits: ReadLimits) -> Any:
    """``json.loads`` with depth and number-length limits, where every long array without
    nested brackets is a :class:`NumberArray` (parsed later, only if used)."""
    data = raw.encode() if isinstance(raw, str) else bytes(raw)
    deepest = json_depth(data)
    if deepest > limits.max_json_depth:
        raise RecordingError(f"{name}: JSON nested {deepest} levels deep, at most "
                             f"{limits.max_json_depth} allowed")
    spans: list[tuple[int, int]] = []
    last: tuple[int, int] | None = None
    for pos, c in _structure(data, limits, name):
        if c == 93 and last is not None and last[1] == 91 and pos - last[0] > _SHORT_ARRAY:
            spans.append((last[0], pos))
        last = (pos, c)
    pieces, prev = [], 0
    for i, (a, b) in enumerate(spans):
        pieces += [data[prev:a], b'"\x00%d"' % i]
        prev = b + 1
    pieces.append(data[prev:])
    skeleton = b"".join(pieces) if spans else data
    value = _loads(skeleton, name, limits, strict=not spans)
    if not spans:
        return value
    arrays = [NumberArray(data, a + 1, b) for a, b in spans]

    def swap(v: Any) -> Any:
        if isinstance(v, str) and v.startswith("\x00") and v[1:].isdigit() \
                and int(v[1:]) < len(arrays):
            return arrays[int(v[1:])]
        return v

    stack = [value]
    while stack:
        v = stack.pop()
        items = v.items() if isinstance(v, dict) else enumerate(v) if isinstance(v, list) else ()
        for k, x in list(items):
            v[k] = swap(x)
            if isinstance(x, (dict, list)):
                stack.append(x)
    return swap(value)


def _loads(data: bytes, name: str, limits: ReadLimits, strict: bool = True) -> Any:
    def number(text: str) -> float:
        if len(text) > limits.max_number_chars:
            raise RecordingError(f"{name}: JSON number with {len(text)} characters "
                                 f"({text[:20]}...), at most {limits.max_number_chars}")
        return float(text)

    try:
        return _json.loads(data.decode("utf-8"), parse_int=number, parse_float=number,
                           strict=strict)
    except (_json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise RecordingError(f"{name}: invalid JSON ({exc})") from None


def json_depth(raw: bytes) -> int:
    """Deepest nesting of ``[``/``{`` outside strings; vectorised, in 1 MiB blocks."""
    depth = 0
    deepest = 0
    for _, ch, _ in _bracket_blocks(raw):
        if not ch.size:
            continue
        step = np.where((ch == 91) | (ch == 123), 1, -1)
        levels = depth + np.cumsum(step)
        deepest = max(deepest, int(levels.max()))
        depth = int(levels[-1])
    return deepest


def loads_bounded(raw: bytes | str, name: str, limits: ReadLimits) -> Any:
    """``json.loads`` with depth and number-length limits (RecordingError on breach)."""
    data = raw.encode() if isinstance(raw, str) else bytes(raw)
    depth = json_depth(data)
    if depth > limits.max_json_depth:
        raise RecordingError(f"{name}: JSON nested {depth} levels deep, at most "
                             f"{limits.max_json_depth} allowed")

    return _loads(data, name, limits)


def columns_from_object(data: Any, name: str, select: ColumnSelector,
                        limits: ReadLimits | None = None) -> dict[str, np.ndarray]:
    """The columns of a decoded JSON recording (object of lists, optionally under "columns")."""
    if isinstance(data, Mapping) and isinstance(data.get("columns"), Mapping):
        data = data["columns"]
    if not isinstance(data, Mapping):
        raise RecordingError(f"{name}: JSON must be an object of columns {{name: [values]}}")
    if not data:
        raise RecordingError(f"{name}: no columns (empty JSON object)")
    limits = limits or ReadLimits()
    columns = {}
    values = 0
    for k, v in data.items():
        target = select.target(k)
        if target is None:
            continue
        if isinstance(v, NumberArray):
            values += v.count()
            limits.check_values(values, name)
            columns[target] = v.parse(name, k, limits)
            continue
        if isinstance(v, np.ndarray) and v.ndim == 1 and v.dtype.kind in "biuf":
            values += v.size
            limits.check_values(values, name)
            columns[target] = v.astype(float, copy=False)
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
    return Columns(columns_from_object(loads_columns(raw, name, limits), name, select, limits))


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
