"""Durable store of systems and recordings (the front process is its only writer).

Layout under the data directory (one directory per system)::

    systems/<name>/spec.json                      the model spec, as PUT
    systems/<name>/recordings/<id>.data.<fmt>     the raw bytes, as uploaded
    systems/<name>/recordings/<id>.json           meta: role, arrival index, sha256, ...
    systems/<name>/checkpoint.pt                  the trainer + drift state (torch.save)

Durability: every file is written to a temporary name, fsync'ed, renamed into place, and
the directory is fsync'ed.  The raw bytes are written before the meta file, so the meta
file is the commit point: a recording exists if and only if its meta exists.  A crash
between the two leaves an orphan raw file, removed on the next start, and never an
acknowledged recording without its data.  The HTTP 202 is sent only after the commit.
"""
from __future__ import annotations

import hashlib
import json
import logging
import os
import re
import shutil
import threading
import time
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from ..errors import DuplicateConflict, SpecConflict, UnknownSystem
from .checkpoints import load_checkpoint, save_checkpoint
from .files import atomic_write, fsync_dir, mkdir_durable
from .recordings import (FORMATS, RecordingMeta, UploadFacts, auto_role, find_recording, raw_name,
                         role_counts)

log = logging.getLogger("siva.service.store")

#: system names (also directory names): use ``fullmatch``; ``\Z``, not ``$``, which would
#: accept a trailing newline ("a\n" and "a" would share a log directory)
NAME_RE = re.compile(r"\A[A-Za-z0-9][A-Za-z0-9_.-]{0,63}\Z")
@dataclass
class _System:
    name: str
    spec: dict[str, Any]
    path: Path
    recordings: list[RecordingMeta]
    lock: threading.Lock

    def counts(self) -> dict[str, int]:
        return role_counts(self.recordings)


class Store:
    """Thread-safe durable store; an in-memory index mirrors the disk for fast reads."""

    def __init__(self, root: Path, *, auto_validation_every: int = 4) -> None:
        self.root = Path(root)
        self.auto_validation_every = auto_validation_every
        self._lock = threading.Lock()
        self._systems: dict[str, _System] = {}
        mkdir_durable(self.root / "systems")

    # ------------------------------------------------------------------ load
    def load(self) -> list[str]:
        """Read every system back from disk, cleaning up what a crash left half-written."""
        loaded: list[str] = []
        base = self.root / "systems"
        for d in sorted(p for p in base.iterdir() if p.is_dir()):
            if d.name.startswith(".") or not NAME_RE.fullmatch(d.name):
                if d.name.startswith(".deleted-"):
                    shutil.rmtree(d, ignore_errors=True)  # an interrupted DELETE
                continue
            self._remove_tmp(d)
            spec_path = d / "spec.json"
            try:
                spec = json.loads(spec_path.read_text())
            except (OSError, json.JSONDecodeError) as exc:
                # a system dir without a committed spec: PUT was never acknowledged
                log.warning("skipping %s: no readable spec.json (%s)", d, exc)
                continue
            recs = self._load_recordings(d)
            self._systems[d.name] = _System(d.name, spec, d, recs, threading.Lock())
            loaded.append(d.name)
        return loaded

    @staticmethod
    def _remove_tmp(d: Path) -> None:
        for p in list(d.glob(".*.tmp")) + list((d / "recordings").glob(".*.tmp")):
            p.unlink(missing_ok=True)

    def _load_recordings(self, d: Path) -> list[RecordingMeta]:
        rdir = d / "recordings"
        if not rdir.is_dir():
            return []
        metas: list[RecordingMeta] = []
        raw_files: dict[str, Path] = {}
        for p in rdir.iterdir():
            if p.name.startswith("."):
                continue
            if p.suffix == ".json" and not p.name.endswith(".data.json"):
                try:
                    m = RecordingMeta.from_dict(json.loads(p.read_text()))
                except (OSError, ValueError, KeyError, TypeError) as exc:
                    log.error("%s: unreadable recording meta (%s); ignored", p, exc)
                    continue
                metas.append(m)
            else:
                raw_files[p.name] = p
        kept = []
        for m in metas:
            raw = rdir / raw_name(m.id, m.fmt)
            if raw.name not in raw_files:
                log.error("%s: recording %s has meta but no data; ignored", d.name, m.id)
                continue
            raw_files.pop(raw.name)
            kept.append(m)
        for orphan in raw_files.values():  # raw written, meta never committed: not acknowledged
            log.info("%s: removing uncommitted upload %s", d.name, orphan.name)
            orphan.unlink(missing_ok=True)
        kept.sort(key=lambda m: m.index)
        return kept

    # ------------------------------------------------------------------ systems
    def systems(self) -> list[str]:
        with self._lock:
            return sorted(self._systems)

    def _get(self, name: str) -> _System:
        with self._lock:
            s = self._systems.get(name)
        if s is None:
            raise UnknownSystem(f"system {name!r} does not exist (PUT /v1/systems/{name} first)")
        return s

    def has(self, name: str) -> bool:
        with self._lock:
            return name in self._systems

    def spec(self, name: str) -> dict[str, Any]:
        return self._get(name).spec

    def put_spec(self, name: str, spec: dict[str, Any]) -> bool:
        """Store a (validated) spec; True if created, False if the same spec was there."""
        if not NAME_RE.fullmatch(name):
            raise ValueError(f"invalid system name {name!r}")
        with self._lock:
            existing = self._systems.get(name)
            if existing is not None:
                if existing.spec == spec:
                    return False
                raise SpecConflict(f"system {name!r} already exists with a different spec "
                                   "(DELETE it first, or use another name)")
            d = self.root / "systems" / name
            try:
                mkdir_durable(d)
                mkdir_durable(d / "recordings")
                atomic_write(d / "spec.json", json.dumps(spec, indent=2, sort_keys=True).encode())
            except OSError:
                # disk full or read-only: leave no half-created system behind (load() would
                # skip it anyway: no spec.json means the PUT was never acknowledged)
                shutil.rmtree(d, ignore_errors=True)
                raise
            self._systems[name] = _System(name, spec, d, [], threading.Lock())
            return True

    def delete_system(self, name: str) -> None:
        """Remove a system: rename it to a tombstone (the atomic commit), then delete files.

        The rename comes first and the index changes only once it succeeded, so a DELETE
        that fails (read-only disk: OSError, a 507) changes nothing, and one that succeeded
        stays deleted after a crash (``load`` removes the tombstones).
        """
        with self._lock:
            s = self._systems.get(name)
            if s is None:
                raise UnknownSystem(f"system {name!r} does not exist")
            with s.lock:
                trash = s.path.with_name(f".deleted-{name}-{uuid.uuid4().hex[:8]}")
                os.replace(s.path, trash)
                self._systems.pop(name, None)
        try:
            fsync_dir(trash.parent)
        except OSError as exc:  # the rename is done; at worst a crash now undoes it
            log.warning("%s: cannot fsync the deletion (%s)", name, exc)
        shutil.rmtree(trash, ignore_errors=True)

    # ------------------------------------------------------------------ recordings
    def add_recording(self, name: str, raw: bytes, *, role: str | None, fmt: str,
                      filename: str, info: UploadFacts,
                      before_commit: Callable[[RecordingMeta], None] | None = None
                      ) -> tuple[RecordingMeta, bool]:
        """Durably store one validated upload; returns (meta, duplicate).

        ``role=None`` applies :func:`auto_role`.  The same bytes uploaded again (a client
        retry) return the stored record with ``duplicate=True`` instead of a second copy,
        unless an explicit different role was asked, which is a conflict.

        ``before_commit(meta)`` runs after the raw bytes are durable and before the meta
        file (the commit point), under the system's lock: the service writes the event log
        there, so the log is a write-ahead record - every committed recording is logged
        first.  If it raises, nothing is committed and the exception propagates.
        """
        if fmt not in FORMATS:
            raise ValueError(f"unknown format {fmt!r}")
        s = self._get(name)
        sha = hashlib.sha256(raw).hexdigest()
        with s.lock:
            for m in s.recordings:
                if m.sha256 == sha:
                    if role is not None and role != m.role:
                        raise DuplicateConflict(
                            f"this recording is already stored as {m.id} with role {m.role!r}")
                    return m, True
            index = (s.recordings[-1].index + 1) if s.recordings else 1
            source = "explicit" if role is not None else "auto"
            if role is None:
                role = auto_role(index, s.counts(), self.auto_validation_every)
            rid = f"r{index:06d}-{sha[:10]}"
            meta = RecordingMeta(
                id=rid, system=name, index=index, role=role, role_source=source, sha256=sha,
                fmt=fmt, filename=filename, bytes=len(raw),
                n_samples=int(info.n_samples), fs=float(info.fs),
                duration_s=float(info.duration_s), columns=tuple(info.columns),
                received_at=time.time(), channel_map=info.channel_map or None,
                units=info.units or None)
            rdir = s.path / "recordings"
            raw_path = rdir / raw_name(rid, fmt)
            atomic_write(raw_path, raw)
            try:
                if before_commit is not None:
                    before_commit(meta)
                atomic_write(rdir / f"{rid}.json", json.dumps(meta.to_dict(), indent=1).encode())
            except BaseException:
                raw_path.unlink(missing_ok=True)
                raise
            s.recordings.append(meta)
            return meta, False

    def recordings(self, name: str) -> list[RecordingMeta]:
        s = self._get(name)
        with s.lock:
            return list(s.recordings)

    def recording(self, name: str, rid: str) -> RecordingMeta:
        return find_recording(self.recordings(name), name, rid)

    def last_index(self, name: str) -> int:
        """Arrival index of the newest recording (0: none), without copying the list."""
        s = self._get(name)
        with s.lock:
            return s.recordings[-1].index if s.recordings else 0

    def counts(self, name: str) -> dict[str, int]:
        s = self._get(name)
        with s.lock:
            return s.counts()

    def read_raw(self, name: str, meta: RecordingMeta) -> bytes:
        return (self._get(name).path / "recordings" / raw_name(meta.id, meta.fmt)).read_bytes()

    # ------------------------------------------------------------------ checkpoints
    def checkpoint_path(self, name: str) -> Path:
        return self._get(name).path / "checkpoint.pt"

    def save_checkpoint(self, name: str, state: dict[str, Any]) -> None:
        save_checkpoint(self.checkpoint_path(name), state)

    def load_checkpoint(self, name: str) -> dict[str, Any] | None:
        return load_checkpoint(self.checkpoint_path(name))
