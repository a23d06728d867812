"""Batched fixed-step simulation of a Structure for many parameter sets at once.

Why fixed-step RK4 and not an adaptive solver: output-error refinement differentiates the
simulated response with respect to the parameters by finite differences, which needs a
response that is a smooth function of theta (adaptive step control is not), and Approach III
/ Jacobians need hundreds of parameter sets simulated together, which vectorises only when
every set takes the same steps.  RK4 with ``substeps`` steps per sample, the force linearly
interpolated between samples (as MATLAB ``interp1`` in the paper; a cubic spline on request),
matches ``solve_ivp(DOP853, rtol=1e-10)`` to ~1e-7 relative at omega*h <= 0.05, the target
of the automatic step choice (``auto_substeps``).  Force laws with a kink (clearance, the
|dv| of a quadratic damper) lose RK4's order where it is crossed: ~1e-4 at that step, less
with more substeps.

Modules (pure numerics: no records, no processing chain):

- ``solver``: ``simulate`` and ``Simulation``; ``warmup``.
- ``substeps``: the automatic step choice (``auto_substeps``, ``OMEGA_H``, ``REAL_H_FIT``).
- ``grid``: the force on the RK4 stage grid (``stage_force``), the divergence bound.
- ``backends``: which backend runs, and dispatch to it.
- ``numba_kernel``: a kernel generated from the element kinds' ``expr`` strings
  (straight-line scalar code, a serial loop over the parameter sets), compiled once per
  structure *signature* and cached in-process and on disk.
- ``rk4_numpy``: generic RK4 on ``structure.accelerations`` vectorised over the batch;
  used for user-defined kinds without ``expr`` or when numba is unavailable.

What drives the simulation of a measured record (initial state, gated force) is policy,
not numerics: ``siva_core._impl.excitation``; ``initial_state_and_force`` and
``gate_force`` are re-exported here (lazily) for existing callers.
"""
from __future__ import annotations

from typing import Any

from .backends import choose_backend
from .grid import MEASURED_FORCE_INTERP, adjusted_stage_force, set_measured_force_interp, stage_force
from .numba_kernel import compiled_kernel
from .solver import Simulation, simulate, simulate_split, warmup
from .substeps import OMEGA_H, REAL_H_FIT, auto_substeps

#: the previous private name, still imported by callers outside this package
_choose_backend = choose_backend

_EXCITATION = ("initial_state_and_force", "gate_force")


def __getattr__(name: str) -> Any:
    # excitation needs the processing chain; the numerics must not import it
    if name in _EXCITATION:
        from .. import excitation

        return getattr(excitation, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["Simulation", "simulate", "simulate_split", "auto_substeps", "initial_state_and_force", "gate_force",
           "compiled_kernel", "warmup", "stage_force", "adjusted_stage_force", "MEASURED_FORCE_INTERP", "set_measured_force_interp", "choose_backend",
           "OMEGA_H", "REAL_H_FIT"]
