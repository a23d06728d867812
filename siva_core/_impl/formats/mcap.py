"""MCAP: one channel, topic ``/recording``, JSON messages with a JSON schema.

Why MCAP: rigs and robots already log to it, and tools (``mcap info``, Foxglove) open it.
Each message body is exactly the JSON recording format (an object of equal-length columns),
so one message may hold the whole record; a long or streamed record may be split into
several messages with the same columns, concatenated in log-time order.  ``log_time`` of a
message is its first sample's time in nanoseconds.  Rows count from 0 over the concatenated
record.

Bounded: every chunk's declared uncompressed size, and their total, are checked before the
chunk is decompressed - against the absolute limit and against ``max_expansion`` times the
file (a 36 KB file declaring 127 MiB is a bomb) - and decompression never produces more
than declared; message bodies go through the bounded JSON parser (numbers straight into
float64 arrays, counted against ``max_values`` first).
"""
from __future__ import annotations

import io
import json as _json
from pathlib import Path
from typing import IO, Any

from ._base import (ColumnSelector, Columns, Format, ReadLimits, RecordingError,
                    RecordingTooLarge, RecordLike, register_format)
import numpy as np

from .json import NumberArray, columns_from_object, loads_columns

MCAP_MAGIC = b"\x89MCAP0\r\n"   # the one definition in the project (the service log uses it)
TOPIC = "/recording"
SCHEMA_NAME = "siva.Recording"

# Columns are arrays of numbers; names follow the CSV convention (time, acc_<dof>, ...).
JSON_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": SCHEMA_NAME,
    "description": "A block of rows of a recording: equal-length columns, SI units "
                   "(time [s], disp_<dof> [m], vel_<dof> [m/s], acc_<dof> [m/s^2], "
                   "force_<dof> [N]).",
    "type": "object",
    "required": ["time"],
    "properties": {"time": {"type": "array", "items": {"type": "number"}}},
    "additionalProperties": {"type": "array", "items": {"type": "number"}},
}


def write_mcap(rec: RecordLike, path_or_file: str | Path | IO[bytes], *,
               rows_per_message: int | None = None) -> None:
    """Write ``rec`` to an MCAP file (path or binary file object); ``rows_per_message``
    splits the record into blocks (None: one message)."""
    from mcap.writer import Writer

    if isinstance(path_or_file, (str, Path)):
        with open(path_or_file, "wb") as fh:
            write_mcap(rec, fh, rows_per_message=rows_per_message)
        return
    n = len(rec.time)
    step = n if not rows_per_message else max(1, int(rows_per_message))
    writer = Writer(path_or_file)
    writer.start(profile="", library="siva")
    schema_id = writer.register_schema(name=SCHEMA_NAME, encoding="jsonschema",
                                       data=_json.dumps(JSON_SCHEMA).encode())
    channel_id = writer.register_channel(topic=TOPIC, message_encoding="json",
                                         schema_id=schema_id,
                                         metadata={"name": str(rec.name)})
    for seq, i0 in enumerate(range(0, n, step)):
        block = {"time": rec.time[i0:i0 + step].tolist(),
                 **{k: v[i0:i0 + step].tolist() for k, v in rec.channels.items()}}
        t_ns = max(0, int(round(float(rec.time[i0]) * 1e9)))
        writer.add_message(channel_id, log_time=t_ns, publish_time=t_ns, sequence=seq,
                           data=_json.dumps(block, allow_nan=True).encode())
    writer.finish()


def mcap_bytes(rec: RecordLike, **kw: Any) -> bytes:
    """The MCAP file of ``rec`` as bytes (for uploads and tests)."""
    buf = io.BytesIO()
    write_mcap(rec, buf, **kw)
    return buf.getvalue()


def _decompress(chunk: Any, name: str) -> bytes:
    """A chunk's records, never more than its declared uncompressed size."""
    size = chunk.uncompressed_size
    if chunk.compression == "zstd":
        import zstandard

        # a stream read of at most size + 1 bytes: whatever the frame header claims
        with zstandard.ZstdDecompressor().stream_reader(io.BytesIO(chunk.data)) as stream:
            parts, got = [], 0
            while got <= size:
                part = stream.read(size + 1 - got)
                if not part:
                    break
                parts.append(part)
                got += len(part)
            out = b"".join(parts)
    elif chunk.compression == "lz4":
        import lz4.frame

        out = lz4.frame.LZ4FrameDecompressor().decompress(chunk.data, max_length=size + 1)
    elif chunk.compression == "":
        out = chunk.data
    else:
        raise RecordingError(f"{name}: MCAP chunk compression {chunk.compression!r} is not "
                             "supported (zstd, lz4 or none)")
    if len(out) > size:
        raise RecordingTooLarge(f"{name}: an MCAP chunk decompresses to more than its "
                                f"declared {size} bytes")
    if len(out) != size:
        raise RecordingError(f"{name}: an MCAP chunk holds {len(out)} bytes, its header "
                             f"declares {size}")
    return out


def _records(raw: bytes, name: str, limits: ReadLimits):
    """Every record, chunks opened under the size limits."""
    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader, breakup_chunk

    total = 0
    for record in StreamReader(io.BytesIO(raw), emit_chunks=True, validate_crcs=True,
                               record_size_limit=len(raw)).records:
        if not isinstance(record, Chunk):
            yield record
            continue
        total += record.uncompressed_size
        limits.check_expansion("an MCAP chunk", record.uncompressed_size, len(raw), name)
        limits.check_expansion("the MCAP chunks", total, len(raw), name)
        plain = Chunk(compression="", data=_decompress(record, name),
                      message_start_time=record.message_start_time,
                      message_end_time=record.message_end_time,
                      uncompressed_crc=record.uncompressed_crc,
                      uncompressed_size=record.uncompressed_size)
        yield from breakup_chunk(plain, validate_crc=True)


def read_mcap(raw: bytes, name: str, select: ColumnSelector, limits: ReadLimits) -> Columns:
    """The ``/recording`` channel of an MCAP file as columns."""
    from mcap.records import Channel, Message

    if not raw.startswith(MCAP_MAGIC):
        raise RecordingError(f"{name}: not an MCAP file (bad magic bytes)")
    channels: dict[int, Any] = {}
    blocks: list[tuple[int, int, dict[str, Any]]] = []
    k = 0
    try:
        for record in _records(raw, name, limits):
            if isinstance(record, Channel):
                channels[record.id] = record
                continue
            if not isinstance(record, Message):
                continue
            channel = channels.get(record.channel_id)
            k += 1
            if channel is None or channel.topic != TOPIC:
                continue
            if channel.message_encoding != "json":
                raise RecordingError(f"{name}: topic {TOPIC} has message encoding "
                                     f"{channel.message_encoding!r}, expected 'json'")
            body = loads_columns(record.data, f"{name}: message {k - 1} on {TOPIC}", limits)
            if isinstance(body, dict) and isinstance(body.get("columns"), dict):
                body = body["columns"]
            if not isinstance(body, dict):
                raise RecordingError(f"{name}: message {k - 1} on {TOPIC} must be an object "
                                     "of columns {name: [values]}")
            blocks.append((record.log_time, k - 1, body))
    except RecordingError:
        raise
    except Exception as exc:  # noqa: BLE001 - any unreadable upload is a user error
        raise RecordingError(f"{name}: unreadable MCAP file ({type(exc).__name__}: {exc})") \
            from None
    if not blocks:
        topics = ", ".join(sorted({c.topic for c in channels.values()})) or "none"
        raise RecordingError(f"{name}: no message on topic {TOPIC} (topics: {topics})")
    blocks.sort(key=lambda b: (b[0], b[1]))
    names = list(blocks[0][2])
    parts: dict[str, list[Any]] = {c: [] for c in names}
    kept = {c for c in names if select.target(c) is not None}
    select.skipped.clear()  # the columns_from_object call below reports them
    values = 0
    for _, k, body in blocks:
        if list(body) != names and set(body) != set(names):
            raise RecordingError(f"{name}: message {k} has columns {sorted(body)}, "
                                 f"the first message has {sorted(names)}")
        n_time = _length(body.get("time"))
        for c, v in body.items():
            if not isinstance(v, (list, NumberArray)):
                raise RecordingError(f"{name}: column {c!r} in message {k} must be a list "
                                     "of numbers")
            if n_time is not None and _length(v) != n_time:
                raise RecordingError(f"{name}: column {c!r} in message {k} has {_length(v)} "
                                     f"values, 'time' has {n_time}")
            if c in kept:
                values += _length(v) or 0
                limits.check_values(values, name)
                parts[c].append(v)
    columns = {}
    for c, vs in parts.items():
        if c not in kept:
            columns[c] = []
            continue
        arrays = [columns_from_object({c: v}, f"{name}", select, limits)[select.target(c)]
                  for v in vs]
        columns[c] = np.concatenate(arrays) if arrays else np.empty(0)
    select.skipped.clear()
    return Columns(columns_from_object(columns, name, select, limits))


def _length(v: Any) -> int | None:
    if isinstance(v, NumberArray):
        return v.count()
    return len(v) if isinstance(v, list) else None


FORMAT = register_format(Format(
    "mcap", (".mcap",), read_mcap, mcap_bytes,
    media_types=("application/x-mcap", "application/mcap"),
    sniff=lambda raw: raw.startswith(MCAP_MAGIC),
    description="MCAP, topic /recording, JSON messages"))
