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
        if interp in ("moments", "linear") and len(F) > 1:
            return _staged_batch(F, m, interp)
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




def _prefiltered(F: np.ndarray, interp: str) -> np.ndarray:
    """The samples the piecewise-linear reading goes through (``stage_force``'s prefilter
    for "moments", the samples themselves for "linear"), along axis -2."""
    if interp != "moments":
        return F
    G = F.copy()
    G[..., 1:-1, :] -= (F[..., 2:, :] - 2.0 * F[..., 1:-1, :] + F[..., :-2, :]) / 12.0
    return G


def _staged_batch(F: np.ndarray, m: int, interp: str) -> np.ndarray:
    """``stage_force`` of each of the (B, T, n) forces, the same numbers as one by one:
    the first in full, each other one as a copy of it with only the sample intervals
    whose prefiltered end points differ recomputed.  Why: the parametric replicates
    differ only in the few samples of a hammer pulse (new force-sensor noise there), and
    staging each in full cost 0.6 s of LO-NO's identify (docs/perf.md 8.3)."""
    B, T, n = F.shape
    G = _prefiltered(F, interp)
    first = stage_force(F[0], m, interp)
    out = np.empty((B,) + first.shape)
    out[0] = first
    w = (np.arange(2 * m) / (2.0 * m))[None, :, None]
    for b in range(1, B):
        out[b] = first
        same = np.all(G[b] == G[0], axis=-1)           # (T,) end points as the first's
        if not same[-1]:
            out[b, -1] = G[b, -1]
        changed = np.flatnonzero(~(same[:-1] & same[1:]))   # intervals to recompute
        if changed.size == 0:
            continue
        i0, i1 = int(changed[0]), int(changed[-1]) + 1
        out[b, 2 * m * i0:2 * m * i1] = (G[b, i0:i1, None, :] * (1.0 - w)
                                         + G[b, i0 + 1:i1 + 1, None, :] * w).reshape(-1, n)
    return out


def adjusted_stage_force(F: np.ndarray, m: int, interp: str, shifts: np.ndarray | None = None,
                         spreads: np.ndarray | None = None) -> np.ndarray:
    """(B, rows, n): the force read as ``stage_force`` does, delayed by ``shifts[b]``
    samples (the model sees f(t - shift dt)) and with its spread (second moment about the
    centroid) changed by ``spreads[b]`` dt^2, for each set b.

    Why: where a hammer pulse's few samples fall within it changes what its reading puts
    into the modes -- impulse, timing and spread (docs/perf.md 6.3); the impulse is the
    fitted force multiplier, these are the next two moments as per-record nuisances.  The
    spread is the prefilter of the "moments" reading, G = F - w D2 F, with w = 1/12 - spread/2
    (straight lines through G have the samples' own spread plus dt^2 (1/6 - 2 w); "linear"
    starts from w = 0): impulse and centroid stay, and the force stays linear in each
    nuisance.  Piecewise linear, so the delayed reading is exact; before the record's start
    the first sample's value holds.  ``F`` (T, n), or (B, T, n): one force per set."""
    if interp not in ("linear", "moments"):
        raise ValueError(f"an adjusted force needs interp 'linear' or 'moments', got {interp!r}")
    w0 = 1.0 / 12.0 if interp == "moments" else 0.0
    B = max(len(np.ravel(x)) for x in (shifts, spreads, [0.0]) if x is not None)
    if F.ndim == 3:
        B = len(F)
    sh = np.broadcast_to(np.zeros(1) if shifts is None else np.asarray(shifts, float).ravel(), (B,))
    sp = np.broadcast_to(np.zeros(1) if spreads is None else np.asarray(spreads, float).ravel(),
                         (B,))
    Fs = np.broadcast_to(F, (B,) + F.shape[-2:])
    T, n = Fs.shape[1:]
    x = np.arange(2 * m * (T - 1) + 1) / (2.0 * m)
    idx = np.arange(T, dtype=float)
    out = np.zeros((B, len(x), n))
    for b in range(B):
        f = Fs[b]
        G = f.copy()
        G[1:-1] -= (w0 - 0.5 * sp[b]) * (f[2:] - 2.0 * f[1:-1] + f[:-2])
        for j in range(n):
            if np.any(G[:, j]):
                out[b, :, j] = np.interp(x - sh[b], idx, G[:, j])
    return out
