"""Coulomb (dry) friction f = fc sign(dv), smoothed as fc tanh(dv / V_SMOOTH).

The smoothing velocity keeps the ODE Lipschitz so fixed-step integrators stay accurate;
1 mm/s is well below the velocities of impact tests yet avoids chattering.
"""
from ._base import ElementKind, register_element, xp_of

V_SMOOTH = 1e-3


def _force(d, dv, fc):
    return fc * xp_of(dv).tanh(dv / V_SMOOTH)


COULOMB = register_element(ElementKind(
    name="coulomb", coefficients=("fc",), force=_force,
    expr=f"fc * tanh(dv / {V_SMOOTH!r})", linear=frozenset({"fc"}), nonnegative=frozenset({"fc"}),
    doc=f"f = fc*tanh(dv/{V_SMOOTH})", units={"fc": "N"}))
