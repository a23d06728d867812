"""A force gain that the reading of a few-sample hammer pulse explains is not a fault.

The model reads a measured force between its samples one way (``stage_force``'s
"moments"); straight lines through the same samples are as consistent with them and put
``1 + (1 - cos(w dt)) / 6`` times less force into a mode at ``w`` (their spread exceeds
the samples' own by dt^2 / 6: a low-pass sinc^2(f dt), against the moments reading's
(1 + (1 - cos w dt) / 6) sinc^2(f dt)).  The structure's true force lies between or beyond
such readings (docs/perf.md section 4: a continuous pulse of 3-5 samples differs from both
by 1-4 % in what it puts into the modes).  So a force gain of that size is what the pulse's
unknown shape between its samples does, not a transducer fault, and it is not named
(issue 16, seed 15110: a 1-DOF at 256 Hz, 22.7 Hz mode, a 2-sample pulse; the records
were simulated with the straight-line reading, the truth model then leaves a train cost of
1.2e-3 read by moments and 9.2e-5 by straight lines; a force gain 1.029 "closed" 0.93 of
what the right coulomb left and the set rule named both).

On a 1-DOF model the one accelerometer's gain is a force gain (1/g), judged the same way.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ..recording import Recording
from ..structure import Structure
from .results import Candidate

#: the band is this many times the two readings' difference at the lowest mode: the true
#: pulse lies beyond either reading (see the module doc), and a joint fit moves the gain by
#: a few tenths of a percent more (15110: 2.5 % reading difference, fitted gain 2.9 %)
READING_MARGIN = 2.0


def reading_difference(frequency_hz: float, fs: float) -> float:
    """Relative difference of the force the straight-line and the moments readings of
    the same samples put into a mode at ``frequency_hz`` (sampling rate ``fs``)."""
    return (1.0 - math.cos(2.0 * math.pi * frequency_hz / fs)) / 6.0


def reading_band(c: Candidate, records: Sequence[Recording], structure: Structure | None = None,
                 theta: np.ndarray | None = None) -> float | None:
    """The relative size of gain that the pulse reading explains for candidate ``c``
    (``READING_MARGIN`` x the readings' difference at the model's lowest linear mode,
    at the records' lowest sampling rate), or None when ``c`` is not a force gain (nor a
    1-DOF model's accelerometer gain) or has no model to take the mode from.  The model
    is ``c``'s own unless ``structure`` and ``theta`` (e.g. a set's joint fit) are given."""
    structure = structure if structure is not None else c.structure
    theta = theta if theta is not None else c.theta
    if c.category != "sensor" or structure is None or theta is None or not records:
        return None
    kind = c.effect.kind
    if not (kind == "force_gain" or (kind == "accelerometer_gain" and structure.n_dof == 1)):
        return None
    try:
        modes = [f for f in structure.linear_modes(theta)["frequency_hz"] if f > 0]
    except Exception:  # noqa: BLE001 - no modes, no band
        return None
    if not modes:
        return None
    fs = min(r.fs for r in records)
    return READING_MARGIN * reading_difference(min(modes), fs)


def explained_by_reading(c: Candidate, records: Sequence[Recording],
                         structure: Structure | None = None,
                         theta: np.ndarray | None = None) -> bool:
    """Whether ``c`` is a force gain within the band the pulse reading explains."""
    band = reading_band(c, records, structure, theta)
    gain = c.coefficients.get(c.effect.magnitude) if band is not None else None
    if gain is None or not np.isfinite(gain) or gain <= 0:
        return False
    return abs(math.log(gain)) <= math.log1p(band)
