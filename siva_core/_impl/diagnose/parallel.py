"""Independent diagnosis work on the cores (issue 16, speed): the scans, fits and
judgements of one step that do not read each other's results run in a pool of threads.

Threads, not processes: the simulator's numba kernel is compiled ``nogil`` and the chain's
filters and numpy's array work release the GIL; a process pool would have to pickle
structures and effects (they hold lambdas), and numba's OpenMP layer aborts a process that
forks after its first parallel region ran (measured: "fork() called from a process already
using GNU OpenMP").  Each task writes only its own candidate, and every schedule is fixed
before the tasks start (never "whichever fit finished first"), so a diagnosis gives the
same result with any number of workers (tested with 1 and 2)."""
from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Iterable, Sequence, TypeVar

from .settings import DiagnoseSettings

T = TypeVar("T")
R = TypeVar("R")

#: the environment variable that sets the worker count when the settings leave it at 0
ENV = "SIVA_DIAGNOSE_WORKERS"


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # not on Linux
        return os.cpu_count() or 1


def worker_count(settings: DiagnoseSettings) -> int:
    """``settings.workers`` when > 0, else ``$SIVA_DIAGNOSE_WORKERS``, else every core."""
    n = int(settings.workers or 0)
    if n <= 0:
        env = os.environ.get(ENV, "").strip()
        n = int(env) if env.isdigit() and int(env) > 0 else _cores()
    return max(1, n)


def run_each(fn: Callable[[T], R], items: Iterable[T], workers: int) -> list[R]:
    """``[fn(x) for x in items]``, on up to ``workers`` threads; results in item order.
    The first exception (in item order) is raised once the running tasks have ended; the
    tasks not started yet are dropped (a time limit's exception is not held up by them)."""
    todo = list(items)
    if workers <= 1 or len(todo) <= 1:
        return [fn(x) for x in todo]
    pool = ThreadPoolExecutor(max_workers=min(workers, len(todo)),
                              thread_name_prefix="siva-diagnose")
    try:
        futures = [pool.submit(fn, x) for x in todo]
        return [f.result() for f in futures]
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def waves(items: Sequence[T], size: int, first_alone: bool = True) -> list[list[T]]:
    """``items`` in waves of ``size`` (the first item alone when ``first_alone``): the fits
    of a wave run together and are stopped early against the leader of the waves before
    it.  Fixed by the settings, not by the worker count, so the result does not depend
    on it."""
    items, size = list(items), max(1, int(size))
    head = [items[:1]] if first_alone and items else []
    rest = items[1:] if head else items
    return head + [rest[k:k + size] for k in range(0, len(rest), size)]
