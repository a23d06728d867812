"""A set without the members that do not show (issue 16, branch placeriv).

A set that passes every check but one member's own contribution (``set_members.shown``)
is refused whole, and a smaller set that never held the right member is named instead
(fresh seed 17676: cubic damper m1-m3 + damper m2-ground + damper m3-ground closed 0.999
with the m2-ground damper moving the outputs by 2e-6; refused, the pair with a cubic
damper m2-ground was chosen and its law swapped to a damper m2-ground: the place came
from the stage that fitted the m2-ground damper first, the pair with the right damper
m3-ground was never fitted).  A member that does not move the outputs is a member the
set does not need, so the set *without* it is fitted jointly from the set's own values
(the remaining members, the nominal parameters) and judged as every other set; no
threshold is added.  Only sets that keep two members or more: a single is judged by the
single rule.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from ..processing import Processing
from ..recording import Recording
from ..structure import Structure
from .budget import clock_of
from .outputs import Progress, _say
from .set_fit import SetFit, _refit, finish_set
from .set_members import members_model
from .settings import DiagnoseSettings


def without_members(s: SetFit, drop: Sequence[int], structure: Structure,
                    train: Sequence[Recording], val: Sequence[Recording],
                    proc: Processing, gap_before: float, before_blocks: np.ndarray,
                    settings: DiagnoseSettings, progress: Progress | None = None
                    ) -> SetFit | None:
    """``s`` without its members ``drop``, re-fitted jointly from ``s``'s values, within
    the time budget; None when fewer than two members stay or it cannot be fitted."""
    keep = [k for k in range(len(s.members)) if k not in set(drop)]
    if len(keep) < 2 or s.structure is None or s.theta is None:
        return None
    label = " + ".join(s.members[k].label() for k in keep)
    return clock_of(settings).run(
        "pruned set", label, lambda: _fit(s, keep, structure, train, val, proc,
                                          gap_before, before_blocks, settings, progress))


def _fit(s: SetFit, keep: Sequence[int], structure: Structure, train: Sequence[Recording],
         val: Sequence[Recording], proc: Processing, gap_before: float,
         before_blocks: np.ndarray, settings: DiagnoseSettings,
         progress: Progress | None) -> SetFit | None:
    base, start, members = members_model(structure, s, keep)
    last = next((o for o in reversed(members) if o.category == "structure"), None)
    if last is None:
        return None
    sensor = s.sensor if any(s.sensor is s.members[k] for k in keep) else None
    recs = sensor.correct(train) if sensor is not None else list(train)
    try:
        theta, cost, res = _refit(base, [base.vector(start)], recs, proc, settings.fit_nfev)
    except Exception as exc:  # noqa: BLE001 - a set that cannot be fitted is none
        _say(progress, f"set {s.label()} without its silent members: fit failed ({exc})")
        return None
    got = base.as_dict(theta)
    out = SetFit(last.effect, last.loc, {c: got[p] for c, p in last.names.items()
                                         if c != last.effect.magnitude},
                 structure=base, names=dict(last.names), theta=np.asarray(theta, float),
                 fitted=True, amplitudes=last.amplitudes, members=members, sensor=sensor,
                 note=f"{s.label()} without its members that do not show")
    _say(progress, f"set {s.label()}: a member does not show, re-fitted without it")
    return finish_set(out, cost, res, val, proc, gap_before, before_blocks, progress)
