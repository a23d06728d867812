"""What a stage's outcome means for the search: a lead kept tentatively (a part of a
larger gap), a gap explained (no further stage), and the named effect polished and its
coefficients refreshed before the next stage builds on it."""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from ..processing import Processing
from ..recording import Recording
from .fitting import continue_fit
from .outputs import Progress, _say
from .results import Candidate
from .scoring import judge as _judge
from .settings import DiagnoseSettings


def partial_lead(rule: dict[str, Any], ranking: Sequence[Candidate],
             settings: DiagnoseSettings) -> bool:
    """The best candidate was refused for its size or for a rival of another kind, not for
    noise or inconsistency, and closes at least ``settings.step_min`` of the gap: possibly
    one of several effects (with two real effects the other one *is* a rival of another
    kind, measured: coulomb m1-ground + velocity-squared damper m3-ground on the chain,
    closure 0.30, separation failed), or for a record it leaves worse (issue 16: the right
    coulomb LO-ground closed 0.73 but left the 899 N record 51 x worse, the second effect
    missing).  It is kept tentatively; the set is named only if the
    final rule passes on it (and the backward step keeps it)."""
    checks = rule.get("checks") or {}
    return bool(ranking and checks and checks["above_noise"]
                and not (checks["closure"] and checks["separation"] and checks["consistent"])
                and ranking[0].closure >= settings.step_min)


def large_part(ranking: Sequence[Candidate], gap_before: float, noise: float | None,
               settings: DiagnoseSettings) -> dict[str, float] | None:
    """The best candidate is kept tentatively, whatever its closure, when the part of the
    gap it removes is itself at least ``faint_noise`` x the spectral noise floor (and the
    gap at least as large): several effects, none closing half the gap alone, each many
    times the noise.  ``partial_lead`` needs ``step_min`` of the whole gap and a gap above
    the stage's floor, which is capped by the best *train* cost: with two effects acting
    at different amplitudes neither holds (fresh seed 17335: a cubic damper m1-m4 lowered
    the train cost 0.121 -> 0.015 but closed 0.20 of the validation gap, 75 x the floor
    removed; the coulomb m1-m2, strong at the small validation amplitudes, was never
    screened from the nominal model; seed 17330: a poor nominal fit, train cost 0.43,
    made the stage's floor 0.31 against a spectral one of 0.0021, and the gap read as
    "at the noise level").  Returns the numbers (for the stage's entry), or None.  What is
    named is still decided by the set rule (``sets.choose_set``); a tentative effect is
    never named alone."""
    if not ranking or noise is None or not noise > 0 or not np.isfinite(gap_before):
        return None
    top = ranking[0]
    if top.reading or not np.isfinite(top.gap_after):
        return None
    removed = gap_before - top.gap_after
    if gap_before < settings.faint_noise * noise or removed < settings.faint_noise * noise:
        return None
    return {"removed": float(removed), "removed_x_floor": float(removed / noise),
            "gap_x_floor": float(gap_before / noise), "closure": float(top.closure),
            "faint_noise": settings.faint_noise}


def refresh_coefficients(verdicts: Sequence[Candidate]) -> None:
    """Earlier structural effects were re-fitted jointly with the later ones: report their
    coefficients from the last fit (their stage-1 intervals no longer apply)."""
    last = next((v for v in reversed(verdicts) if v.category == "structure"), None)
    if last is None or last.structure is None or last.theta is None:
        return
    values = last.structure.as_dict(last.theta)
    for v in verdicts:
        if v is last or v.category != "structure" or not v.names:
            continue
        new = {k: values[p] for k, p in v.names.items() if p in values}
        if new:
            v.coefficients, v.intervals = new, {}


def explained(v: Candidate, settings: DiagnoseSettings, noise: float | None) -> bool:
    """No further stage after ``v``: what it leaves is below ``gap_min`` *and* within
    ``kind_check_noise`` x the spectral noise floor (issue 16: a clearance closing 0.857
    left 0.0025, below the fixed floor but 4 x the noise, and the missing damper of the
    pair was never looked for)."""
    return bool(v.gap_after <= settings.gap_min and (
        noise is None or v.gap_after <= settings.kind_check_noise * noise))


def polish(v: Candidate, train: Sequence[Recording], val: Sequence[Recording],
            proc: Processing, settings: DiagnoseSettings, gap: float, blocks: np.ndarray,
            progress: Progress | None) -> None:
    """More evaluations for a stage's verdict before the next stage builds on it."""
    cost = v.train_cost
    try:
        continue_fit(v, train, proc, settings.fit_nfev)
    except Exception as exc:  # noqa: BLE001 - the stage's fit stands
        _say(progress, f"{v.label()}: polishing fit failed ({exc})")
        return
    if v.train_cost < cost:
        _judge(v, val, proc, gap, blocks, progress)
