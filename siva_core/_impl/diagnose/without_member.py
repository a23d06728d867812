"""The best fit known *without* a named member (``set_members.contributions``): the model
a member's own contribution is measured against.

A member's contribution was the output change when its magnitude is set to zero with the
rest of the fit held.  When the fit re-tunes the nominal parameters around the element
(a cubic damper taking the large records while the linear damping is lowered), zeroing
the element alone leaves a model that fits nothing -- the lowered linear damping without
the element -- and on small validation records it changes the outputs little although
the fitted model differs from the nominal refit by far more than the noise (fresh seed
17396: a quadratic damper, nominal gap 0.12 = 460 x the floor, the cubic damper closing
0.995; held, its contribution was 0.00015 = 0.57 x the floor, the held model's train
cost 0.34 against the nominal refit's 0.11 and the set's 0.005).

So "without the member" is also the fit already made without it -- the nominal refit
for a single, the set without the member (``set_test.without_fits``) for a set -- when
that fit is the better fit of the *train* records (never the validation records the
contribution is measured on) than the member zeroed with the rest held; the contribution
is then the larger of the two output changes (a member whose own term moves the outputs
shows as before: no verdict the held measure passed is lost).  An element fitted to a
residue (the issue's null: a 16 N/m clearance, or a candidate that only re-tunes a
poorly fitted nominal model) changes the train cost little when zeroed, so the held
model is the better fit and the contribution is the held one.  No model is fitted here:
each known fit is simulated once on the train and validation records.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from ..processing import Processing
from ..recording import Recording
from ..structure import Structure
from .outputs import _Outputs
from .results import Candidate


def _residual(structure: Structure, theta: np.ndarray, records: Sequence[Recording],
              proc: Processing) -> np.ndarray | None:
    try:
        r = _Outputs(structure, records, proc, theta).residuals(theta)[0]
    except Exception:  # noqa: BLE001 - a model that cannot be simulated is no reference
        return None
    return r if np.all(np.isfinite(r)) else None


class KnownFits:
    """The nominal refit and the train records, to find the best fit known without a
    member; each model's train cost and validation residual are simulated once."""

    def __init__(self, structure: Structure, theta: np.ndarray,
                 train: Sequence[Recording], val: Sequence[Recording],
                 proc: Processing) -> None:
        self.structure, self.theta = structure, np.asarray(theta, float)
        self.train, self.val, self.proc = list(train), list(val), proc
        self._cache: dict[int, tuple[object, float, np.ndarray | None]] = {}

    def _known(self, c: Candidate | None) -> tuple[float, np.ndarray | None]:
        """(train cost, validation residual) of a fit (None: the nominal refit)."""
        key = id(c)
        if key not in self._cache:
            if c is None:
                st, th, tr, va = self.structure, self.theta, self.train, self.val
            elif c.structure is None or c.theta is None:
                self._cache[key] = (c, np.inf, None)
                return np.inf, None
            else:
                st, th = c.structure, c.theta
                tr, va = c.correct(self.train), c.correct(self.val)
            rt = _residual(st, th, tr, self.proc)
            cost = float(rt @ rt) if rt is not None else np.inf
            self._cache[key] = (c, cost, _residual(st, th, va, self.proc))
        _, cost, res = self._cache[key]
        return cost, res

    def train_cost(self, structure: Structure, theta: np.ndarray,
                   records: Sequence[Recording]) -> float:
        """The train cost of one model (``records``: the train records as it corrects
        them)."""
        r = _residual(structure, theta, records, self.proc)
        return float(r @ r) if r is not None else np.inf

    def reference(self, s: Candidate, held: np.ndarray, without: Candidate | None
                  ) -> tuple[np.ndarray | None, str]:
        """The validation residual of the best fit known without a member of ``s``:
        ``held`` (its theta with the member's magnitude zeroed, the rest held) or
        ``without`` (the fit without it; None = the nominal refit), the one with the
        lower train cost; and which one ("held" or "refit")."""
        assert s.structure is not None
        held_cost = self.train_cost(s.structure, held, s.correct(self.train))
        cost, res = self._known(without)
        if res is not None and cost < held_cost:
            return res, "refit"
        return None, "held"
