"""The part of the store a trainer uses, read straight from a (shared) data directory."""
from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

from ..errors import UnknownSystem
from .checkpoints import load_checkpoint, save_checkpoint
from .recordings import RecordingMeta, find_recording, raw_name, role_counts
from .store import NAME_RE

log = logging.getLogger("siva.service.store")


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
        return find_recording(self.recordings(name), name, rid)

    def counts(self, name: str) -> dict[str, int]:
        return role_counts(self.recordings(name))

    def read_raw(self, name: str, meta: RecordingMeta) -> bytes:
        return (self._dir(name) / "recordings" / raw_name(meta.id, meta.fmt)).read_bytes()

    def save_checkpoint(self, name: str, state: dict[str, Any]) -> None:
        save_checkpoint(self._dir(name) / "checkpoint.pt", state)

    def load_checkpoint(self, name: str) -> dict[str, Any] | None:
        return load_checkpoint(self._dir(name) / "checkpoint.pt")
