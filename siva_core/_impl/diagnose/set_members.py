"""The members of a fitted set (issue 16): each one's coefficients in the joint fit, and
each one's own contribution to the simulated validation outputs (``sets.choose_set``'s
check that every named effect shows above the noise)."""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ..processing import Processing
from ..recording import Recording
from .outputs import _Outputs
from .results import Candidate
from .set_fit import SetFit
from .settings import DiagnoseSettings


def member_coefficients(s: Candidate) -> list[dict[str, float]]:
    """Each structural member's coefficients in the set's joint fit (by its parameter
    names: the first member's names survive in the augmented model)."""
    if not isinstance(s, SetFit) or s.structure is None or s.theta is None:
        return [dict(s.coefficients)]
    vals = s.structure.as_dict(s.theta)
    out = []
    for m in s.members:
        if m.category == "sensor":
            out.append(dict(m.coefficients))
        else:
            out.append({k: vals[p] for k, p in m.names.items() if p in vals})
    return out


def contributions(s: Candidate, val: Sequence[Recording], proc: Processing) -> list[float]:
    """Each structural member's own contribution to the simulated validation outputs, in
    the gap's units (NMSE): the squared output change when its magnitude is set to zero,
    the rest of the fit held.  Sensor members: the change of the records their
    correction makes, the same way (nominal outputs held)."""
    if s.structure is None or s.theta is None:
        return []
    members = s.members if isinstance(s, SetFit) else [s]
    outs = _Outputs(s.structure, s.correct(val), proc, s.theta)
    r0 = outs.residuals(s.theta)[0]
    result = []
    for m in members:
        if m.category == "sensor":
            raw = _Outputs(s.structure, val, proc, s.theta).residuals(s.theta)[0]
            result.append(float((raw - r0) @ (raw - r0)) if raw.shape == r0.shape
                          else math.inf)
            continue
        names = m.names if isinstance(s, SetFit) else s.names
        p = names.get(m.effect.magnitude)
        if p is None or p not in s.structure.free:
            result.append(math.inf)
            continue
        th = np.array(s.theta, float)
        th[s.structure.free.index(p)] = 0.0
        r1 = outs.residuals(th)[0]
        d = r1 - r0
        result.append(float(d @ d) if np.all(np.isfinite(d)) else math.inf)
    return result


def below_noise(contribution: float, noise: float | None, settings: DiagnoseSettings) -> bool:
    """Whether a member's own contribution fails to show above the noise
    (``contribution_noise`` x the spectral floor; never without a floor)."""
    return noise is not None and not contribution > settings.contribution_noise * noise
