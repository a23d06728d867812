"""What a diagnosis produces: locations, candidates (screened, fitted) and the whole result."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from ..effects import Effect
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
    ee_score: float = 0.0         # share of the equation-error residual explained
    ee_start: tuple[dict[str, float], dict[str, float]] | None = None  # joint equation-
    # error solution (nominal parameters, new coefficients): a fit start
    ee_shape: dict[str, float] = field(default_factory=dict)

    @property
    def key(self) -> tuple[str, tuple[str, str]]:
        return (self.effect.kind, self.loc.between)

    def label(self) -> str:
        return f"{self.effect.kind} {self.loc.between[0]}-{self.loc.between[1]}"

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "kind": self.effect.kind, "between": list(self.loc.between),
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

    def to_json(self) -> dict[str, Any]:
        v = None
        if self.verdict is not None:
            c = self.verdict
            v = {"kind": c.effect.kind, "between": list(c.loc.between), "effect": c.effect.name,
                 "family": c.effect.family, "closure": _num(c.closure),
                 "coefficients": _clean(c.coefficients),
                 "explanation": c.effect.describe(c.coefficients)}
        return {
            "verdict": v,
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
        }


def _num(x: float) -> float | None:
    return None if x is None or not np.isfinite(x) else float(x)


def _clean(d: Mapping[str, float]) -> dict[str, float | None]:
    return {k: _num(v) for k, v in d.items()}
