"""Restarts of a poor nominal fit from damping spread over the elements (step 1 of the method).

Output error in the dampers has local minima: the equation-error start puts the damping of a
mode on whichever element the noise favours, and refine then trades one damper against its
neighbour (17007: c_m1g 123, c_m1m2 -2.9 N s/m where the truth has 58.8 / 59.4; the fit
stayed at train cost 0.177 against the truth's 0.146).  A start with the damping spread over
the elements in proportion to their springs (stiffness-proportional damping, the usual
engineering default: a joint's losses grow with its stiffness) at the fit's own modal damping
leaves that basin; refine frees every damper again from there.
"""
from __future__ import annotations

import copy
import math
from typing import Sequence

import numpy as np

from ..processing import Processing
from ..recording import Recording
from ..structure import Structure
from .outputs import Progress, _say
from .settings import FAST, DiagnoseSettings

#: a restart replaces the fit only when it lowers the train cost this many times: a fit that
#: is poor because an effect is missing is not improved that much by moving its dampers, and a
#: small gain would only move the nominal point the later stages start from (the quieter
#: starts' lesson on lono:two:0, 0.114 -> 0.103, changed that diagnosis)
RESTART_GAIN = 2.0

#: the element kinds kept by ``linear_refit``
LINEAR_KINDS = ("spring", "damper")

#: the damping ratio assumed when the fit's lowest mode has none usable
DEFAULT_ZETA = 0.01


def spread_damping(structure: Structure, theta: np.ndarray) -> np.ndarray | None:
    """``theta`` with every free linear damper set to beta x the stiffness of the spring
    beside it (same two ends), beta giving the lowest linear mode of ``theta`` its damping
    ratio (zeta_1 = beta omega_1 / 2); None when no damper has a spring beside it or the
    modes are not usable."""
    free = list(structure.free)
    th = np.array(theta, float)
    try:
        modes = structure.linear_modes(th)
        values = structure.full_values(th)
    except Exception:  # noqa: BLE001 - no modes, no restart
        return None
    if not modes["frequency_hz"]:
        return None
    w1 = 2 * math.pi * float(modes["frequency_hz"][0])
    zeta = float(modes["damping_ratio"][0])
    if not (np.isfinite(zeta) and 0.0 < zeta < 0.5):
        zeta = DEFAULT_ZETA
    if not w1 > 0:
        return None
    beta = 2.0 * zeta / w1
    springs = {frozenset(el.between): float(np.asarray(values[el.params[0]]).ravel()[0])
               for el in structure.elements if el.kind.name == "spring"}
    changed = False
    for el in structure.elements:
        if el.kind.name != "damper" or el.params[0] not in free:
            continue
        k = springs.get(frozenset(el.between))
        if k is None or not k > 0:
            continue
        th[free.index(el.params[0])] = beta * k
        changed = True
    return th if changed else None


#: a free linear spring below this share of the model's stiffest free spring has collapsed
#: (``restored_springs``)
COLLAPSED = 0.01


def restored_springs(structure: Structure, theta: np.ndarray) -> np.ndarray | None:
    """``theta`` with every collapsed free linear spring (below ``COLLAPSED`` x the
    stiffest free one) set to the geometric mean of the others, or None when none has
    collapsed or the fitted model keeps a mode per DOF.

    Why: a poor fit can trade a mode away (fresh seed 17734, a 2-DOF chain with a
    clearance m1-ground and a damper m2-ground, modes 29.6 and 71.7 Hz: from the damping
    spread start the nominal fit drove k_m1g to 251 N/m (truth 2.1e5), a mode at ~0 Hz
    below the high-pass where the records have one at ~30 Hz; train cost 0.285, a
    validation gap of 0.305 that no single effect closed).  A spring of the size of its
    neighbours gives the mode back; refine frees it from there (17734: 0.285 -> 0.073,
    k_m1g 3.05e5).  Kept, as every restart, only when it lowers the train cost
    ``RESTART_GAIN`` x: a spring that is truly soft is not moved."""
    free = list(structure.free)
    th = np.array(theta, float)
    idx = [free.index(el.params[0]) for el in structure.elements
           if el.kind.name == "spring" and el.params and el.params[0] in free]
    if len(idx) < 2:
        return None
    k = np.abs(th[idx])
    low = k < COLLAPSED * k.max()
    if not low.any() or low.all():
        return None
    try:
        if len(structure.linear_modes(th)["frequency_hz"]) >= structure.n_dof:
            return None
    except Exception:  # noqa: BLE001 - no modes to count: the restart is tried
        pass
    th[np.asarray(idx)[low]] = float(np.exp(np.mean(np.log(k[~low]))))
    return th


def linear_refit(structure: Structure, chain: Processing,
                 train: Sequence[Recording]) -> dict[str, float] | None:
    """Equation-error least squares of the model's springs and dampers alone (its
    nonlinear elements removed), or None when it has none or the fit fails.

    Why: on noisy states the regressor of a known cubic spring is correlated with its
    linear spring's, and least squares can hand the stiffness of one to the other: 17052
    (k_m2m3 -2.1e3 with k3 2.8e15, truth 3.9e5 and 4.4e10) and the null 21124 (k_m2m3 -15
    with k3 1.0e13, truth 4.0e4 and 8.7e11) ended their nominal fits there (train 0.71 and
    0.13, the truth's parameters 0.048 on 21124).  Without the nonlinear regressors the
    springs carry the stiffness; the output-error fit then frees the nonlinear coefficients
    from zero."""
    from ..baselines import least_squares

    spec = copy.deepcopy(structure.spec)
    kept = [el for el in spec.get("elements", []) if el.get("kind") in LINEAR_KINDS]
    if len(kept) == len(spec.get("elements", [])):
        return None
    spec["elements"] = kept
    names = {p for el in kept for p in el.get("params", {}).values() if isinstance(p, str)}
    if spec.get("parameters"):
        spec["parameters"] = {k: v for k, v in spec["parameters"].items() if k in names}
    try:
        lin = Structure.from_dict(spec)
        fit = least_squares(lin, [chain.apply(r, lin.dofs) for r in train])
        return {k: float(v) for k, v in lin.as_dict(lin.vector(fit)).items()}
    except Exception:  # noqa: BLE001 - one restart fewer
        return None


def refine_restarts(structure: Structure, train: Sequence[Recording], proc: Processing,
                    starts: Sequence[tuple[str, np.ndarray]], cost: float,
                    settings: DiagnoseSettings, progress: Progress | None,
                    gain: float = RESTART_GAIN) -> tuple[str, np.ndarray, float] | None:
    """(label, theta, train cost) of the best of ``starts`` after refinement, or None when
    none lowers ``cost`` ``gain`` x.  Each start is refined: starting costs do not rank
    basins (the quieter starts measured that on 19000)."""
    from ..refine import output_error, refine

    def stop(stage: int, last: bool, iteration: int, c: float, prob: object = None) -> bool:
        """Speed: on the full records, a restart still above the fit's cost after
        ``stop_after`` iterations would need the rest to halve it (``early_stop``'s
        measurements: the last iterations gain a small factor)."""
        return last and iteration >= settings.stop_after and c > cost

    best: tuple[str, np.ndarray, float] | None = None
    for label, th in starts:
        try:
            res = refine(structure, th, list(train), proc, max_nfev=settings.nominal_nfev,
                         uncertainty=FAST, stop=stop)
            c = float(output_error(structure, res.theta[None], list(train), proc)[0])
        except Exception:  # noqa: BLE001 - a start that cannot be simulated
            continue
        _say(progress, f"nominal restart from {label}: train cost {c:.4g} (was {cost:.4g})")
        if np.isfinite(c) and c * gain < cost and (best is None or c < best[2]):
            best = (label, res.theta, c)
    return best

