"""Candidate unmodelled effects, one module per family, chosen by name from :data:`EFFECTS`.

Like the element kinds (``..elements``), every effect registers itself on import; a user
can add one with :func:`register_effect`.  The diagnosis (``..diagnose``) tries each effect
at each location of a model.
"""
from ._base import EFFECTS, Amplitudes, Effect, register_effect
from . import contact, damping, friction, stiffness  # noqa: F401  (registers)

__all__ = ["EFFECTS", "Amplitudes", "Effect", "register_effect"]
