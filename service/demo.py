"""`siva serve --demo`: a simulated LO-NO rig that streams impact tests into the service.

Why: a newcomer should see, in one command and without data of their own, what the service
is for - estimates converging, intervals shrinking as records accumulate, and a drift alarm
when the structure changes.  The demo goes through the public HTTP API (the Python client in
a background thread), so it also exercises exactly what a real data-acquisition script does.

The rig is the paper's two-DOF LO-NO (eq. 7, ``examples/models/lono.toml``) at the paper's
Table 2 values (``shared/data/lono/truth.json``); both are embedded here because the
installed package (docker image) has neither folder.  Each record: an impact-hammer
half-sine pulse of 6.2 ms at t = 0.1 s on NO, peak drawn uniformly in 30-900 N; 2048 Hz;
what instruments give (``acc_LO``, ``acc_NO`` with 0.3 % white noise - relative to the
channel's peak - plus a 60 Hz hum of 0.02 m/s^2, random phase; ``force_NO`` with 0.2 %
noise).  One record in ``validation_every`` is sent as validation.  After ``drop_after``
records the LO's ground stiffness k1 drops by ``drop`` (15 %: a loosened support), but only
once the service's drift monitor has frozen its reference (after convergence) - otherwise
there is nothing to drift from.
"""
from __future__ import annotations

import io
import logging
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

log = logging.getLogger("siva.demo")

#: examples/models/lono.toml, as the JSON body of PUT (kept equal by tests/service/test_demo.py)
LONO_SPEC: dict[str, Any] = {
    "name": "lono",
    "dofs": ["LO", "NO"],
    "mass": {"LO": 1.37, "NO": 1.37},
    "elements": [
        {"kind": "damper", "between": ["LO", "ground"], "params": {"c": "b1"}},
        {"kind": "spring", "between": ["LO", "ground"], "params": {"k": "k1"}},
        {"kind": "damper", "between": ["LO", "NO"], "params": {"c": "b2"}},
        {"kind": "spring", "between": ["LO", "NO"], "params": {"k": "k2"}},
        {"kind": "power_spring", "between": ["LO", "NO"],
         "params": {"alpha": "alpha", "beta": "beta"}},
    ],
    "parameters": {"beta": {"scale": 1}},
}
#: shared/data/lono/truth.json "truth" (the paper's Table 2, Approach III)
LONO_TRUTH: dict[str, float] = {"b1": 3.8405, "b2": 0.78563, "k1": 19273.0, "k2": 1947.6,
                                "alpha": 27641000.0, "beta": 2.0012}


@dataclass
class DemoConfig:
    """What the demo streams and when (defaults: the documented demo)."""

    system: str = "lono-demo"
    seed: int | None = None          # None: a fresh random seed (logged)
    n_records: int = 60              # 0: stream until stopped
    interval_s: float = 4.0          # at most one record per interval ...
    min_epochs_between: int = 10     # ... and never faster than the service trains
    validation_every: int = 4        # records 4, 8, 12, ... are validation
    drop_after: int = 24             # k1 drops after this many records (once converged)
    drop: float = 0.15               # relative stiffness loss
    drop_parameter: str = "k1"
    amplitude_n: tuple[float, float] = (30.0, 900.0)
    pulse_s: float = 6.2e-3
    impact_at_s: float = 0.1
    fs: float = 2048.0
    duration_s: float = 4.0
    acc_noise: float = 0.003         # std relative to the channel's peak
    force_noise: float = 0.002
    hum_amplitude: float = 0.02      # m/s^2 at 60 Hz
    wait_server_s: float = 60.0
    truth: dict[str, float] = field(default_factory=lambda: dict(LONO_TRUTH))


# ---------------------------------------------------------------------------- simulation
def lono_structure():
    from siva_core import Structure

    return Structure.from_dict(LONO_SPEC)


def half_sine(t: np.ndarray, peak: float, start: float, width: float) -> np.ndarray:
    """An impact-hammer pulse: peak * sin(pi (t - start) / width) on [start, start + width]."""
    x = (t - start) / width
    return np.where((x >= 0) & (x <= 1), peak * np.sin(np.pi * np.clip(x, 0, 1)), 0.0)


def simulate_impact(theta: dict[str, float], amplitude: float, rng: np.random.Generator,
                    cfg: DemoConfig | None = None, structure: Any = None) -> dict[str, np.ndarray]:
    """One measured impact test of the LO-NO rig: columns time, acc_LO, acc_NO, force_NO."""
    cfg = cfg or DemoConfig()
    structure = structure or lono_structure()
    n = int(round(cfg.duration_s * cfg.fs)) + 1
    t = np.arange(n) / cfg.fs
    force = np.zeros((n, structure.n_dof))
    k_no = structure.dofs.index("NO")
    force[:, k_no] = half_sine(t, amplitude, cfg.impact_at_s, cfg.pulse_s)
    vec = structure.vector(theta)
    acc = _simulate(structure, vec, t, force)
    cols: dict[str, np.ndarray] = {"time": t}
    for k, d in enumerate(structure.dofs):
        a = acc[:, k]
        noise = cfg.acc_noise * np.max(np.abs(a)) * rng.standard_normal(n)
        hum = cfg.hum_amplitude * np.sin(2 * np.pi * 60.0 * t + rng.uniform(0, 2 * np.pi))
        cols[f"acc_{d}"] = a + noise + hum
    f = force[:, k_no]
    cols["force_NO"] = f + cfg.force_noise * amplitude * rng.standard_normal(n)
    return cols


def _simulate(structure: Any, theta: np.ndarray, t: np.ndarray, force: np.ndarray) -> np.ndarray:
    """Accelerations (T, n_dof) from rest: the project's RK4 simulator with automatic
    substeps (accurate to ~1e-7, far below the 0.3 % noise)."""
    from siva_core import simulate

    z = np.zeros(structure.n_dof)
    return np.asarray(simulate(structure, theta, t, z, z, force, substeps="auto").a)


def to_csv(cols: dict[str, np.ndarray]) -> bytes:
    """CONTRACT.md CSV: header row, then one row per sample."""
    names = list(cols)
    buf = io.StringIO()
    buf.write(",".join(names) + "\n")
    np.savetxt(buf, np.column_stack([cols[k] for k in names]), delimiter=",", fmt="%.10e")
    return buf.getvalue().encode()


# ---------------------------------------------------------------------------- streaming
@dataclass
class DemoEvent:
    """What the demo did, for the console and for tests: one entry per record sent."""

    index: int                       # 1-based
    role: str
    amplitude_n: float
    dropped: bool                    # sent after the stiffness drop
    id: str | None
    epoch_at_send: int | None
    wall_time: float


class DemoStreamer(threading.Thread):
    """Background thread: waits for the server, registers the rig, streams records.

    Stops after ``n_records`` or when :meth:`stop` is called; never raises into the server
    (errors are logged and the demo ends).
    """

    def __init__(self, base_url: str, token: str | None = None, cfg: DemoConfig | None = None,
                 *, on_event: Callable[[DemoEvent], None] | None = None) -> None:
        super().__init__(name="siva-demo", daemon=True)
        self.base_url = base_url
        self.token = token
        self.cfg = cfg or DemoConfig()
        if self.cfg.seed is None:
            self.cfg.seed = int(np.random.SeedSequence().entropy % (2**31))
        self.rng = np.random.default_rng(self.cfg.seed)
        self.events: list[DemoEvent] = []
        self.drop_index: int | None = None   # records sent before the drop
        self.error: BaseException | None = None
        self._halt = threading.Event()
        self._on_event = on_event

    def stop(self) -> None:
        self._halt.set()

    @property
    def theta(self) -> dict[str, float]:
        """The rig's current true parameters (after the drop, the damaged ones)."""
        th = dict(self.cfg.truth)
        if self.drop_index is not None:
            th[self.cfg.drop_parameter] *= 1.0 - self.cfg.drop
        return th

    def run(self) -> None:
        from clients.client import SivaClient, SivaClientError

        cfg = self.cfg
        # the demo's own polling would otherwise fill the server console, one line per GET
        logging.getLogger("httpx").setLevel(max(logging.WARNING,
                                                logging.getLogger("httpx").level))
        try:
            with SivaClient(self.base_url, self.token, timeout=60.0) as client:
                if not self._wait_healthy(client):
                    raise RuntimeError(f"demo: server at {self.base_url} not up after "
                                       f"{cfg.wait_server_s:g} s")
                client.register(cfg.system, LONO_SPEC)
                log.info("demo: streaming LO-NO impacts into system %r (seed %d); k1 drops "
                         "after record %d. Watch %s/v1/systems/%s/estimate and .../drift",
                         cfg.system, cfg.seed, cfg.drop_after, self.base_url, cfg.system)
                structure = lono_structure()
                last_epoch = -10**9
                i = 0
                while not self._halt.is_set() and (cfg.n_records == 0 or i < cfg.n_records):
                    est = self._estimate(client)
                    epoch = int(est.get("epoch") or 0) if est else 0
                    # pace by training only while it trains (before the first validation
                    # record it waits for data, and waiting for it here would deadlock)
                    training = est is not None and est.get("state") in ("training", "converged")
                    if i > 0 and training and epoch - last_epoch < cfg.min_epochs_between:
                        self._halt.wait(min(cfg.interval_s, 0.5))
                        continue
                    # once monitoring runs, never more than two records ahead of it (each
                    # record is fitted once; on a slow machine the story stays the same)
                    mon = (est or {}).get("monitoring") or {}
                    if (i > 0 and mon.get("processed_index") is not None
                            and mon["processed_index"] >= 0 and mon["processed_index"] < i - 2):
                        self._halt.wait(min(cfg.interval_s, 0.5))
                        continue
                    if (self.drop_index is None and i >= cfg.drop_after
                            and self._has_reference(client, est)):
                        self.drop_index = i
                        log.warning("demo: %s drops by %.0f %% after record %d",
                                    cfg.drop_parameter, cfg.drop * 100, i)
                    i += 1
                    role = "validation" if i % cfg.validation_every == 0 else "train"
                    amp = float(self.rng.uniform(*cfg.amplitude_n))
                    cols = simulate_impact(self.theta, amp, self.rng, cfg, structure)
                    ack = client.upload(cfg.system, to_csv(cols), role=role)
                    ev = DemoEvent(i, role, amp, self.drop_index is not None, ack.get("id"),
                                   epoch, time.time())
                    self.events.append(ev)
                    log.info("demo: record %d sent (%s, hammer %.0f N%s) at epoch %d", i, role,
                             amp, ", after the drop" if ev.dropped else "", epoch)
                    last_epoch = epoch
                    if self._on_event:
                        self._on_event(ev)
                    self._halt.wait(cfg.interval_s)
        except (SivaClientError, RuntimeError, OSError, ValueError) as exc:
            self.error = exc
            log.error("demo stopped: %s", exc)

    def _wait_healthy(self, client: Any) -> bool:
        deadline = time.monotonic() + self.cfg.wait_server_s
        while not self._halt.is_set() and time.monotonic() < deadline:
            if client.health():
                return True
            self._halt.wait(0.2)
        return False

    def _has_reference(self, client: Any, est: dict[str, Any] | None) -> bool:
        """Whether drift monitoring has frozen its reference (else a change cannot alarm);
        a service without a drift report falls back to "the estimate has converged"."""
        from clients.client import SivaClientError

        if est is None or not est.get("converged"):
            return False
        try:
            report = client.drift(self.cfg.system)
        except SivaClientError:
            return True
        return "reference" not in report or report["reference"] is not None

    def _estimate(self, client: Any) -> dict[str, Any] | None:
        from clients.client import SivaClientError

        try:
            return client.estimate(self.cfg.system)
        except SivaClientError as exc:
            if exc.status is None or exc.status >= 500:
                raise
            return None  # no estimate yet (no data): fine


def start_demo(base_url: str, token: str | None = None, cfg: DemoConfig | None = None,
               **kw: Any) -> DemoStreamer:
    """Start the demo thread (``siva serve --demo`` calls this once the server listens)."""
    streamer = DemoStreamer(base_url, token, cfg, **kw)
    streamer.start()
    return streamer


# ---------------------------------------------------------------------------- embedding
class ServerThread:
    """The real service (uvicorn + ``create_app``) on a free local port, in a thread.

    Why: tests, the benchmark and notebooks need the service exactly as ``siva serve``
    runs it - real sockets, lifespan, workers - without a subprocess to manage.
    ``with ServerThread(settings) as url: ...`` stops it (workers checkpoint, logs close).
    """

    def __init__(self, settings: Any, host: str = "127.0.0.1", port: int = 0,
                 startup_timeout: float = 60.0) -> None:
        import socket

        import uvicorn

        from .api.app import create_app

        if port == 0:
            with socket.socket() as s:
                s.bind((host, 0))
                port = s.getsockname()[1]
        self.host, self.port = host, port
        self.url = f"http://{host}:{port}"
        self.app = create_app(settings)
        config = uvicorn.Config(self.app, host=host, port=port, log_level="warning",
                                access_log=False, lifespan="on")
        self.server = uvicorn.Server(config)
        self._thread = threading.Thread(target=self.server.run, name="siva-server", daemon=True)
        self._timeout = startup_timeout

    @property
    def service(self) -> Any:
        return self.app.state.service

    def start(self) -> str:
        self._thread.start()
        deadline = time.monotonic() + self._timeout
        while not self.server.started:
            if not self._thread.is_alive() or time.monotonic() > deadline:
                raise RuntimeError(f"siva server on {self.url} did not start")
            time.sleep(0.05)
        return self.url

    def stop(self, timeout: float = 120.0) -> None:
        self.server.should_exit = True
        self._thread.join(timeout)

    def __enter__(self) -> str:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
