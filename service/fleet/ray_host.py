"""A trainer host: the Ray actor that runs several systems' trainers (``SIVA_EXECUTOR=ray``).

This module is what runs *inside* the actor process; service/ray_executor.py is the
front's side.  It does not import ray: the front wraps :class:`TrainerHost` with
``ray.remote`` and the actor options (detached, named, ``max_restarts``).

Inside, each system is an ordinary :class:`~service.trainer.SystemWorker` (trainer thread,
refiner thread, checkpoints) working on the shared data dir through the narrow
:class:`~service.storage.trainer_view.TrainerStoreView`.  Its event-log calls go into an
:class:`EventQueue` that the front drains and writes to the MCAP log: the front stays the
log's one writer, events keep their order, and an event is dropped from the queue only
once the front acknowledged it (a poll lost in transit is sent again).
"""
from __future__ import annotations

import logging
import os
import threading
import time
import uuid
from collections import deque
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..errors import UnknownSystem
from ..settings import Settings
from ..storage.trainer_view import TrainerStoreView
from .ray_placement import read_placement

if TYPE_CHECKING:  # the trainer (torch) is imported when a system is added
    from ..trainer import DriftReport

log = logging.getLogger("siva.service.ray_host")

#: events kept for a front that does not drain them (it is down): the oldest snapshot
#: events go first, data-set events (needed for an exact replay) are kept
MAX_QUEUED_EVENTS = 5000


class EventQueue:
    """Stands in for the event log in a trainer actor; the front drains it in order."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._items: deque[tuple[int, str, tuple[Any, ...], dict[str, Any]]] = deque()
        self._seq = 0

    def _put(self, method: str, args: tuple[Any, ...], kw: dict[str, Any]) -> None:
        with self._lock:
            self._seq += 1
            self._items.append((self._seq, method, args, kw))
            if len(self._items) > MAX_QUEUED_EVENTS:
                for k, item in enumerate(self._items):
                    if item[1] == "log_snapshot":
                        del self._items[k]
                        break
                else:
                    self._items.popleft()

    def log_dataset(self, *args: Any, **kw: Any) -> None:
        self._put("log_dataset", args, kw)

    def log_snapshot(self, *args: Any, **kw: Any) -> None:
        self._put("log_snapshot", args, kw)

    def log_anchor(self, *args: Any, **kw: Any) -> None:
        self._put("log_anchor", args, kw)

    def pending(self, acked: int) -> list[tuple[int, str, tuple[Any, ...], dict[str, Any]]]:
        """Forget what the front acknowledged (seq <= ``acked``); the rest, in order."""
        with self._lock:
            while self._items and self._items[0][0] <= acked:
                self._items.popleft()
            return list(self._items)


def settings_dict(settings: Settings) -> dict[str, Any]:
    """Settings as plain values (what the actor is created with, and compared by)."""
    d = asdict(settings)
    d["data_dir"] = str(Path(d["data_dir"]).resolve())  # actors run in other directories
    return d


class TrainerHost:
    """The systems placed on this actor (service/ray_placement.py), one worker each."""

    def __init__(self, host_id: str, settings: dict[str, Any], cpus: float) -> None:
        time.sleep(float(settings.get("ray_start_delay_s") or 0.0))  # tests: a cold start
        import torch

        from ..trainer import SystemWorker

        logging.basicConfig(level=logging.INFO,
                            format="%(asctime)s %(levelname)s %(name)s: %(message)s")
        self._worker_cls = SystemWorker
        self.host_id = host_id
        self.settings_in = settings
        threads = max(1, int(cpus))  # torch's thread count follows the actor's CPU share
        torch.set_num_threads(threads)
        s = Settings(**settings)
        self.settings = s if s.torch_threads else s.with_(torch_threads=threads)
        self.store = TrainerStoreView(Path(s.data_dir))
        self.incarnation = uuid.uuid4().hex
        self.created = time.time()
        self.pid = os.getpid()
        self._lock = threading.Lock()
        self.workers: dict[str, Any] = {}
        self.queues: dict[str, EventQueue] = {}
        self.generation: dict[str, int] = {}
        self._sent: dict[str, tuple[Any, Any]] = {}  # what the front has: (snapshot, report)
        for name in read_placement(Path(s.data_dir)).get(host_id, []):
            try:
                self.add(name)
            except UnknownSystem:
                log.warning("host %s: system %s is placed here but deleted", host_id, name)
        log.info("trainer host %s (pid %d, incarnation %s): %d system(s)", host_id, self.pid,
                 self.incarnation[:8], len(self.workers))

    # ------------------------------------------------------------------ systems
    def add(self, name: str) -> int:
        """Start ``name``'s worker unless a live one runs; returns its generation (a dead
        one is replaced: the front's supervisor asks this after a trainer thread died)."""
        from siva_core import Structure

        with self._lock:
            w = self.workers.get(name)
            if w is not None and not w.died and not w.stopping:
                return self.generation[name]
            structure = Structure.from_dict(self.store.spec(name))
            q = self.queues.setdefault(name, EventQueue())
            w = self._worker_cls(name, structure, self.store, self.settings, q)
            self.workers[name] = w
            self.generation[name] = self.generation.get(name, 0) + 1
            self._sent.pop(name, None)
            gen = self.generation[name]
        w.start()
        return gen

    def remove(self, name: str, generation: int, timeout: float) -> bool:
        """Stop ``name``'s worker (final checkpoint) if it is still that generation."""
        with self._lock:
            w = self.workers.get(name)
            if w is None or self.generation.get(name) != generation:
                return False
            del self.workers[name]
        w.stop(timeout=timeout)
        return True

    def notify(self, name: str) -> None:
        w = self.workers.get(name)
        if w is not None:
            w.notify()

    def _worker(self, name: str) -> Any:
        w = self.workers.get(name)
        if w is None:
            raise KeyError(f"system {name!r} is not on trainer host {self.host_id}")
        return w

    def reset_drift(self, name: str) -> DriftReport:
        return self._worker(name).reset_drift()

    def drift_report(self, name: str) -> DriftReport:
        """Asked for by a GET .../drift: a drift report holds up to SIVA_HISTORY_LIMIT
        snapshots (about 1 MB), too much to ship with every poll; active alarms travel
        with every snapshot."""
        return self._worker(name).drift_report()

    def stop_all(self, timeout: float) -> list[str]:
        """Stop every worker (final checkpoints) within ``timeout``; the late ones' names."""
        from ..trainer import stop_workers

        with self._lock:
            workers = list(self.workers.values())
        return stop_workers(workers, timeout)

    # ------------------------------------------------------------------ the front's poll
    def poll(self, acked: dict[str, int], full: bool = False, only: str | None = None,
             incarnation: str | None = None) -> dict[str, Any]:
        """Per system: status, the snapshot when it changed since the last poll (with
        ``full``: also the drift report), and the events not yet acknowledged.  ``acked`` counts
        only for the ``incarnation`` it was made for: Ray retries a poll sent to a process
        that died on its successor, whose event numbers start again at 1."""
        if incarnation != self.incarnation:
            acked, full = {}, True
        now = time.monotonic()
        out: dict[str, Any] = {}
        with self._lock:
            items = [(n, w) for n, w in self.workers.items() if only in (None, n)]
        for name, w in items:
            snap, report = w.snapshot(), w.drift_report()
            sent = self._sent.get(name)
            entry: dict[str, Any] = {"status": {
                "generation": self.generation.get(name), "alive": w.alive, "died": w.died,
                "stopping": w.stopping, "error": w.error, "epoch": int(w.epoch),
                "heartbeat_age_s": now - w.heartbeat, "checkpoint_error": w.checkpoint_error,
                "last_index": int(w.buffer.last_index)}}
            if full or sent is None or sent[0] is not snap:
                entry["snapshot"] = snap
            if full or sent is None:
                entry["drift"] = report
            if only is None:
                self._sent[name] = (snap, report)
                q = self.queues.get(name)
                entry["events"] = q.pending(int(acked.get(name, 0))) if q else []
            out[name] = entry
        return {"incarnation": self.incarnation, "pid": self.pid, "host": self.host_id,
                "created": self.created,
                "node": _node_id(), "settings": self.settings_in, "systems": out}


def _node_id() -> str | None:
    try:
        import ray

        return ray.get_runtime_context().get_node_id()
    except Exception:  # noqa: BLE001 - informational only
        return None
