"""The front's handle of one system trained in a Ray trainer host: what the routes call
(``TrainerHandle``, ``executor.py``), answered from the poller's copies so that no request
ever blocks on an actor (``ray_executor.py`` polls; ``ray_starter.py`` attaches the
system to its host in the background, meanwhile its state is ``starting``)."""
from __future__ import annotations

import logging
import threading
import time
from typing import Any, Protocol

from siva_core import Structure

from ..errors import Unavailable
from ..trainer import DriftReport, Snapshot, base_snapshot


class HostAccess(Protocol):
    """What a handle needs of its executor (``RayExecutor``): the Ray module, the trainer
    hosts (created on demand, or only if known), their reachability, the store and the
    starter.  A protocol, so this module does not import the executor that imports it."""

    ray: Any
    store: Any

    def host(self, host_id: str) -> Any: ...
    def known_host(self, host_id: str) -> Any | None: ...
    def reachable(self, host_id: str) -> bool: ...
    def unreachable_for(self, host_id: str) -> float | None: ...
    def start_later(self, handle: "RayTrainer", delay: float = 0.0) -> None: ...


log = logging.getLogger("siva.service.ray")

#: a host unreachable this long is reported in /healthz (Ray is restarting it)
UNREACHABLE_AFTER_S = 5.0
#: drift reports: a copy younger than this is served as is; a read waits at most
#: DRIFT_WAIT_S for a newer one; one read keeps the copy refreshed for DRIFT_WANTED_S
DRIFT_FRESH_S = 2.0
DRIFT_WAIT_S = 0.4
DRIFT_FIRST_WAIT_S = 10.0
DRIFT_WANTED_S = 60.0
#: an attach waits this long for the host's ``add`` (then reports a start error in
#: /healthz and waits again on the same call: an ``add`` is never sent twice)
ADD_WAIT_S = 120.0
#: a worker that has not seen the store's newest recording this long is notified again
RENOTIFY_AFTER_S = 5.0


class RayTrainer:
    """The front's handle of one system trained in a trainer host (no call blocks a read)."""

    def __init__(self, executor: HostAccess, name: str, structure: Structure,
                 host_id: str) -> None:
        self.executor = executor
        self.name = name
        self.structure = structure
        self.host_id = host_id
        self.generation: int | None = None
        self._snapshot: Snapshot = base_snapshot(name, "starting")
        self._drift = DriftReport()
        self._status: dict[str, Any] = {}
        self._stopping = False
        self._lock = threading.Lock()            # generation vs. stopping (attach, stop)
        self._add_ref: Any = None                # an ``add`` sent whose answer is not in yet
        self.tried = threading.Event()           # set once a first attach has ended
        self.epoch = 0
        self.heartbeat = time.monotonic()
        self.checkpoint_error: str | None = None
        self.start_error: str | None = None
        self.drift_at = -1e9                     # time.monotonic() of the drift copy
        self.drift_ref: Any = None               # a drift report on its way
        self.drift_wanted_until = -1e9           # keep it fresh until then (it is read)
        self._behind_since: float | None = None  # the worker lags the store since then

    # ------------------------------------------------------------------ control
    def start(self) -> None:
        """Queue the attach (``attach``, on a starter thread) and return at once: the PUT
        that registered the system answers once its spec is stored, however slow the
        cluster; until attached, reads serve the ``starting`` snapshot and uploads go to
        the store, which the worker reads when it starts."""
        self.executor.start_later(self)

    def attach(self) -> bool:
        """Starter thread: start (or find) the system on its host and fetch a first
        snapshot, so the first read after a restart already shows the resumed epoch.
        True when done (attached, or stopped meanwhile: then what it started is removed);
        False to be tried again (the cluster cannot take it now: /healthz says so)."""
        try:
            return self._attach()
        finally:
            self.tried.set()

    def _attach(self) -> bool:
        ray = self.executor.ray
        try:
            if self._stopping:
                self._reap()
                return True
            host = self.executor.host(self.host_id)
            if self._stopping:  # deleted while its host was being created
                self._reap()
                return True
            if self._add_ref is None:
                self._add_ref = host.add.remote(self.name)
            ready, _ = ray.wait([self._add_ref], timeout=ADD_WAIT_S)
            if not ready:
                raise TimeoutError(f"the trainer host did not add it within {ADD_WAIT_S:.0f} s")
            ref, self._add_ref = self._add_ref, None
            generation = ray.get(ref)
            with self._lock:
                cancelled = self._stopping
                if not cancelled:
                    self.generation = generation
            if cancelled:  # deleted (or the service stops) while it was being added
                self._remove(host, generation, 0.0)
                return True
            first = ray.get(host.poll.remote({}, True, self.name), timeout=60)
        except Exception as exc:  # noqa: BLE001 - cluster down or full: retried
            if self._stopping:
                self._reap()
                return True
            self.start_error = f"{type(exc).__name__}: {exc}"
            log.error("%s: cannot start its trainer on Ray host %s (%s); retrying",
                      self.name, self.host_id, self.start_error)
            return False
        self.start_error = None
        entry = first["systems"].get(self.name)
        if entry is not None:
            self.update(entry)
        self.notify()  # a found-running worker may have missed a notify (front killed)
        return True

    def _reap(self) -> None:
        """A handle stopped before it learnt its generation: remove the worker that its
        ``add`` (answer pending) or the host's construction (the system was still in the
        placement file) started, if any; its generation comes from a poll of it alone."""
        ray = self.executor.ray
        ref, self._add_ref = self._add_ref, None
        host = self.executor.known_host(self.host_id)
        if host is None:
            return
        try:
            if ref is not None:
                ray.wait([ref], timeout=ADD_WAIT_S)
            found = ray.get(host.poll.remote({}, False, self.name), timeout=60)
        except Exception as exc:  # noqa: BLE001 - the host is gone or slow: nothing to do
            log.warning("%s: cannot check host %s for a worker to remove (%s)", self.name,
                        self.host_id, type(exc).__name__)
            return
        entry = found["systems"].get(self.name)
        generation = ((entry or {}).get("status") or {}).get("generation")
        if generation is not None:
            self._remove(host, generation, 0.0)

    def _remove(self, host: Any, generation: int, timeout: float) -> None:
        try:
            ref = host.remove.remote(self.name, generation, timeout)
            self.executor.ray.get(ref, timeout=timeout + 10)
        except Exception as exc:  # noqa: BLE001 - the actor is gone or slow: nothing to stop
            log.warning("%s: stopping the trainer on host %s: %s", self.name, self.host_id, exc)

    def notify(self) -> None:
        host = self.executor.known_host(self.host_id)
        if host is None or self.generation is None:
            return  # not attached yet: the worker reads every stored record when it starts
        try:
            host.notify.remote(self.name)
        except Exception:  # noqa: BLE001 - a restarting actor re-reads every record anyway
            log.warning("%s: notify failed (trainer host restarting?)", self.name)

    def request_stop(self) -> None:
        self._stopping = True

    def stop(self, timeout: float = 60.0) -> None:
        """Stop this system's worker (final checkpoint), waiting at most ``timeout``.  Not
        attached yet: nothing to wait for; an attach in flight removes what it started."""
        with self._lock:
            self._stopping = True
            generation = self.generation
        host = self.executor.known_host(self.host_id)
        if generation is None or host is None:
            return
        self._remove(host, generation, timeout)

    def reset_drift(self) -> DriftReport:
        ray = self.executor.ray
        host = self.executor.known_host(self.host_id)
        if host is None or self.generation is None:
            raise Unavailable(f"system {self.name!r}: its trainer is starting on Ray; "
                              "retry in a few seconds", retry_after_s=5)
        try:
            report = ray.get(host.reset_drift.remote(self.name), timeout=120)
        except Exception as exc:  # noqa: BLE001 - restarting or unreachable: say so
            raise Unavailable(f"system {self.name!r}: its trainer actor is unavailable "
                              f"({type(exc).__name__}); retry in a minute",
                              retry_after_s=60) from None
        self._drift, self.drift_at = report, time.monotonic()
        return report

    # ------------------------------------------------------------------ reads
    def snapshot(self) -> Snapshot:
        return self._snapshot

    def drift_report(self) -> DriftReport:
        """The drift report, fetched on demand: a report holds up to SIVA_HISTORY_LIMIT
        snapshots (about 1 MB), too much for every poll.  A read waits at most
        ``DRIFT_WAIT_S`` for a copy older than ``DRIFT_FRESH_S`` (the first read of a
        system ``DRIFT_FIRST_WAIT_S``), else gets the last copy; the poller keeps a report
        that was read in the last minute fresh."""
        now = time.monotonic()
        self.drift_wanted_until = now + DRIFT_WANTED_S
        if now - self.drift_at > DRIFT_FRESH_S:
            self.request_drift()
            # the first read has only the copy of the start (no history yet): worth a wait
            first = self.drift_at < 0
            self.collect_drift(timeout=DRIFT_FIRST_WAIT_S if first else DRIFT_WAIT_S)
        return self._drift

    def request_drift(self) -> None:
        host = self.executor.known_host(self.host_id)
        if self.drift_ref is None and host is not None and self.generation is not None:
            try:
                self.drift_ref = host.drift_report.remote(self.name)
            except Exception:  # noqa: BLE001 - the host is restarting: the last copy
                self.drift_ref = None

    def collect_drift(self, timeout: float = 0.0) -> None:
        """Take the requested report if it is there within ``timeout`` seconds."""
        ref = self.drift_ref
        if ref is None:
            return
        ray = self.executor.ray
        try:
            ready, _ = ray.wait([ref], timeout=timeout)
            if not ready:
                return  # still coming: the poller collects it
            self._drift = ray.get(ref)
            self.drift_at = time.monotonic()
        except Exception as exc:  # noqa: BLE001 - restarting: the last copy will do
            log.warning("%s: drift report not fetched (%s); the last copy is served",
                        self.name, type(exc).__name__)
        self.drift_ref = None

    @property
    def alive(self) -> bool:
        return bool(self._status.get("alive")) and self.executor.reachable(self.host_id)

    @property
    def died(self) -> bool:
        return bool(self._status.get("died")) and not self._stopping

    @property
    def stopping(self) -> bool:
        return self._stopping

    @property
    def error(self) -> str | None:
        return self._status.get("error")

    def problem(self) -> str | None:
        if self.start_error:
            return (f"system {self.name!r}: its trainer could not be started on Ray "
                    f"({self.start_error}); retrying")
        down = self.executor.unreachable_for(self.host_id)
        if down is not None and down > UNREACHABLE_AFTER_S:
            return (f"system {self.name!r}: its trainer actor (host {self.host_id}) has not "
                    f"answered for {down:.0f} s; Ray restarts it from the checkpoint")
        return None

    def update(self, entry: dict[str, Any]) -> None:
        """Poller thread: take what a poll brought (reference swaps only)."""
        status = entry.get("status") or {}
        if self.generation is None:  # a restarted host numbers its systems anew
            self.generation = status.get("generation")
        elif status.get("generation") not in (None, self.generation):
            return  # another generation of this system (the supervisor replaced it)
        if "snapshot" in entry:
            self._snapshot = entry["snapshot"]
        if "drift" in entry:
            self._drift = entry["drift"]
        self._status = status
        self.epoch = int(status.get("epoch", self.epoch))
        self.heartbeat = time.monotonic() - float(status.get("heartbeat_age_s", 0.0))
        self.checkpoint_error = status.get("checkpoint_error")
        self._check_caught_up(status.get("last_index"))

    def _check_caught_up(self, seen: int | None) -> None:
        """Notify again when the worker has not seen the store's newest recording for
        ``RENOTIFY_AFTER_S``: a notify is fire-and-forget, and one sent just before the
        front was killed may never have left it."""
        if seen is None or self._stopping:
            return
        try:
            newest = self.executor.store.last_index(self.name)
        except Exception:  # noqa: BLE001 - deleted meanwhile
            return
        if newest <= seen:
            self._behind_since = None
            return
        now = time.monotonic()
        if self._behind_since is None:
            self._behind_since = now
        elif now - self._behind_since >= RENOTIFY_AFTER_S:
            log.debug("%s: the trainer has not seen recording %d yet; notifying again",
                      self.name, newest)
            self._behind_since = now
            self.notify()
