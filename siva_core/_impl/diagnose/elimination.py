"""The backward step of the greedy search for several effects: an effect added early may
only have stood in for a later one (a look-alike that the later, true effect makes
redundant); it is dropped when the others alone close the gap about as well."""
from __future__ import annotations

import time
from typing import Sequence

import numpy as np

from ..processing import Processing
from ..recording import Recording
from ..structure import Structure
from .fitting import _intervals
from .model_edit import augmented
from .outputs import Progress, _say
from .results import Candidate
from .scoring import judge
from .settings import FAST, DiagnoseSettings


def without_first(verdicts: Sequence[Candidate], structure: Structure,
                  train: Sequence[Recording], val: Sequence[Recording], proc: Processing,
                  gap_before: float, before_blocks: np.ndarray,
                  settings: DiagnoseSettings, progress: Progress | None = None
                  ) -> Candidate | None:
    """For two structural effects found in turn: the model with the *second* one only,
    fitted from the joint fit's values and judged on the validation records.  Returned
    when the first effect's share of what is left with it is below ``step_min`` (the
    first was a stand-in: measured, a cubic spring m2-ground named before the true
    clearance m2-ground of a 3-DOF chain, then shrunk to nothing by the joint fit), else
    None (both effects stay)."""
    from ..refine import output_error, refine

    if len(verdicts) != 2 or any(v.category != "structure" or v.structure is None
                                 or v.theta is None for v in verdicts):
        return None
    first, second = verdicts
    t0 = time.perf_counter()
    joint = second.structure.as_dict(second.theta)
    scales = {k: max(abs(v), 1e-12) for k, v in second.coefficients.items()}
    aug, names = augmented(structure, second.effect, second.loc, scales)
    start = {p: joint[p] for p in structure.free}
    start.update({names[k]: v for k, v in second.coefficients.items()})
    res = refine(aug, aug.vector(start), list(train), proc, max_nfev=settings.fit_nfev,
                 horizons=None, uncertainty=FAST)
    alone = Candidate(second.effect, second.loc, dict(second.shape), structure=aug,
                      names=names, theta=res.theta, fitted=True, score=second.score,
                      ee_score=second.ee_score, amplitudes=second.amplitudes)
    vals = aug.as_dict(res.theta)
    alone.coefficients = {k: vals[p] for k, p in names.items()}
    alone.parameters = {p: vals[p] for p in structure.free}
    alone.intervals = _intervals(res, aug, names)
    alone.train_cost = float(output_error(aug, res.theta[None], list(train), proc)[0])
    alone.fit_time_s = time.perf_counter() - t0
    judge(alone, val, proc, gap_before, before_blocks, progress)
    if not np.isfinite(alone.gap_after) or not second.gap_after > 0:
        return None
    share = 1.0 - second.gap_after / alone.gap_after  # what the first adds to the second
    _say(progress, f"backward step: {second.label()} alone leaves {alone.gap_after:.4g}, "
                   f"with {first.label()} {second.gap_after:.4g} (its share {share:.3f})")
    alone.note = f"{first.label()} dropped (backward step: its share {share:.3f})"
    return alone if share < settings.step_min else None
