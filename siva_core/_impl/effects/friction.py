"""Dry (Coulomb) friction: a sliding contact, a bolted joint or a guide rubbing."""
from ._base import Effect, register_effect

COULOMB = register_effect(Effect(
    name="coulomb", kind="coulomb", family="dry friction",
    explanation=("dry friction: a force of constant size opposing the sliding velocity, so "
                 "the amplitude drops by a fixed amount per cycle (linear, not exponential, "
                 "decay) and the relative error grows as the vibration gets small - late in a "
                 "decay and on low-amplitude records."),
    magnitude="fc", positive=frozenset({"fc"})))
