"""Reading an event log, tolerant of a crash: every complete record is kept, a torn or
corrupt one is skipped and the scan resynchronises at the next chunk with a valid CRC."""
from __future__ import annotations

import io
import struct
from pathlib import Path
from typing import Any, Iterator

from mcap.exceptions import EndOfFile, McapError
from mcap.records import Channel, Message, Metadata, Schema
from mcap.stream_reader import MAGIC_SIZE, StreamReader

from .channels import MAGIC, TOPICS, LogEvent

_FOOTER_OPCODE = 0x02
_FOOTER_RECORD = 1 + 8 + 20  # opcode + length + (summary_start, summary_offset_start, crc)


def is_finished(path: str | Path) -> bool:
    """True when the file ends with a footer and the closing magic (a clean ``close()``)."""
    with open(path, "rb") as fh:
        fh.seek(0, io.SEEK_END)
        size = fh.tell()
        if size < 2 * MAGIC_SIZE + _FOOTER_RECORD:
            return False
        fh.seek(size - MAGIC_SIZE - _FOOTER_RECORD)
        tail = fh.read()
    return tail[-MAGIC_SIZE:] == MAGIC and tail[0] == _FOOTER_OPCODE


def _record_ok(raw: bytes, pos: int, end: int) -> bool:
    """Whether ``raw[pos:end]`` is one record mcap's stream reader parses (CRCs checked)."""
    try:
        for _ in StreamReader(io.BytesIO(raw[pos:end]), skip_magic=True,
                              validate_crcs=True).records:
            pass
    except EndOfFile:
        pass
    except Exception:  # noqa: BLE001 - any unparseable record is not a good one
        return False
    return True


def _record_end(raw: bytes, pos: int) -> int | None:
    """End of the record framed at ``pos`` if it fits in the file (opcode 0: no record)."""
    if pos + 9 > len(raw) or raw[pos] == 0:
        return None
    (length,) = struct.unpack_from("<Q", raw, pos + 1)
    end = pos + 9 + length
    return end if end <= len(raw) else None


def _good_records(raw: bytes) -> list[tuple[int, int]]:
    """Byte ranges of the complete, parseable records (after the magic), in file order.

    Record framing is checked by hand (opcode + length must fit in the file; opcode 0 - what
    a crash leaves in pre-allocated space - is no record) and each record is then parsed
    by mcap's own stream reader, with CRC checks.  A torn or corrupt record does not end
    the file: the scan resynchronises at the next chunk that parses with a valid CRC, so
    events written after a torn chunk stay readable.
    """
    if len(raw) < MAGIC_SIZE and MAGIC.startswith(raw):
        return []  # died while writing the magic: an empty log
    if raw[:MAGIC_SIZE] != MAGIC:
        raise McapError("not an MCAP file (bad magic)")
    good: list[tuple[int, int]] = []
    pos = MAGIC_SIZE
    n = len(raw)
    resynced = False  # after damage only CRC-checked chunks are trusted
    while pos + 9 <= n:
        if resynced and raw[pos] != _CHUNK_OPCODE:
            pos = _resync(raw, pos)
            continue
        end = _record_end(raw, pos)
        if end is not None and _record_ok(raw, pos, end):
            good.append((pos, end))
            if raw[pos] == _FOOTER_OPCODE:
                break
            pos = end
            continue
        resynced = True
        pos = _resync(raw, pos + 1)
    return good


_CHUNK_OPCODE = 0x06


def _resync(raw: bytes, start: int) -> int:
    """The next position at or after ``start`` where a complete chunk parses, else EOF."""
    pos = raw.find(bytes([_CHUNK_OPCODE]), start)
    while pos != -1:
        end = _record_end(raw, pos)
        if end is not None and _record_ok(raw, pos, end):
            return pos
        pos = raw.find(bytes([_CHUNK_OPCODE]), pos + 1)
    return len(raw)


def _good_bytes(raw: bytes) -> tuple[list[Any], int]:
    """The records of the good ranges, parsed range by range (a range that parses alone
    but not in sequence is dropped, not fatal), and how many bytes were kept."""
    records: list[Any] = []
    kept = MAGIC_SIZE
    for a, b in _good_records(raw):
        recs: list[Any] = []
        try:
            for rec in StreamReader(io.BytesIO(raw[a:b]), skip_magic=True,
                                    validate_crcs=True).records:
                recs.append(rec)
        except EndOfFile:
            pass
        except Exception:  # noqa: BLE001 - damaged: skip this record only
            continue
        records.extend(recs)
        kept += b - a
    return records, kept


def iter_raw(path: str | Path) -> Iterator[tuple[Schema | None, Channel, Message]]:
    """(schema, channel, message) in file order; tolerant of a missing footer."""
    records, _kept = _good_bytes(Path(path).read_bytes())
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    for rec in records:
        if isinstance(rec, Schema):
            schemas[rec.id] = rec
        elif isinstance(rec, Channel):
            channels[rec.id] = rec
        elif isinstance(rec, Message) and rec.channel_id in channels:
            ch = channels[rec.channel_id]
            yield schemas.get(ch.schema_id), ch, rec


def read_events(path: str | Path) -> list[LogEvent]:
    """All siva events of a log in the order they were written (unknown topics skipped)."""
    out: list[LogEvent] = []
    for _schema, ch, msg in iter_raw(path):
        model = TOPICS.get(ch.topic)
        if model is None:
            continue
        out.append(LogEvent(ch.topic, msg.log_time, model.model_validate_json(msg.data)))
    return out


def read_metadata(path: str | Path) -> dict[str, dict[str, str]]:
    """The metadata records of a log by name (the first of each name; footer optional):
    ``siva`` (format, system, settings), ``siva.platform`` (the fingerprint, logs written
    since it was added), ``siva.recovery`` / ``siva.repair`` (what start-up fixed)."""
    records, _kept = _good_bytes(Path(path).read_bytes())
    out: dict[str, dict[str, str]] = {}
    for rec in records:
        if isinstance(rec, Metadata):
            out.setdefault(rec.name, dict(rec.metadata))
    return out
