"""The time budget of a diagnosis: an anytime search.

Why: the search over stages, pairs, sets of three, look-alike swaps and tie-breaks can
run for minutes on 3-4 DOF structures with two effects (12 of 60 fresh scenarios ran past
the benchmark's 300 s CPU limit), and a user wants an answer.  Work is opened in units
(a stage, one pair fit, one grown set, one swap refit, a polish, a bootstrap); a unit is
opened only while the time spent plus what such a unit has cost so far fits the budget.
Nothing is ever interrupted mid-way, so every candidate and set that exists was fitted and
judged in full: the verdict is chosen among them by the same checks as without a budget
(a budget stop can leave an effect unnamed, never name one that was not checked).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable, TypeVar

T = TypeVar("T")


@dataclass
class Budget:
    """Seconds allowed from ``start`` (``None``: no budget) and what was left unopened.

    cpu: measure this process's CPU seconds (every thread) instead of wall seconds: a
        benchmark whose limit is CPU time on a shared machine, where wall time depends
        on the other processes' load.
    """

    seconds: float | None
    cpu: bool = False
    start: float = field(default=0.0)
    reached_at: float | None = None
    reached_in: str | None = None
    skipped: dict[str, list[str]] = field(default_factory=dict)
    costs: dict[str, list[float]] = field(default_factory=dict)
    say: Callable[[str], None] | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        self.start = self.now()

    def now(self) -> float:
        return time.process_time() if self.cpu else time.perf_counter()

    def elapsed(self) -> float:
        return self.now() - self.start

    def expected(self, kind: str, cost: float = 0.0) -> float:
        """What a unit of ``kind`` is expected to cost: the longest of its kind so far
        (units of one kind differ in size; the longest keeps the stop on the safe side)
        or the caller's estimate, whichever is larger."""
        seen = self.costs.get(kind) or [0.0]
        return max(cost, max(seen))

    def allows(self, kind: str, what: str, cost: float = 0.0) -> bool:
        """May a unit of ``kind`` (described by ``what``) be opened now?  When not, it
        is recorded as not searched, with the point where the budget was first reached."""
        if self.seconds is None:
            return True
        t = self.elapsed()
        # once reached, nothing more is opened: what is judged afterwards is a fixed set
        # of fits (a later small unit must not complete a search the budget cut)
        if not self.reached and t + self.expected(kind, cost) <= self.seconds:
            return True
        if self.reached_at is None:
            self.reached_at, self.reached_in = t, f"{kind}: {what}"
            if self.say is not None:  # the progress output says it when it happens
                self.say(f"time budget {self.seconds:g} s reached at {t:.0f} s: {kind} "
                         f"{what} (expected {self.expected(kind, cost):.0f} s) and all "
                         "further work not opened; the verdict comes from what was "
                         "fitted and checked so far")  # e.g. 'stage 3 of 3', 'pair a + b'
        self.skipped.setdefault(kind, []).append(what)
        return False

    def took(self, kind: str, seconds: float) -> None:
        self.costs.setdefault(kind, []).append(float(seconds))

    def run(self, kind: str, what: str, fn: Callable[[], T], cost: float = 0.0
            ) -> T | None:
        """``fn()`` when the budget allows a unit of ``kind``, its time recorded; else
        None (the callers already treat None as a fit that gave nothing)."""
        if not self.allows(kind, what, cost):
            return None
        t0 = self.now()
        try:
            return fn()
        finally:
            self.took(kind, self.now() - t0)

    def n_skipped(self) -> int:
        """Units not opened so far: a step compares it before and after to know it was
        cut (its checks incomplete)."""
        return sum(len(v) for v in self.skipped.values())

    @property
    def reached(self) -> bool:
        return self.reached_at is not None

    def as_rule(self) -> dict[str, Any]:
        """The report's ``rule["budget"]``: the budget, whether and where it was reached,
        what was not searched (per kind of work)."""
        out: dict[str, Any] = {"seconds": self.seconds,
                               "clock": "cpu" if self.cpu else "wall",
                               "reached": self.reached,
                               "elapsed_time_s": float(self.elapsed())}
        if self.reached:
            out["reached_at_time_s"] = float(self.reached_at or 0.0)
            out["reached_in"] = self.reached_in
            out["not_searched"] = {k: list(v) for k, v in self.skipped.items()}
        return out

    def text(self) -> str:
        """One sentence for the reason and the progress output."""
        if not self.reached:
            return ""
        parts = ", ".join(f"{len(v)} {k}" + ("" if len(v) == 1 else " units")
                          for k, v in self.skipped.items())
        return (f"time budget {self.seconds:g} s ({'CPU' if self.cpu else 'wall'}) reached "
                f"at {self.reached_at:.0f} s before {self.reached_in}; not searched: "
                f"{parts}; the verdict is what was fitted and checked until then")


def clock_of(settings: Any) -> Budget:
    """The diagnosis's budget (``settings.clock``, set by ``diagnose``), or an unlimited
    one for a helper called on its own."""
    c = getattr(settings, "clock", None)
    return c if isinstance(c, Budget) else Budget(None)
