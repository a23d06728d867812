"""The force's spread as a nuisance: where a pulse's width between its few samples is
identifiable, and whether ``best`` and ``linearize`` fit it when not told."""
from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from ..recording import Recording
from ..simulate import grid as _grid


#: fit the pulse's spread only when the top linear mode has fewer than 4 pi (~12.6) samples
#: per period (omega dt >= 0.5): its effect on a mode's amplitude is ~ (omega dt)^2 x the
#: spread change, so at 30x sampling it is ~0.3 % and not identifiable -- fitted there it
#: absorbed other errors and moved the dampings (chain3_end_1k, docs/perf.md 6.4).  Set
#: after seeing chain3_end_1k (30x: worse) and chain4_inner_disp (5.8x: fixed).
SPREAD_MIN_OMEGA_DT = 0.5


#: ``best`` and the output-error phase fit the spread (where identifiable) only when True.
#: Off: on fresh seeds 10000-10019 it fixed chain4_inner_disp (c1 coverage 30 -> 95 %) but
#: broke twodof_end_slow (k1, k2 shifted ~3 se) and chain3_end_1k (docs/perf.md 6.4).
FIT_FORCE_SPREAD_BY_DEFAULT = False


def default_force_spread(structure: Any, theta: Any, records: Sequence[Recording],
                         interp: str | None = None) -> bool:
    """Whether ``best`` and ``linearize`` fit the force's spread when not told."""
    return FIT_FORCE_SPREAD_BY_DEFAULT and force_spread_identifiable(structure, theta, records,
                                                                     interp)


def force_spread_identifiable(structure: Any, theta: Any, records: Sequence[Recording],
                              interp: str | None = None) -> bool:
    """Whether ``best`` and the output-error phase fit the force's spread per record:
    a piecewise-linear force reading and omega_max dt >= ``SPREAD_MIN_OMEGA_DT`` for the
    linearised model at ``theta`` on some record (False when that cannot be computed)."""
    if (interp or _grid.MEASURED_FORCE_INTERP) not in ("linear", "moments"):
        return False
    try:
        f_hz = np.asarray(structure.linear_modes(theta)["frequency_hz"], dtype=float)
    except (KeyError, ValueError, np.linalg.LinAlgError, ZeroDivisionError):
        return False
    f_hz = f_hz[np.isfinite(f_hz)]
    if f_hz.size == 0:
        return False
    dt = max(float(r.dt) for r in records)
    return bool(2 * math.pi * float(f_hz.max()) * dt >= SPREAD_MIN_OMEGA_DT)
