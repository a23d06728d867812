"""Attaching systems to their Ray trainer hosts off the request path.

Why a starter: starting a system on Ray (creating its host actor, ``add`` on it, a first
poll) can take minutes on a loaded cluster, and the ``PUT`` that registered the system
must answer as soon as its spec is stored.  The front hands each new trainer handle to
this starter and returns; a small pool of threads attaches the handles, retries the ones
that cannot be attached now, and never runs two attaches of the same system at once (a
system deleted and registered again waits until its old attach has cleaned up).
"""
from __future__ import annotations

import logging
import threading
import time
from typing import Protocol

log = logging.getLogger("siva.service.ray")

#: starter threads: starts of systems on different hosts run side by side
STARTER_THREADS = 4
#: an attach that failed is tried again this much later
RETRY_AFTER_S = 5.0


class Attachable(Protocol):
    """What the starter needs of a trainer handle (``RayTrainer``)."""

    name: str

    def attach(self) -> bool: ...   # True: done (attached, or no longer wanted)
    @property
    def stopping(self) -> bool: ...


class Starter:
    """A pool of threads attaching trainer handles, one attach per system at a time."""

    def __init__(self, threads: int = STARTER_THREADS,
                 retry_after_s: float = RETRY_AFTER_S) -> None:
        self.retry_after_s = retry_after_s
        self._cond = threading.Condition()
        self._due: dict[str, tuple[float, Attachable]] = {}  # name -> (when, handle)
        self._busy: set[str] = set()
        self._closed = False
        self._threads = [threading.Thread(target=self._run, name=f"siva-ray-starter-{k}",
                                          daemon=True) for k in range(threads)]
        for t in self._threads:
            t.start()

    def submit(self, handle: Attachable, delay: float = 0.0) -> None:
        """Attach ``handle`` in ``delay`` seconds (it replaces a queued handle of its name)."""
        with self._cond:
            if self._closed:
                return
            self._due[handle.name] = (time.monotonic() + delay, handle)
            self._cond.notify_all()

    def pending(self, name: str) -> bool:
        """Whether an attach of ``name`` is queued or running."""
        with self._cond:
            return name in self._due or name in self._busy

    def close(self, timeout: float) -> None:
        """Take no more work; wait at most ``timeout`` for the running attaches (they end
        on their own: a stopped handle's attach only cleans up)."""
        with self._cond:
            self._closed = True
            self._due.clear()
            self._cond.notify_all()
        deadline = time.monotonic() + timeout
        for t in self._threads:
            t.join(max(0.0, deadline - time.monotonic()))

    def _next(self) -> Attachable | None:
        with self._cond:
            while not self._closed:
                now = time.monotonic()
                free = [(when, name) for name, (when, _) in self._due.items()
                        if name not in self._busy]
                ready = [(when, name) for when, name in free if when <= now]
                if ready:
                    _, name = min(ready)
                    handle = self._due.pop(name)[1]
                    self._busy.add(name)
                    return handle
                self._cond.wait(timeout=min(w for w, _ in free) - now if free else None)
            return None

    def _run(self) -> None:
        while (handle := self._next()) is not None:
            done = False
            try:
                done = handle.attach()
            except Exception:  # noqa: BLE001 - a bug in one attach must not stop the pool
                log.exception("%s: attaching its trainer failed", handle.name)
            finally:
                with self._cond:
                    self._busy.discard(handle.name)
                    if not done and not handle.stopping and not self._closed \
                            and handle.name not in self._due:
                        self._due[handle.name] = (time.monotonic() + self.retry_after_s,
                                                  handle)
                    self._cond.notify_all()
