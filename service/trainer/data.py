"""The trainer's data: which stored records it uses, parsed and processed once.

Why apart from the loop: choosing records (the replay buffer), parsing them, choosing one
processing chain for the set and applying it is a concern of its own, shared by the
equation-error phase (processed states) and the output-error phase (raw records for the
linearisation).  ``refresh`` returns a new :class:`DataSet` only when the selection or the
chain changed; everything is cached per record id.
"""
from __future__ import annotations

import logging
from typing import Any

from siva_core import Processing, Recording, RecordingError, States, Structure

from ..errors import UnknownSystem
from ..settings import Settings
from ..storage.recordings import RecordingMeta
from ..storage.store import Store
from ..storage.uploads import processing_for
from .replay_buffer import ReplayBuffer
from .types import DataSet

log = logging.getLogger("siva.service.worker")


class SystemDeleted(Exception):
    """The system was deleted from the store under the trainer."""


def same_chain(a: Any, b: Any) -> bool:
    """Equality of two processing chains, even when a field holds numpy arrays."""
    try:
        return bool(a == b)
    except (ValueError, TypeError):
        return repr(a) == repr(b)


class DataFeed:
    """Replay buffer + parsed records + processed states of one system (trainer thread)."""

    def __init__(self, name: str, structure: Structure, store: Store, settings: Settings) -> None:
        self.name = name
        self.structure = structure
        self.store = store
        self.buffer = ReplayBuffer(settings.replay_window, settings.replay_reservoir,
                                   settings.validation_window, f"{settings.seed}:{name}")
        self.recs: dict[str, Recording] = {}
        self.states: dict[str, States] = {}
        self.processing: Processing | None = None
        self.rejected: dict[str, str] = {}       # unreadable bytes: permanent
        self.unprocessable: dict[str, str] = {}  # processing failed in the current set
        self.train_ids: list[str] = []
        self.val_ids: list[str] = []
        self.version = 0

    def refresh(self, epoch: int, force: bool = False) -> DataSet | None:
        """Pick up new records; a new :class:`DataSet` when the selection changed (or
        ``force``) and both roles are present, else None."""
        try:
            metas = self.store.recordings(self.name)
        except UnknownSystem as exc:
            raise SystemDeleted(self.name) from exc
        by_id: dict[str, RecordingMeta] = {m.id: m for m in metas}
        self.buffer.extend(m for m in metas if m.index > self.buffer.last_index)
        wanted = [i for i in self.buffer.train_ids + self.buffer.val_ids if i not in self.rejected]
        for rid in wanted:
            if rid in self.recs:
                continue
            meta = by_id[rid]
            try:
                raw = self.store.read_raw(self.name, meta)
                self.recs[rid] = Recording.read(raw, self.structure.dofs, name=rid, fmt=meta.fmt,
                                                **meta.read_options(self.structure))
            except (OSError, RecordingError) as exc:
                log.error("%s: recording %s unusable: %s", self.name, rid, exc)
                self.rejected[rid] = str(exc)
        for rid in list(self.recs):
            if rid not in wanted:
                del self.recs[rid]
        recs = [self.recs[i] for i in wanted if i in self.recs]
        try:
            proc = processing_for(recs, self.structure.dofs)
        except Exception as exc:  # noqa: BLE001 - fall back to the plain chain, say so
            log.error("%s: Processing.auto failed (%s); using Processing()", self.name, exc)
            proc = Processing()
        chain_changed = not same_chain(proc, self.processing)
        if chain_changed:
            self.states.clear()
            self.processing = proc
        for rid in list(self.states):
            if rid not in self.recs:
                del self.states[rid]
        self.unprocessable = {}
        for rid, rec in self.recs.items():
            if rid in self.states:
                continue
            try:
                self.states[rid] = proc.apply(rec, self.structure.dofs)
            except Exception as exc:  # noqa: BLE001
                # the chain chosen for the whole set does not suit this record (it passed
                # its own chain at upload): use the record's own chain rather than lose it
                try:
                    own = processing_for([rec], self.structure.dofs)
                    self.states[rid] = own.apply(rec, self.structure.dofs)
                    log.warning("%s: %s processed with its own chain (the common one "
                                "failed: %s)", self.name, rid, exc)
                except Exception as exc2:  # noqa: BLE001
                    log.error("%s: processing %s failed: %s", self.name, rid, exc2)
                    self.unprocessable[rid] = f"processing failed: {exc2}"
        train = [i for i in self.buffer.train_ids if i in self.states]
        val = [i for i in self.buffer.val_ids if i in self.states]
        changed = (train, val) != (self.train_ids, self.val_ids) or chain_changed
        self.train_ids, self.val_ids = train, val
        if not (train and val) or not (changed or force):
            return None
        self.version += 1
        return DataSet(self.version, epoch, tuple(train), tuple(val), self.processing)

    @property
    def ready(self) -> bool:
        return bool(self.train_ids and self.val_ids)

    def train_states(self) -> list[States]:
        return [self.states[i] for i in self.train_ids]

    def val_states(self) -> list[States]:
        return [self.states[i] for i in self.val_ids]

    def records(self, ids: tuple[str, ...] | list[str]) -> tuple[Recording, ...]:
        return tuple(self.recs[i] for i in ids)

    def samples(self, ids: list[str]) -> int:
        return int(sum(len(self.states[i]) for i in ids if i in self.states))

    def problems(self) -> dict[str, str]:
        return {**self.rejected, **self.unprocessable}
