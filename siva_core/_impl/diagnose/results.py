"""What a diagnosis produces: locations, candidates (screened, fitted) and the whole result."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

from ..effects import Amplitudes, Effect
from ..processing import Processing
from ..recording import Recording
from ..structure import Structure


@dataclass
class Location:
    """Where an element goes: DOF indices (j = -1 for ground) and names."""

    i: int
    j: int
    between: tuple[str, str]


@dataclass
class Candidate:
    """One effect at one location: its screening score and, if fitted, its gaps."""

    effect: Effect
    loc: Location
    shape: dict[str, float]
    score: float = 0.0            # share of the nominal train residual explained (linear)
    estimate: float = 0.0         # Gauss-Newton estimate of the magnitude
    admissible: bool = True       # estimate has the physical sign
    fitted: bool = False
    theta: np.ndarray | None = None
    structure: Structure | None = None
    coefficients: dict[str, float] = field(default_factory=dict)
    parameters: dict[str, float] = field(default_factory=dict)
    train_cost: float = math.nan
    gap_before: float = math.nan
    gap_after: float = math.nan
    closure: float = math.nan
    per_record: list[dict[str, Any]] = field(default_factory=list)
    fit_time_s: float = 0.0
    note: str = ""
    stopped: bool = False         # its fit was cut short: it could not win (early stop)
    ee_score: float = 0.0         # share of the equation-error residual explained
    ee_start: tuple[dict[str, float], dict[str, float]] | None = None  # joint equation-
    # error solution (nominal parameters, new coefficients): a fit start
    ee_shape: dict[str, float] = field(default_factory=dict)
    names: dict[str, str] = field(default_factory=dict)   # coefficient -> new parameter
    scan_cost: float = math.inf   # train cost at the best point of the magnitude scan
    scan_theta: np.ndarray | None = None   # best scan point + its Gauss-Newton re-tune
    scan_raw: np.ndarray | None = None     # the best scan point itself
    intervals: dict[str, tuple[float, float]] = field(default_factory=dict)  # 95 %
    amplitudes: Amplitudes | None = None   # what an element here sees (nominal, train)
    closure_added: float = math.nan  # in a named set: the share of the nominal gap the
    # set loses without this member (what it adds)
    contribution: float = math.nan   # its own output change on the validation records
    rivals: list[dict[str, Any]] = field(default_factory=list)  # look-alikes the data
    # cannot separate from it: [{"candidate", "closure"}]
    reading: bool = False  # a force gain the pulse's reading explains: never named
    # (``pulse_reading``)
    nuisances: list["Candidate"] = field(default_factory=list)  # in a named set: the
    # pulse-reading gains fitted with it, never named (``sets.choose_set``)

    @property
    def key(self) -> tuple[str, tuple[str, str]]:
        return (self.effect.kind, self.loc.between)

    @property
    def category(self) -> str:
        """"sensor" for a measurement fault, "structure" for a missing element."""
        return "sensor" if self.effect.family == "sensor" else "structure"

    def label(self) -> str:
        if self.category == "sensor":
            return f"{self.effect.kind} {self.loc.between[0]}"
        return f"{self.effect.kind} {self.loc.between[0]}-{self.loc.between[1]}"

    def correct(self, records: Sequence[Recording]) -> list[Recording]:
        """The records this candidate's model is compared with (a sensor fault corrects
        them; a structural candidate leaves them as measured)."""
        if self.category != "sensor" or self.effect.magnitude not in self.coefficients:
            return list(records)
        from .sensor_faults import corrected

        return corrected(records, self.effect, self.loc.between[0],
                         self.coefficients[self.effect.magnitude])

    def verdict_json(self) -> dict[str, Any]:
        """The verdict entry: what, where, how big (with 95 % interval and units), why."""
        from .units import coefficient_units

        out: dict[str, Any] = {
            "category": self.category, "kind": self.effect.kind,
            "between": [self.loc.between[0]] if self.category == "sensor"
            else list(self.loc.between),
            "effect": self.effect.name, "family": self.effect.family,
            "closure": _num(self.closure), "coefficients": _clean(self.coefficients),
            "intervals": {k: [_num(lo), _num(hi)] for k, (lo, hi) in self.intervals.items()},
            "units": coefficient_units(self.effect, self.coefficients),
            "explanation": self.effect.describe(self.coefficients)}
        if self.category == "sensor":
            out["channel"] = self.loc.between[0]
        if np.isfinite(self.closure_added):
            out["closure_added"] = float(self.closure_added)
        if np.isfinite(self.contribution):
            out["contribution"] = float(self.contribution)
        if self.rivals:
            out["rivals"] = list(self.rivals)
        return out

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "category": self.category, "kind": self.effect.kind,
            "between": list(self.loc.between),
            "gap_before": _num(self.gap_before), "gap_after": _num(self.gap_after),
            "closure": _num(self.closure), "effect": self.effect.name,
            "family": self.effect.family, "coefficients": _clean(self.coefficients),
            "parameters": _clean(self.parameters), "train_cost": _num(self.train_cost),
            "screen_score": _num(self.score), "per_record": self.per_record,
            "fit_time_s": round(self.fit_time_s, 3)}
        if self.note:
            out["note"] = self.note
        return out


@dataclass
class Diagnosis:
    """Everything a diagnosis produced; ``to_json`` gives the CONTRACT shape (extended)."""

    verdict: Candidate | None
    ranking: list[Candidate]
    verdicts: list[Candidate]
    screened: list[Candidate]
    where: dict[str, Any]
    nominal: dict[str, Any]
    rule: dict[str, Any]
    processing: Processing
    timing: dict[str, float]
    structure: Structure
    theta_nominal: np.ndarray
    train: list[Recording]
    val: list[Recording]
    plots: dict[str, Any] = field(default_factory=dict, repr=False)  # HTML report data
    signatures: dict[str, Any] = field(default_factory=dict)
    stages: list[dict[str, Any]] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        v = self.verdict.verdict_json() if self.verdict is not None else None
        return {
            "verdict": v,
            "verdicts": [c.verdict_json() for c in self.verdicts],
            "ranking": [c.to_json() for c in self.ranking],
            "where": self.where,
            "nominal": self.nominal,
            "rule": self.rule,
            "screening": [{"kind": c.effect.kind, "between": list(c.loc.between),
                           "shape": _clean(c.shape), "score": _num(c.score),
                           "estimate": _num(c.estimate), "admissible": c.admissible,
                           "ee_score": _num(c.ee_score),
                           "fitted": c.fitted} for c in self.screened],
            "processing": self.processing.describe() if hasattr(self.processing, "describe")
            else repr(self.processing),
            "records": {"train": [r.name for r in self.train], "val": [r.name for r in self.val]},
            "timing_s": {k: round(v, 3) for k, v in self.timing.items()},
            "signatures": self.signatures,
            "stages": self.stages,
        }


def _num(x: float) -> float | None:
    return None if x is None or not np.isfinite(x) else float(x)


def _clean(d: Mapping[str, float]) -> dict[str, float | None]:
    return {k: _num(v) for k, v in d.items()}
