"""The pieces a ``Structure`` is made of: elements between DOFs (or ground), global
parameters with their settings, and the error a spec that cannot be used raises."""
from __future__ import annotations

from dataclasses import dataclass

from ..elements import ElementKind

GROUND = "ground"


class SpecError(ValueError):
    """A model spec that cannot be used; the message names what and where."""


@dataclass(frozen=True)
class ParameterInfo:
    """Settings of one global parameter: its scale hint, or a fixed (known) value."""

    name: str
    scale: float | None = None
    fixed: float | None = None
    lower: float | None = None
    upper: float | None = None
    initial: float | None = None   # a nominal value (checks before training: the modes)


@dataclass(frozen=True)
class Element:
    """One element instance: a kind between DOF ``i`` and ``j`` (``j = -1`` is ground)."""

    kind: ElementKind
    between: tuple[str, str]
    i: int
    j: int
    params: tuple[str, ...]  # global parameter name per kind coefficient, in kind order

