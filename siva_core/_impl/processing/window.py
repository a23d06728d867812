"""Which samples the chain keeps, and the force it keeps: the start (just after an
impact, a time, or the record's start), the force gated to its pulse(s), and the integer
decimation factor."""
from __future__ import annotations

from typing import Sequence

import numpy as np

from ..impulse import detect_impulse
from ..recording import Recording


def start_index(rec: Recording, dofs: Sequence[str], start: str | float,
                impact_threshold: float) -> int:
    """Index of the first kept sample: 0, a time, or just after the force pulse."""
    if start == "start":
        return 0
    if isinstance(start, (int, float)):
        return int(np.searchsorted(rec.time, rec.time[0] + float(start)))
    if start != "impact":
        raise ValueError(f"start must be 'start', 'impact' or seconds, got {start!r}")
    pulse = detect_impulse(rec.stack("force", dofs, fill=0.0), impact_threshold,
                           require_impulsive=False)
    return 0 if pulse is None else pulse.end


def gated_force(rec: Recording, dofs: Sequence[str], gate: bool, impact_threshold: float,
                gate_margin: float) -> np.ndarray:
    """(T, n_dof) force columns (0 where a DOF has none), zero outside the pulse(s) when
    ``gate`` (|F| above ``impact_threshold`` of its peak, widened by ``gate_margin`` s)."""
    f = rec.stack("force", dofs, fill=0.0)
    if gate:
        pulse = detect_impulse(f, impact_threshold, require_impulsive=False)
        if pulse is not None:
            f = f * pulse.gate(int(round(gate_margin * rec.fs)))[:, None]
    return f


def decimation_factor(fs: float, decimate_to: float | None) -> int:
    """Integer decimation factor reaching ``decimate_to`` (1 when off or above fs)."""
    if decimate_to is None or decimate_to >= fs:
        return 1
    return max(1, int(round(fs / decimate_to)))
