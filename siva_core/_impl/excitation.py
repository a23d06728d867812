"""What drives a simulation of a measured record: its initial state and its force.

Not numerics (the simulator, ``simulate``, knows nothing of records or chains): this is
the policy that turns a Recording and its processing chain into (q0, v0, force), shared
by output-error refinement, diagnosis and reports.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from .impulse import detect_impulse
from .processing import Processing
from .recording import Recording

#: samples kept on each side of an impulsive force's pulse by ``gate_force`` (its flanks)
GATE_MARGIN_SAMPLES = 2


def initial_state_and_force(structure: Any, rec: Recording, processing: Processing, *,
                            initial: str = "auto", force_gate: str | None = "auto"
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(q0, v0, force or None) to simulate ``rec`` on its own time axis.

    ``initial``: "derived" = the chain's state at the first sample; "rest" = zero; "auto" =
    rest when the record has an impulsive force that starts after the first sample (a
    pre-triggered impact test starts at rest, while a zero-phase band-pass smears the
    impact backwards and would put a spurious initial velocity of ~1 % of the peak into
    the derived state), the derived state otherwise (free decays, continuous excitation).
    ``force_gate``: "auto" zeroes an impulsive force outside its pulse; when the chain
    gates the force itself (``processing.gate_force``) its force (``Processing.force``) is
    used, so that the simulation is driven by the force the chain reports.
    """
    if initial not in ("auto", "derived", "rest"):
        raise ValueError(f"initial must be 'auto', 'derived' or 'rest', got {initial!r}")
    force = rec.stack("force", structure.dofs, fill=0.0) if rec.has_force(structure.dofs) else None
    pulse = detect_impulse(force)
    starts_later = pulse is not None and pulse.window(GATE_MARGIN_SAMPLES)[0] > 0
    if initial == "rest" or (initial == "auto" and starts_later):
        q0 = np.zeros(structure.n_dof)
        v0 = np.zeros(structure.n_dof)
    else:
        q, v, _, _ = processing.derive(rec, structure.dofs)
        q0, v0 = q[0].copy(), v[0].copy()
    if force is not None and force_gate is not None and processing.gate_force:
        return q0, v0, np.asarray(processing.force(rec, structure.dofs), dtype=float)
    return q0, v0, gate_force(force, force_gate)


def gate_force(force: np.ndarray | None, mode: str | None = "auto") -> np.ndarray | None:
    """Zero a measured *impulsive* force outside its pulse (``detect_impulse``, widened by
    ``GATE_MARGIN_SAMPLES``), as the paper applies the hammer force only up to the pulse
    end: sensor noise on the force channel is not a force, and integrated over a long free
    decay it drives a spurious random response (5 % of the LO-NO response at 0.2 % force
    noise).  Continuous excitation is left untouched."""
    if force is None or mode is None:
        return force
    if mode != "auto":
        raise ValueError(f"force_gate must be 'auto' or None, got {mode!r}")
    pulse = detect_impulse(force)
    if pulse is None:
        return force
    lo, hi = pulse.window(GATE_MARGIN_SAMPLES)
    gated = np.zeros_like(force)
    gated[lo:hi] = force[lo:hi]
    return gated


__all__ = ["initial_state_and_force", "gate_force", "GATE_MARGIN_SAMPLES"]
