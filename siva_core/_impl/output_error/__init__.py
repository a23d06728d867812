"""The output error: records simulated from their force and initial state and passed
through the same processing chain as the measurement (see ``refine`` for the fit).

The package, one concept per module: ``records`` (:class:`_Record`, one measured record
prepared once: compared quantities, processed targets, initial state, force and its kick
patterns), ``problem`` (:class:`OutputErrorProblem`, the batched residuals),
``sample_gain`` (the gain of the hit's accelerations at the pulse samples, profiled out
when a force multiplier is fitted), ``spread``
(whether the force's spread is identifiable and fitted), ``profiled``
(:func:`force_profiled_output_error`, the cost with the force nuisances profiled out) and
``metrics`` (:func:`output_error`, :func:`displacement_mse`).
"""
from ..pulse_kick import sampled_force_acceleration
from .metrics import displacement_mse, output_error
from .problem import OutputErrorProblem
from .profiled import force_profiled_output_error
from .records import _Record, _state_derived  # noqa: F401  (re-exported)
from .spread import (FIT_FORCE_SPREAD_BY_DEFAULT, SPREAD_MIN_OMEGA_DT, default_force_spread,
                     force_spread_identifiable)

#: the name tests use for the accelerations at the force samples
_sampled_force_acceleration = sampled_force_acceleration

__all__ = ["FIT_FORCE_SPREAD_BY_DEFAULT", "OutputErrorProblem", "SPREAD_MIN_OMEGA_DT",
           "default_force_spread", "displacement_mse", "force_profiled_output_error",
           "force_spread_identifiable", "output_error"]
