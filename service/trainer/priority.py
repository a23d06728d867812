"""The process's refiner work in order of urgency, and trainers that yield to monitoring.

Why: every system has a refiner thread, but refinements run one at a time in the process
(they are CPU-heavy and use numba's threads), and with many systems per process their
trainers (one thread each) take the cores and the interpreter lock.  Measured with 16
LO-NO systems on 2 cores, a record every 30 s each: re-anchors (a linearisation over up
to 12 records, ~6 CPU-s) and a refiner's 1/17 share of the CPU left the per-record
monitoring so far behind that no record was fitted within minutes.  A per-record fit is
small (~1 CPU-s) and is what a monitoring user waits for; so, process-wide:

* :meth:`RefineQueue.hold` grants the refinement slot to the most urgent waiter first
  (``MONITOR`` < ``BEST`` < ``ANCHOR`` < ``VALIDATION``; first come, first served within
  a level; up to ``SIVA_MONITOR_FITS`` per-record fits of different systems at once), and
  a waiter may give up its turn (``abandon``: its own system got a record
  to fit, which then goes first; the re-anchor, coalescing, runs after);
* :meth:`RefineQueue.yield_to_monitoring`: a trainer waits before its next epoch while a
  per-record fit (or a system's first ``best``, which starts its monitoring) waits or
  runs, at most ``max_wait`` seconds, so that every estimate keeps being published (the
  ensemble still updates; ``SIVA_MONITOR_YIELD_S``).

The trainer thread of a system never holds the slot, so no deadlock is possible.
"""
from __future__ import annotations

import heapq
import itertools
import threading
import time
from contextlib import contextmanager
from typing import Callable, Iterator

MONITOR, BEST, ANCHOR, VALIDATION = 0, 1, 2, 3
#: the levels trainers yield to: a per-record fit, a first best (it starts the monitoring)
URGENT = BEST
#: how often a waiter re-checks ``abandon`` and a yielding trainer its stop event
POLL_S = 0.25


class RefineQueue:
    """The refinement slot of the process, the most urgent first.  Work is exclusive,
    except per-record fits: up to ``monitor_fits`` of them (of different systems) run at
    once - a fit is mostly single-threaded, so one at a time would
    leave a core idle, or under load get one thread's share of the machine."""

    def __init__(self, monitor_fits: int = 1) -> None:
        self._cv = threading.Condition()
        self._running: set[tuple[int, int]] = set()
        self._waiting: list[tuple[int, int]] = []     # heap of (priority, ticket)
        self._tickets = itertools.count()
        self._monitoring = 0                           # urgent work waiting or running
        self.monitor_fits = max(1, int(monitor_fits))

    def _may_run(self, key: tuple[int, int]) -> bool:
        """(under the condition) ``key`` is the most urgent waiter and the slot allows it."""
        if self._waiting[0] != key:
            return False
        if not self._running:
            return True
        if key[0] != MONITOR or any(k[0] != MONITOR for k in self._running):
            return False
        # the simulation kernels are serial and compiled ``nogil`` (branch speed6): fits
        # in several threads run side by side
        return len(self._running) < self.monitor_fits

    @contextmanager
    def hold(self, priority: int = VALIDATION,
             abandon: Callable[[], bool] | None = None) -> Iterator[bool]:
        """Wait for the slot (yields True) - or give up when ``abandon()`` turns true
        while waiting (yields False: the caller must not do the work)."""
        got = self._acquire(priority, abandon)
        try:
            yield got is not None
        finally:
            if got is not None:
                self._release(got)

    def _acquire(self, priority: int, abandon: Callable[[], bool] | None) -> tuple[int, int] | None:
        key = (priority, next(self._tickets))
        with self._cv:
            heapq.heappush(self._waiting, key)
            if priority <= URGENT:
                self._monitoring += 1
            try:
                while not self._may_run(key):
                    if abandon is not None and abandon():
                        self._drop(key)
                        return None
                    self._cv.wait(POLL_S if abandon is not None else None)
            except BaseException:
                self._drop(key)
                raise
            heapq.heappop(self._waiting)
            self._running.add(key)
            self._cv.notify_all()  # the next fit may join
            return key

    def _drop(self, key: tuple[int, int]) -> None:
        """(under the condition) forget a waiter that will not run."""
        self._waiting.remove(key)
        heapq.heapify(self._waiting)
        if key[0] <= URGENT:
            self._monitoring -= 1
        self._cv.notify_all()

    def _release(self, key: tuple[int, int]) -> None:
        with self._cv:
            self._running.discard(key)
            if key[0] <= URGENT:
                self._monitoring -= 1
            self._cv.notify_all()

    # the plain lock protocol (``with REFINE_LOCK:``): the least urgent level
    def __enter__(self) -> None:
        self._entered = self._acquire(VALIDATION, None)

    def __exit__(self, *exc: object) -> None:
        self._release(self._entered)  # type: ignore[arg-type]

    @property
    def monitoring_due(self) -> int:
        """Per-record fits and first bests waiting for or holding the slot."""
        return self._monitoring

    def yield_to_monitoring(self, max_wait: float, stop: threading.Event | None = None) -> float:
        """A trainer, between two epochs: wait while a per-record fit or a first best waits
        or runs, at most ``max_wait`` s; returns the seconds waited."""
        if max_wait <= 0 or self._monitoring <= 0:
            return 0.0
        t0 = time.monotonic()
        with self._cv:
            while self._monitoring > 0 and not (stop is not None and stop.is_set()):
                left = max_wait - (time.monotonic() - t0)
                if left <= 0:
                    break
                self._cv.wait(min(left, POLL_S))
        return time.monotonic() - t0
