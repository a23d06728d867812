"""The refiner thread: ``best``, the output-error refinement, off the trainer's thread.

It also runs ``step`` (the worker's per-record monitoring) whenever poked, until there is
nothing left to do; then it sleeps without polling.

Why a second thread per system: ``recommend_best`` (Approach III over the ensemble, then
the output-error refinement, ``siva_core.recommend_best``) takes seconds to
minutes, and neither training nor reads may wait for it.  The trainer hands it a job (a
copy of the ensemble's last samples, the ids of the most recent training records and the
processing chain); a job not yet started is superseded by a newer one.  The refiner
re-parses those records from the store and hands the result back through ``on_result``.
It only reads copies: the trainer's state and random generators are untouched, so
``siva replay`` still reproduces the trainer exactly (``best`` itself is not replayed).
"""
from __future__ import annotations

import logging
import threading
import time
from typing import Any, Callable

from siva_core import Processing, Recording, Structure

from .estimate import jsonable
from .store import Store

log = logging.getLogger("siva.service.worker")

#: one refinement at a time in the process (they are CPU-heavy and use numba's threads)
REFINE_LOCK = threading.Lock()


class Refiner:
    """A job slot and a daemon thread that empties it (one per system)."""

    def __init__(self, name: str, structure: Structure, store: Store, *,
                 on_result: Callable[[dict[str, Any], dict[str, Any]], None],
                 on_error: Callable[[str], None],
                 step: Callable[[], bool] | None = None) -> None:
        self.name = name
        self.structure = structure
        self.store = store
        self._on_result = on_result
        self._on_error = on_error
        self._step = step
        self._poked = True  # look for work once at start
        self._stop = threading.Event()
        self._cv = threading.Condition()
        self._job: dict[str, Any] | None = None
        self._thread = threading.Thread(target=self._loop, name=f"siva-refine-{name}",
                                        daemon=True)

    def start(self) -> None:
        self._thread.start()

    def request_stop(self) -> None:
        self._stop.set()
        with self._cv:
            self._cv.notify_all()

    def stop(self, timeout: float) -> None:
        """A refinement cannot be interrupted; its result is simply dropped (daemon thread)."""
        self.request_stop()
        if self._thread.is_alive():
            self._thread.join(max(0.0, timeout))

    def is_alive(self) -> bool:
        return self._thread.is_alive()

    def poke(self) -> None:
        """New records are stored: run ``step`` until it has nothing left to do."""
        with self._cv:
            self._poked = True
            self._cv.notify_all()

    def submit(self, job: dict[str, Any]) -> None:
        """Queue ``job`` (keys: version, epoch, candidates, train, processing)."""
        with self._cv:
            self._job = job  # a job not yet started is superseded by this one
            self._cv.notify_all()

    def _loop(self) -> None:
        while not self._stop.is_set():
            with self._cv:
                while self._job is None and not self._poked and not self._stop.is_set():
                    self._cv.wait(30.0)
                job, self._job = self._job, None
                self._poked = False
            if self._stop.is_set():
                continue
            if job is not None:
                try:
                    best = self.run(job)
                except Exception as exc:  # noqa: BLE001 - never kills the thread or the service
                    log.exception("%s: refinement failed", self.name)
                    self._on_error(f"refinement failed: {type(exc).__name__}: {exc}")
                    best = None
                if best is not None:
                    self._on_result(best, job)
            while self._step is not None and not self._stop.is_set():
                try:
                    if not self._step():
                        break
                except Exception as exc:  # noqa: BLE001 - a bad record must not stop monitoring
                    log.exception("%s: monitoring step failed", self.name)
                    self._on_error(f"monitoring failed: {type(exc).__name__}: {exc}")
                    break

    def run(self, job: dict[str, Any]) -> dict[str, Any] | None:
        """``recommend_best`` on the job's records, re-parsed from the store.  None when a
        record was deleted meanwhile or the service stops."""
        from siva_core import recommend_best

        t0 = time.perf_counter()
        by_id = {m.id: m for m in self.store.recordings(self.name)}
        recs = []
        for rid in job["train"]:
            meta = by_id.get(rid)
            if meta is None:
                return None  # deleted meanwhile
            raw = self.store.read_raw(self.name, meta)
            recs.append(Recording.read(raw, self.structure.dofs, name=rid, fmt=meta.fmt,
                                       **meta.read_options(self.structure)))
        proc = job["processing"] if job["processing"] is not None else Processing()
        with REFINE_LOCK:
            if self._stop.is_set():
                return None
            rec = recommend_best(self.structure, job["candidates"], recs, proc)
        params: dict[str, Any] = {}
        for k, p in enumerate(self.structure.free):
            v = float(rec.theta[k])
            s = None if rec.std is None else float(rec.std[k])
            params[p] = {"value": v, "std": s,
                         "ci95": None if s is None else [v - 1.96 * s, v + 1.96 * s]}
        seconds = time.perf_counter() - t0
        log.info("%s: best from %d candidates on %d record(s) in %.1f s (refined=%s, "
                 "output error %.3g)", self.name, len(job["candidates"]), len(recs), seconds,
                 rec.refined, rec.output_error if rec.output_error is not None else float("nan"))
        return jsonable({
            "parameters": params, "epoch": job["epoch"], "n_records": len(recs),
            "time": time.time(), "output_error": rec.output_error,
            "refined": rec.refined, "records": job["train"], "n_candidates": len(job["candidates"]),
            "approach_III": self.structure.as_dict(rec.theta_III), "note": rec.note,
            "seconds": seconds})
