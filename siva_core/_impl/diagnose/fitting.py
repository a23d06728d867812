"""Candidate fits (step 4): nominal + one effect by output error on the train records."""
from __future__ import annotations

import math
import time
from typing import Sequence

import numpy as np

from ..effects import Amplitudes
from ..processing import Processing
from ..recording import Recording
from ..structure import Structure
from .model_edit import augmented
from .nominal import _plausible
from .results import Candidate
from .settings import DiagnoseSettings


def fit_candidate(c: Candidate, structure: Structure, theta_nom: np.ndarray,
                  train: Sequence[Recording], proc: Processing, amp: Amplitudes,
                  settings: DiagnoseSettings, force_scale: float) -> None:
    """Fit nominal + candidate by output error on the train records (in place).

    Starts: the nominal fit with the new magnitude at a few multiples of the score test's
    estimate (its best shape), and the joint equation-error solution when there is one;
    each start is costed, the best is refined (growing horizons: a new element shifts the
    phase late in long records, where the landscape has local minima)."""
    from ..refine import output_error, refine

    t0 = time.perf_counter()
    eff = c.effect
    floor = eff.typical_magnitude(amp, c.shape, force_scale)
    ref_mag = c.estimate if c.estimate != 0 else \
        (c.ee_start[1][eff.magnitude] if c.ee_start else floor)
    scales = {**{k: max(abs(v), 1e-12) for k, v in (c.shape or c.ee_shape).items()},
              eff.magnitude: max(abs(ref_mag), floor * 1e-3, 1e-300)}
    aug, names = augmented(structure, eff, c.loc, scales)
    groups: list[np.ndarray] = []
    if c.admissible and c.estimate != 0:
        nominal_values = structure.as_dict(theta_nom)
        batch = []
        for m in eff.starts(c.estimate, floor):
            vals = dict(nominal_values)
            vals.update({names[k]: v for k, v in c.shape.items()})
            vals[names[eff.magnitude]] = m
            batch.append(aug.vector(vals))
        groups.append(np.stack(batch))
    if c.ee_start is not None:
        nominal_ee, coeffs_ee = c.ee_start
        th_ee = aug.vector({**nominal_ee, **{names[k]: v for k, v in coeffs_ee.items()}})
        if _plausible(aug, th_ee, min(r.fs for r in train)):
            groups.append(th_ee[None])
    if not groups:
        raise ValueError("no admissible start (negative magnitude for a signed effect)")
    best_cost, th0 = math.inf, None
    for batch in groups:  # separately: a batch takes the substeps of its stiffest set
        try:
            costs = output_error(aug, batch, list(train), proc)
        except Exception:  # noqa: BLE001 - a start that cannot be simulated is skipped
            continue
        k = int(np.argmin(costs))
        if costs[k] < best_cost:
            best_cost, th0 = float(costs[k]), batch[k]
    if th0 is None:
        raise ValueError("every start diverges")
    res = refine(aug, th0, list(train), proc, max_nfev=settings.fit_nfev)
    c_ref = float(output_error(aug, res.theta[None], list(train), proc)[0])
    theta, cost = (res.theta, c_ref) if c_ref <= best_cost else (th0, best_cost)
    c.structure, c.theta = aug, theta
    vals = aug.as_dict(theta)
    c.coefficients = {k: vals[p] for k, p in names.items()}
    c.parameters = {p: vals[p] for p in structure.free}
    c.train_cost = cost
    c.fitted = True
    c.fit_time_s = time.perf_counter() - t0
