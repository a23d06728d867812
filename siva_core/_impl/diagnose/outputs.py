"""Simulated outputs on a set of records in refine's normalisation, and the geometry of
candidate locations (which DOFs an element joins, relative motion across it)."""
from __future__ import annotations

from typing import Any, Callable, Sequence

import numpy as np

from ..effects import Effect
from ..processing import Processing, States
from ..recording import Recording
from ..structure import GROUND, Structure
from .results import Location

Progress = Callable[[str], None]


class _Outputs:
    """Simulated outputs of one structure on a set of records, through the chain, in the
    normalisation of ``refine.output_error`` (each DOF of each record / its measured RMS).

    Wraps ``refine.OutputErrorProblem`` (same records, force gating, substeps, targets) so
    that costs here are exactly those ``refine`` minimises, and adds what the diagnosis
    needs beyond a cost: per-record/per-DOF blocks, the processed signals themselves, and
    simulation with an extra external force (the screening sensitivities).
    """

    def __init__(self, structure: Structure, records: Sequence[Recording], proc: Processing,
                 theta_ref: np.ndarray) -> None:
        from ..refine import OutputErrorProblem

        self.structure = structure
        self.proc = proc
        self.prob = OutputErrorProblem.build(structure, list(records), proc,
                                             theta_ref=np.atleast_2d(theta_ref))
        self.n_groups = self.prob.n_groups

    @property
    def records(self) -> list[Any]:
        return self.prob.records

    def residuals(self, thetas: np.ndarray) -> np.ndarray:
        return self.prob.residuals(np.atleast_2d(thetas))

    def blocks(self, res: np.ndarray) -> np.ndarray:
        """(n_records, n_dof) NMSE per record and DOF from one residual vector."""
        out = np.empty((len(self.records), self.structure.n_dof))
        col = 0
        for k, r in enumerate(self.records):
            size = r.target.size
            blk = res[col:col + size].reshape(r.target.shape)
            out[k] = np.sum(blk ** 2, axis=0) * self.n_groups
            col += size
        return out

    def signals(self, theta: np.ndarray, k: int, force: np.ndarray | None = None
                ) -> tuple[States | None, Any]:
        """Record ``k`` simulated at one theta (optionally driven by another force) and
        processed the way ``refine`` does it (same interpolation, chain and substeps).
        Returns (processed states or None if diverged, the raw full-rate Simulation)."""
        from ..simulate import simulate

        r = self.records[k]
        f = r.force if force is None else force
        sim = simulate(self.structure, np.asarray(theta, float), r.rec.time, r.q0, r.v0, f,
                       substeps=r.substeps, backend=self.prob.backend, interp=self.prob.interp)
        if not (np.all(np.isfinite(sim.q)) and np.all(np.isfinite(sim.v))
                and np.all(np.isfinite(sim.a))):
            return None, sim
        chain = self.prob.chain
        return chain.apply_simulated(r.rec, self.structure.dofs, sim.q, sim.v, sim.a), sim

    def output(self, st: States, k: int) -> np.ndarray:
        """Normalised compared quantities (T', n_dof) of processed simulated states."""
        r = self.records[k]
        sim = np.stack([getattr(st, _ATTR[q])[:, d] for d, q in enumerate(r.quantities)], -1)
        return sim * self.weight(k)

    def weight(self, k: int) -> np.ndarray:
        return self.prob.weight(k)


_ATTR = {"disp": "q", "vel": "v", "acc": "a"}


def _say(progress: Progress | None, msg: str) -> None:
    if progress is not None:
        progress(msg)


def _locations(structure: Structure) -> list[Location]:
    """Every DOF to ground, then every DOF pair (in DOF order)."""
    n = structure.n_dof
    out = [Location(i, -1, (structure.dofs[i], GROUND)) for i in range(n)]
    out += [Location(i, j, (structure.dofs[i], structure.dofs[j]))
            for i in range(n) for j in range(i + 1, n)]
    return out


def candidate_sites(structure: Structure, effects: Sequence[Effect]
                    ) -> list[tuple[Effect, Location]]:
    """Every effect at every location, minus the kinds the model already has there."""
    return [(eff, loc) for loc in _locations(structure) for eff in effects
            if not _has_element(structure, eff.kind, loc)]


def _has_element(structure: Structure, kind: str, loc: Location) -> bool:
    for el in structure.elements:
        if el.kind.name != kind:
            continue
        if {el.i, el.j} == {loc.i, loc.j}:
            return True
    return False


def _relative(q: np.ndarray, v: np.ndarray, loc: Location) -> tuple[np.ndarray, np.ndarray]:
    d = q[..., loc.i] - (q[..., loc.j] if loc.j >= 0 else 0.0)
    dv = v[..., loc.i] - (v[..., loc.j] if loc.j >= 0 else 0.0)
    return d, dv


def _gain_values(structure: Structure, theta: np.ndarray) -> np.ndarray:
    return structure.gains(theta)
