"""Polynomial stiffness and damping nonlinearities (cubic/quadratic springs and dampers)."""
from ._base import ElementKind, register_element

CUBIC_SPRING = register_element(ElementKind(
    name="cubic_spring", coefficients=("k3",), force=lambda d, dv, k3: k3 * d**3,
    units={"k3": "N/m^3"},
    expr="k3 * d * d * d", linear=frozenset({"k3"}), doc="f = k3*d^3"))

QUADRATIC_SPRING = register_element(ElementKind(
    name="quadratic_spring", coefficients=("k2",), force=lambda d, dv, k2: k2 * d**2,
    units={"k2": "N/m^2"},
    expr="k2 * d * d", linear=frozenset({"k2"}), doc="f = k2*d^2"))

CUBIC_DAMPER = register_element(ElementKind(
    name="cubic_damper", coefficients=("c3",), force=lambda d, dv, c3: c3 * d**2 * dv,
    units={"c3": "N·s/m^3"},
    expr="c3 * d * d * dv", linear=frozenset({"c3"}), nonnegative=frozenset({"c3"}), doc="f = c3*d^2*dv"))

QUADRATIC_DAMPER = register_element(ElementKind(
    name="quadratic_damper", coefficients=("c2",), force=lambda d, dv, c2: c2 * dv * abs(dv),
    units={"c2": "N/(m/s)^2"},
    expr="c2 * dv * abs(dv)", linear=frozenset({"c2"}), nonnegative=frozenset({"c2"}), doc="f = c2*dv*|dv|"))
