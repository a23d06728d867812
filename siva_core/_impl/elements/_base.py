"""The element-kind contract and the registry every kind adds itself to.

An element is a force between two DOFs (or a DOF and ground).  With d = q_i - q_j and
dv = v_i - v_j it pushes DOF i by -f and DOF j by +f, so that M q'' = -sum f + F(t).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

ForceFn = Callable[..., Any]


def xp_of(x: Any) -> Any:
    """The array namespace (numpy or torch) of ``x``, so one formula serves both."""
    if type(x).__module__.startswith("torch"):
        import torch

        return torch
    return np


@dataclass(frozen=True)
class ElementKind:
    """One kind of element: its coefficient names and its force law.

    ``force(d, dv, **coeffs)`` must work elementwise on numpy arrays and torch tensors
    (use :func:`xp_of` for functions such as ``tanh``).  ``expr`` is the same law as a
    scalar Python expression in ``d``, ``dv``, the coefficient names and ``abs``/``tanh``/
    ``copysign``; it lets the batched simulator compile the model.  ``linear`` names the
    coefficients that enter f linearly (used by least-squares initialisation).  ``units``
    gives each coefficient's SI unit (displacement in m, velocity in m/s, force in N), shown
    next to every value in reports and the dashboard.
    """

    name: str
    coefficients: tuple[str, ...]
    force: ForceFn
    expr: str | None = None
    linear: frozenset[str] = field(default_factory=frozenset)
    doc: str = ""
    units: dict[str, str] = field(default_factory=dict)
    #: coefficients that are >= 0 for a passive element (a damper's c: negative damping
    #: creates energy); a spec's ``lower`` below 0 lifts the bound
    nonnegative: frozenset[str] = field(default_factory=frozenset)

    def unit(self, coefficient: str) -> str:
        """SI unit of a coefficient ("" when the kind does not say)."""
        return self.units.get(coefficient, "")


REGISTRY: dict[str, ElementKind] = {}


def register_element(kind: ElementKind, *, replace: bool = False) -> ElementKind:
    """Add a kind to the registry (the Python API for user-defined elements)."""
    if not replace and kind.name in REGISTRY:
        raise ValueError(f"element kind {kind.name!r} is already registered")
    if not kind.coefficients:
        raise ValueError(f"element kind {kind.name!r} needs at least one coefficient")
    REGISTRY[kind.name] = kind
    return kind
