"""The RK4 stage grid both backends step on: the force at every stage time, and the bound
beyond which a state counts as diverged."""
from __future__ import annotations

import numpy as np

#: a state beyond this magnitude is treated as a diverged simulation (rest filled with NaN)
BLOWUP = 1e100


#: how a *measured* force is evaluated between its samples when a record is simulated for
#: an output-error fit (``refine``, ``linearize``, validation): see ``stage_force``
MEASURED_FORCE_INTERP = "moments"


def set_measured_force_interp(interp: str) -> str:
    """Choose how output-error fits read a measured force between samples (an ablation
    knob for benchmarks: ``"moments"``, the default, ``"linear"`` or ``"cubic"``); returns
    the previous choice so a caller can restore it."""
    global MEASURED_FORCE_INTERP
    if interp not in ("moments", "linear", "cubic"):
        raise ValueError(f"force interpolation must be 'linear', 'moments' or 'cubic', "
                         f"got {interp!r}")
    previous, MEASURED_FORCE_INTERP = MEASURED_FORCE_INTERP, interp
    return previous


def stage_force(F: np.ndarray, m: int, interp: str = "linear") -> np.ndarray:
    """The sampled force (T, n) at every RK4 stage time: (2 m (T-1) + 1, n), i.e. on the
    grid t_0 + k h/2 ((B, T, n) -> (B, rows, n): one force per parameter set).

    "linear": straight lines between samples (MATLAB interp1, as the paper).  A straight
    line through point samples of a smooth pulse is a *wider* pulse: its spread (second
    moment) exceeds the samples' own by dt^2/6, i.e. it low-passes the force by
    sinc^2(f dt).  With a hammer pulse of 4 samples that biased a 3-DOF chain's dampings by
    up to 1.5 % (docs/perf.md, issue 20).
    "moments": straight lines through the samples prefiltered by 1 - D2/12 (D2 the second
    difference), so that the continuous force has exactly the samples' impulse, centroid
    and spread (the first three moments), the consistent reading of point samples of a
    force whose shape between them is unknown: the chain's damping bias fell to <= 0.45 %
    (what is left is aliasing of the pulse's kinks, unknowable from the samples).
    "cubic": a not-a-knot cubic spline through the samples (similar to "moments" on
    pulses; a band-limited excitation sampled a few times per period, Silverbox)."""
    if F.ndim == 3:  # one force per parameter set: (B, T, n) -> (B, rows, n)
        return np.stack([stage_force(f, m, interp) for f in F])
    T, n = F.shape
    if interp == "moments":
        # prefilter so that the piecewise-linear force has the samples' own moments
        G = F.copy()
        G[1:-1] -= (F[2:] - 2.0 * F[1:-1] + F[:-2]) / 12.0
        F, interp = G, "linear"
    if interp == "linear":
        w = (np.arange(2 * m) / (2.0 * m))[None, :, None]
        out = np.empty((2 * m * (T - 1) + 1, n))
        out[:-1] = (F[:-1, None, :] * (1.0 - w) + F[1:, None, :] * w).reshape(-1, n)
        out[-1] = F[-1]
        return out
    x = np.arange(2 * m * (T - 1) + 1) / (2.0 * m)  # in sample units
    if interp == "cubic":
        from scipy.interpolate import CubicSpline

        return CubicSpline(np.arange(T, dtype=float), F, axis=0)(x)
    raise ValueError(f"force interpolation must be 'linear', 'moments' or 'cubic', "
                     f"got {interp!r}")



def shifted_stage_force(F: np.ndarray, m: int, interp: str, shifts: np.ndarray) -> np.ndarray:
    """(B, rows, n): the force read as ``stage_force`` does, then delayed by ``shifts[b]``
    samples for set b (the model sees f(t - shift dt)).  Why: the instant at which a
    hammer pulse's few samples fall within it changes what its piecewise-linear reading
    puts into the modes (docs/perf.md 6.3); a fitted sub-sample delay per record absorbs
    the part of that error that acts as a timing error.  Only "linear" and "moments"
    (piecewise linear, so the delayed reading is exact); before the record's start the
    first sample's value holds.  ``F`` (T, n), or (B, T, n): one force per set."""
    shifts = np.asarray(shifts, dtype=float).ravel()
    if F.ndim == 3:
        return np.concatenate([shifted_stage_force(f, m, interp, s[None])
                               for f, s in zip(F, shifts)])
    if interp == "moments":
        G = F.copy()
        G[1:-1] -= (F[2:] - 2.0 * F[1:-1] + F[:-2]) / 12.0
    elif interp == "linear":
        G = F
    else:
        raise ValueError(f"a shifted force needs interp 'linear' or 'moments', got {interp!r}")
    T, n = G.shape
    x = np.arange(2 * m * (T - 1) + 1) / (2.0 * m)
    idx = np.arange(T, dtype=float)
    out = np.empty((len(shifts), len(x), n))
    for b, s in enumerate(shifts):
        for j in range(n):
            out[b, :, j] = np.interp(x - s, idx, G[:, j]) if np.any(G[:, j]) else 0.0
    return out
