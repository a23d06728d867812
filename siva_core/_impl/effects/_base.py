"""The candidate-effect contract and the registry every effect family adds itself to.

An *effect* is a physical mechanism a nominal model may be missing (dry friction, an
amplitude-dependent damping, a clearance, a softening/hardening stiffness, ...).  Each one
adds exactly one element of a registered element kind between two DOFs (or a DOF and
ground).  What the diagnosis needs to know about it lives here, next to the physics:

* which coefficient sets its *size* (``magnitude``, entering the force linearly, so the
  first-order effect of the element on the response is proportional to it and a score
  test / Gauss-Newton step can estimate it);
* the *shape* coefficients (e.g. the clearance ``gap``) that are not screened linearly but
  over a small grid relative to the amplitudes the element sees;
* which coefficients are physically signed (a damper or friction that feeds energy in is
  not an unmodelled effect, it is an artefact of fitting noise);
* how to start a fit (a few magnitudes around the screening estimate) and a one-line
  explanation of why the effect leaves the signature it does.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..elements import REGISTRY as ELEMENT_KINDS


@dataclass(frozen=True)
class Amplitudes:
    """What an element at one location sees on the training records (nominal model).

    ``d_max``/``v_max``: largest |relative displacement| / |relative velocity|;
    ``d_rms``/``v_rms``: their RMS over the kept part of the records.
    """

    d_max: float
    v_max: float
    d_rms: float
    v_rms: float


ShapeGrid = Callable[[Amplitudes], list[dict[str, float]]]


def _no_shape(_: Amplitudes) -> list[dict[str, float]]:
    return [{}]


@dataclass(frozen=True)
class Effect:
    """One candidate unmodelled effect: an element kind plus how to screen and fit it."""

    name: str
    kind: str
    family: str
    explanation: str
    magnitude: str
    positive: frozenset[str] = field(default_factory=frozenset)
    shape_grid: ShapeGrid = _no_shape
    start_factors: tuple[float, ...] = (0.3, 1.0, 3.0)
    interpret: Callable[[dict[str, float]], str] | None = None

    @property
    def coefficients(self) -> tuple[str, ...]:
        return ELEMENT_KINDS[self.kind].coefficients

    def force(self, d: np.ndarray, dv: np.ndarray, coeffs: dict[str, float]) -> np.ndarray:
        """Force of the element for these coefficient values (the element kind's law)."""
        return np.asarray(ELEMENT_KINDS[self.kind].force(d, dv, **coeffs), dtype=float)

    def unit_force(self, d: np.ndarray, dv: np.ndarray, shape: dict[str, float]) -> np.ndarray:
        """Force per unit ``magnitude`` (the screening signature), shape coefficients fixed."""
        return self.force(d, dv, {**shape, self.magnitude: 1.0})

    def typical_magnitude(self, amp: Amplitudes, shape: dict[str, float],
                          force_scale: float) -> float:
        """Magnitude whose force is ``force_scale`` at the RMS amplitude: a scale hint for
        coefficients that start at 0 and a floor for multi-start magnitudes."""
        f = float(np.abs(self.unit_force(np.array(max(amp.d_max, 1e-30)),
                                         np.array(max(amp.v_max, 1e-30)), shape)))
        return force_scale / f if f > 0 else force_scale

    def starts(self, estimate: float, floor: float) -> list[float]:
        """Magnitudes to multi-start a fit from: factors of the screening estimate (its
        sign kept unless the coefficient must be positive)."""
        base = estimate if np.isfinite(estimate) and abs(estimate) > 0 else floor
        if self.magnitude in self.positive:
            base = abs(base)
        return [float(f * base) for f in self.start_factors]

    def describe(self, coeffs: dict[str, float]) -> str:
        """The explanation, specialised to the identified coefficients when it matters."""
        extra = self.interpret(coeffs) if self.interpret else ""
        return f"{self.explanation}{' ' + extra if extra else ''}"


EFFECTS: dict[str, Effect] = {}


def register_effect(effect: Effect, *, replace: bool = False) -> Effect:
    """Add an effect to the registry (also the Python API for user-defined effects)."""
    if effect.kind not in ELEMENT_KINDS:
        raise ValueError(f"effect {effect.name!r}: unknown element kind {effect.kind!r}")
    coeffs = ELEMENT_KINDS[effect.kind].coefficients
    if effect.magnitude not in coeffs:
        raise ValueError(f"effect {effect.name!r}: magnitude {effect.magnitude!r} is not a "
                         f"coefficient of kind {effect.kind!r} {coeffs}")
    if effect.magnitude not in ELEMENT_KINDS[effect.kind].linear:
        raise ValueError(f"effect {effect.name!r}: magnitude {effect.magnitude!r} must enter "
                         "the force linearly (it is screened by a first-order expansion)")
    if not replace and effect.name in EFFECTS:
        raise ValueError(f"effect {effect.name!r} is already registered")
    EFFECTS[effect.name] = effect
    return effect


def sign_word(value: float, positive: str, negative: str) -> str:
    return positive if value >= 0 else negative


__all__ = ["Amplitudes", "Effect", "EFFECTS", "register_effect", "sign_word"]
