"""One open log file of one system: the MCAP writer, its channels, and the durability step
after every message (each message its own compressed chunk, then flush + fsync)."""
from __future__ import annotations

import logging
import os
import threading
import time
from pathlib import Path
from typing import Mapping

from mcap.writer import CompressionType, Writer
from pydantic import BaseModel

from .channels import FORMAT_VERSION, PLATFORM_METADATA, TOPICS, schema_bytes
from .fingerprint import platform_fingerprint

log = logging.getLogger("siva.mcap_log")


class SystemLogFile:
    """One open MCAP file: writer, channel ids, and the durability step after each message."""

    def __init__(self, path: Path, system: str, metadata: Mapping[str, str]) -> None:
        self.path = path
        path.parent.mkdir(parents=True, exist_ok=True)
        self._fh = open(path, "xb")
        # chunk_size=1: every message closes its own (compressed, CRC'd) chunk immediately,
        # so nothing sits in a buffer when the process dies.
        try:
            self._writer = Writer(self._fh, chunk_size=1, compression=CompressionType.ZSTD)
            self._writer.start(profile="", library=f"siva ({FORMAT_VERSION})")
            self._writer.add_metadata("siva", {"format": FORMAT_VERSION, "system": system,
                                               **{k: str(v) for k, v in metadata.items()}})
            # what bit-identity of a replay depends on (fingerprint.py)
            self._writer.add_metadata(PLATFORM_METADATA, platform_fingerprint())
            self._sync()
        except BaseException:  # e.g. disk full: leave no headless file behind
            self.abandon()
            path.unlink(missing_ok=True)
            raise
        self._channels: dict[str, int] = {}
        self._sequence: dict[str, int] = {}
        self._last_time = 0
        self.lock = threading.Lock()  # one writer at a time per file; files are independent
        self.has_spec = False

    def _channel(self, topic: str) -> int:
        if topic not in self._channels:
            model = TOPICS[topic]
            sid = self._writer.register_schema(f"siva.{model.__name__}", "jsonschema",
                                               schema_bytes(model))
            self._channels[topic] = self._writer.register_channel(topic, "json", sid)
            self._sequence[topic] = 0
        return self._channels[topic]

    def write(self, topic: str, event: BaseModel) -> None:
        cid = self._channel(topic)
        # strictly increasing log times keep log-time order == write order for every reader
        now = max(time.time_ns(), self._last_time + 1)
        self._last_time = now
        self._sequence[topic] += 1
        self._writer.add_message(cid, log_time=now, publish_time=now,
                                 sequence=self._sequence[topic],
                                 data=event.model_dump_json().encode())
        self._sync()

    def count(self, topic: str) -> int:
        """Events of ``topic`` written to this file so far."""
        return self._sequence.get(topic, 0)

    def _sync(self) -> None:
        self._fh.flush()
        os.fsync(self._fh.fileno())

    def close(self) -> None:
        self._writer.finish()
        self._sync()
        self._fh.close()

    def abandon(self) -> None:
        """Close without a footer after a failed write (its tail may be torn; the records
        before it are complete and fsync'ed; :func:`recover` finishes it at the next start)."""
        try:
            self._fh.close()
        except OSError:
            pass


def finish(sl: SystemLogFile) -> None:
    """Close a system's open file; a disk that refuses leaves it to crash recovery."""
    with sl.lock:
        try:
            sl.close()
        except OSError as exc:
            log.warning("cannot finish %s: %s", sl.path, exc)
            sl.abandon()
