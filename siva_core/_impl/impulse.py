"""The one impulse detector: is a measured force a hammer pulse, and where is it?

Rule (also in docs/formats.md): let |F|(t) be the largest absolute force over the DOFs.
A sample is *in the pulse* when |F| > ``threshold`` x max |F| (``PULSE_THRESHOLD`` = 2 %
by default: 10 x the 0.2 % force-sensor noise of the reference rigs, and low enough to keep
a half-sine's flanks).  The force is *impulsive* when fewer than ``MAX_PULSE_FRACTION``
(10 %) of the samples are in the pulse; a continuous excitation (multisine, shaker, noise)
is not.  Everything that needs to know about the pulse (the automatic chain, the chain's
force gating and "start after the impact", the simulator's initial state and force gate)
asks :func:`detect_impulse`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: fraction of the peak |F| above which a sample belongs to the pulse
PULSE_THRESHOLD = 0.02
#: a force in its pulse on at least this fraction of the samples is not impulsive
MAX_PULSE_FRACTION = 0.10


@dataclass(frozen=True)
class Impulse:
    """Where a detected pulse is, in samples of the record."""

    peak: int          # sample of max |F|
    first: int         # first sample in the pulse
    last: int          # last sample in the pulse (several hits: the last one's)
    end: int           # first sample after the peak back below the threshold (else peak)
    mask: np.ndarray   # (T,) bool: in the pulse

    def window(self, margin: int = 0) -> tuple[int, int]:
        """[lo, hi) from the first to the last sample in the pulse, widened by ``margin``."""
        return max(0, self.first - margin), min(len(self.mask), self.last + 1 + margin)

    def gate(self, margin: int = 0) -> np.ndarray:
        """(T,) 1.0 within ``margin`` samples of a sample in the pulse, else 0.0 (each hit
        of a multi-hit record keeps its own gate; the noise between hits is dropped)."""
        on = self.mask
        if margin > 0:
            on = np.convolve(on.astype(float), np.ones(2 * margin + 1), mode="same") > 0
        return on.astype(float)


def force_magnitude(force: np.ndarray) -> np.ndarray:
    """(T,) largest |F| over the DOFs of a (T,) or (T, n_dof) force."""
    f = np.abs(np.asarray(force, dtype=float))
    return f if f.ndim == 1 else f.max(axis=1)


def detect_impulse(force: np.ndarray | None, threshold: float = PULSE_THRESHOLD,
                   *, require_impulsive: bool = True) -> Impulse | None:
    """The pulse of ``force`` ((T,) or (T, n_dof)), None when there is no force or (with
    ``require_impulsive``) when the force is not impulsive (see the module's rule).

    ``require_impulsive=False`` locates the samples above the threshold whatever their
    share, for a chain told explicitly to gate its force.
    """
    if force is None:
        return None
    mag = force_magnitude(force)
    if mag.size == 0:
        return None
    top = float(mag.max())
    if not top > 0:
        return None
    mask = mag > threshold * top
    if require_impulsive and not np.mean(mask) < MAX_PULSE_FRACTION:
        return None
    above = np.flatnonzero(mask)
    peak = int(np.argmax(mag))
    below = np.flatnonzero(mag[peak:] < threshold * top)
    end = peak + int(below[0]) if below.size else peak
    return Impulse(peak, int(above[0]), int(above[-1]), end, mask)


__all__ = ["Impulse", "detect_impulse", "force_magnitude", "PULSE_THRESHOLD",
           "MAX_PULSE_FRACTION"]
