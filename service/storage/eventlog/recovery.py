"""Finishing a log a crashed process left without footer (start-up does it; ``recover``)."""
from __future__ import annotations

import os
from pathlib import Path

from mcap.records import Channel, Message, Metadata, Schema
from mcap.writer import CompressionType, Writer

from ..files import fsync_dir
from .channels import FORMAT_VERSION
from .reader import _good_bytes, is_finished


def recover(path: str | Path, *, keep_partial: bool = True) -> Path:
    """Finish an unfinished log: keep every complete record, add summary and footer.

    The original is kept next to it as ``<name>.partial`` unless ``keep_partial`` is false
    (the service's start-up: what was kept is noted in the ``siva.recovery`` metadata);
    the returned path (the original name) is a finished MCAP file.  A file that is already
    finished is returned unchanged.
    """
    path = Path(path)
    if is_finished(path):
        return path
    raw = path.read_bytes()
    records, end = _good_bytes(raw)
    tmp = path.with_name(path.name + ".recovering")
    with open(tmp, "wb") as fh:
        w = Writer(fh, chunk_size=1, compression=CompressionType.ZSTD)
        w.start(profile="", library=f"siva ({FORMAT_VERSION}, recovered)")
        schema_ids: dict[int, int] = {}
        channel_ids: dict[int, int] = {}
        schemas: dict[int, Schema] = {}
        for rec in records:
            if isinstance(rec, Schema):
                schemas[rec.id] = rec
            elif isinstance(rec, Metadata):
                w.add_metadata(rec.name, dict(rec.metadata))
            elif isinstance(rec, Channel):
                sid = 0
                if rec.schema_id:
                    if rec.schema_id not in schema_ids:
                        s = schemas[rec.schema_id]
                        schema_ids[rec.schema_id] = w.register_schema(s.name, s.encoding, s.data)
                    sid = schema_ids[rec.schema_id]
                channel_ids[rec.id] = w.register_channel(rec.topic, rec.message_encoding, sid,
                                                         dict(rec.metadata))
            elif isinstance(rec, Message) and rec.channel_id in channel_ids:
                w.add_message(channel_ids[rec.channel_id], log_time=rec.log_time,
                              publish_time=rec.publish_time, sequence=rec.sequence,
                              data=rec.data)
        w.add_metadata("siva.recovery", {"from": path.name + (".partial" if keep_partial
                                                              else " (unfinished, removed)"),
                                         "bytes_kept": str(end), "bytes_total": str(len(raw))})
        w.finish()
        fh.flush()
        os.fsync(fh.fileno())
    if keep_partial:
        os.replace(path, path.with_name(path.name + ".partial"))
    os.replace(tmp, path)
    fsync_dir(path.parent)
    return path
