"""Bounds on a drawn effect over *every* record of a scenario (issue 16, third round).

The generator sizes an effect towards a visibility measured on the validation records;
without a bound on the others an effect could dominate a train record so that the
structure barely moves there (seed 13002: a coulomb fc of 52 N against hammer peaks of
2.6-9.1 N; 13007: a 1890 N s/m damper locking its DOF; 13008: fc 25 N against 7-27 N).
Such a scenario tests nothing the issue asks for ("from 3 x the noise to strong", not
"the structure stops"), so every effect must, on every record (train and validation):

* change the accelerations by at most ``DOMINANCE`` of their RMS (pooled over channels;
  the response of the structure stays the structure's);
* for a coulomb: ``fc`` at most ``FRICTION_SHARE`` of the peak elastic force the hit
  produces at the place's DOFs on the *smallest* record (the mass keeps sliding);
* for a damper of any law: every mode's damping ratio, with the damper's equivalent
  linear coefficient at the peak relative velocity of the *largest* record added, at most
  ``ZETA_MAX`` (a damper that does not lock the DOF; an overdamped mode fails).

An effect must also *show on the train records* (visibility on the larger train record
at least ``TRAIN_VISIBLE`` x the noise): the diagnosis fits candidates to the train
records, and an effect they never see (seed 13012: a clearance whose 0.35 mm gap the
13.6 and 18.9 N train hits never close, seen only on the 122 N validation record) is
found by no method; such an effect is grown (a clearance's gap halved, any other law's
coefficient doubled, within the bounds above) or dropped.

``excess`` says by how much an effect is over its bounds (1 = within); the generator
shrinks it until it is within (the bound wins over the drawn visibility).
"""
from __future__ import annotations

from typing import Any, Callable, Sequence

import numpy as np

from siva_core import EFFECTS, Structure, with_effect

DOMINANCE = 0.5
FRICTION_SHARE = 0.3
ZETA_MAX = 0.25
TRAIN_VISIBLE = 3.0
DAMPERS = ("damper", "quadratic_damper", "cubic_damper")


def stiffness(spec: dict[str, Any], truth: dict[str, float]) -> np.ndarray:
    """The nominal linear springs' stiffness matrix (the DOFs' order of ``spec``)."""
    dofs = list(spec["dofs"])
    K = np.zeros((len(dofs), len(dofs)))
    for el in spec["elements"]:
        if el["kind"] != "spring":
            continue
        a, b = el["between"]
        k = float(truth[el["params"]["k"]])
        i = dofs.index(a)
        K[i, i] += k
        if b != "ground":
            j = dofs.index(b)
            K[j, j] += k
            K[i, j] -= k
            K[j, i] -= k
    return K


def dominance(change: np.ndarray, base: np.ndarray) -> float:
    """RMS of the accelerations' change over their RMS, pooled over the channels."""
    return float(np.sqrt(np.sum(change ** 2)) / max(np.sqrt(np.sum(base ** 2)), 1e-30))


def peak_elastic(K: np.ndarray, q: np.ndarray, idx: Sequence[int]) -> float:
    """Peak of the nominal springs' force on the place's DOFs over a response ``q``."""
    f = np.asarray(q, float) @ K.T
    return float(np.max(np.abs(f[:, list(idx)])))


def max_damping(st: Structure, truth: dict[str, float], kind: str,
                place: tuple[str, str], coeffs: dict[str, float], v_peak: float) -> float:
    """Largest modal damping ratio with the damper's equivalent linear coefficient at
    ``v_peak`` added (1.0 when a mode is overdamped)."""
    eff = EFFECTS[kind]
    v = max(abs(v_peak), 1e-12)
    c_eq = coeffs[eff.magnitude] * abs(float(eff.unit_force(np.array(0.0), np.array(v), {}))) / v
    lin = with_effect(st, "damper", place, {"c": c_eq})
    modes = lin.linear_modes(lin.vector(truth))
    zeta = modes["damping_ratio"]
    if len(zeta) < st.n_dof:
        return 1.0
    return float(max(zeta))


def excess(kind: str, place: tuple[str, str], coeffs: dict[str, float],
           changes: Callable[[dict[str, float]], list[float]],
           elastic_small: float, damping: Callable[[dict[str, float]], float]) -> float:
    """How many times the effect is over its bounds (<= 1: within every one).
    ``changes(coeffs)``: the dominance on each record; ``elastic_small``: the peak elastic
    force at the place on the smallest record; ``damping(coeffs)``: max_damping."""
    over = max(changes(coeffs)) / DOMINANCE
    if kind == "coulomb":
        over = max(over, coeffs["fc"] / max(FRICTION_SHARE * elastic_small, 1e-30))
    if kind in DAMPERS:
        over = max(over, damping(coeffs) / ZETA_MAX)
    return float(over)


def shrink(kind: str, coeffs: dict[str, float], factor: float) -> dict[str, float]:
    """The effect scaled down by ``factor`` (a clearance's stiffness, not its gap)."""
    return {k: (x * factor if k != "gap" else x) for k, x in coeffs.items()}


def grow(kind: str, coeffs: dict[str, float], factor: float) -> dict[str, float]:
    """The effect made to show at smaller amplitudes: a clearance's gap halved, any other
    law scaled up by ``factor`` (> 1)."""
    if kind == "clearance":
        return {**coeffs, "gap": coeffs["gap"] * 0.5}
    return {k: x * max(factor, 1.0) for k, x in coeffs.items()}
