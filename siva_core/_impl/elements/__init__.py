"""Element kinds, one module each, chosen by name from :data:`REGISTRY`."""
from ._base import REGISTRY, ElementKind, register_element, xp_of
from . import clearance, coulomb, damper, polynomial, power_spring, spring  # noqa: F401  (registers)

__all__ = ["REGISTRY", "ElementKind", "register_element", "xp_of"]
