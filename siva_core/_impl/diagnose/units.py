"""SI units of element coefficients and sensor-fault values (DOFs in metres, forces in N)."""
from __future__ import annotations

from typing import Any, Mapping

#: (element kind, coefficient) -> unit, for translational DOFs in m and forces in N
UNITS: dict[tuple[str, str], str] = {
    ("spring", "k"): "N/m",
    ("damper", "c"): "N/(m/s)",
    ("cubic_spring", "k3"): "N/m^3",
    ("quadratic_spring", "k2"): "N/m^2",
    ("cubic_damper", "c3"): "N s/m^3",
    ("quadratic_damper", "c2"): "N/(m/s)^2",
    ("coulomb", "fc"): "N",
    ("clearance", "k"): "N/m",
    ("clearance", "gap"): "m",
    ("power_spring", "alpha"): "N/m^beta",
    ("power_spring", "beta"): "-",
    ("accelerometer_gain", "gain"): "- (measured/true)",
    ("force_gain", "gain"): "- (measured/true)",
    ("channel_delay", "delay"): "s",
}


def unit(kind: str, coefficient: str) -> str:
    return UNITS.get((kind, coefficient), "")


def coefficient_units(effect: Any, coefficients: Mapping[str, Any]) -> dict[str, str]:
    return {k: unit(effect.kind, k) for k in coefficients}


def with_unit(kind: str, coefficient: str, value: float) -> str:
    u = unit(kind, coefficient)
    return f"{value:.4g} {u}" if u and u != "-" else f"{value:.4g}"
