"""The output-error metrics of parameter sets: the normalised cost and the paper's
displacement MSE."""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from ..processing import Processing
from ..recording import Recording
from ..simulate import simulate
from .problem import OutputErrorProblem


def output_error(structure: Any, thetas: Any, records: Recording | Sequence[Recording],
                 processing: Processing | None = None, *, quantity: str | Sequence[str] = "auto",
                 **kw: Any) -> np.ndarray:
    """(B,) normalised output-error cost of each parameter set: the mean over records and
    DOFs of MSE / (measured RMS)^2 (0 = perfect, 1 = as bad as predicting zero).

    Each record is simulated (``simulate``), rebuilt as a Recording with the measured
    channels, put through the same chain and compared with the processed measurement on
    the measured quantities.  ``kw``: substeps ("auto"), backend, force_gate, initial,
    interp, omega_h (see ``OutputErrorProblem.build``).
    """
    th = np.atleast_2d(np.asarray(thetas, dtype=float))
    prob = OutputErrorProblem.build(structure, records, processing, quantity=quantity,
                                    theta_ref=th, **kw)
    return prob.cost(th)


def displacement_mse(structure: Any, thetas: Any, records: Recording | Sequence[Recording],
                     processing: Processing | None = None, *, chain: bool = True,
                     dof_reduce: str = "mean", **kw: Any) -> np.ndarray:
    """(B,) the paper's metric: MSE [m^2] between simulated and measured (processed)
    displacement, averaged over DOFs and records (paper Sec. 3.1 / 3.2).

    ``chain=True`` (default) passes the simulated record through the same chain as the
    measurement (unbiased); ``chain=False`` compares the raw simulated displacement, taken
    where the chain kept samples, with the processed measurement, as the paper did.
    ``dof_reduce="sum"`` is the paper's LO-NO definition (x and y errors added).  inf for a
    diverged simulation.
    """
    if dof_reduce not in ("mean", "sum"):
        raise ValueError("dof_reduce must be 'mean' or 'sum'")
    th = np.atleast_2d(np.asarray(thetas, dtype=float))
    prob = OutputErrorProblem.build(structure, records, processing, quantity="disp",
                                    theta_ref=th, **kw)
    total = np.zeros(th.shape[0])
    for k, r in enumerate(prob.records):
        if chain:
            sims = [None if st is None else st.q
                    for st in prob.simulated_states(th, k, need="q")]
        else:
            meas = prob.chain.apply(r.rec, structure.dofs)
            sim = simulate(structure, th, r.rec.time, r.q0, r.v0, r.force, substeps=r.substeps,
                           backend=prob.backend, interp=prob.interp)
            sl = slice(meas.start_index, meas.start_index + meas.decimation * len(meas),
                       meas.decimation)
            sims = [sim.q[b, sl] for b in range(th.shape[0])]
        for b, q in enumerate(sims):
            if q is None or not np.all(np.isfinite(q)):
                total[b] = np.inf
                continue
            mse = np.mean((q - r.target) ** 2, axis=0)
            total[b] += mse.mean() if dof_reduce == "mean" else mse.sum()
    return total / len(prob.records)
