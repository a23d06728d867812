"""``SIVA_EXECUTOR=ray``: the trainers run in Ray actors; this process stays the front.

Layout (docs/fleet.md): systems are packed into *trainer hosts*, detached named actors
(``ray_host.py``), ``SIVA_RAY_SYSTEMS_PER_ACTOR`` systems each (``ray_placement.py``),
each asking ``SIVA_RAY_CPUS_PER_ACTOR`` logical CPUs, spread over the cluster's nodes
(``SPREAD``).  An actor whose process or node dies is restarted by Ray
(``max_restarts=-1``) and resumes its systems from their checkpoints in the shared data
dir; a front that dies (kill -9) finds its actors again by name when it restarts.

The front never blocks on an actor in a request: a ``PUT`` returns once the spec is stored
and a pool of starter threads (``ray_starter.py``) attaches the system to its host (creating
the actor if needed), retrying while the cluster cannot take it; until then the system's
state is ``starting``.  One poller thread fetches, every
``SIVA_RAY_POLL_S``, each host's changed snapshots and its queued event-log entries, which
it writes to the MCAP log in order (acknowledging them on the next poll).
A new actor incarnation (a restart) starts a new log segment for its systems, as a
restarted trainer thread does, so ``siva replay`` stitches the segments.
"""
from __future__ import annotations

import hashlib
import logging
import threading
import time
from typing import Any

from siva_core import Structure

from ..settings import Settings
from .ray_host import TrainerHost, settings_dict
from .ray_placement import Placement
from .ray_starter import Starter
from .ray_trainer import DRIFT_FRESH_S, RayTrainer

log = logging.getLogger("siva.service.ray")

#: the service's start waits at most this long for its systems' trainers (``await_starts``)
BOOT_WAIT_S = 120.0


class RayExecutor:
    """Trainer hosts on a Ray cluster (``SIVA_RAY_ADDRESS``; none: a local Ray)."""

    kind = "ray"

    def __init__(self, settings: Settings, store: Any, events: Any) -> None:
        try:
            import ray
        except ImportError:
            raise RuntimeError("SIVA_EXECUTOR=ray needs Ray: pip install '.[ray]'") from None
        self.ray = ray
        self.settings = settings
        self.store = store
        self.events = events
        if not ray.is_initialized():
            _init_keeping_signal_handlers(ray, settings)
        self._settings = settings_dict(settings)
        self._started = time.time()
        # actor names are unique per data dir: two services may share one cluster
        self._key = hashlib.sha1(str(settings.data_dir.resolve()).encode()).hexdigest()[:10]
        self._remote = ray.remote(TrainerHost)
        self._lock = threading.Lock()  # short holds only: never across a Ray call
        self._creating: dict[str, threading.Lock] = {}  # host id -> its creation lock
        self._closed = False
        self.placement = Placement(settings.data_dir, settings.ray_systems_per_actor)
        self._hosts: dict[str, Any] = {}
        self._handles: dict[str, RayTrainer] = {}
        self._acked: dict[str, dict[str, int]] = {}
        self._incarnation: dict[str, str] = {}
        self._info: dict[str, dict[str, Any]] = {}
        self._down_since: dict[str, float] = {}
        self._full: set[str] = set()
        self._restarts: dict[str, int] = {}
        self.starter = Starter()
        self._stop = threading.Event()
        self._poller = threading.Thread(target=self._poll_loop, name="siva-ray-poller",
                                        daemon=True)
        self._poller.start()

    # ------------------------------------------------------------------ hosts
    def actor_name(self, host_id: str) -> str:
        return f"siva-{self._key}-{host_id}"

    def host(self, host_id: str) -> Any:
        """The host actor (created if needed; an existing one is reused unless it runs with
        other settings, then it is replaced).  Creating one can take minutes: only the
        starter threads call this for a host that is not known yet."""
        actor = self._hosts.get(host_id)
        if actor is not None:
            return actor
        with self._lock:
            creating = self._creating.setdefault(host_id, threading.Lock())
        with creating:  # one creation per host; other hosts and the poller go on
            actor = self._hosts.get(host_id)
            if actor is not None:
                return actor
            if self._closed:
                raise RuntimeError("the Ray executor is stopping")
            actor = self._create(host_id)
            try:
                info = self.ray.get(actor.poll.remote({}, False, ""), timeout=120)
            except Exception:  # noqa: BLE001 - let the poller find out
                info = None
            if info is not None and info.get("settings") != self._settings:
                log.warning("trainer host %s runs with other settings: replacing it", host_id)
                self.ray.kill(actor, no_restart=True)
                time.sleep(0.5)
                actor = self._create(host_id)
            elif info is not None and info.get("created", 0.0) < self._started:
                log.info("trainer host %s found running (pid %s): its systems train on, "
                         "resumed from memory rather than from checkpoint", host_id,
                         info.get("pid"))
            with self._lock:
                closed = self._closed
                if not closed:
                    self._hosts[host_id] = actor
                    self._full.add(host_id)
            if closed:  # stop_all ran meanwhile and did not see this actor: no leak
                self._kill(actor)
                raise RuntimeError("the Ray executor is stopping")
            return actor

    def known_host(self, host_id: str) -> Any | None:
        """The host actor if it exists already (never creates one, never blocks)."""
        return self._hosts.get(host_id)

    def _kill(self, actor: Any) -> None:
        if self.settings.ray_keep_actors:
            return
        try:
            self.ray.kill(actor, no_restart=True)
        except Exception:  # noqa: BLE001
            pass

    def _create(self, host_id: str) -> Any:
        return self._remote.options(
            name=self.actor_name(host_id), namespace=self.settings.ray_namespace,
            lifetime="detached", get_if_exists=True, max_restarts=-1, max_task_retries=-1,
            max_concurrency=16, num_cpus=self.settings.ray_cpus_per_actor,
            scheduling_strategy="SPREAD",
        ).remote(host_id, self._settings, self.settings.ray_cpus_per_actor)

    def reachable(self, host_id: str) -> bool:
        return host_id not in self._down_since

    def unreachable_for(self, host_id: str) -> float | None:
        since = self._down_since.get(host_id)
        return None if since is None else time.monotonic() - since

    # ------------------------------------------------------------------ executor
    def trainer(self, name: str, structure: Structure) -> RayTrainer:
        with self._lock:
            host_id = self.placement.assign(name)
        handle = RayTrainer(self, name, structure, host_id)
        self._handles[name] = handle
        return handle

    def start_later(self, handle: RayTrainer, delay: float = 0.0) -> None:
        """Attach ``handle`` to its host from a starter thread (``RayTrainer.start``)."""
        self.starter.submit(handle, delay)

    def await_starts(self, handles: list[Any], timeout: float = BOOT_WAIT_S) -> None:
        """At the service's start: wait (at most ``timeout`` in all) until each system's
        first attach has ended, so that the first read after a restart of the front shows
        the resumed epoch; the attaches run side by side, and one that fails goes on being
        retried in the background (/healthz says so).  A PUT never waits for this."""
        deadline = time.monotonic() + timeout
        for h in handles:
            if not h.tried.wait(max(0.0, deadline - time.monotonic())):
                log.warning("the trainers of %d system(s) are still starting after %.0f s; "
                            "the service answers meanwhile", sum(
                                not g.tried.is_set() for g in handles), timeout)
                return

    def removed(self, name: str) -> None:
        with self._lock:
            self.placement.remove(name)
        self._handles.pop(name, None)
        for acked in self._acked.values():
            acked.pop(name, None)

    def stop_all(self, handles: list[Any], timeout: float) -> list[str]:
        """Stop every host's workers (final checkpoints), write their last events, and
        (unless SIVA_RAY_KEEP_ACTORS) remove the actors: a clean stop of the service stops
        its trainers; only a crash of the front leaves them running, to be found again."""
        for h in handles:
            h.request_stop()
        with self._lock:
            self._closed = True  # no actor is created from now on (``host``)
        self.starter.close(timeout=min(10.0, timeout))
        self._stop.set()
        self._poller.join(timeout=10)
        with self._lock:
            hosts = dict(self._hosts)
        refs = {hid: a.stop_all.remote(timeout) for hid, a in hosts.items()}
        late: list[str] = []
        for hid, ref in refs.items():
            try:
                late += self.ray.get(ref, timeout=timeout + 10)
            except Exception as exc:  # noqa: BLE001
                log.warning("stopping trainer host %s: %s", hid, exc)
        self.poll_once()  # the final snapshots' events into the log
        for a in hosts.values():
            self._kill(a)
        return late

    def describe(self) -> dict[str, Any]:
        """For /healthz: hosts, their process, node, systems and restarts."""
        hosts = []
        for hid in sorted(self._hosts):
            info = self._info.get(hid, {})
            hosts.append({"host": hid, "actor": self.actor_name(hid), "pid": info.get("pid"),
                          "node": info.get("node"), "incarnation": info.get("incarnation"),
                          "restarts": self._restarts.get(hid, 0),
                          "reachable": self.reachable(hid),
                          "systems": sorted(self.placement.hosts.get(hid, []))})
        return {"kind": self.kind, "address": self.settings.ray_address,
                "namespace": self.settings.ray_namespace, "hosts": hosts}

    # ------------------------------------------------------------------ the poller
    def _poll_loop(self) -> None:
        while not self._stop.wait(self.settings.ray_poll_s):
            try:
                self.poll_once()
                self._refresh_drift()
            except Exception:  # noqa: BLE001 - keep polling
                log.exception("polling the trainer hosts failed")

    def _refresh_drift(self) -> None:
        """Collect drift reports on their way; ask again for those read lately."""
        now = time.monotonic()
        for h in list(self._handles.values()):
            h.collect_drift()
            if h.drift_wanted_until > now and now - h.drift_at > DRIFT_FRESH_S:
                h.request_drift()

    def poll_once(self) -> None:
        with self._lock:
            hosts = dict(self._hosts)
        refs = {}
        for hid, actor in hosts.items():
            full = hid in self._full
            refs[hid] = (actor.poll.remote(dict(self._acked.get(hid, {})), full, None,
                                           self._incarnation.get(hid)), full)
        for hid, (ref, full) in refs.items():
            try:
                res = self.ray.get(ref, timeout=max(10.0, 10 * self.settings.ray_poll_s))
            except Exception as exc:  # noqa: BLE001 - dead, restarting, or slow
                if hid not in self._down_since:
                    log.warning("trainer host %s did not answer (%s)", hid,
                                type(exc).__name__)
                    self._down_since[hid] = time.monotonic()
                self._full.add(hid)
                continue
            self._down_since.pop(hid, None)
            if full:
                self._full.discard(hid)
            self._apply(hid, res)

    def _apply(self, hid: str, res: dict[str, Any]) -> None:
        known = self._incarnation.get(hid)
        restarted = known is not None and known != res["incarnation"]
        if restarted:
            self._restarts[hid] = self._restarts.get(hid, 0) + 1
            log.error("trainer host %s restarted (pid %s): its systems resume from their "
                      "checkpoints", hid, res.get("pid"))
        if known != res["incarnation"]:
            self._acked[hid] = {}
        self._incarnation[hid] = res["incarnation"]
        self._info[hid] = {k: res.get(k) for k in ("pid", "node", "incarnation")}
        acked = self._acked.setdefault(hid, {})
        for name, entry in res["systems"].items():
            handle = self._handles.get(name)
            if restarted:
                self._event("rotate", name)  # a new segment, as after a process restart
                if handle is not None and handle.generation is not None:
                    handle.generation = None  # adopt the new incarnation's numbering
            if handle is not None:
                handle.update(entry)
            for seq, method, args, kw in entry.get("events", []):
                if seq > acked.get(name, 0):
                    self._event(method, *args, **kw)
                    acked[name] = seq

    def _event(self, method: str, *args: Any, **kw: Any) -> None:
        try:
            getattr(self.events, method)(*args, **kw)
        except Exception:  # noqa: BLE001 - the log is an audit trail, not a dependency
            log.exception("event log %s failed", method)


def _init_keeping_signal_handlers(ray: Any, settings: Settings) -> None:
    """``ray.init`` replaces SIGTERM's handler with one that exits at once; keep the
    server's (uvicorn's graceful shutdown, which checkpoints the trainers)."""
    import signal

    saved = {}
    if threading.current_thread() is threading.main_thread():
        saved = {sig: signal.getsignal(sig) for sig in (signal.SIGTERM, signal.SIGINT)}
    ray.init(address=settings.ray_address, namespace=settings.ray_namespace,
             logging_level=logging.WARNING, log_to_driver=False, configure_logging=False)
    for sig, handler in saved.items():
        if handler is not None:
            signal.signal(sig, handler)
