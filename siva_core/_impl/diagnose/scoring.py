"""How a fitted model is judged: its output error on the validation records, in total and
per record, against the nominal model's (the gap it closes)."""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ..processing import Processing
from ..recording import Recording
from ..structure import Structure
from .outputs import Progress, _Outputs, _say
from .results import Candidate, _num


def validation_gap(structure: Structure, theta: np.ndarray, val: Sequence[Recording],
                   proc: Processing) -> tuple[float, np.ndarray]:
    """Normalised output error of ``theta`` on ``val`` and its (record x DOF) blocks;
    infinite when the simulation diverges."""
    outs = _Outputs(structure, val, proc, theta)
    r = outs.residuals(theta)[0]
    if not np.all(np.isfinite(r)):
        return math.inf, np.full((len(val), structure.n_dof), np.inf)
    return float(r @ r), outs.blocks(r)


def judge(c: Candidate, val: Sequence[Recording], proc: Processing, gap_before: float,
          before_blocks: np.ndarray, progress: Progress | None = None) -> None:
    """The candidate's validation gap, closure and per-record closures (in place)."""
    c.gap_before = gap_before
    c.gap_after, after_blocks = validation_gap(c.structure, c.theta, c.correct(val), proc)
    c.closure = 1.0 - c.gap_after / gap_before if gap_before > 0 else 0.0
    c.per_record = []
    for j, rec in enumerate(val):
        gb, ga = float(before_blocks[j].mean()), float(after_blocks[j].mean())
        c.per_record.append({"record": rec.name, "gap_before": gb,
                             "gap_after": _num(ga),
                             "closure": _num(1 - ga / gb) if gb > 0 else None})
    _say(progress, f"{c.label()}: closure {c.closure:.3f} (val gap {gap_before:.4g} -> "
                   f"{c.gap_after:.4g}; train {c.train_cost:.4g}; {c.fit_time_s:.1f} s) "
                   + ", ".join(f"{k}={v:.4g}" for k, v in c.coefficients.items()))
