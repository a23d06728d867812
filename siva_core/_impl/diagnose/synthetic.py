"""Synthetic impact records of a model with a known extra element (tests, benchmark)."""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from ..recording import Recording
from ..structure import Structure


def synthetic_impacts(structure: Structure, theta: Any, peaks: Sequence[float], *,
                      dof: str, fs: float = 2048.0, duration: float = 4.0,
                      pulse: float = 6.2e-3, t_hit: float = 0.1, acc_noise: float = 3e-3,
                      force_noise: float = 2e-3, seed: int = 0) -> list[Recording]:
    """Impact-hammer records of ``structure`` as instruments give them (acc per DOF and the
    force, no displacement): half-sine pulses of the given peaks on ``dof``, white noise of
    ``acc_noise`` x each acceleration's peak and ``force_noise`` x the force peak.

    Used by the tests and the benchmark to check the diagnosis on effects, magnitudes and
    seeds other than the shipped examples (``with_effect`` builds the generator)."""
    from ..simulate import simulate

    rng = np.random.default_rng(seed)
    t = np.arange(int(round(duration * fs))) / fs
    k = structure.dofs.index(dof)
    out = []
    for peak in peaks:
        F = np.zeros((len(t), structure.n_dof))
        on = (t >= t_hit) & (t <= t_hit + pulse)
        F[on, k] = peak * np.sin(np.pi * (t[on] - t_hit) / pulse)
        sim = simulate(structure, np.asarray(theta, float), t, np.zeros(structure.n_dof),
                       np.zeros(structure.n_dof), F, substeps="auto")
        cols: dict[str, np.ndarray] = {"time": t}
        for d, name in enumerate(structure.dofs):
            a = sim.a[:, d]
            cols[f"acc_{name}"] = a + acc_noise * np.max(np.abs(a)) * rng.standard_normal(len(t))
        cols[f"force_{dof}"] = F[:, k] + force_noise * peak * rng.standard_normal(len(t))
        out.append(Recording.from_columns(cols, structure.dofs, name=f"impact_{peak:g}N"))
    return out
