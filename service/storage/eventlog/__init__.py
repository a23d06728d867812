"""The event log: one MCAP file per system per process start, the audit trail of a running
identification and the input of ``siva replay`` (docs/logs.md).

- ``channels.py``    topics, message models and their JSON Schemas (the file format)
- ``writer.py``      :class:`EventLog`: durable, write-ahead appends, one file per system
- ``log_file.py``    one open file: the MCAP writer, channels, flush + fsync per message
- ``reader.py``      :func:`read_events`, :func:`read_metadata`: tolerant of a torn tail
- ``recovery.py``    :func:`recover`: finish a file a crashed process left open
- ``fingerprint.py`` the platform fingerprint a bit-identical replay depends on
"""
from __future__ import annotations

from .channels import (FORMAT_VERSION, PLATFORM_METADATA, TOPIC_ANCHOR, TOPIC_DATASET,
                        TOPIC_RECORDING, TOPIC_REPAIR, TOPIC_SNAPSHOT, TOPIC_SPEC, AnchorEvent,
                        DatasetEvent, LogEvent, LoggedEstimate, RecordingEvent, RepairEvent,
                        SnapshotEvent, SpecEvent)
from .reader import is_finished, iter_raw, read_events, read_metadata
from .recovery import recover
from .writer import EventLog, LogPosition, LogRemoval

__all__ = ["EventLog", "LogPosition", "LogRemoval", "read_events", "read_metadata", "iter_raw",
           "is_finished", "recover", "LogEvent", "SpecEvent", "RecordingEvent", "DatasetEvent",
           "AnchorEvent", "SnapshotEvent", "RepairEvent", "LoggedEstimate", "FORMAT_VERSION",
           "PLATFORM_METADATA", "TOPIC_SPEC", "TOPIC_RECORDING", "TOPIC_DATASET", "TOPIC_ANCHOR",
           "TOPIC_SNAPSHOT", "TOPIC_REPAIR"]
