"""Viscous damper: f = c dv."""
from ._base import ElementKind, register_element

DAMPER = register_element(ElementKind(
    name="damper", coefficients=("c",), force=lambda d, dv, c: c * dv,
    units={"c": "N/(m/s)"},
    expr="c * dv", linear=frozenset({"c"}), nonnegative=frozenset({"c"}), doc="f = c*dv"))
