"""Fleet benchmark: N LO-NO systems streaming simulated impacts into one ``siva serve``.

Starts the real server (``python -m siva_cli serve`` on a free 127.0.0.1 port, temporary
data dir), with the trainers as threads in it (``SIVA_EXECUTOR=threads``) or as Ray
actors on a local two-node cluster (``SIVA_EXECUTOR=ray``, ``scripts/ray-local-cluster.sh``
on a port of its own), registers N systems with the paper's LO-NO model
(``examples/models/lono.toml``: 2 DOF, 6 free parameters, 4 s records at 2048 Hz - the
realistic case; a 1-DOF linear model would train faster and understate the cost), gives
each a training and a validation record, waits until every trainer has published an
epoch (and, by default, every system is onboarded: its first ``best`` exists, so its
monitoring runs: ``--onboard best``; the time this took is reported), then for
``--window`` seconds streams one record per system every ``--period``
seconds, staggered (system i starts at i * period / N; every 4th record is validation),
from 16 concurrent uploaders (each structure uploads on its own).  Records come from ``service.demo.simulate_impact`` (hammer 30-900 N, sensor noise, hum).

Measured per executor and N, over the window:

* aggregate epochs per second: sum over systems of the epoch increase / window;
* record to estimate: from the 202 of an upload to the first GET .../estimate whose
  ``data.train`` / ``data.validation`` lists the record (the record is in the training
  data of a published snapshot; polled every 0.5 s when the server answers at once) - p50,
  p95, and the same to that snapshot's own ``time`` (free of the polling);
* record to monitored: from the 202 to the first GET .../estimate whose
  ``monitoring.processed_index`` (the drift report's, the same number) is >= the record's
  index: its per-record fit went into the headline and the drift test (polled every 2 s)
  - p50, p95; and at the end the records the drift report lists as fitted (``records``,
  ``ok``) out of those acknowledged;
* the longest gap between successive published snapshots of any system (their own
  ``time``, from the drift report's history at the end of the window: exact), not
  counting time a system was seen idle or waiting for data (GET /v1/systems every 2 s);
  must be <= 60 s with 64 systems;
* memory: RSS (and PSS) of the server plus, with Ray, the trainer-host and Ray daemon
  processes; the base before any system, then (total - base) / N per system;
* CPU: CPU seconds of those processes / window (cores in use), per epoch and per record.

    python benchmarks/bench_fleet.py [--executor threads|ray|both] [--systems 1,4,16,64]
           [--period 30] [--window S] [--snapshot-every 5] [--quick] [--json FILE]
    python benchmarks/bench_fleet.py --systems none --sparse-prefill 16   # sparse records only

Before the fleet cases, a sparse-record run per executor (``run_sparse``) measures the
CPU of onboarding one system, of an idle system and of one record arriving at an idle one
(``--sparse-prefill 16``: with a full replay buffer, the steady state).

Traffic goes to 127.0.0.1 only; every loop has a deadline.  Needs psutil (the test extra)
and, for ``ray``, the ray extra (``pip install .[ray]``).
"""
from __future__ import annotations

import argparse
import importlib.util
import os
import statistics
import sys
import tempfile
import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _fleet_report import (machine, marginal_memory, monitoring_verdict,  # noqa: E402,F401
                           must_show, sparse_table, table, write_json)
from _fleet_processes import (GROUPS, LocalRayCluster, ProcessMeter, ServerProcess,  # noqa: E402
                              machine_busy_seconds, total, unhandled_errors)
from clients import SivaClient, SivaClientError  # noqa: E402
from service.demo import (LONO_SPEC, LONO_TRUTH, lono_structure, simulate_impact,  # noqa: E402
                          to_csv)

#: states in which no new snapshot is expected (not counted as a gap)
PAUSED = {"idle", "waiting_for_data", "waiting_for_validation", "starting", "error"}
#: server settings of every run (everything else: the service's defaults)
SERVER_ENV = {"SIVA_LOG_LEVEL": "WARNING", "SIVA_TORCH_THREADS": "1",
              "SIVA_SNAPSHOT_EVERY": "5"}   # the service's default, stated (--snapshot-every)
METRICS_EVERY_S = 2.0
UPLOADERS = 16                  # concurrent uploads (one client each)
PENDING_POLL_S = 0.5
MONITORED_POLL_S = 2.0          # when only the monitoring of a system's records is awaited
POLL_PASS_S = 1.0
MEMORY_EVERY_S = 10.0
ONBOARD_TIMEOUT_S = 300.0       # + 40 s per system
PROGRESS_EVERY_S = 15.0


@dataclass
class Case:
    executor: str
    n: int
    window_s: float
    period_s: float
    sparse_records: int = 0     # > 0: the sparse-record run (run_sparse) instead
    prefill: int = 2            # sparse run: records stored before onboarding
    onboard: str = "best"       # before the window: every trainer has an "epoch", or a "best"

    @property
    def label(self) -> str:
        return f"{self.executor} " + ("sparse" if self.sparse_records else f"N={self.n}")

    def planned_s(self, grace_s: float) -> float:
        """A rough duration, for the ETA."""
        setup = 15 + 0.6 * self.n + (25 if self.executor == "ray" else 0)
        if self.sparse_records:
            return setup + 60 + 8 * self.prefill + (30 + 3 * self.prefill) * self.sparse_records
        onboard = 25.0 * self.n if self.onboard == "best" else 1.5 * self.n
        return setup + 20 + onboard + self.window_s + min(grace_s, 15)


@dataclass
class Upload:
    system: str
    id: str
    index: int
    role: str
    t_ack: float
    ack_s: float
    queued_s: float = 0.0                   # due -> sent (all uploader threads busy)
    error: str | None = None                # the upload failed (no 202)
    in_data_s: float | None = None          # first seen in data.train/validation (client)
    in_data_published_s: float | None = None  # that snapshot's own time - t_ack
    monitored_s: float | None = None        # first seen fitted by the monitoring


def snapshot_gaps(times: list[float], t0: float, t_end: float,
                  paused_at: list[float]) -> dict[str, float]:
    """The longest time without a newly published snapshot of one system over [t0, t_end].

    ``times``: every snapshot's own ``time`` (the drift report's history: exact, whatever
    the benchmark's polling); ``paused_at``: when the system was seen idle or waiting for
    data - no snapshot is due then, so an interval containing such a moment is no gap.  The
    interval from the last snapshot to ``t_end`` counts too (a system that stopped
    updating must not hide)."""
    before = [t for t in times if t <= t0]
    inside = sorted(t for t in times if t0 < t <= t_end)
    prev = max(before) if before else t0
    gaps = []
    for t in inside + [t_end]:
        if not any(prev <= p <= t for p in paused_at):
            gaps.append(t - prev)
        prev = t
    return {"max_gap": max(gaps, default=0.0), "updates": len(inside)}


@dataclass
class Progress:
    """One line every ``PROGRESS_EVERY_S`` with the ETA of the whole run."""

    cases: list[Case]
    grace_s: float
    t_start: float = field(default_factory=time.monotonic)
    done: int = 0
    _last: float = 0.0

    def eta(self, case_left_s: float) -> float:
        rest = sum(c.planned_s(self.grace_s) for c in self.cases[self.done + 1:])
        return case_left_s + rest

    def line(self, case: Case, what: str, case_left_s: float, force: bool = False) -> None:
        now = time.monotonic()
        if not force and now - self._last < PROGRESS_EVERY_S:
            return
        self._last = now
        eta = self.eta(case_left_s)
        print(f"[{time.strftime('%H:%M:%S')}] case {self.done + 1}/{len(self.cases)} "
              f"{case.label}: {what} | elapsed {fmt_min(now - self.t_start)}, "
              f"ETA {fmt_min(eta)}", file=sys.stderr, flush=True)


def fmt_min(s: float) -> str:
    return f"{int(s // 60)}m{int(s % 60):02d}s"


# ---------------------------------------------------------------------------- records
def record_pool(n: int, seed: int) -> list[bytes]:
    """``n`` distinct LO-NO impact records (CSV), shared by every system (the store
    deduplicates within a system only)."""
    rng = np.random.default_rng(seed)
    structure = lono_structure()
    return [to_csv(simulate_impact(LONO_TRUTH, float(rng.uniform(30.0, 900.0)), rng,
                                   structure=structure)) for _ in range(n)]


# ---------------------------------------------------------------------------- observing
def fleet_states(client: SivaClient) -> dict[str, dict[str, Any]]:
    """GET /v1/systems: state and epoch of every system, in one request."""
    return {s["name"]: s for s in client._http.get("/v1/systems").json()["systems"]}


def pct(xs: list[float], q: float) -> float | None:
    return float(np.percentile(np.asarray(xs), q)) if xs else None


def bounded_wait(cond: Callable[[], Any], timeout: float, every: float) -> Any:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        out = cond()
        if out:
            return out
        time.sleep(every)
    return None


class Uploaders:
    """Concurrent uploads, one HTTP client per worker thread: every structure's data
    acquisition uploads on its own, so a slow 202 for one must not hold back the others
    (nor the benchmark's observations).  Done uploads are collected with :meth:`done`."""

    def __init__(self, url: str, workers: int) -> None:
        self.url = url
        self._local = threading.local()
        self._pool = ThreadPoolExecutor(workers, thread_name_prefix="uploader")
        self._futures: list[Future[Upload]] = []

    def _client(self) -> SivaClient:
        c = getattr(self._local, "client", None)
        if c is None:
            c = self._local.client = SivaClient(self.url, timeout=600)
        return c

    def _upload(self, system: str, body: bytes, role: str, t_due: float) -> Upload:
        t_send = time.time()
        try:
            ack = self._client().upload(system, body, role=role)
        except SivaClientError as exc:  # e.g. a timeout: counted, not fatal
            return Upload(system, "", -1, role, time.time(), time.time() - t_send,
                          queued_s=t_send - t_due, error=str(exc)[:300])
        t_ack = time.time()
        return Upload(system, ack["id"], int(ack["index"]), role, t_ack, t_ack - t_send,
                      queued_s=t_send - t_due)

    def submit(self, system: str, body: bytes, role: str) -> None:
        self._futures.append(self._pool.submit(self._upload, system, body, role, time.time()))

    def run(self, fn: Callable[..., Any], *args: Any) -> Future[Any]:
        return self._pool.submit(lambda: fn(self._client(), *args))

    def in_flight(self) -> int:
        return sum(not f.done() for f in self._futures)

    def done(self) -> list[Upload]:
        """Uploads acknowledged since the last call (an upload that failed raises here)."""
        out = [f.result() for f in self._futures if f.done()]
        self._futures = [f for f in self._futures if not f.done()]
        return out

    def close(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)


# ---------------------------------------------------------------------------- one case
@dataclass
class Running:
    """A started service: its client, the meter of its processes, its memory before any system."""

    client: SivaClient
    meter: ProcessMeter
    base_memory: dict[str, float]
    log_errors: int = 0


@contextmanager
def running_service(executor: str, node_cpus: int, keep_logs: Path | None, tag: str,
                    status: Callable[[str], None]) -> Iterator[Running]:
    """The server (and with ``ray`` a fresh local cluster) for one case; stopped on exit,
    its log checked for unhandled errors (and kept in ``keep_logs``)."""
    with tempfile.TemporaryDirectory(prefix="siva-fleet-") as tmp:
        cluster = LocalRayCluster(node_cpus) if executor == "ray" else None
        env = {**SERVER_ENV, "SIVA_EXECUTOR": executor}
        server = ServerProcess(Path(tmp) / "data", env, Path(tmp) / "server.log")
        run: Running | None = None
        try:
            if cluster is not None:
                status("starting the Ray cluster")
                server.env["SIVA_RAY_ADDRESS"] = cluster.start()
            server.start()
            meter = ProcessMeter(server.pid, cluster)
            time.sleep(2.0)
            with SivaClient(server.url, timeout=120) as client:
                run = Running(client, meter, meter.memory(pss=True))
                yield run
        finally:
            server.stop()
            if cluster is not None:
                cluster.stop()
            text = server.log_text()
            if keep_logs is not None:
                keep_logs.mkdir(parents=True, exist_ok=True)
                (keep_logs / f"server-{executor}-{tag}.log").write_text(text)
            if run is not None:
                run.log_errors = unhandled_errors(text)


def run_case(case: Case, pool: list[bytes], progress: Progress, grace_s: float,
             node_cpus: int, keep_logs: Path | None) -> dict[str, Any]:
    names = [f"s{i:03d}" for i in range(case.n)]
    status = lambda what: progress.line(case, what, case.planned_s(grace_s), True)  # noqa: E731
    with running_service(case.executor, node_cpus, keep_logs, str(case.n), status) as svc:
        result = measure(case, svc.client, svc.meter, names, pool, progress, grace_s)
        result["memory_base"] = svc.base_memory
    result["server_log_errors"] = svc.log_errors
    return summarise(case, result)


# ---------------------------------------------------------------------------- sparse records
def run_sparse(case: Case, pool: list[bytes], progress: Progress, node_cpus: int,
               keep_logs: Path | None) -> dict[str, Any]:
    """The cost of one record when records are rare (the fleet's normal case): one system
    is onboarded (register, ``case.prefill`` records - every 4th validation - until it
    idles: converged, first ``best``, every record fitted by the monitoring), then each
    record is sent once the system idles again, and the CPU of every process of the
    service is summed from the upload until the system is idle again with the record
    fitted.  An epoch costs in proportion to the training records held (at most
    SIVA_REPLAY_WINDOW + SIVA_REPLAY_RESERVOIR = 12), hence the prefill: 16 records (12 train,
    4 validation) give a long-monitored structure's steady state."""
    executor, n_records = case.executor, case.sparse_records
    status = lambda what: progress.line(case, what, case.planned_s(0), True)  # noqa: E731
    with running_service(executor, node_cpus, keep_logs, "sparse", status) as svc:
        c, meter = svc.client, svc.meter

        def settled(index: int, epoch_before: int) -> dict[str, Any] | None:
            e = c.estimate("cal")
            mon = e.get("monitoring") or {}
            ok = (e.get("state") == "idle" and e.get("epoch", 0) > epoch_before
                  and (mon.get("processed_index") or -1) >= index)
            return e if ok else None

        cpu0, t0 = meter.cpu(), time.monotonic()
        c.register("cal", LONO_SPEC)
        n_pre = max(2, case.prefill)
        for k in range(n_pre):  # every 4th validation; with fewer than 4, the last one
            validation = k % 4 == 3 or (n_pre < 4 and k == n_pre - 1)
            ack = c.upload("cal", pool[k], role="validation" if validation else "train")
        status(f"onboarding one system with {n_pre} records (until converged, "
               "best, every record fitted, idle)")
        est = bounded_wait(lambda: settled(int(ack["index"]), 0), 900, 1.0)
        if est is None:
            raise RuntimeError("the sparse-record system did not reach idle in 900 s")
        onboarding = {"cpu_s": sum(ProcessMeter.cpu_delta(cpu0, meter.cpu()).values()),
                      "wall_s": time.monotonic() - t0, "epochs": int(est["epoch"])}
        cpu0 = meter.cpu()
        time.sleep(15.0)
        idle_cores = sum(ProcessMeter.cpu_delta(cpu0, meter.cpu()).values()) / 15.0
        records = []
        for k in range(n_records):
            status(f"record {k + 1}/{n_records}")
            before = int(est["epoch"])
            cpu0, t0 = meter.cpu(), time.monotonic()
            ack = c.upload("cal", pool[n_pre + k], role="train")
            est = bounded_wait(lambda: settled(int(ack["index"]), before), 600, 0.5)
            if est is None:
                raise RuntimeError(f"record {k + 1} was not trained on and fitted in 600 s")
            cpu = ProcessMeter.cpu_delta(cpu0, meter.cpu())
            records.append({"cpu_s": sum(cpu.values()), "cpu_by_group_s": cpu,
                            "wall_s": time.monotonic() - t0,
                            "epochs": int(est["epoch"]) - before,
                            "fit_s": (est.get("monitoring") or {}).get("seconds_per_record")})
        memory = meter.memory(pss=True)
    med = lambda key: statistics.median(r[key] for r in records) if records else None  # noqa: E731
    return {"executor": executor, "prefill": n_pre, "onboarding": onboarding,
            "idle_cores": idle_cores,
            "records": records, "memory_base": svc.base_memory, "memory_end": memory,
            "server_log_errors": svc.log_errors,
            "cpu_s_per_record": statistics.median(r["cpu_s"] for r in records) if records else None,
            "epochs_per_record": med("epochs"), "wall_s_per_record": med("wall_s"),
            "loadavg": os.getloadavg()}


def measure(case: Case, client: SivaClient, meter: ProcessMeter, names: list[str],
            pool: list[bytes], progress: Progress, grace_s: float) -> dict[str, Any]:
    t_setup = time.monotonic()

    def onboard(c: SivaClient, name: str) -> None:
        c.register(name, LONO_SPEC)
        c.upload(name, pool[0], role="train")
        c.upload(name, pool[1], role="validation")

    uploaders = Uploaders(client.base_url, UPLOADERS)
    try:
        futures = [uploaders.run(onboard, name) for name in names]
        for i, f in enumerate(futures):
            f.result()
            progress.line(case, f"registered {i + 1}/{case.n}", case.planned_s(grace_s))
        result = _warm_and_measure(case, client, meter, names, pool, progress, grace_s,
                                   uploaders, t_setup)
    finally:
        uploaders.close()
    return result


def _warm_and_measure(case: Case, client: SivaClient, meter: ProcessMeter, names: list[str],
                      pool: list[bytes], progress: Progress, grace_s: float,
                      uploaders: Uploaders, t_setup: float) -> dict[str, Any]:
    if case.executor == "ray":
        hosts = bounded_wait(lambda: meter.memory()["trainer_hosts"], 120, 1.0)
        if not hosts:
            raise RuntimeError("SIVA_EXECUTOR=ray but no Ray trainer-host process "
                               f"({'ray::TrainerHost'}) appeared: does this checkout have the "
                               "ray executor (service/fleet/ray_executor.py)?")

    def all_started() -> bool:
        states = fleet_states(client)
        progress.line(case, f"warm-up: {sum(s['epoch'] > 0 for s in states.values())}/"
                            f"{case.n} trainers have an epoch", case.window_s + 30)
        return all(states.get(n, {}).get("epoch", 0) > 0 for n in names)

    warm_timeout = 120 + 3 * case.n
    started = bounded_wait(all_started, warm_timeout, 1.0)
    warmup_s = time.monotonic() - t_setup
    onboarded: dict[str, float] = {}
    if case.onboard == "best":
        t_on = time.monotonic()
        bounded_wait(lambda: _onboarded(client, names, onboarded, t_on, case, progress),
                     ONBOARD_TIMEOUT_S + 40.0 * case.n, 2.0)

    window = FleetWindow(case, client, meter, names, pool, progress, grace_s, uploaders)
    return {"warmup_s": warmup_s, "all_trainers_started": bool(started),
            "onboard": case.onboard, "onboarded": len(onboarded),
            "onboarding_s": max(onboarded.values()) if onboarded else None,
            "onboarding_timeout": case.onboard == "best" and len(onboarded) < len(names),
            **window.run()}


def _onboarded(client: SivaClient, names: list[str], done: dict[str, float], t0: float,
               case: Case, progress: Progress) -> bool:
    """Every system has its first ``best`` and its monitoring has fitted the onboarding
    records (``done``: name -> seconds it took)."""
    for n in names:
        if n in done:
            continue
        est = client.estimate(n)
        mon = est.get("monitoring") or {}
        if est.get("best") and (mon.get("processed_index") or -1) >= 1:
            done[n] = time.monotonic() - t0
    progress.line(case, f"onboarding: {len(done)}/{len(names)} systems have a best and "
                        "fitted their first records", case.window_s + 30)
    return len(done) == len(names)


class FleetWindow:
    """The measurement window: stream, observe, then wait (``grace_s``) for the last records."""

    def __init__(self, case: Case, client: SivaClient, meter: ProcessMeter, names: list[str],
                 pool: list[bytes], progress: Progress, grace_s: float,
                 uploaders: Uploaders) -> None:
        self.case, self.client, self.meter, self.names = case, client, meter, names
        self.pool, self.progress, self.grace_s = pool, progress, grace_s
        self.uploaders = uploaders
        self.failed: list[Upload] = []
        self.paused_at: dict[str, list[float]] = {n: [] for n in names}
        self.uploads: list[Upload] = []
        self.pending: dict[str, list[Upload]] = {n: [] for n in names}
        self.last_poll = {n: 0.0 for n in names}
        self.sent = {n: 0 for n in names}
        self.offsets = {n: i * case.period_s / case.n for i, n in enumerate(names)}
        self.mem_samples: list[dict[str, float]] = []
        self.state_obs: dict[str, int] = {}

    def run(self) -> dict[str, Any]:
        states0 = self._observe()
        cpu0, busy0, load0 = self.meter.cpu(), machine_busy_seconds(), os.getloadavg()
        t0, m0 = time.time(), time.monotonic()
        end = m0 + self.case.window_s
        next_metrics = next_memory = m0
        while (now := time.monotonic()) < end:
            self._send_due(now - m0)
            if now >= next_metrics:
                next_metrics = now + METRICS_EVERY_S
                self._observe()
            if now >= next_memory:
                next_memory = now + MEMORY_EVERY_S
                self.mem_samples.append(self.meter.memory(pss=len(self.mem_samples) % 3 == 0))
            self._poll_pending(streaming=True)
            self._collect()
            self.progress.line(self.case, f"window {now - m0:4.0f}/{self.case.window_s:.0f} s, "
                                          f"{len(self.uploads)} records acknowledged, "
                                          f"{self.uploaders.in_flight()} in flight",
                               end - now + min(self.grace_s, 15))
            time.sleep(0.05)
        t_end, wall = time.time(), time.monotonic() - m0
        cpu1, busy1, load1 = self.meter.cpu(), machine_busy_seconds(), os.getloadavg()
        states1 = self._observe()
        gaps = self._gaps(t0, t_end, states0, states1)
        self.mem_samples.append(self.meter.memory(pss=True))
        grace_end = time.monotonic() + self.grace_s
        while (now := time.monotonic()) < grace_end and (self.uploaders.in_flight() or any(
                u.in_data_s is None or u.monitored_s is None for u in self.uploads)):
            self._collect()
            self._poll_pending(streaming=False)
            self.progress.line(self.case, f"grace: {sum(u.in_data_s is None for u in self.uploads)}"
                                          " records not yet in a published estimate, "
                                          f"{sum(u.monitored_s is None for u in self.uploads)} "
                                          "not yet monitored", grace_end - now)
            time.sleep(0.05)
        self._collect()
        fitted = self._fitted()
        return {
            "window_s": wall, "t_start_unix": t0, "sent": sum(self.sent.values()),
            "unacknowledged": self.uploaders.in_flight(),
            "failed_uploads": [asdict(u) for u in self.failed],
            "epochs": {n: int(states1.get(n, {}).get("epoch", 0))
                       - int(states0.get(n, {}).get("epoch", 0)) for n in self.names},
            "states_end": _count(s.get("state") for s in states1.values()),
            "converged_end": sum(bool(s.get("converged")) for s in states1.values()),
            "state_observations": self.state_obs,
            "uploads": [asdict(u) for u in self.uploads],
            "gaps": gaps, "fitted": fitted,
            "cpu_s": ProcessMeter.cpu_delta(cpu0, cpu1),
            "machine_busy_cores": (busy1 - busy0) / wall,
            "loadavg_start": load0, "loadavg_end": load1,
            "memory_samples": self.mem_samples,
        }

    def _send_due(self, elapsed: float) -> None:
        """Upload every record that is due (system i: at offset_i + k * period)."""
        for n in self.names:
            k = self.sent[n]
            if elapsed < self.offsets[n] + k * self.case.period_s or 2 + k >= len(self.pool):
                continue
            role = "validation" if k % 4 == 3 else "train"
            self.uploaders.submit(n, self.pool[2 + k], role)
            self.sent[n] += 1

    def _collect(self) -> None:
        """Acknowledged uploads join the records awaited in an estimate."""
        for up in self.uploaders.done():
            if up.error is not None:
                self.failed.append(up)
                continue
            self.uploads.append(up)
            self.pending[up.system].append(up)

    def _observe(self) -> dict[str, dict[str, Any]]:
        """Snapshot times (/metrics) and states (/v1/systems) of every system."""
        states = fleet_states(self.client)
        t_obs = time.time()
        for n in self.names:
            st = states.get(n, {}).get("state")
            self.state_obs[str(st)] = self.state_obs.get(str(st), 0) + 1
            if st in PAUSED:
                self.paused_at[n].append(t_obs)
        return states

    def _gaps(self, t0: float, t_end: float, states0: dict[str, dict[str, Any]],
              states1: dict[str, dict[str, Any]]) -> dict[str, dict[str, float]]:
        """Per system, from its drift report's history of published snapshots."""
        out = {}
        for n in self.names:
            epochs = (int(states1.get(n, {}).get("epoch", 0))
                      - int(states0.get(n, {}).get("epoch", 0)))
            # + idle publishes, + the one before t0
            limit = epochs // int(SERVER_ENV["SIVA_SNAPSHOT_EVERY"]) + 50
            hist = self.client._http.get(f"/v1/systems/{n}/drift", params={"limit": limit}).json()
            times = [float(e["time"]) for e in hist.get("history", []) if e.get("time")]
            out[n] = snapshot_gaps(times, t0, t_end, self.paused_at[n])
        return out

    def _fitted(self) -> dict[str, dict[str, Any]]:
        """Per system, from its drift report: which acknowledged records the monitoring
        fitted (``records`` with ``ok``), failed on, or has not reached."""
        out = {}
        for n in self.names:
            ids = {u.id for u in self.uploads if u.system == n}
            rep = self.client._http.get(f"/v1/systems/{n}/drift",
                                        params={"limit": 2000}).json()
            ok = {r["id"] for r in rep.get("records", []) if r.get("ok")}
            failed = set(rep.get("failures") or {}) | {r["id"] for r in rep.get("records", [])
                                                        if not r.get("ok")}
            secs = [float(r["seconds"]) for r in rep.get("records", [])
                    if r.get("id") in ids and r.get("seconds") is not None]
            out[n] = {"acknowledged": len(ids), "fitted_ok": len(ids & ok),
                      "failed": sorted(ids & failed), "fit_seconds": secs,
                      "processed_index": rep.get("processed_index")}
        return out

    def _poll_pending(self, streaming: bool) -> None:
        """GET .../estimate of systems with records not yet seen (every 0.5 s; every 2 s
        when only the monitoring is awaited, also after the window).  One pass
        takes at most ``POLL_PASS_S`` (a slow server must not stall the window's clock:
        the systems longest unpolled go first)."""
        t_pass = time.monotonic()
        for n in sorted(self.names, key=self.last_poll.__getitem__):
            if time.monotonic() - t_pass > POLL_PASS_S:
                break
            todo = self.pending[n]
            since = time.monotonic() - self.last_poll[n]
            if not todo or since < PENDING_POLL_S:
                continue
            if all(u.in_data_s is not None for u in todo) and since < MONITORED_POLL_S:
                continue
            self.last_poll[n] = time.monotonic()
            est = self.client.estimate(n)
            t_obs = time.time()
            data = est.get("data") or {}
            listed = set(data.get("train") or []) | set(data.get("validation") or [])
            processed = (est.get("monitoring") or {}).get("processed_index")
            for u in todo:
                if u.in_data_s is None and u.id in listed:
                    u.in_data_s = t_obs - u.t_ack
                    u.in_data_published_s = max(0.0, float(est.get("time", t_obs)) - u.t_ack)
                if u.monitored_s is None and processed is not None and processed >= u.index:
                    u.monitored_s = t_obs - u.t_ack
            self.pending[n] = [u for u in todo if u.in_data_s is None or u.monitored_s is None]


def _count(xs: Any) -> dict[str, int]:
    out: dict[str, int] = {}
    for x in xs:
        out[str(x)] = out.get(str(x), 0) + 1
    return out


def summarise(case: Case, r: dict[str, Any]) -> dict[str, Any]:
    """The numbers of the table (and everything raw, for the JSON)."""
    wall = r["window_s"]
    ups = r["uploads"]
    in_data = [u["in_data_s"] for u in ups if u["in_data_s"] is not None]
    published = [u["in_data_published_s"] for u in ups if u["in_data_published_s"] is not None]
    monitored = [u["monitored_s"] for u in ups if u["monitored_s"] is not None]
    epochs = sum(r["epochs"].values())
    gaps = [g["max_gap"] for g in r["gaps"].values()]
    updates = [g["updates"] for g in r["gaps"].values()]
    cpu = r["cpu_s"]
    cpu_total = sum(cpu.values())
    base = r["memory_base"]
    peak = max(r["memory_samples"], key=total)
    pss = [m for m in r["memory_samples"] if "server_pss_mb" in m]
    last_pss = pss[-1] if pss else {}
    obs = r["state_observations"]
    n_obs = max(1, sum(obs.values()))
    return {
        "executor": case.executor, "n_systems": case.n, "period_s": case.period_s,
        "window_s": wall, "warmup_s": r["warmup_s"],
        "all_trainers_started": r["all_trainers_started"],
        "epochs_per_s": epochs / wall,
        "epochs_per_s_per_system": {"min": min(r["epochs"].values()) / wall,
                                    "median": statistics.median(r["epochs"].values()) / wall},
        "records_sent": r.get("sent", len(ups)), "records_acknowledged": len(ups),
        "records_unacknowledged_after_grace": r.get("unacknowledged", 0),
        "failed_uploads": len(r.get("failed_uploads", [])),
        "upload_ack_s": {"p50": pct([u["ack_s"] for u in ups], 50),
                         "p95": pct([u["ack_s"] for u in ups], 95),
                         "queued_p95": pct([u.get("queued_s", 0.0) for u in ups], 95)},
        "record_to_estimate_s": {
            "definition": "202 -> first GET .../estimate whose data.train/validation lists "
                          "the record (client time, polled every 0.5 s)",
            "n": len(in_data), "not_seen": len(ups) - len(in_data),
            "p50": pct(in_data, 50), "p95": pct(in_data, 95),
            "max": max(in_data) if in_data else None,
            "published_p50": pct(published, 50), "published_p95": pct(published, 95)},
        "record_to_monitored_s": {
            "definition": "202 -> first estimate whose monitoring.processed_index >= the "
                          "record's index (its per-record fit is in the headline and the "
                          "drift test; polled every 2 s); fitted_ok: the drift report "
                          "lists its fit as ok at the end",
            "n": len(monitored), "not_seen": len(ups) - len(monitored),
            "p50": pct(monitored, 50), "p95": pct(monitored, 95),
            "max": max(monitored) if monitored else None,
            "fitted_ok": sum(f["fitted_ok"] for f in r.get("fitted", {}).values()),
            "failed": sum(len(f["failed"]) for f in r.get("fitted", {}).values()),
            "fit_seconds_p50": pct([x for f in r.get("fitted", {}).values()
                                    for x in f["fit_seconds"]], 50)},
        "onboard": r.get("onboard"), "onboarded": r.get("onboarded"),
        "onboarding_s": r.get("onboarding_s"),
        "onboarding_timeout": r.get("onboarding_timeout"),
        "max_update_gap_s": max(gaps) if gaps else None,
        "median_max_gap_s": statistics.median(gaps) if gaps else None,
        "min_updates_per_system": min(updates) if updates else 0,
        "idle_share": obs.get("idle", 0) / n_obs,
        "states_end": r["states_end"], "converged_end": r["converged_end"],
        "memory_mb": {
            "base_rss": total(base), "peak_rss": total(peak),
            "per_system_rss": (total(peak) - total(base)) / case.n,
            "base_pss": total(base, "pss"), "end_pss": total(last_pss, "pss"),
            "per_system_pss": (total(last_pss, "pss") - total(base, "pss")) / case.n,
            "trainer_hosts": peak.get("trainer_hosts", 0),
            "peak_by_group": {g: peak.get(f"{g}_rss_mb", 0.0) for g in GROUPS}},
        "cpu": {
            "cores": cpu_total / wall, "by_group_cores": {g: v / wall for g, v in cpu.items()},
            "machine_busy_cores": r["machine_busy_cores"],
            "cpu_s_per_epoch": cpu_total / epochs if epochs else None,
            "cpu_s_per_record": cpu_total / len(ups) if ups else None},
        "loadavg": {"start": r["loadavg_start"], "end": r["loadavg_end"]},
        "server_log_errors": r["server_log_errors"],
        "raw": {k: r[k] for k in ("epochs", "gaps", "uploads", "memory_samples", "memory_base",
                                  "state_observations", "fitted")},
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--executor", choices=("threads", "ray", "both"), default="both")
    ap.add_argument("--systems", default="1,4,16,64", help="comma-separated N")
    ap.add_argument("--period", type=float, default=30.0,
                    help="seconds between two records of one system")
    ap.add_argument("--window", type=float, default=None,
                    help="measurement window per case (default 120 + 3 N s)")
    ap.add_argument("--grace", type=float, default=90.0,
                    help="after the window, wait at most this for records not yet seen "
                         "(in an estimate, and fitted by the monitoring)")
    ap.add_argument("--onboard", choices=("best", "epoch"), default="best",
                    help="start the window once every system has its first best (its "
                         "monitoring runs: the steady state of a monitored fleet) or once "
                         "every trainer has an epoch (young systems: no monitoring yet)")
    ap.add_argument("--node-cpus", type=int, default=4, help="logical CPUs per Ray node")
    ap.add_argument("--quick", action="store_true",
                    help="reduced: N=1,4, 45 s windows, a record every 15 s")
    ap.add_argument("--sparse-records", type=int, default=3,
                    help="records of the sparse-record run per executor (0: none)")
    ap.add_argument("--sparse-prefill", type=int, default=16,
                    help="records stored before the sparse run's onboarding (16: a full "
                         "replay buffer, 12 train + 4 validation)")
    ap.add_argument("--snapshot-every", type=int, default=5,
                    help="SIVA_SNAPSHOT_EVERY of the server: epochs between published estimates")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--logs", help="keep the server logs in this folder")
    ap.add_argument("--json", help="also write the results here")
    args = ap.parse_args()
    SERVER_ENV["SIVA_SNAPSHOT_EVERY"] = str(max(1, args.snapshot_every))
    systems = [] if args.systems == "none" else [int(x) for x in args.systems.split(",")
                                                  if x.strip()]
    period, window = args.period, args.window
    if args.quick:
        systems = [n for n in systems if n <= 4] or [1]
        period, window = 15.0, window or 45.0
        args.sparse_records = min(args.sparse_records, 2)
        args.sparse_prefill = 2
    if (systems and min(systems) < 1) or period <= 0 or not (systems or args.sparse_records):
        ap.error("--systems needs positive integers (or none, with --sparse-records > 0) "
                 "and --period must be > 0")
    executors = ["threads", "ray"] if args.executor == "both" else [args.executor]
    if args.executor == "both" and importlib.util.find_spec("ray") is None:
        print("ray is not installed (pip install '.[ray]'): measuring threads only",
              flush=True)
        executors = ["threads"]
    cases = [Case(ex, 1, 0.0, 0.0, args.sparse_records, args.sparse_prefill)
             for ex in executors if args.sparse_records > 0]
    cases += [Case(ex, n, window or 120.0 + 3.0 * n, period, onboard=args.onboard)
              for n in systems for ex in executors]
    n_records = max([2 + int(c.window_s / c.period_s) + 2 for c in cases if not c.sparse_records]
                    + [max(2, c.prefill) + c.sparse_records for c in cases if c.sparse_records])
    t = time.perf_counter()
    pool = record_pool(n_records, args.seed)
    print(f"{len(pool)} LO-NO records simulated in {time.perf_counter() - t:.1f} s "
          f"({len(pool[0]) / 1e6:.2f} MB CSV each); load average {os.getloadavg()}",
          file=sys.stderr, flush=True)
    progress = Progress(cases, args.grace)
    results: list[dict[str, Any]] = []
    sparse: list[dict[str, Any]] = []
    logs = Path(args.logs) if args.logs else None
    for i, case in enumerate(cases):
        progress.done = i
        try:
            if case.sparse_records:
                res = run_sparse(case, pool, progress, args.node_cpus, logs)
            else:
                res = run_case(case, pool, progress, args.grace, args.node_cpus, logs)
        except Exception as exc:  # noqa: BLE001 - one failed case must not lose the others
            res = {"executor": case.executor, "n_systems": case.n,
                   "error": f"{type(exc).__name__}: {exc}"[:2000]}
        (sparse if case.sparse_records else results).append(res)
        progress.line(case, "done" if "error" not in res else f"FAILED: {res['error'][:200]}",
                      0.0, True)
        if args.json:  # after every case: a long run keeps what it measured
            write_json(args.json, results, sparse, period, args, SERVER_ENV)
    print(f"\nFleet benchmark, LO-NO systems, one record per system every {period:g} s "
          f"(staggered), {machine()['cpus_logical']} CPUs, {time.strftime('%Y-%m-%d %H:%M')} UTC")
    print(table(results))
    for ex, m in marginal_memory(results).items():
        print(f"{ex}: each added system costs {m['rss_mb_per_system']:.0f} MB RSS "
              f"({m['pss_mb_per_system']:.0f} MB PSS), N={m['from_n']} -> {m['to_n']}")
    for line in must_show(results):
        print(line)
    if sparse:
        print("\nSparse records (one system; each record sent once it idles; CPU of every "
              "process of the service from the upload until idle again with the record fitted):")
        print("  (an epoch costs in proportion to the training records held: at most 12)")
        print(sparse_table(sparse))
    return 1 if any("error" in r for r in results + sparse) else 0


if __name__ == "__main__":
    sys.exit(main())
