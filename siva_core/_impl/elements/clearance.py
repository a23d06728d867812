"""Clearance (dead-zone) spring: k (d - gap) beyond +gap, k (d + gap) below -gap, else 0."""
from ._base import ElementKind, register_element, xp_of


def _force(d, dv, k, gap):
    xp = xp_of(d)
    over = xp.where(d > gap, d - gap, d * 0)
    under = xp.where(d < -gap, d + gap, d * 0)
    return k * (over + under)


CLEARANCE = register_element(ElementKind(
    name="clearance", coefficients=("k", "gap"), force=_force,
    expr="k * ((d - gap) if d > gap else ((d + gap) if d < -gap else 0.0))",
    linear=frozenset({"k"}), nonnegative=frozenset({"k", "gap"}), doc="f = k*(d-gap) for d>gap, k*(d+gap) for d<-gap, else 0",
    units={"k": "N/m", "gap": "m"}))
