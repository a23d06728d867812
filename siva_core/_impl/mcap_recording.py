"""A recording as MCAP: one channel, topic ``/recording``, JSON messages with a JSON schema.

Why MCAP: rigs and robots already log to it, and tools (``mcap info``, Foxglove) open it.
Each message body is exactly the JSON recording format (an object of equal-length columns,
``{"time": [...], "acc_x": [...], ...}``), so one message may hold the whole record; a
long or streamed record may be split into several messages with the same columns, which
are concatenated in log-time order.  ``log_time`` of a message is its first sample's time
in nanoseconds.  Validation is that of :meth:`Recording.from_columns` (errors name the
file, the column and the row, rows counted from 0 over the concatenated record).
"""
from __future__ import annotations

import io
import json
from pathlib import Path
from typing import IO, Any, Sequence


from .recording import Recording, RecordingError

TOPIC = "/recording"
SCHEMA_NAME = "siva.Recording"
MAGIC = b"\x89MCAP0\r\n"

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


def write_mcap_recording(rec: Recording, path_or_file: str | Path | IO[bytes], *,
                         rows_per_message: int | None = None) -> None:
    """Write ``rec`` to an MCAP file (path or binary file object).

    ``rows_per_message`` splits the record into blocks (None: one message).
    """
    from mcap.writer import Writer

    if isinstance(path_or_file, (str, Path)):
        with open(path_or_file, "wb") as fh:
            write_mcap_recording(rec, fh, rows_per_message=rows_per_message)
        return
    n = len(rec)
    step = n if not rows_per_message else max(1, int(rows_per_message))
    writer = Writer(path_or_file)
    writer.start(profile="", library="siva")
    schema_id = writer.register_schema(name=SCHEMA_NAME, encoding="jsonschema",
                                       data=json.dumps(JSON_SCHEMA).encode())
    channel_id = writer.register_channel(topic=TOPIC, message_encoding="json",
                                         schema_id=schema_id,
                                         metadata={"name": str(rec.name)})
    for seq, i0 in enumerate(range(0, n, step)):
        block = {"time": rec.time[i0:i0 + step].tolist(),
                 **{k: v[i0:i0 + step].tolist() for k, v in rec.channels.items()}}
        t_ns = max(0, int(round(float(rec.time[i0]) * 1e9)))
        writer.add_message(channel_id, log_time=t_ns, publish_time=t_ns, sequence=seq,
                           data=json.dumps(block, allow_nan=True).encode())
    writer.finish()


def mcap_bytes(rec: Recording, **kw: Any) -> bytes:
    """The MCAP file of ``rec`` as bytes (for uploads and tests)."""
    buf = io.BytesIO()
    write_mcap_recording(rec, buf, **kw)
    return buf.getvalue()


def read_mcap_recording(raw: bytes, dofs: Sequence[str] | None = None,
                        name: str = "upload") -> Recording:
    """Read the ``/recording`` channel of an MCAP file into a validated Recording."""
    from mcap.reader import NonSeekingReader

    if not isinstance(raw, (bytes, bytearray, memoryview)):
        raise RecordingError(f"{name}: MCAP reader needs bytes")
    raw = bytes(raw)
    if not raw.startswith(MAGIC):
        raise RecordingError(f"{name}: not an MCAP file (bad magic bytes)")
    blocks: list[tuple[int, int, dict[str, Any]]] = []
    topics: set[str] = set()
    try:
        reader = NonSeekingReader(io.BytesIO(raw), validate_crcs=True)
        for k, (schema, channel, message) in enumerate(reader.iter_messages()):
            topics.add(channel.topic)
            if channel.topic != TOPIC:
                continue
            if channel.message_encoding != "json":
                raise RecordingError(f"{name}: topic {TOPIC} has message encoding "
                                     f"{channel.message_encoding!r}, expected 'json'")
            try:
                body = json.loads(message.data)
            except (json.JSONDecodeError, UnicodeDecodeError) as exc:
                raise RecordingError(f"{name}: message {k} on {TOPIC} is not valid JSON "
                                     f"({exc})") from None
            if isinstance(body, dict) and isinstance(body.get("columns"), dict):
                body = body["columns"]
            if not isinstance(body, dict):
                raise RecordingError(f"{name}: message {k} on {TOPIC} must be an object of "
                                     "columns {name: [values]}")
            blocks.append((message.log_time, k, body))
    except RecordingError:
        raise
    except Exception as exc:  # noqa: BLE001 - any unreadable upload is a user error
        raise RecordingError(f"{name}: unreadable MCAP file ({type(exc).__name__}: {exc})") \
            from None
    if not blocks:
        found = ", ".join(sorted(topics)) or "none"
        raise RecordingError(f"{name}: no message on topic {TOPIC} (topics: {found})")
    blocks.sort(key=lambda b: (b[0], b[1]))
    names = list(blocks[0][2])
    columns: dict[str, list[Any]] = {c: [] for c in names}
    for _, k, body in blocks:
        if list(body) != names and set(body) != set(names):
            raise RecordingError(f"{name}: message {k} has columns {sorted(body)}, "
                                 f"the first message has {sorted(names)}")
        lengths = {c: len(v) if isinstance(v, list) else -1 for c, v in body.items()}
        for c, v in body.items():
            if not isinstance(v, list):
                raise RecordingError(f"{name}: column {c!r} in message {k} must be a list "
                                     "of numbers")
            if lengths[c] != lengths.get("time", lengths[c]):
                raise RecordingError(f"{name}: column {c!r} in message {k} has {lengths[c]} "
                                     f"values, 'time' has {lengths['time']}")
            columns[c].extend(v)
    return Recording.from_json(columns, dofs, name=name)


def is_mcap(raw: bytes) -> bool:
    """Does ``raw`` start like an MCAP file?"""
    return bytes(raw[:len(MAGIC)]) == MAGIC


__all__ = ["TOPIC", "JSON_SCHEMA", "write_mcap_recording", "read_mcap_recording", "mcap_bytes",
           "is_mcap"]
