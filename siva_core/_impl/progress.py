"""Progress with an ETA for long command-line runs (identify, replay): one stderr line at a time.

Why a separate hook: the trainers stay as they are; a caller counts epochs and this turns them
into ``epoch 120/600 (20 %), 3.1 epochs/s, ETA 2 min 34 s``.  The ETA is to ``total``, which
for SIVA is the epoch cap: an upper bound, since training stops earlier once converged.
"""
from __future__ import annotations

import sys
import time
from typing import Callable, TextIO

#: a callback that shows one line of progress (None: silent)
Progress = Callable[[str], None]


def human_seconds(s: float) -> str:
    """``14 s``, ``2 min 34 s``, ``1 h 05 min``."""
    s = max(0.0, float(s))
    if s < 60:
        return f"{s:.0f} s"
    if s < 3600:
        return f"{int(s // 60)} min {int(s % 60):02d} s"
    return f"{int(s // 3600)} h {int(s % 3600 // 60):02d} min"


class Eta:
    """Rate and time left from the epochs done since construction."""

    def __init__(self, total: int, *, start: int = 0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.total = max(1, int(total))
        self.start = int(start)
        self.clock = clock
        self.t0 = clock()

    def text(self, done: int, unit: str = "epoch") -> str:
        done = int(done)
        pct = 100.0 * done / self.total
        elapsed = self.clock() - self.t0
        n = done - self.start
        if n <= 0 or elapsed <= 0:
            return f"{unit} {done}/{self.total} ({pct:.0f} %)"
        rate = n / elapsed
        left = max(0, self.total - done) / rate
        return (f"{unit} {done}/{self.total} ({pct:.0f} %), {rate:.3g} {unit}s/s, "
                f"ETA {human_seconds(left)}")


class EpochProgress:
    """Calls ``update(done)`` often; writes a line at most every ``every_s`` seconds."""

    def __init__(self, what: str, total: int, *, every_s: float = 2.0,
                 stream: TextIO | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.what = what
        self.eta = Eta(total, clock=clock)
        self.every_s = every_s
        self.stream = stream
        self.clock = clock
        self._last = -float("inf")

    def update(self, done: int, extra: str = "", *, force: bool = False) -> None:
        now = self.clock()
        if not force and now - self._last < self.every_s:
            return
        self._last = now
        stream = self.stream or sys.stderr
        print(f"{self.what}: {self.eta.text(done)}{'  ' + extra if extra else ''}",
              file=stream, flush=True)


class FractionProgress:
    """Progress of a run that reports the fraction done (diagnose): ``diagnose: 35 %,
    42 s elapsed, ETA 1 min 18 s``.  The ETA assumes the rest goes at the mean rate so far;
    for diagnose, whose later stages may be skipped, it is an upper bound."""

    def __init__(self, what: str, *, every_s: float = 2.0, stream: TextIO | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.what = what
        self.every_s = every_s
        self.stream = stream
        self.clock = clock
        self.t0 = clock()
        self._last = -float("inf")

    def text(self, fraction: float) -> str:
        f = min(max(float(fraction), 0.0), 1.0)
        elapsed = self.clock() - self.t0
        head = f"{self.what}: {100 * f:.0f} %, {human_seconds(elapsed)} elapsed"
        if f <= 0 or f >= 1:
            return head
        return f"{head}, ETA {human_seconds(elapsed * (1 - f) / f)}"

    def update(self, fraction: float, *, force: bool = False) -> None:
        now = self.clock()
        if not force and now - self._last < self.every_s:
            return
        self._last = now
        print(self.text(fraction), file=self.stream or sys.stderr, flush=True)
