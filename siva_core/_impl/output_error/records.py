"""One measured record prepared for the output error: which quantity is compared per DOF,
the processed targets, the initial state and the force (with its kick patterns)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..processing import States
from ..pulse_kick import force_kick_patterns
from ..recording import Recording
from ..simulate import stage_force

_QTY_ATTR = {"disp": "q", "vel": "v", "acc": "a"}


@dataclass
class _Record:
    """One measured record, prepared once: processed targets, initial state, force."""

    rec: Recording
    q0: np.ndarray
    v0: np.ndarray
    force: np.ndarray | None
    quantities: list[str]        # compared quantity per DOF
    target: np.ndarray           # (T', n_dof) processed measured values of those quantities
    rms: np.ndarray              # (n_dof,) RMS of each target column
    substeps: int = 1
    state_rms: np.ndarray | None = None  # (2 n_dof,) RMS of processed q then v (scales)
    _staged: tuple[int, str, np.ndarray] | None = None
    #: (T,) the hit's force samples on its DOF (``hit_dof``) when the record is one short
    #: pulse, else None: the shape the kick's patterns are made of (``kick_basis``)
    kick_pulse: np.ndarray | None = None
    hit_dof: int = 0
    _kick: tuple[int, str, np.ndarray] | None = None
    #: (id of ``kick_pulse``, its processed sample-gain pattern or None), cached by
    #: ``sample_gain.sample_gain_pattern``
    _gain_pattern: tuple[int, np.ndarray | None] | None = None
    #: (substeps, parameter sets (P, n_free), Q, V, A) the substep pilot of ``build``
    #: simulated at those substeps: ``OutputErrorProblem`` takes them once for the same
    #: sets instead of simulating them again (None when there is none, or once taken)
    pilot: tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None

    def staged(self, interp: str) -> np.ndarray | None:
        """The force on the RK4 stage grid, computed once per (substeps, interp)."""
        if self.force is None:
            return None
        if self._staged is None or self._staged[:2] != (self.substeps, interp):
            self._staged = (self.substeps, interp, stage_force(self.force, self.substeps, interp))
        return self._staged[2]

    def kick_basis(self, interp: str) -> np.ndarray:
        """(rows, 2) the kick's two patterns on the RK4 stage grid: the pulse itself
        (an impulse in units of the hit's) and its central difference (a doublet, in
        samples): see ``force_kick_patterns``."""
        if self.kick_pulse is None:
            raise ValueError(f"{self.rec.name}: no single short pulse to kick with")
        if self._kick is None or self._kick[:2] != (self.substeps, interp):
            self._kick = (self.substeps, interp,
                          stage_force(force_kick_patterns(self.kick_pulse), self.substeps,
                                      interp))
        return self._kick[2]


def _quantities(rec: Recording, dofs: Sequence[str], quantity: str | Sequence[str]) -> list[str]:
    """Quantity compared per DOF: 'auto' = the lowest derivative that was *measured*
    (disp, else vel, else acc), so nothing the chain derived is preferred to a measurement."""
    if isinstance(quantity, str) and quantity != "auto":
        if quantity not in _QTY_ATTR:
            raise ValueError(f"quantity must be 'auto', 'disp', 'vel' or 'acc', got {quantity!r}")
        return [quantity] * len(dofs)
    if not isinstance(quantity, str):
        q = list(quantity)
        if len(q) != len(dofs) or any(x not in _QTY_ATTR for x in q):
            raise ValueError(f"quantity per DOF must be {len(dofs)} of disp/vel/acc, got {q}")
        return q
    out = []
    for d in dofs:
        for qty in ("disp", "vel", "acc"):
            if rec.get(qty, d) is not None:
                out.append(qty)
                break
        else:
            raise ValueError(f"{rec.name}: DOF {d!r} has no measured disp/vel/acc")
    return out


def _extract(st: States, qtys: Sequence[str]) -> np.ndarray:
    return np.stack([getattr(st, _QTY_ATTR[q])[:, k] for k, q in enumerate(qtys)], axis=-1)


def _state_derived(rec: Recording, dofs: Sequence[str]) -> bool:
    """Some DOF's displacement or velocity is not measured (the chain derives it)."""
    return any(rec.get("disp", d) is None or rec.get("vel", d) is None for d in dofs)
