"""A set grown by one member (issue 16: three effects, two structural + a sensor fault).

The pair search names at most two effects; a third one (the generator draws up to two
structural effects and a sensor fault) was named only when the greedy stages happened to
find all three in turn.  Here a fitted set (a pair) gets one more member -- a structural
single at a place the set does not use, or a sensor fault when it has none -- and the
whole set is re-fitted jointly from the set's fit and the member's single fit, the same
way ``sets.fit_pair`` fits a pair: a sensor fault's value is re-tuned with the structural
model (``joint_sensor``), a structural member joins the model on the records the set's
sensor member corrects.  Which sets are grown and how a grown set is judged against its
sub-sets is ``sets.choose_set``'s business.
"""
from __future__ import annotations

import time
from typing import Sequence

import numpy as np

from ..processing import Processing
from ..recording import Recording
from ..structure import Structure
from .joint_sensor import retune_sensor
from .model_edit import augmented
from .outputs import Progress, _say
from .results import Candidate
from .set_fit import SetFit, _refit, finish_set
from .settings import DiagnoseSettings


def can_grow(base: SetFit, c: Candidate) -> bool:
    """``c`` can join ``base``: a sensor fault when the set has none, a structural effect
    at a place no structural member uses."""
    if any(m.key == c.key for m in base.members):
        return False
    if c.category == "sensor":
        return base.sensor is None
    return all(m.loc.between != c.loc.between for m in base.members
               if m.category == "structure")


def grow(base: SetFit, c: Candidate, structure: Structure, train: Sequence[Recording],
         val: Sequence[Recording], proc: Processing, gap_before: float,
         before_blocks: np.ndarray, settings: DiagnoseSettings,
         progress: Progress | None = None) -> SetFit | None:
    """``base`` plus the fitted single ``c``, re-fitted jointly and judged on the
    validation records; None when it cannot be built or simulated."""
    if not can_grow(base, c) or base.structure is None or base.theta is None:
        return None
    t0 = time.perf_counter()
    nfev = settings.fit_nfev
    try:
        vals = base.structure.as_dict(base.theta)
        if c.category == "sensor":  # the set's model on the records c corrects
            aug, names = base.structure, dict(base.names)
            starts = [np.asarray(base.theta, float)]
            nom_c = {p: v for p, v in (c.parameters or {}).items()
                     if p in vals and p in structure.free}
            if nom_c:
                starts.append(aug.vector({**vals, **nom_c}))
            theta, cost, res = _refit(aug, starts, c.correct(train), proc, nfev)
            sensor = c
            effect, loc, shape, amps = base.effect, base.loc, dict(base.shape), base.amplitudes
        else:  # c joins the model, on the records the set's sensor member corrects
            scales = {k: max(abs(v), 1e-12) for k, v in c.coefficients.items()}
            aug, names = augmented(base.structure, c.effect, c.loc, scales)
            start = {**vals, **{names[k]: v for k, v in c.coefficients.items()}}
            theta, cost, res = _refit(aug, [aug.vector(start)], base.correct(train), proc,
                                      nfev)
            sensor = base.sensor
            effect, loc, shape, amps = c.effect, c.loc, dict(c.shape), c.amplitudes
        if sensor is not None:  # the fault's value re-fitted with the grown model
            again = retune_sensor(sensor, aug, theta, train, proc, max(10, nfev // 2))
            if again is not None:
                sensor, theta, cost, res = again
    except Exception as exc:  # noqa: BLE001 - a set that cannot be fitted is not a set
        _say(progress, f"set {base.label()} + {c.label()}: fit failed ({exc})")
        return None
    members = [sensor if m.category == "sensor" else m for m in base.members]
    members += [sensor] if c.category == "sensor" else [c]
    out = SetFit(effect, loc, shape, structure=aug, names=names, theta=theta, fitted=True,
                 amplitudes=amps, members=members, sensor=sensor)
    finish_set(out, cost, res, val, proc, gap_before, before_blocks, progress)
    out.fit_time_s = time.perf_counter() - t0
    return out
