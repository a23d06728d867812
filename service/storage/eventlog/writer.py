"""Event logs of the service: one MCAP file per system per process start.

Why MCAP: the log is both the audit trail of a running identification (what arrived, when,
and what the service estimated) and the input of ``siva replay``, so it must be a standard,
self-describing container that outside tools (``mcap info``, Foxglove) open.

Layout: ``<data>/logs/<system>/<UTC start time>-<pid>.mcap``.  Topics (message encoding
``json``, schema encoding ``jsonschema``, schemas generated from the pydantic models below):

- ``/siva/spec``       :class:`SpecEvent` - the model spec (+ trainer settings, e.g. seed)
- ``/siva/recording``  :class:`RecordingEvent` - one accepted recording: the uploaded bytes
  exactly as received (base64), their format, role, and the training epoch at arrival
- ``/siva/dataset``    :class:`DatasetEvent` - (optional) the moment the trainer's data set
  changed: the epoch and the recording ids in use; replay prefers it over arrival epochs
- ``/siva/anchor``     :class:`AnchorEvent` - the trainer entered (or re-anchored) the
  output-error phase after ``epoch`` epochs: the anchor theta, the records and chain it was
  linearised on, the bootstrap replicate count and seed (replay recomputes it exactly)
- ``/siva/snapshot``   :class:`SnapshotEvent` - an estimate as served by GET .../estimate
- ``/siva/repair``     :class:`RepairEvent` - start-up found the log behind the store and
  repaired it (service/reconcile.py): what was missing, and - when the log can no longer
  explain the checkpoint training resumes from - that trainer state, so replay starts there

Recordings are logged as the original bytes (not re-encoded float arrays) so that a replay
parses exactly what the live service parsed - bit-identical states - and the file stays
compact: every message is its own zstd-compressed chunk, which packs the base64 text back
to below the size of the raw CSV.

Crash safety: every message is written as one complete chunk, then the file is flushed and
fsync'ed, so a process killed mid-write loses at most the message being written.  A file
without footer (the process died) is still readable (:func:`read_events` keeps every
complete record, resynchronising after a torn one) and :func:`recover` rewrites it as a
finished file.  A write that fails (disk full, read-only) abandons the file - its tail may
be torn - and the next event opens a new file that starts with the spec again.

Write-ahead: the service logs a recording *before* the store commits it and before the
HTTP 202, and a failed log write fails the upload (507), so every acknowledged recording
is in the log of its system (see docs/reliability.md).
"""
from __future__ import annotations

import base64
import hashlib
import io
import json
import logging
import os
import shutil
import struct
import threading
import time
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Iterator, Literal, Mapping, Sequence

from mcap.exceptions import EndOfFile, McapError
from mcap.records import Channel, Message, Metadata, Schema
from mcap.stream_reader import MAGIC_SIZE, StreamReader
from mcap.writer import CompressionType, Writer
from pydantic import BaseModel, ConfigDict, Field

from siva_core import MCAP_MAGIC

from .fingerprint import platform_fingerprint

log = logging.getLogger("siva.mcap_log")

FORMAT_VERSION = "siva-log/1"
TOPIC_SPEC = "/siva/spec"
TOPIC_RECORDING = "/siva/recording"
TOPIC_DATASET = "/siva/dataset"
TOPIC_SNAPSHOT = "/siva/snapshot"
TOPIC_ANCHOR = "/siva/anchor"
TOPIC_REPAIR = "/siva/repair"
PLATFORM_METADATA = "siva.platform"
MAGIC = MCAP_MAGIC
_FOOTER_OPCODE = 0x02
_FOOTER_RECORD = 1 + 8 + 20  # opcode + length + (summary_start, summary_offset_start, crc)


# ------------------------------------------------------------------------ message models
class SpecEvent(BaseModel):
    """The model spec of a system, as registered (CONTRACT.md structure)."""

    system: str
    spec: dict[str, Any] = Field(description="model spec, the JSON form of the TOML file")
    settings: dict[str, Any] = Field(default_factory=dict,
                                     description="trainer settings needed to replay (seed, preset)")
    wall_time: float = Field(description="UNIX time [s] when logged")


class RecordingEvent(BaseModel):
    """One accepted recording, byte for byte as uploaded."""

    system: str
    id: str
    role: Literal["train", "validation"]
    format: str = Field(description="csv, json, npz or mcap: how to parse `data`")
    epoch: int = Field(ge=0, description="training epochs completed when it arrived")
    name: str | None = None
    size: int = Field(ge=0, description="bytes of the decoded payload")
    sha256: str
    data: str = Field(description="the uploaded bytes, base64 (RFC 4648)")
    wall_time: float
    channel_map: dict[str, str] | None = Field(
        None, description="the upload's ?map= channel renames (stored name -> column)")
    units: dict[str, str] | None = Field(None, description="the upload's ?unit= declarations")

    def payload(self) -> bytes:
        """The uploaded bytes; checked against the logged hash so corruption is loud."""
        raw = base64.b64decode(self.data)
        if hashlib.sha256(raw).hexdigest() != self.sha256:
            raise ValueError(f"recording {self.id}: payload does not match its sha256")
        return raw


class DatasetEvent(BaseModel):
    """The trainer's data set changed before training epoch ``epoch + 1``."""

    system: str
    epoch: int = Field(ge=0, description="epochs completed when the new data set took effect")
    train: list[str]
    validation: list[str]
    processing: dict[str, Any] | None = Field(
        None, description="the processing chain's settings (siva_core Processing fields)")
    wall_time: float


class AnchorEvent(BaseModel):
    """The output-error phase was anchored (linearised) before training epoch ``epoch + 1``."""

    system: str
    epoch: int = Field(ge=0, description="epochs completed when the anchor took effect")
    theta: list[float] = Field(description="anchor parameters, in the model's free order")
    train: list[str] = Field(description="records the output error was linearised on")
    validation: list[str] = Field(description="records the discriminator judges")
    processing: dict[str, Any] | None = None
    source: str = Field(description="best (the first recommend_best) | headline | given")
    n_noise: int = Field(ge=0, description="parametric-bootstrap replicates")
    seed: int
    resume: bool = Field(False, description="restored from a checkpoint (no state reset)")
    wall_time: float


try:  # the HTTP API's own model, so the log's schema is the one /openapi.json documents
    from service.api.schemas import Estimate as _Estimate
except ImportError:  # pragma: no cover - schemas.py is part of the service
    class _Estimate(BaseModel):  # type: ignore[no-redef]
        model_config = ConfigDict(extra="allow")
        parameters: dict[str, dict[str, Any]]
        discriminator: dict[str, Any]
        epoch: int
        converged: bool
        n_recordings: dict[str, int]


class SnapshotEvent(BaseModel):
    """An estimate as served by GET /v1/systems/{name}/estimate at ``epoch``."""

    system: str
    epoch: int = Field(ge=0)
    estimate: _Estimate
    wall_time: float

    def estimate_dict(self) -> dict[str, Any]:
        """The logged estimate as plain JSON types (extra keys included)."""
        return self.estimate.model_dump(mode="json")


class RepairEvent(BaseModel):
    """Start-up found this system's log behind the store (the truth) and repaired it.

    ``recordings``: stored recordings the log lacked, logged just before this event.
    ``baseline_*``: when the remaining log cannot reproduce the checkpoint the trainer
    resumes from (its history was lost), that trainer state (``torch.save`` bytes, base64)
    at ``baseline_epoch``: a replay starts from it instead of from scratch."""

    system: str
    reasons: list[str] = Field(description="what was found missing or inconsistent")
    recordings: list[str] = Field(default_factory=list,
                                  description="ids of the recordings logged by this repair")
    baseline_epoch: int | None = Field(None, ge=0)
    baseline_train: list[str] = Field(default_factory=list)
    baseline_validation: list[str] = Field(default_factory=list)
    baseline_sha256: str | None = None
    baseline_state: str | None = Field(None, description="torch.save of the trainer state, base64")
    wall_time: float

    def state_bytes(self) -> bytes | None:
        """The baseline trainer state; checked against its hash so corruption is loud."""
        if self.baseline_state is None:
            return None
        raw = base64.b64decode(self.baseline_state)
        if hashlib.sha256(raw).hexdigest() != self.baseline_sha256:
            raise ValueError(f"repair of {self.system}: baseline state does not match its sha256")
        return raw


_TOPICS: dict[str, type[BaseModel]] = {
    TOPIC_SPEC: SpecEvent,
    TOPIC_RECORDING: RecordingEvent,
    TOPIC_DATASET: DatasetEvent,
    TOPIC_SNAPSHOT: SnapshotEvent,
    TOPIC_ANCHOR: AnchorEvent,
    TOPIC_REPAIR: RepairEvent,
}


def _schema_bytes(model: type[BaseModel]) -> bytes:
    return json.dumps(model.model_json_schema(), separators=(",", ":")).encode()


# ------------------------------------------------------------------------ writing
class _SystemLog:
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
            # what bit-identity of a replay depends on (service/fingerprint.py)
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
            model = _TOPICS[topic]
            sid = self._writer.register_schema(f"siva.{model.__name__}", "jsonschema",
                                               _schema_bytes(model))
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


def _finish(sl: _SystemLog) -> None:
    """Close a system's open file; a disk that refuses leaves it to crash recovery."""
    with sl.lock:
        try:
            sl.close()
        except OSError as exc:
            log.warning("cannot finish %s: %s", sl.path, exc)
            sl.abandon()


class EventLog:
    """Append-only MCAP event logs for all systems of one service process.

    Files open lazily, one per system, at the first event of that system in this process.
    Thread-safe (routes and workers log concurrently).  After :meth:`close`, further events
    are dropped with a warning rather than raised, so a late worker tick during shutdown
    cannot crash the service.  ``settings`` (e.g. ``{"seed": 42, "preset": "fast"}``) is
    written into every spec event and the file metadata, so a replay uses the same trainer.
    """

    def __init__(self, data_dir: str | Path, *, settings: Mapping[str, Any] | None = None,
                 recover_unfinished: bool = True) -> None:
        self.root = Path(data_dir) / "logs"
        self.settings = dict(settings or {})
        self._lock = threading.Lock()
        self._logs: dict[str, _SystemLog] = {}
        self._specs: dict[str, SpecEvent] = {}  # re-logged first in every new file
        self._opened: set[str] = set()          # systems that had a file in this process
        self._closed = False
        self._started = datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%S.%fZ")
        self.recovered: list[Path] = []
        if recover_unfinished and self.root.is_dir():
            # a previous process that died leaves footer-less files: finish them now
            for p in sorted(self.root.glob("*/*.mcap")):
                try:
                    if not is_finished(p) and not _writer_alive(p):
                        self.recovered.append(recover(p, keep_partial=False))
                        log.warning("event log %s was unfinished (a crash): recovered", p)
                except (OSError, McapError, ValueError) as exc:
                    log.warning("cannot recover %s: %s", p, exc)
            # copies kept by earlier versions once their log is finished (the recovery
            # itself is recorded in the finished file's siva.recovery metadata)
            for p in sorted(self.root.glob("*/*.mcap.partial")):
                done = p.with_name(p.name[:-len(".partial")])
                try:
                    if done.exists() and is_finished(done) and not _writer_alive(done):
                        p.unlink()
                except OSError as exc:
                    log.warning("cannot remove %s: %s", p, exc)

    # -- public API
    def folder(self, system: str) -> Path:
        """The folder of ``system``'s log files (one per process start)."""
        return self.root / _safe(system)

    def path(self, system: str) -> Path | None:
        """The file of ``system`` in this process, if one was opened."""
        with self._lock:
            sl = self._logs.get(system)
            return sl.path if sl else None

    def log_spec(self, system: str, spec_dict: Mapping[str, Any],
                 settings: Mapping[str, Any] | None = None) -> None:
        ev = SpecEvent(system=system, spec=json.loads(json.dumps(dict(spec_dict))),
                       settings={**self.settings, **(settings or {})}, wall_time=time.time())
        self._write(system, TOPIC_SPEC, ev)
        self._specs[system] = ev

    def rotate(self, system: str) -> None:
        """Finish the current file of ``system``; its next event opens a new one (e.g. when
        a trainer restarts from its checkpoint: a new segment, as after a process restart)."""
        with self._lock:
            sl = self._logs.pop(system, None)
        if sl is not None:
            _finish(sl)

    def log_recording(self, system: str, rec_id: str, role: str, raw_bytes: bytes, fmt: str,
                      epoch: int, name: str | None = None,
                      channel_map: Mapping[str, str] | None = None,
                      units: Mapping[str, str] | None = None) -> None:
        raw = bytes(raw_bytes)
        ev = RecordingEvent(system=system, id=str(rec_id), role=_role(role), format=fmt,
                            epoch=int(epoch), name=name, size=len(raw),
                            sha256=hashlib.sha256(raw).hexdigest(),
                            data=base64.b64encode(raw).decode("ascii"), wall_time=time.time(),
                            channel_map=dict(channel_map) if channel_map else None,
                            units=dict(units) if units else None)
        self._write(system, TOPIC_RECORDING, ev)

    def log_dataset(self, system: str, epoch: int, train_ids: Sequence[str],
                    validation_ids: Sequence[str], processing: Any = None) -> None:
        """Record that the trainer got a new data set after ``epoch`` completed epochs
        (and, optionally, the processing chain it was prepared with)."""
        proc = None
        if processing is not None:
            proc = json.loads(json.dumps(processing if isinstance(processing, Mapping)
                                         else _jsonable(processing), default=_jsonable))
        ev = DatasetEvent(system=system, epoch=int(epoch), train=[str(i) for i in train_ids],
                          validation=[str(i) for i in validation_ids], processing=proc,
                          wall_time=time.time())
        self._write(system, TOPIC_DATASET, ev)

    def log_anchor(self, system: str, epoch: int, anchor: Mapping[str, Any], *,
                   resume: bool = False) -> None:
        """Record that the trainer was anchored for the output-error phase after ``epoch``
        completed epochs (``anchor``: trainer.anchoring.anchor_record)."""
        ev = AnchorEvent(system=system, epoch=int(epoch),
                         theta=[float(x) for x in anchor["theta"]],
                         train=[str(i) for i in anchor["train"]],
                         validation=[str(i) for i in anchor["validation"]],
                         processing=anchor.get("processing"), source=str(anchor["source"]),
                         n_noise=int(anchor["n_noise"]), seed=int(anchor["seed"]),
                         resume=resume, wall_time=time.time())
        self._write(system, TOPIC_ANCHOR, ev)

    def log_snapshot(self, system: str, snapshot_dict: Mapping[str, Any]) -> None:
        snap = json.loads(json.dumps(dict(snapshot_dict), default=_jsonable))
        ev = SnapshotEvent(system=system, epoch=int(snap.get("epoch", 0) or 0), estimate=snap,
                           wall_time=time.time())
        self._write(system, TOPIC_SNAPSHOT, ev)

    def remove(self, system: str, *, archive: bool = False) -> dict[str, Any]:
        """Finish the system's open file, then delete its log folder or, with ``archive``,
        move it to ``<data>/archive/logs/<system>-<UTC time>/`` (outside ``logs/``: no
        longer recovered at start-up, nor stitched into a new system of the same name).

        Returns what was done: ``{"action": "deleted" | "archived" | "none", "files": n}``
        (+ ``"archive"``, the folder relative to the data directory).  Raises OSError when
        the disk refuses (the caller reports it; the files are then still there)."""
        with self._lock:
            sl = self._logs.pop(system, None)
            self._specs.pop(system, None)
        if sl is not None:
            _finish(sl)
        folder = self.root / _safe(system)
        if not folder.is_dir():
            return {"action": "none", "files": 0}
        files = len(list(folder.glob("*.mcap")))
        if not archive:
            shutil.rmtree(folder)
            return {"action": "deleted", "files": files}
        stamp = datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%SZ")
        dest = self.root.parent / "archive" / "logs" / f"{_safe(system)}-{stamp}"
        while dest.exists():
            dest = dest.with_name(dest.name + "x")
        dest.parent.mkdir(parents=True, exist_ok=True)
        os.replace(folder, dest)
        return {"action": "archived", "files": files,
                "archive": str(dest.relative_to(self.root.parent))}

    def log_repair(self, system: str, reasons: Sequence[str], recordings: Sequence[str] = (),
                   baseline: Mapping[str, Any] | None = None) -> None:
        """Record a start-up repair (service/reconcile.py); ``baseline``: ``epoch``,
        ``train``, ``validation`` and ``state`` (torch.save bytes of the trainer state)."""
        kw: dict[str, Any] = {}
        if baseline is not None:
            raw = bytes(baseline["state"])
            kw = dict(baseline_epoch=int(baseline["epoch"]),
                      baseline_train=[str(i) for i in baseline.get("train", ())],
                      baseline_validation=[str(i) for i in baseline.get("validation", ())],
                      baseline_sha256=hashlib.sha256(raw).hexdigest(),
                      baseline_state=base64.b64encode(raw).decode("ascii"))
        ev = RepairEvent(system=system, reasons=list(reasons),
                         recordings=[str(r) for r in recordings], wall_time=time.time(), **kw)
        self._write(system, TOPIC_REPAIR, ev)

    def position(self, system: str) -> dict[str, Any] | None:
        """Where the log of ``system`` stands: its current file and how many data-set
        events that file holds (a checkpoint keeps it, so start-up can tell whether the
        log still explains the checkpoint)."""
        with self._lock:
            sl = self._logs.get(system)
            if sl is None:
                return None
            return {"file": sl.path.name, "datasets": sl.count(TOPIC_DATASET)}

    def close(self) -> None:
        """Finish every file (summary + footer).  Idempotent."""
        with self._lock:
            self._closed = True
            logs, self._logs = self._logs, {}
        for sl in logs.values():
            try:
                with sl.lock:  # waits for a write in progress
                    sl.close()
            except OSError as exc:  # the data is already fsync'ed; recover() can finish it
                log.warning("cannot finish %s: %s", sl.path, exc)

    def __enter__(self) -> "EventLog":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- internals
    def _write(self, system: str, topic: str, event: BaseModel) -> None:
        """Append one event durably, or raise (OSError: disk full, read-only).

        After a failed write the file is abandoned - its tail may be a torn chunk - and the
        next event starts a new file (spec first), so later events stay readable."""
        retired: _SystemLog | None = None
        with self._lock:
            if self._closed:
                log.warning("event log closed; dropping %s event of %r", topic, system)
                return
            sl = self._logs.get(system)
            if sl is not None and topic == TOPIC_SPEC and sl.has_spec:
                # a second spec in one process: the system was deleted and created again.
                # A new file keeps "one file = one incarnation" for replay.
                retired, sl = sl, None
            if sl is None:
                stamp = (self._started if retired is None and system not in self._opened else
                         datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%S.%fZ"))
                self._opened.add(system)
                path = self.root / _safe(system) / f"{stamp}-{os.getpid()}.mcap"
                while path.exists():  # a replacement within the same microsecond
                    path = path.with_name(f"{path.stem}x.mcap")
                sl = _SystemLog(path, system, {"started": self._started, "pid": os.getpid(),
                                               **{f"settings.{k}": v
                                                  for k, v in self.settings.items()}})
                self._logs[system] = sl
            sl.lock.acquire()
        try:
            if retired is not None:
                with retired.lock:
                    retired.close()
            spec = self._specs.get(system)
            if not sl.has_spec and topic != TOPIC_SPEC and spec is not None:
                sl.write(TOPIC_SPEC, spec)  # a replacement file stays self-contained
                sl.has_spec = True
            sl.write(topic, event)
            if topic == TOPIC_SPEC:
                sl.has_spec = True
        except BaseException:
            with self._lock:
                if self._logs.get(system) is sl:
                    del self._logs[system]
            sl.abandon()
            raise
        finally:
            sl.lock.release()


def _writer_alive(path: Path) -> bool:
    """Whether the process named in ``<time>-<pid>.mcap`` still runs (do not touch its file)."""
    pid = path.stem.rpartition("-")[2]
    if not pid.isdigit() or int(pid) == os.getpid():
        return False
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _role(role: str) -> str:
    r = (role or "train").lower()
    return {"val": "validation", "validate": "validation"}.get(r, r)


def _safe(system: str) -> str:
    """A directory name for a system name (names are validated upstream; belt and braces)."""
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in system).lstrip(".") or "_"


def _jsonable(x: Any) -> Any:
    import dataclasses

    if dataclasses.is_dataclass(x) and not isinstance(x, type):
        return dataclasses.asdict(x)
    if hasattr(x, "tolist"):
        return x.tolist()
    if hasattr(x, "model_dump"):
        return x.model_dump()
    raise TypeError(f"not JSON serialisable: {type(x).__name__}")


# ------------------------------------------------------------------------ reading
@dataclass
class LogEvent:
    """One decoded message: topic, log time [ns] and the typed event."""

    topic: str
    log_time: int
    event: SpecEvent | RecordingEvent | DatasetEvent | SnapshotEvent | RepairEvent


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
        model = _TOPICS.get(ch.topic)
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


# ------------------------------------------------------------------------ recovery
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
    _fsync_dir(path.parent)
    return path


def _fsync_dir(folder: Path) -> None:
    fd = os.open(folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
