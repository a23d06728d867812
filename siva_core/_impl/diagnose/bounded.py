"""A nominal model whose simulation escapes on the validation records.

A nonlinear coefficient fitted on small train records can be one that makes the larger
validation records escape: a softening cubic spring k + k3 d^2 turns negative beyond
|d| = sqrt(-k/k3) (fresh seed 17471: k3 = -5.8e11 on k = 5.9e4 N/m, i.e. beyond 0.3 mm,
fitted on 29 and 53 N hits; the 132 and 190 N validation hits diverged).  Its validation
gap is then not a number, and read as one it said "the nominal model already fits the
validation records to the noise level (gap nan)".  An escaping model is not a model of
those records at all: the nominal is refitted on the train records with its nonlinear
coefficients at zero (the linear part, which cannot escape) when that one stays bounded on
every validation record; else the records it cannot simulate are left out, with a note.
"""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from ..processing import Processing
from ..recording import Recording
from ..structure import Structure
from .identified import pinned
from .nominal import NominalFit, nonlinear_params
from .outputs import Progress, _say
from .scoring import validation_gap
from .settings import FAST, DiagnoseSettings


def diverging(structure: Structure, theta: np.ndarray, val: Sequence[Recording],
              proc: Processing) -> list[str]:
    """Names of the records whose simulation (or processed output) is not finite."""
    out = []
    for rec in val:
        try:
            ok = bool(np.isfinite(validation_gap(structure, theta, [rec], proc)[0]))
        except Exception:  # noqa: BLE001 - a record that cannot be simulated diverges
            ok = False
        if not ok:
            out.append(rec.name)
    return out


def _linear_refit(structure: Structure, fit: NominalFit, train: Sequence[Recording],
                  proc: Processing, settings: DiagnoseSettings
                  ) -> tuple[np.ndarray, float] | None:
    """(theta with the nonlinear coefficients at 0, its train cost) refitted on train."""
    from ..refine import output_error, refine

    params = [p for p in nonlinear_params(structure) if p in structure.free]
    if not params:
        return None
    st = structure
    for p in params:
        st = pinned(st, p, 0.0)
    keep = [k for k, p in enumerate(structure.free) if p not in params]
    try:
        res = refine(st, fit.theta[keep], list(train), proc,
                     max_nfev=settings.nominal_nfev, uncertainty=FAST, horizons=None)
    except Exception:  # noqa: BLE001 - no bounded refit
        return None
    full = np.zeros_like(fit.theta, dtype=float)
    full[keep] = res.theta
    cost = float(output_error(structure, full[None], list(train), proc)[0])
    return (full, cost) if np.isfinite(cost) else None


def bounded_nominal(structure: Structure, fit: NominalFit, train: Sequence[Recording],
                    val: Sequence[Recording], proc: Processing, settings: DiagnoseSettings,
                    progress: Progress | None = None
                    ) -> tuple[NominalFit, list[Recording], dict[str, Any] | None]:
    """(nominal fit, validation records to judge on, note or None): the fit unchanged
    when it simulates every validation record; else its linear-part refit when that one
    does; else the fit with the records it cannot simulate left out.  Raises when it
    simulates none and no bounded refit exists (no gap can be measured at all)."""
    bad = diverging(structure, fit.theta, val, proc)
    if not bad:
        return fit, list(val), None
    fitted = ", ".join(f"{p} = {v:.3g}" for p, v in structure.as_dict(fit.theta).items()
                       if p in nonlinear_params(structure))
    head = (f"the fitted nominal model ({fitted or 'linear'}) diverges on the validation "
            f"record(s) {', '.join(bad)}")
    lin = _linear_refit(structure, fit, train, proc, settings)
    if lin is not None and not diverging(structure, lin[0], val, proc):
        note = {"diverged": bad, "refit": "linear part", "train_cost": lin[1],
                "train_cost_before": fit.train_cost,
                "text": f"{head}: its nonlinear coefficients, fitted on the smaller train "
                        "records, do not extrapolate; the search starts from the nominal "
                        f"refitted on the train records with them at 0 (train cost "
                        f"{lin[1]:.3g}, was {fit.train_cost:.3g})"}
        _say(progress, f"nominal: {note['text']}")
        return (NominalFit(lin[0], lin[1], f"{fit.start}, nonlinear part at 0 (bounded on "
                           "the validation records)", fit.ls_theta, fit.ls_chain),
                list(val), note)
    kept = [r for r in val if r.name not in bad]
    if not kept:
        raise ValueError(f"diagnose: {head}, every one, and no bounded refit of it exists: "
                         "no validation gap can be measured")
    note = {"diverged": bad, "refit": None,
            "text": f"{head}: those records are left out of the validation"}
    _say(progress, f"nominal: {note['text']}")
    return fit, kept, note
