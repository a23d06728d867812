"""The typed seams between the trainer's parts: frozen values handed between threads.

Why frozen dataclasses: the trainer thread, the refiner thread and the HTTP readers share
these; a value that cannot change after it is built needs no lock, and a field list says
what crosses a seam (no ``dict[str, Any]`` whose keys only the writer knows).  The JSON
shapes the HTTP API serves are built from them at the edge (``to_json``).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from siva_core import Processing, Recording

from ..monitoring.monitor_values import HeadlineEstimate


@dataclass(frozen=True)
class DataSet:
    """The records the trainer uses from epoch ``epoch`` on (``version`` counts changes)."""

    version: int
    epoch: int
    train: tuple[str, ...]
    validation: tuple[str, ...]
    processing: Processing | None


@dataclass(frozen=True)
class ParameterValue:
    """One parameter of a point estimate: value, standard error and 95 % interval."""

    value: float
    std: float | None
    ci95: tuple[float, float] | None
    n: int | None = None


@dataclass(frozen=True)
class Best:
    """An output-error point estimate (``recommend_best``, or the monitor's headline)."""

    parameters: dict[str, ParameterValue]
    epoch: int
    n_records: int
    time: float
    records: tuple[str, ...]
    source: Literal["recommend_best", "records"]
    method: str
    output_error: float | None = None
    refined: bool | None = True
    note: str | None = None
    approach_III: dict[str, float] | None = None
    n_candidates: int | None = None
    seconds: float | None = None
    modal: dict[str, Any] | None = None

    def theta(self, names: list[str]) -> np.ndarray:
        return np.array([self.parameters[p].value for p in names], dtype=float)

    def to_json(self) -> dict[str, Any]:
        """The ``best`` key of GET .../estimate (schemas.Best)."""
        out: dict[str, Any] = {
            "parameters": {p: {"value": v.value, "std": v.std,
                               "ci95": None if v.ci95 is None else list(v.ci95),
                               **({"n": v.n} if v.n is not None else {})}
                           for p, v in self.parameters.items()},
            "epoch": self.epoch, "n_records": self.n_records, "time": self.time,
            "records": list(self.records), "source": self.source, "method": self.method,
            "output_error": self.output_error, "refined": self.refined}
        for key in ("note", "approach_III", "n_candidates", "seconds", "modal"):
            v = getattr(self, key)
            if v is not None:
                out[key] = v
        return out


@dataclass(frozen=True)
class RefineJob:
    """Work for the refiner thread, from the trainer thread.

    ``kind = "best"``: Approach III over ``candidates`` and the output-error refinement on
    ``refine_records`` (the first ``best``); then (``anchor``) the first anchor job.
    ``kind = "anchor"``: only the linearisation, at ``theta`` (None: the current headline),
    settled at the output-error optimum of ``data``'s training records (the first anchor,
    or a re-anchor after the data changed)."""

    kind: Literal["best", "anchor"]
    data: DataSet
    epoch: int
    train_records: tuple[Recording, ...]
    val_records: tuple[Recording, ...]
    n_noise: int
    seed: int
    candidates: np.ndarray | None = None
    theta: np.ndarray | None = None           # None: the headline when the job runs
    refine_records: tuple[Recording, ...] = ()
    anchor: bool = True                       # also linearise (the output-error phase)


@dataclass(frozen=True)
class Anchor:
    """Where the output-error phase is linearised: ``theta`` on the records of ``data``.

    Everything ``siva replay`` needs to rebuild the same linearisation bit for bit (the
    records come from the log, the chain from ``data.processing``): theta, the record ids,
    the bootstrap replicate count and seed.  ``linearization``/``val_linearization`` are
    the computed objects (not logged: recomputed deterministically)."""

    theta: np.ndarray
    data: DataSet
    source: str
    n_noise: int
    seed: int
    linearization: Any = field(default=None, compare=False, repr=False)
    val_linearization: Any = field(default=None, compare=False, repr=False)


@dataclass(frozen=True)
class RecordVerdict:
    record: str
    T: float | None
    p_value: float | None
    verdict: Literal["accepted", "rejected"] | None
    n_eff: float | None = None
    error: str | None = None


@dataclass(frozen=True)
class Verdict:
    """``validation_score`` of one parameter set on the validation records."""

    of: Literal["headline", "ensemble"]
    theta: dict[str, float]
    verdict: Literal["accepted", "rejected"]
    T: float | None
    p_value: float | None
    alpha: float
    tolerance: float
    per_record: tuple[RecordVerdict, ...]
    records: tuple[str, ...]
    time: float
    seconds: float

    def to_json(self) -> dict[str, Any]:
        return {"of": self.of, "verdict": self.verdict, "T": self.T, "p_value": self.p_value,
                "alpha": self.alpha, "tolerance": self.tolerance,
                "per_record": [{"record": r.record, "T": r.T, "p_value": r.p_value,
                                "verdict": r.verdict, "n_eff": r.n_eff,
                                **({"error": r.error} if r.error else {})}
                               for r in self.per_record],
                "records": list(self.records), "parameters": dict(self.theta),
                "time": self.time, "seconds": self.seconds}


@dataclass(frozen=True)
class ValidationJob:
    """Validate the headline and the ensemble mean on the validation records of ``data``."""

    data: DataSet
    records: tuple[Recording, ...]
    headline: np.ndarray | None
    ensemble: np.ndarray | None
    key: tuple[Any, ...]


def best_from(d: Any) -> Best | None:
    """A :class:`Best` from its JSON (a checkpoint, the monitor's view)."""
    if not d or not d.get("parameters"):
        return None
    params = {p: ParameterValue(float(v["value"]), v.get("std"),
                                None if not v.get("ci95") else (v["ci95"][0], v["ci95"][1]),
                                v.get("n"))
              for p, v in d["parameters"].items() if v.get("value") is not None}
    src = "records" if d.get("source") == "records" else "recommend_best"
    return Best(params, int(d.get("epoch") or 0), int(d.get("n_records") or 0),
                float(d.get("time") or time.time()), tuple(d.get("records") or ()), src,
                str(d.get("method") or ""), output_error=d.get("output_error"),
                refined=d.get("refined"), note=d.get("note"),
                approach_III=d.get("approach_III"), n_candidates=d.get("n_candidates"),
                seconds=d.get("seconds"), modal=d.get("modal"))


def best_from_headline(h: HeadlineEstimate | None, epoch: int) -> Best | None:
    """The monitor's headline as a :class:`Best` (``source = "records"``), from ``epoch``."""
    if h is None or not h.parameters:
        return None
    params = {p: ParameterValue(float(v["mean"]), v.get("std"),
                                None if not v.get("ci95") else (v["ci95"][0], v["ci95"][1]),
                                v.get("n"))
              for p, v in h.parameters.items() if v.get("mean") is not None}
    return Best(params, int(epoch or 0), int(h.n_records or 0), float(h.time or time.time()),
                tuple(h.records), "records", h.method or "", output_error=None, refined=True,
                modal=h.modal)
