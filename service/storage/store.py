"""Durable store of systems and recordings, and the bounded in-memory replay buffer.

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
import io
import json
import logging
import os
import random
import re
import shutil
import threading
import time
import uuid
from collections import deque
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable, Iterable, Literal

from siva_core import RECORDING_FORMATS as REGISTRY

log = logging.getLogger("siva.service.store")

Role = Literal["train", "validation"]
ROLES: tuple[str, ...] = ("train", "validation")
#: system names (also directory names): use ``fullmatch``; ``\Z``, not ``$``, which would
#: accept a trailing newline ("a\n" and "a" would share a log directory)
NAME_RE = re.compile(r"\A[A-Za-z0-9][A-Za-z0-9_.-]{0,63}\Z")
FORMATS = tuple(REGISTRY)  # every registered recording format


class StoreError(Exception):
    """Base of the store's refusals (mapped to 4xx by the routes)."""


class UnknownSystem(StoreError):
    pass


class SpecConflict(StoreError):
    pass


class DuplicateConflict(StoreError):
    pass


class UnknownRecording(StoreError):
    pass


# --------------------------------------------------------------------------- durable files
def fsync_dir(path: Path) -> None:
    """Make a rename/create/unlink in ``path`` durable (POSIX: fsync the directory)."""
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def atomic_write(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically and durably (temp file, fsync, rename, fsync dir)."""
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
    try:
        view = memoryview(data)
        while view:
            n = os.write(fd, view)
            view = view[n:]
        os.fsync(fd)
    except BaseException:
        os.close(fd)
        tmp.unlink(missing_ok=True)
        raise
    os.close(fd)
    try:
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    fsync_dir(path.parent)


def _mkdir_durable(path: Path) -> None:
    if path.is_dir():
        return
    path.mkdir(parents=True, exist_ok=True)
    fsync_dir(path.parent)


# --------------------------------------------------------------------------- metadata
@dataclass(frozen=True)
class RecordingMeta:
    """What the store knows about one acknowledged recording (immutable)."""

    id: str
    system: str
    index: int              # arrival index within the system, 1-based, never reused
    role: str
    role_source: str        # "explicit" (the ?role= of the upload) or "auto" (the split rule)
    sha256: str
    fmt: str
    filename: str
    bytes: int
    n_samples: int
    fs: float
    duration_s: float
    columns: tuple[str, ...]
    received_at: float      # unix time of the acknowledgement
    channel_map: dict[str, str] | None = None  # the upload's ?map= (stored name -> column)
    units: dict[str, str] | None = None        # the upload's ?unit= (column -> unit)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["columns"] = list(self.columns)
        return d

    def read_options(self, structure: Any) -> dict[str, Any]:
        """``Recording.read`` keywords for this stored file: the system's ``[channels]``
        overridden by the upload's own mapping."""
        return structure.read_options(self.channel_map, self.units)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "RecordingMeta":
        d = dict(d)
        d["columns"] = tuple(d.get("columns", ()))
        return cls(**{k: d[k] for k in cls.__dataclass_fields__ if k in d})


@dataclass
class _System:
    name: str
    spec: dict[str, Any]
    path: Path
    recordings: list[RecordingMeta]
    lock: threading.Lock

    def counts(self) -> dict[str, int]:
        return _role_counts(self.recordings)


def _role_counts(metas: Iterable[RecordingMeta]) -> dict[str, int]:
    c = {r: 0 for r in ROLES}
    for m in metas:
        c[m.role] += 1
    return c


def auto_role(index: int, counts: dict[str, int], every: int) -> str:
    """The documented split for uploads without ``role``.

    The first record goes to train; while there is train data but no validation record, the
    next goes to validation; after that, arrival ``index`` goes to validation when
    ``index % every == 0`` (so 1 in ``every`` records validates) and to train otherwise.
    """
    if counts.get("train", 0) == 0:
        return "train"
    if counts.get("validation", 0) == 0:
        return "validation"
    return "validation" if index % every == 0 else "train"


# --------------------------------------------------------------------------- the store
class Store:
    """Thread-safe durable store; an in-memory index mirrors the disk for fast reads."""

    def __init__(self, root: Path, *, auto_validation_every: int = 4) -> None:
        self.root = Path(root)
        self.auto_validation_every = auto_validation_every
        self._lock = threading.Lock()
        self._systems: dict[str, _System] = {}
        _mkdir_durable(self.root / "systems")

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
            raw = rdir / _raw_name(m.id, m.fmt)
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
                _mkdir_durable(d)
                _mkdir_durable(d / "recordings")
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
                      filename: str, info: dict[str, Any],
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
                n_samples=int(info.get("n_samples", 0)), fs=float(info.get("fs", 0.0)),
                duration_s=float(info.get("duration_s", 0.0)),
                columns=tuple(info.get("columns", ())), received_at=time.time(),
                channel_map=info.get("channel_map") or None, units=info.get("units") or None)
            rdir = s.path / "recordings"
            raw_path = rdir / _raw_name(rid, fmt)
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
        return _find_recording(self.recordings(name), name, rid)

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
        return (self._get(name).path / "recordings" / _raw_name(meta.id, meta.fmt)).read_bytes()

    # ------------------------------------------------------------------ checkpoints
    def checkpoint_path(self, name: str) -> Path:
        return self._get(name).path / "checkpoint.pt"

    def save_checkpoint(self, name: str, state: dict[str, Any]) -> None:
        _save_checkpoint(self.checkpoint_path(name), state)

    def load_checkpoint(self, name: str) -> dict[str, Any] | None:
        return _load_checkpoint(self.checkpoint_path(name))


def _find_recording(metas: list[RecordingMeta], name: str, rid: str) -> RecordingMeta:
    for m in metas:
        if m.id == rid:
            return m
    raise UnknownRecording(f"system {name!r} has no recording {rid!r}")


def _raw_name(rid: str, fmt: str) -> str:
    return f"{rid}.data.{fmt}"


def _save_checkpoint(path: Path, state: dict[str, Any]) -> None:
    """torch.save into memory, then one atomic durable write (never a torn checkpoint)."""
    import torch

    buf = io.BytesIO()
    torch.save(state, buf)
    atomic_write(path, buf.getvalue())


def _load_checkpoint(path: Path) -> dict[str, Any] | None:
    import torch

    if not path.exists():
        return None
    try:
        # our own file in our own data dir; it holds numpy arrays, hence weights_only=False
        return torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # noqa: BLE001 - a bad checkpoint means: start fresh
        log.error("%s: unreadable checkpoint (%s); training restarts from scratch", path, exc)
        return None


# --------------------------------------------------------------------------- trainer's view
class TrainerStoreView:
    """The part of the store a trainer uses, read straight from a shared data dir.

    Why a separate, narrow view: with ``SIVA_EXECUTOR=ray`` trainers run in other processes,
    possibly on other machines that mount the same data dir, while the front process stays
    the only writer of systems and recordings.  A trainer needs five things: the recordings'
    metadata, their bytes, the counts, and its own checkpoint (read and write).  It never
    cleans up, renames or deletes (that is the front's ``Store.load``/``delete_system``),
    so it cannot race an upload in flight: a recording is visible once its meta file - the
    store's commit point, written after the bytes - exists.  Any backend with "list keys
    under a prefix, get, atomic put" (an object store) could implement the same five calls.
    """

    def __init__(self, root: Path) -> None:
        self.root = Path(root)
        self._cache: dict[str, dict[str, RecordingMeta]] = {}  # system -> meta file -> meta

    def _dir(self, name: str) -> Path:
        d = self.root / "systems" / name
        if not NAME_RE.fullmatch(name) or not (d / "spec.json").is_file():
            raise UnknownSystem(f"system {name!r} does not exist")
        return d

    def spec(self, name: str) -> dict[str, Any]:
        return json.loads((self._dir(name) / "spec.json").read_text())

    def recordings(self, name: str) -> list[RecordingMeta]:
        rdir = self._dir(name) / "recordings"
        cache = self._cache.setdefault(name, {})
        try:
            files = [p for p in rdir.iterdir() if p.suffix == ".json"
                     and not p.name.startswith(".") and not p.name.endswith(".data.json")]
        except FileNotFoundError:
            raise UnknownSystem(f"system {name!r} does not exist") from None
        for p in files:
            if p.name not in cache:
                try:
                    cache[p.name] = RecordingMeta.from_dict(json.loads(p.read_text()))
                except (OSError, ValueError, KeyError, TypeError) as exc:
                    log.error("%s: unreadable recording meta (%s); ignored", p, exc)
        return sorted(cache.values(), key=lambda m: m.index)

    def recording(self, name: str, rid: str) -> RecordingMeta:
        return _find_recording(self.recordings(name), name, rid)

    def counts(self, name: str) -> dict[str, int]:
        return _role_counts(self.recordings(name))

    def read_raw(self, name: str, meta: RecordingMeta) -> bytes:
        return (self._dir(name) / "recordings" / _raw_name(meta.id, meta.fmt)).read_bytes()

    def save_checkpoint(self, name: str, state: dict[str, Any]) -> None:
        _save_checkpoint(self._dir(name) / "checkpoint.pt", state)

    def load_checkpoint(self, name: str) -> dict[str, Any] | None:
        return _load_checkpoint(self._dir(name) / "checkpoint.pt")


# --------------------------------------------------------------------------- replay buffer
class ReplayBuffer:
    """Which records are held in memory for training (everything stays on disk).

    Policy: the ``window`` most recent train records, plus a reservoir sample (Vitter's
    algorithm R) of size ``reservoir`` over the train records that have left the window,
    and the ``val_window`` most recent validation records.  Records are fed in arrival
    order and the reservoir's generator is seeded from (seed, system), so replaying the
    store after a restart rebuilds exactly the same buffer.  Memory is therefore bounded by
    ``window + reservoir + val_window`` records whatever the stream length.
    """

    def __init__(self, window: int, reservoir: int, val_window: int, seed: str) -> None:
        self.window = window
        self.reservoir_size = reservoir
        self._recent: deque[str] = deque()
        self._reservoir: list[str] = []
        self._aged = 0
        self._val: deque[str] = deque(maxlen=val_window)
        self._rng = random.Random(seed)
        self.last_index = 0

    def add(self, meta: RecordingMeta) -> None:
        if meta.index <= self.last_index:
            return
        self.last_index = meta.index
        if meta.role == "validation":
            self._val.append(meta.id)
            return
        self._recent.append(meta.id)
        if len(self._recent) > self.window:
            self._offer(self._recent.popleft())

    def _offer(self, rid: str) -> None:
        self._aged += 1
        if self.reservoir_size == 0:
            return
        if len(self._reservoir) < self.reservoir_size:
            self._reservoir.append(rid)
        else:
            j = self._rng.randrange(self._aged)
            if j < self.reservoir_size:
                self._reservoir[j] = rid

    def extend(self, metas: Iterable[RecordingMeta]) -> None:
        for m in metas:
            self.add(m)

    @property
    def train_ids(self) -> list[str]:
        return list(self._reservoir) + list(self._recent)

    @property
    def val_ids(self) -> list[str]:
        return list(self._val)
