"""Prometheus ``GET /metrics``: request counters and latencies, and per-system gauges.

Why a custom collector for the systems: the gauges are read from the workers' published
snapshots at scrape time (never from the trainer), so a scrape costs a few dict look-ups,
never waits for training, and a deleted system disappears from the next scrape.  Request
metrics come from a pure ASGI middleware labelled by the route *template*
(``/v1/systems/{name}/estimate``), not the raw path, so the label set stays bounded.

Each app has its own registry (tests run several apps in one process).
"""
from __future__ import annotations

import math
import time
from typing import Any, Iterator, Mapping

from fastapi import Depends, FastAPI, Request
from fastapi.responses import Response
from prometheus_client import (CONTENT_TYPE_LATEST, CollectorRegistry, Counter, Histogram,
                               generate_latest)
from prometheus_client.core import GaugeMetricFamily
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from ..trainer.published import Snapshot

#: alarm state as a number, for a Grafana panel (0 none, 1 raised, 2 confirmed; cleared is 0)
ALARM_LEVEL = {"raised": 1, "active": 1, "confirmed": 2}


def _route_template(scope: Scope) -> str:
    """The matched route's path template (the router leaves it in ``scope["route"]``), or
    "unmatched": 404s for arbitrary paths must not add label values."""
    return str(getattr(scope.get("route"), "path", None) or "unmatched")


class RequestMetricsMiddleware:
    """Counts requests and observes their latency, by method, route template and status."""

    def __init__(self, app: ASGIApp, requests: Counter, latency: Histogram) -> None:
        self.app = app
        self.requests = requests
        self.latency = latency

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        start = time.perf_counter()
        status = 500

        async def tracking_send(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = int(message["status"])
            await send(message)

        try:
            await self.app(scope, receive, tracking_send)
        finally:
            route = _route_template(scope)
            method = scope.get("method", "GET")
            self.requests.labels(method, route, str(status)).inc()
            self.latency.labels(method, route).observe(time.perf_counter() - start)


def _num(x: Any) -> float | None:
    return float(x) if isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) else None


class SystemsCollector:
    """Per-system gauges from the latest published snapshot of every worker."""

    def __init__(self, service: Any) -> None:
        self.service = service

    def describe(self) -> list[Any]:
        return []  # no up-front description: the families depend on the systems

    def collect(self) -> Iterator[GaugeMetricFamily]:
        fam = {
            "param": GaugeMetricFamily("siva_parameter", "headline estimate of a parameter "
                                       "(mean of the reported estimate)", labels=["system", "parameter", "source"]),
            "lo": GaugeMetricFamily("siva_parameter_ci95_lower", "lower bound of the 95 % interval",
                                    labels=["system", "parameter"]),
            "hi": GaugeMetricFamily("siva_parameter_ci95_upper", "upper bound of the 95 % interval",
                                    labels=["system", "parameter"]),
            "best": GaugeMetricFamily("siva_parameter_best", "output-error refined value (best)",
                                      labels=["system", "parameter"]),
            "alarm": GaugeMetricFamily("siva_alarm_state", "drift alarm per parameter: 0 none "
                                       "or cleared, 1 raised, 2 confirmed", labels=["system", "parameter"]),
            "eps": GaugeMetricFamily("siva_epochs_per_second", "training speed",
                                     labels=["system"]),
            "epoch": GaugeMetricFamily("siva_epoch", "trainer epoch of the latest snapshot",
                                       labels=["system"]),
            "conv": GaugeMetricFamily("siva_converged", "1 once the trainer converged",
                                      labels=["system"]),
            "freq": GaugeMetricFamily("siva_natural_frequency_hz", "linear natural frequency "
                                      "of the estimate", labels=["system", "mode"]),
            "zeta": GaugeMetricFamily("siva_damping_ratio", "damping ratio of the estimate",
                                      labels=["system", "mode"]),
            "val_t": GaugeMetricFamily("siva_validation_statistic", "held-out test T = residual "
                                       "power / measurement-noise power (1 = explains all but "
                                       "the noise), pooled or per validation record",
                                       labels=["system", "of", "record"]),
            "val_p": GaugeMetricFamily("siva_validation_p_value", "p-value of the held-out test "
                                       "(H0: unexplained power <= tolerance x noise)",
                                       labels=["system", "of", "record"]),
            "val_rej": GaugeMetricFamily("siva_model_rejected", "1 when the validation test "
                                         "rejects the model (headline, else ensemble), 0 when it "
                                         "accepts it; absent before the first test",
                                         labels=["system"]),
            "ens_final": GaugeMetricFamily("siva_ensemble_final", "1 once the running SIVA "
                                           "ensemble is final (output-error phase converged, "
                                           "with a 95 % interval), 0 while provisional",
                                           labels=["system"]),
            "recs": GaugeMetricFamily("siva_recordings", "stored recordings by role",
                                      labels=["system", "role"]),
            "age": GaugeMetricFamily("siva_snapshot_timestamp_seconds", "unix time of the "
                                     "latest snapshot", labels=["system"]),
        }
        for name, w in sorted(list(self.service.workers.items())):
            self._system(fam, name, w, w.snapshot())
        yield from fam.values()

    def _system(self, fam: dict[str, GaugeMetricFamily], name: str, w: Any,
                snap: Snapshot) -> None:
        source = str(snap.estimate_source or "none")
        for p, s in (snap.parameters or {}).items():
            if not isinstance(s, Mapping):
                continue
            v = _num(s.get("mean", s.get("value")))
            if v is not None:
                fam["param"].add_metric([name, p, source], v)
            ci = s.get("ci95")
            if isinstance(ci, (list, tuple)) and len(ci) == 2:
                lo, hi = _num(ci[0]), _num(ci[1])
                if lo is not None:
                    fam["lo"].add_metric([name, p], lo)
                if hi is not None:
                    fam["hi"].add_metric([name, p], hi)
        best = snap.best
        if isinstance(best, Mapping):
            for p, s in (best.get("parameters") or {}).items():
                v = _num(s.get("value")) if isinstance(s, Mapping) else None
                if v is not None:
                    fam["best"].add_metric([name, p], v)
        levels = {p: 0.0 for p in w.structure.free}
        for a in snap.alarms:
            if not isinstance(a, Mapping) or "parameter" not in a:
                continue
            state = str(a.get("state", "active" if a.get("active", True) else "cleared"))
            levels[str(a["parameter"])] = max(levels.get(str(a["parameter"]), 0.0),
                                              float(ALARM_LEVEL.get(state, 0)))
        for p, lvl in levels.items():
            fam["alarm"].add_metric([name, p], lvl)
        val = snap.validation
        if isinstance(val, Mapping):
            if val.get("verdict") in ("accepted", "rejected"):
                fam["val_rej"].add_metric([name], 1.0 if val["verdict"] == "rejected" else 0.0)
            for of in ("headline", "ensemble"):
                test = val.get(of)
                if not isinstance(test, Mapping):
                    continue
                rows = [("all", test.get("T"), test.get("p_value"))] + [
                    (str(r.get("record")), r.get("T"), r.get("p_value"))
                    for r in test.get("per_record") or [] if isinstance(r, Mapping)]
                for rec, t_val, p_val in rows:
                    if _num(t_val) is not None:
                        fam["val_t"].add_metric([name, of, rec], float(t_val))
                    if _num(p_val) is not None:
                        fam["val_p"].add_metric([name, of, rec], float(p_val))
        if snap.ensemble_state is not None:
            fam["ens_final"].add_metric([name], 1.0 if snap.ensemble_state == "final" else 0.0)
        spe = _num(snap.seconds_per_epoch)
        if spe:
            fam["eps"].add_metric([name], 1.0 / spe)
        ep = _num(snap.epoch)
        if ep is not None:
            fam["epoch"].add_metric([name], ep)
        fam["conv"].add_metric([name], 1.0 if snap.converged else 0.0)
        modal = snap.modal
        if isinstance(modal, Mapping):
            for i, (f, z) in enumerate(zip(modal.get("frequency_hz") or [],
                                           modal.get("damping_ratio") or []), 1):
                if _num(f) is not None:
                    fam["freq"].add_metric([name, str(i)], float(f))
                if _num(z) is not None:
                    fam["zeta"].add_metric([name, str(i)], float(z))
        try:
            counts = self.service.store.counts(name)
        except Exception:  # noqa: BLE001 - deleted between the listing and now
            counts = {}
        for role, n in counts.items():
            fam["recs"].add_metric([name, role], float(n))
        t = _num(snap.time)
        if t is not None:
            fam["age"].add_metric([name], t)


def install(app: FastAPI, service: Any) -> None:
    """Add the request middleware and ``GET /metrics`` with a registry of this app's own."""
    registry = CollectorRegistry()
    requests = Counter("siva_http_requests", "HTTP requests by method, route template and "
                       "status", ["method", "route", "status"], registry=registry)
    latency = Histogram("siva_http_request_duration_seconds", "HTTP request latency",
                        ["method", "route"], registry=registry,
                        buckets=(0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1,
                                 2.5, 5, 10, 30))
    registry.register(SystemsCollector(service))
    app.state.metrics_registry = registry

    from .auth import require_read_token  # reads behind the token when asked (issue 19)

    @app.get("/metrics", include_in_schema=False, dependencies=[Depends(require_read_token)])
    async def metrics(request: Request) -> Response:
        return Response(generate_latest(registry), media_type=CONTENT_TYPE_LATEST)

    app.add_middleware(RequestMetricsMiddleware, requests=requests, latency=latency)


__all__ = ["install", "RequestMetricsMiddleware", "SystemsCollector"]
