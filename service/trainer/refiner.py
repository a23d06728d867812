"""The refiner thread: everything slow that the trainer thread must not wait for.

Per system, one daemon thread empties these slots, in this order:

1. a ``best`` job: the first output-error estimate (``siva_core.recommend_best``:
   Approach III over the equation-error ensemble, then the output-error refinement); it
   queues the first anchor job (3.), which runs after the records are fitted (2.);
2. the per-record monitoring (``step``: one output-error fit per new record, the
   headline and the drift test), until no record is left;
3. an ``anchor`` job: the output-error phase's linearisation (``anchoring.py``) at the
   current headline (so the headline already includes the new records), first settled at
   the training records' output-error optimum (``siva_core.settle``);
4. a validation job: ``validation.py``'s test of the headline and the ensemble.

A job not yet started is superseded by a newer one of its kind.  Refinements take turns
in the process, the most urgent first (``priority.py``: per-record fits before a first
``best``, re-anchors and validations, fleet-wide); a re-anchor or validation still waiting
for its turn when its own system gets a new record gives way to that record's fit and runs
after it, on the newest data (it coalesces the records that arrived meanwhile).  Jobs carry
frozen copies (``types.py``); results go back through callbacks and are applied by the trainer thread
between two epochs, so ``siva replay`` can reproduce the trainer exactly from the log.
"""
from __future__ import annotations

import dataclasses
import logging
import threading
import time
from typing import Callable

import numpy as np

from siva_core import Processing, Structure

from .anchoring import build_anchor
from .priority import ANCHOR, BEST, VALIDATION, RefineQueue
from .types import Anchor, Best, ParameterValue, RefineJob, ValidationJob, Verdict
from .validation import validate

log = logging.getLogger("siva.service.worker")

#: one refinement at a time in the process (they are CPU-heavy and use numba's threads),
#: the most urgent first (priority.py)
REFINE_LOCK = RefineQueue()


class Refiner:
    """Job slots and a daemon thread that empties them (one per system)."""

    def __init__(self, name: str, structure: Structure, *,
                 on_best: Callable[[Best, RefineJob], None],
                 on_anchor: Callable[[Anchor], None],
                 on_verdicts: Callable[[ValidationJob, Verdict | None, Verdict | None], None],
                 on_error: Callable[[str], None],
                 headline_theta: Callable[[], np.ndarray | None],
                 step: Callable[[], bool] | None = None) -> None:
        self.name = name
        self.structure = structure
        self._on_best = on_best
        self._on_anchor = on_anchor
        self._on_verdicts = on_verdicts
        self._on_error = on_error
        self._headline_theta = headline_theta
        self._step = step
        self._poked = True  # look for work once at start
        self._stop = threading.Event()
        self._cv = threading.Condition()
        self._best_job: RefineJob | None = None
        self._anchor_job: RefineJob | None = None
        self._validation: ValidationJob | None = None
        self._thread = threading.Thread(target=self._loop, name=f"siva-refine-{name}",
                                        daemon=True)

    # ------------------------------------------------------------------ control
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

    def submit(self, job: RefineJob) -> None:
        with self._cv:  # a job not yet started is superseded by a newer one of its kind
            if job.kind == "best":
                self._best_job = job
            else:
                self._anchor_job = job
            self._cv.notify_all()

    def submit_validation(self, job: ValidationJob) -> None:
        with self._cv:
            self._validation = job
            self._cv.notify_all()


    # ------------------------------------------------------------------ the thread
    def _loop(self) -> None:
        while not self._stop.is_set():
            with self._cv:
                while (self._best_job is None and self._anchor_job is None
                       and self._validation is None and not self._poked
                       and not self._stop.is_set()):
                    self._cv.wait(30.0)
                best_job, self._best_job = self._best_job, None
                self._poked = False
            if self._stop.is_set():
                continue
            if best_job is not None:
                self._guarded(lambda: self._run_best(best_job), "refinement")
            self._monitor()
            with self._cv:
                anchor_job, self._anchor_job = self._anchor_job, None
                vjob, self._validation = self._validation, None
            if anchor_job is not None:
                self._guarded(lambda: self._run_anchor(anchor_job), "re-anchoring")
            if vjob is not None and not self._poked:
                self._guarded(lambda: self._run_validation(vjob), "validation")
            elif vjob is not None:
                self._requeue(validation=vjob)

    def _requeue(self, anchor: RefineJob | None = None,
                 validation: ValidationJob | None = None) -> None:
        """A job that gave way to a new record's fit runs later, unless superseded meanwhile."""
        with self._cv:
            if anchor is not None and self._anchor_job is None:
                self._anchor_job = anchor
            if validation is not None and self._validation is None:
                self._validation = validation
            self._cv.notify_all()

    def _gives_way(self) -> bool:
        """A new record of this system is waiting to be fitted (or the thread stops)."""
        return self._poked or self._stop.is_set()

    def _guarded(self, fn: Callable[[], None], what: str) -> None:
        try:
            fn()
        except Exception as exc:  # noqa: BLE001 - never kills the thread or the service
            log.exception("%s: %s failed", self.name, what)
            self._on_error(f"{what} failed: {type(exc).__name__}: {exc}")

    def _monitor(self) -> None:
        while self._step is not None and not self._stop.is_set():
            try:
                if not self._step():
                    break
            except Exception as exc:  # noqa: BLE001 - a bad record must not stop monitoring
                log.exception("%s: monitoring step failed", self.name)
                self._on_error(f"monitoring failed: {type(exc).__name__}: {exc}")
                break

    # ------------------------------------------------------------------ jobs
    def _run_best(self, job: RefineJob) -> None:
        """``recommend_best`` on the job's records, then the first anchor at it."""
        from siva_core import recommend_best

        t0 = time.perf_counter()
        proc = job.data.processing if job.data.processing is not None else Processing()
        assert job.candidates is not None
        with REFINE_LOCK.hold(BEST):
            if self._stop.is_set():
                return
            rec = recommend_best(self.structure, job.candidates, list(job.refine_records), proc)
        params: dict[str, ParameterValue] = {}
        for k, p in enumerate(self.structure.free):
            v = float(rec.theta[k])
            s = None if rec.std is None or not np.isfinite(rec.std[k]) else float(rec.std[k])
            params[p] = ParameterValue(v, s, None if s is None else (v - 1.96 * s, v + 1.96 * s))
        seconds = time.perf_counter() - t0
        log.info("%s: best from %d candidates on %d record(s) in %.1f s (refined=%s)",
                 self.name, len(job.candidates), len(job.refine_records), seconds, rec.refined)
        best = Best(params, job.epoch, len(job.refine_records), time.time(),
                    tuple(r.name for r in job.refine_records), "recommend_best",
                    "Approach III over the ensemble, then output-error refinement on the "
                    "most recent training records",
                    output_error=rec.output_error, refined=rec.refined, note=rec.note,
                    approach_III=self.structure.as_dict(rec.theta_III),
                    n_candidates=int(len(job.candidates)), seconds=seconds)
        self._on_best(best, job)
        if job.anchor:
            # the first anchor: after the per-record fits (``_loop`` runs the monitor
            # first), at the headline they give -- a second, record-by-record refinement
            # from ``best``, which a refinement stopped short of the optimum needs
            with self._cv:
                if self._anchor_job is None:
                    self._anchor_job = dataclasses.replace(job, kind="anchor", candidates=None,
                                                           refine_records=())

    def _run_anchor(self, job: RefineJob) -> None:
        theta = job.theta if job.theta is not None else self._headline_theta()
        if theta is None:
            return
        at_headline = job.theta is None
        if not self._anchor(job, theta, "headline" if at_headline else "given",
                            gives_way=at_headline, at_headline=at_headline):
            self._requeue(anchor=job)

    def _anchor(self, job: RefineJob, theta: np.ndarray, source: str,
                gives_way: bool = False, at_headline: bool = False) -> bool:
        """The linearisation at ``theta`` (``at_headline``: at the headline as it is when
        the work starts), once settled at the training records' output-error optimum
        (``siva_core.settle``: the linearisation's optimum is then its anchor).
        ``gives_way``: while waiting for its turn, a new record of this system goes first -
        returns False without anchoring (the caller re-queues)."""
        from siva_core import settle

        t0 = time.perf_counter()
        proc = job.data.processing if job.data.processing is not None else Processing()
        with REFINE_LOCK.hold(ANCHOR, self._gives_way if gives_way else None) as turn:
            if not turn:
                return self._stop.is_set()
            if self._stop.is_set():
                return True
            if at_headline:  # records fitted while waiting moved it
                now = self._headline_theta()
                theta = theta if now is None else now
            settled = settle(self.structure, theta, job.train_records, proc)
            if self._stop.is_set():
                return True
            anchor = build_anchor(self.structure, settled.theta, job.data, job.train_records,
                                  job.val_records, source=source, n_noise=job.n_noise,
                                  seed=job.seed)
        if not settled.converged:
            log.warning("%s: the anchor is not at the output-error optimum (last Gauss-Newton "
                        "step %.1f standard errors): the ensemble may be off", self.name,
                        settled.step_se)
        log.info("%s: output-error anchor (%s) on %d+%d record(s) in %.1f s; settled in %d "
                 "Gauss-Newton step(s), last step %.2f standard errors", self.name, source,
                 len(job.train_records), len(job.val_records), time.perf_counter() - t0,
                 settled.steps, settled.step_se)
        self._on_anchor(anchor)
        return True

    def _run_validation(self, job: ValidationJob) -> None:
        """The held-out test of the headline and the ensemble.  While it waits for its turn
        (behind every system's re-anchors) a new record of this system goes first: the
        refiner thread that waits here is the one that fits that record."""
        proc = job.data.processing if job.data.processing is not None else Processing()
        out: list[Verdict | None] = []
        for theta, of in ((job.headline, "headline"), (job.ensemble, "ensemble")):
            if theta is None or self._stop.is_set():
                out.append(None)
                continue
            with REFINE_LOCK.hold(VALIDATION, self._gives_way) as turn:
                if not turn:
                    if not self._stop.is_set():
                        self._requeue(validation=job)
                    return
                out.append(validate(self.structure, theta, job.records, proc, of))  # type: ignore[arg-type]
        self._on_verdicts(job, out[0], out[1])
