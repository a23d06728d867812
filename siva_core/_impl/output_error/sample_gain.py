"""The hit DOF's accelerations at the hammer pulse's own samples, with their gain profiled
out whenever a force multiplier is fitted (issue 20, docs/perf.md 6.7).

Why: an accelerometer sampled during a hammer pulse reads (F(t_i) - internal forces) / m,
and the simulation takes the force *sample* there (``sampled_force_acceleration``) --
times the record's fitted force multiplier.  But the multiplier is fitted for what the
model's reading of a few-sample pulse puts into the modes *between* the samples (its
impulse: 0.978 for a 4-sample pulse at 1 kHz, docs/perf.md 4 and 6.1), not for the samples
themselves, which the force sensor read right.  Scaled, the pulse's 4-5 accelerations were
off by (multiplier - 1) x the peak -- as large as the free decay's own acceleration --
and the chain's low-pass spread that error over the first ~10 ms of the compared record,
which the fit paid for in damping (chain hit on its end mass, 1024 Hz: c1 +0.06 % at a
155 Hz low-pass, +0.17 % at the 95 Hz one noisy records get, +0.3 % ~ 0.9 standard errors
in the coverage benchmark).  Unscaled would be wrong the other way when the force sensor's
gain is what is off (then the multiplier is right at the samples too).  So neither: the
gain of the force term at the samples is its own nuisance, linear in the residuals, and
is projected out in closed form per parameter set (variable projection: the residuals of
``OutputErrorProblem.record_residuals`` are those at that gain's optimum, and the
finite-difference Jacobians of refine / linearize are the projected problem's).
"""
from __future__ import annotations

from typing import Any

import numpy as np

#: profile out the gain of the hit DOF's accelerations at the pulse samples wherever a
#: force multiplier is fitted; False restores the multiplier there (ablation, tests)
PROFILE_SAMPLE_GAIN = True


def set_sample_gain_profiling(on: bool) -> bool:
    """Ablation knob for benchmarks and tests: whether output-error fits with a force
    multiplier profile out the gain at the pulse samples (``PROFILE_SAMPLE_GAIN``).
    Returns the previous setting so a caller can restore it."""
    global PROFILE_SAMPLE_GAIN
    previous = PROFILE_SAMPLE_GAIN
    PROFILE_SAMPLE_GAIN = bool(on)
    return previous


def sample_gain_pattern(problem: Any, k: int) -> np.ndarray | None:
    """(T',) record ``k``'s weighted, processed hit-DOF acceleration of a unit gain on the
    force samples of its pulse (what a change of that gain does to the residuals), or None
    when nothing is to be projected: no single pulse, the hit DOF not compared in
    acceleration.  Cached on the record (the chain and the samples are fixed)."""
    r = problem.records[k]
    if r.kick_pulse is None or r.quantities[r.hit_dof] != "acc":
        return None
    cached = getattr(r, "_gain_pattern", None)
    if cached is not None and cached[0] == id(r.kick_pulse):
        return cached[1]
    st = problem.structure
    T, n = len(r.rec), st.n_dof
    a = np.zeros((1, T, n))
    a[0, :, r.hit_dof] = r.kick_pulse
    zero = np.zeros_like(a)
    out = problem.chain.apply_simulated(r.rec, st.dofs, zero, zero, a, need="a")
    p = np.asarray(out.a)[0, :, r.hit_dof] * problem.weight(k)[r.hit_dof]
    p = p if np.any(p) and np.all(np.isfinite(p)) else None
    r._gain_pattern = (id(r.kick_pulse), p)
    return p


def project_sample_gain(res: np.ndarray, pattern: np.ndarray, hit: int) -> np.ndarray:
    """(B, T', n) weighted residuals ``res`` with their hit column made orthogonal to
    ``pattern`` (the sample gain at its least-squares optimum for every set)."""
    col = res[:, :, hit]
    c = (col @ pattern) / float(pattern @ pattern)
    out = res.copy()
    out[:, :, hit] = col - c[:, None] * pattern[None, :]
    return out


__all__ = ["PROFILE_SAMPLE_GAIN", "project_sample_gain", "sample_gain_pattern",
           "set_sample_gain_profiling"]
