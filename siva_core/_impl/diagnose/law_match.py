"""One force law expressed in another (issue 16's look-alike laws): the magnitudes at
which a look-alike law's force matches a fitted element's force along the motion that
element's model shows at its place.  Shared by the look-alike second leads
(``grow.law_swap``: a single's law swapped) and the swaps inside a chosen set
(``swap``: one member's law swapped, the rest of the set held)."""
from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from ..effects import Effect
from ..processing import Processing
from ..recording import Recording
from ..structure import Structure
from .results import Location

Points = list[tuple[float, float]]


def place_motion(structure: Structure, theta: np.ndarray, loc: Location,
                 records: Sequence[Recording], proc: Processing
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The relative displacement and velocity at ``loc`` along the model's simulated
    runs of ``records`` (all records, concatenated)."""
    from .outputs import _Outputs, _relative

    outs = _Outputs(structure, list(records), proc, theta)
    ds, vs = [], []
    for k in range(len(outs.records)):
        _, sim = outs.signals(theta, k)
        d, v = _relative(np.asarray(sim.q), np.asarray(sim.v), loc)
        ds.append(np.ravel(d))
        vs.append(np.ravel(v))
    return np.concatenate(ds), np.concatenate(vs)


def motion_points(d: np.ndarray, v: np.ndarray) -> Points:
    """The motion's RMS and its largest amplitude (displacement, velocity)."""
    return [(float(np.sqrt(np.mean(d ** 2))), float(np.sqrt(np.mean(v ** 2)))),
            (float(np.max(np.abs(d))), float(np.max(np.abs(v))))]


def matched_magnitudes(lead: Effect, lead_coeffs: Mapping[str, float], effect: Effect,
                       shape: Mapping[str, float], d: np.ndarray | None,
                       v: np.ndarray | None, pts: Points) -> list[float]:
    """Magnitudes of ``effect`` (its other coefficients at ``shape``) whose force matches
    ``lead``'s (coefficients ``lead_coeffs``): least squares along the motion (d, v) when
    given, then equal forces at each point of ``pts`` (RMS, peak).  A magnitude that must
    be positive is taken in absolute value; zero or non-finite ones are dropped."""
    mag_lead = lead_coeffs.get(lead.magnitude)
    if mag_lead is None or not np.isfinite(mag_lead) or mag_lead == 0:
        return []
    shape_lead = {k: x for k, x in lead_coeffs.items() if k != lead.magnitude}
    shape_c = {k: x for k, x in shape.items() if k != effect.magnitude}
    mags = []
    if d is not None and v is not None:
        try:
            f_lead = mag_lead * np.asarray(lead.unit_force(d, v, shape_lead), float)
            u = np.asarray(effect.unit_force(d, v, shape_c), float)
        except (KeyError, ValueError, TypeError):  # a shape coefficient missing
            f_lead = u = np.array([np.nan])
        uu = float(u @ u)
        if np.all(np.isfinite(f_lead)) and np.all(np.isfinite(u)) and uu > 0:
            mags.append(float(f_lead @ u) / uu)
    for dd, vv in pts:
        try:
            fl = float(np.abs(lead.unit_force(np.array(dd), np.array(vv), shape_lead)))
            fc = float(np.abs(effect.unit_force(np.array(dd), np.array(vv), shape_c)))
        except (KeyError, ValueError, TypeError):
            continue
        if fl > 0 and fc > 0 and np.isfinite(fl) and np.isfinite(fc):
            mags.append(abs(mag_lead) * fl / fc * (-1.0 if mag_lead < 0 else 1.0))
    out = []
    for mag in mags:
        if effect.magnitude in effect.positive:
            mag = abs(mag)
        if np.isfinite(mag) and mag != 0:
            out.append(float(mag))
    return out
