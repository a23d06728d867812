"""Which records the trainer holds in memory: a recent window plus a reservoir sample."""
from __future__ import annotations

import random
from collections import deque
from typing import Iterable

from ..storage.recordings import RecordingMeta


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
