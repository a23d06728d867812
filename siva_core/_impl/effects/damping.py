"""Damping the nominal model lacks: a missing viscous path or amplitude-dependent damping."""
from ._base import Effect, register_effect

DAMPER = register_effect(Effect(
    name="damper", kind="damper", family="viscous damping",
    explanation=("a missing viscous damping path: decay rate independent of amplitude, so "
                 "the error is in the decay envelope on every record alike."),
    magnitude="c", positive=frozenset({"c"})))

QUADRATIC_DAMPER = register_effect(Effect(
    name="quadratic_damper", kind="quadratic_damper", family="velocity-squared damping",
    explanation=("velocity-squared (fluid/aerodynamic drag, turbulent flow through an "
                 "orifice) damping: the equivalent damping grows in proportion to velocity, "
                 "so large-amplitude records and the start of each decay die out faster "
                 "than the viscous model predicts."),
    magnitude="c2", positive=frozenset({"c2"})))

CUBIC_DAMPER = register_effect(Effect(
    name="cubic_damper", kind="cubic_damper", family="amplitude-dependent damping",
    explanation=("amplitude-dependent damping (f = c3 d^2 dv, e.g. micro-slip in joints or "
                 "material damping growing with strain): the equivalent damping grows with "
                 "the square of the deflection, so the gap is largest on high-amplitude "
                 "records, early in the decay, and vanishes at small amplitude."),
    magnitude="c3", positive=frozenset({"c3"})))
