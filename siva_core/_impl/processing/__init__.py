"""Processing chain: from a Recording to full states (q, v, a, F) per DOF.

The paper's chain (Sec. 2.2, 3.2): zero-phase Butterworth band-pass of measured
accelerations, integration to velocity then displacement with a zero-phase high-pass
after each integration, decimation, and a start just after the impact.  Every step is
configurable and can be switched off.  What a recording gives is used as given; only what
is missing is derived (integration upward from acc, differentiation downward from disp).

The chain biases what it produces (filters remove signal along with noise, and the
paper's chain filters q, v, a and F differently, so M a = -f(q, v) + F no longer holds
even for a linear model).  Two remedies live here:

* ``consistent=True`` passes every signal (q, v, a of every DOF and the force) through the
  same total filter, so the equation of motion still holds exactly for the linear terms.
* :meth:`Processing.apply_simulated` / :func:`simulated_recording` pass a *simulated*
  response through exactly the same chain as a measured one, for output-error refinement.

:meth:`Processing.auto` picks a chain from the data (the rule is in its docstring and in
``docs/formats.md``); :meth:`Processing.paper` is the paper's chain, kept for comparison.

The package, one concept per module: ``chain`` (:class:`Processing`, settings and run),
``states`` (:class:`States`, :func:`simulated_recording`), ``filters`` (zero-phase filters
and ledgers), ``calculus`` (integration, differentiation, integration constants),
``derive`` (what a record lacks, derived with ledgers), ``window`` (start, force gate,
decimation), ``spectra`` and ``auto`` (the data-driven choice of :meth:`Processing.auto`).
"""
from .calculus import TAIL_FRACTION, central_difference
from .chain import Processing
from .filters import FilterKey
from .spectra import SpectrumSummary
from .states import States, simulated_recording

__all__ = ["FilterKey", "Processing", "SpectrumSummary", "States", "TAIL_FRACTION",
           "central_difference", "simulated_recording"]
