"""Linear spring: f = k d."""
from ._base import ElementKind, register_element

SPRING = register_element(ElementKind(
    name="spring", coefficients=("k",), force=lambda d, dv, k: k * d,
    units={"k": "N/m"},
    expr="k * d", linear=frozenset({"k"}), nonnegative=frozenset({"k"}), doc="f = k*d"))
