"""Output-error refinement: fit parameters by simulating what was recorded.

Equation-error estimates (least squares, SINDy, SIVA's acceleration MSE) regress on states
that the processing chain produced, so they inherit the chain's bias (band-pass, high-pass
and decimation distort amplitude and phase; see the data README: b2 -68 %, k2 +32 % on
noise-free LO-NO accelerations).  Output error removes it: each record is *simulated* from
its force and initial state, the simulated signals are put into a Recording with the same
channels as the measured one, and that record goes through the *same* chain.  Whatever the
chain does to the measurement it also does to the simulation, so the comparison is fair.

What is simulated (``simulate.initial_state_and_force``): the whole raw record, from the
chain's derived state at its first sample, or from rest for a pre-triggered impact (a
zero-phase band-pass smears the impact backwards into that state), driven by the measured
force gated to its pulse (force-sensor noise between hits is not a force).  The chain is
then run on all parameter sets at once (``Processing.apply_simulated``), so a chain that
starts after the impact or decimates is handled like any other.

``refine`` minimises those residuals with ``scipy.optimize.least_squares`` (trust-region
reflective), the finite-difference Jacobian computed from one batched simulation of n+1
parameter sets, and reports the Gauss-Newton covariance.  What makes it converge from
starts 10-20 % off on strongly nonlinear records (see ``refine``): log-scaled parameters
and a growing fitting horizon; and, optionally, a per-record force scale as a nuisance
parameter for impact records, whose response is very sensitive to the impulse.

The package, one concept per module: ``driver`` (:func:`refine`: the variable map, the
stages, the result), ``result`` (:class:`RefineResult`), ``scaling`` (log-scaled
variables and their bounds), ``horizons`` (the growing fitting horizons), ``solver`` (one
stage: ``least_squares`` with the batched Jacobian) and ``uncertainty`` (Gauss-Newton
and bootstrap covariances).  The output error itself is ``output_error``; its names are
re-exported here, where they were imported from before.
"""
# re-exported: imported from here before the split
from ..output_error import (OutputErrorProblem, _state_derived,  # noqa: F401
                            displacement_mse, force_profiled_output_error, output_error)
from .driver import refine
from .horizons import HORIZON_SKIP_COST  # noqa: F401  (re-exported)
from .result import RefineResult
from .scaling import LOG_RANGE, _log_mask  # noqa: F401  (re-exported)
from .uncertainty import NUMERICAL_REL_STD  # noqa: F401  (re-exported)

__all__ = ["output_error", "force_profiled_output_error", "displacement_mse", "refine",
           "RefineResult", "OutputErrorProblem"]
