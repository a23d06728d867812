"""Power-law spring f = alpha d |d|^beta (the LO-NO rig's geometric wire nonlinearity)."""
from ._base import ElementKind, register_element

_TINY = 1e-300


def _force(d, dv, alpha, beta):
    # |d|^beta with |d| floored: keeps the beta-gradient finite at d = 0.
    return alpha * d * (abs(d) + _TINY) ** beta


POWER_SPRING = register_element(ElementKind(
    name="power_spring", coefficients=("alpha", "beta"), force=_force,
    expr="alpha * d * (abs(d) + 1e-300) ** beta", linear=frozenset({"alpha"}),
    doc="f = alpha*d*|d|^beta", units={"alpha": "N/m^(1+beta)", "beta": "-"}))
