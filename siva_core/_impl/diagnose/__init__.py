"""`siva diagnose`: where the sim-to-real gap lies, which unmodelled effect causes it, and
how far it shrinks once that effect is added.

Method (docs/diagnosis.md has the full rationale and the measured results):

1. **Nominal fit.**  The model as given is fitted to the ``--train`` records by output
   error (``refine``: simulate each record from its force, pass the simulation through the
   same processing chain as the measurement, compare), started from an equation-error
   least-squares guess (for impact records also on states derived with the records padded
   by zeros: the zero-phase filters ring before an early hit, ``nominal.padded_chain``).
   ``gap_before`` = output-error cost of that fit on the ``--val`` records, which are
   never used to fit anything.
2. **Candidates.**  Every registered effect (``effects.EFFECTS``) at every location (each
   DOF to ground, each DOF pair) that the model does not already have.
3. **Screening** (cheap, train records only): a score test.  Adding an element with a
   small magnitude ``c`` changes the force on the structure by ``c g(t)``, ``g`` the
   element's unit force along the nominal trajectory, so to first order its effect on the
   output is the response of the nominal model to ``g`` applied as an extra external force.
   That sensitivity column, with the nominal parameters' Jacobian projected out (the
   nominal model re-tunes itself when an element is added), gives the Gauss-Newton estimate
   of ``c`` and the share of the remaining train residual the candidate explains.  A
   dissipative candidate whose estimate comes out negative (an energy source) scores 0.
4. **Fit** of the best few screened candidates by output error on the train records
   (nominal parameters warm-started at the nominal fit, the new magnitude multi-started at
   a few multiples of the screening estimate, the best start then refined jointly).
   ``gap_after`` on the val records, ``closure = 1 - gap_after / gap_before``.
5. **Verdict** (a rule that guards against over-fitting, constants in ``DiagnoseSettings``):
   the best candidate by validation closure is named only if (a) the nominal gap is above
   the estimated noise floor, (b) its closure is at least ``closure_min``, (c) it leaves
   clearly less gap than the best candidate of a *different* kind (``separation``), and
   (d) no validation record gets worse with it (``record_tolerance``).  Otherwise null.
   A force gain within what the hammer pulse's reading between its samples explains is
   never named (``pulse_reading``), nor an accelerometer gain that such a force gain
   (one common gain of every response channel) out-fits on the train records.
6. **Where**: the nominal model's validation residual split per DOF, per record (against
   amplitude), early/middle/late in each decay (by share of response energy) and by
   frequency band (around the nominal linear modes), with a one-paragraph explanation.
"""
from .command import diagnose_command
from .model_edit import augmented, with_effect
from .outputs import candidate_sites
from .report import html_report
from .results import Candidate, Diagnosis, Location
from .run import diagnose
from .settings import DiagnoseSettings
from .synthetic import synthetic_impacts
from .verdict import decide
from .where import _amplitude_trend, _bands, _energy_windows  # noqa: F401  (tests)

__all__ = ["diagnose", "diagnose_command", "Diagnosis", "DiagnoseSettings", "Candidate",
           "Location", "augmented", "candidate_sites", "decide", "html_report", "with_effect",
           "synthetic_impacts"]
