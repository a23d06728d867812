"""Writing the event log: one MCAP file per system per process start, durably.

Crash safety: every message is written as one complete chunk, then the file is flushed and
fsync'ed, so a process killed mid-write loses at most the message being written.  A write
that fails (disk full, read-only) abandons the file - its tail may be torn - and the next
event opens a new file that starts with the spec again.  The format (topics, models) is in
``channels.py``; reading a (possibly torn) file in ``reader.py``; finishing one in
``recovery.py``.

Write-ahead: the service logs a recording *before* the store commits it and before the
HTTP 202, and a failed log write fails the upload (507), so every acknowledged recording
is in the log of its system (see docs/reliability.md).
"""
from __future__ import annotations

import base64
import hashlib
import json
import logging
import os
import shutil
import threading
import time
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Mapping, Sequence

from mcap.exceptions import McapError
from pydantic import BaseModel

from .channels import (TOPIC_ANCHOR, TOPIC_DATASET, TOPIC_RECORDING, TOPIC_REPAIR, TOPIC_SNAPSHOT,
                        TOPIC_SPEC, AnchorEvent, DatasetEvent, RecordingEvent, RepairEvent,
                        SnapshotEvent, SpecEvent)
from .log_file import SystemLogFile, finish
from .reader import is_finished
from .recovery import recover

log = logging.getLogger("siva.mcap_log")


@dataclass(frozen=True)
class LogRemoval:
    """What :meth:`EventLog.remove` did with a system's log folder (``archive``: the folder,
    relative to the data directory, when archived)."""

    action: str  # deleted | archived | none
    files: int
    archive: str | None = None

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"action": self.action, "files": self.files}
        if self.archive is not None:
            out["archive"] = self.archive
        return out


@dataclass(frozen=True)
class LogPosition:
    """Where a system's log stands: its current file and how many data-set events it holds."""

    file: str
    datasets: int


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
        self._logs: dict[str, SystemLogFile] = {}
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
            finish(sl)

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

    def remove(self, system: str, *, archive: bool = False) -> LogRemoval:
        """Finish the system's open file, then delete its log folder or, with ``archive``,
        move it to ``<data>/archive/logs/<system>-<UTC time>/`` (outside ``logs/``: no
        longer recovered at start-up, nor stitched into a new system of the same name).

        Returns what was done (:class:`LogRemoval`).  Raises OSError when
        the disk refuses (the caller reports it; the files are then still there)."""
        with self._lock:
            sl = self._logs.pop(system, None)
            self._specs.pop(system, None)
        if sl is not None:
            finish(sl)
        folder = self.root / _safe(system)
        if not folder.is_dir():
            return LogRemoval("none", 0)
        files = len(list(folder.glob("*.mcap")))
        if not archive:
            shutil.rmtree(folder)
            return LogRemoval("deleted", files)
        stamp = datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%SZ")
        dest = self.root.parent / "archive" / "logs" / f"{_safe(system)}-{stamp}"
        while dest.exists():
            dest = dest.with_name(dest.name + "x")
        dest.parent.mkdir(parents=True, exist_ok=True)
        os.replace(folder, dest)
        return LogRemoval("archived", files, str(dest.relative_to(self.root.parent)))

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

    def position(self, system: str) -> LogPosition | None:
        """Where the log of ``system`` stands: its current file and how many data-set
        events that file holds (a checkpoint keeps it, so start-up can tell whether the
        log still explains the checkpoint)."""
        with self._lock:
            sl = self._logs.get(system)
            if sl is None:
                return None
            return LogPosition(sl.path.name, sl.count(TOPIC_DATASET))

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
        retired: SystemLogFile | None = None
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
                sl = SystemLogFile(path, system, {"started": self._started, "pid": os.getpid(),
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
