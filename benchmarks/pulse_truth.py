"""Whether a drawn gain fault is within what the hammer pulse's reading explains, from
the generator's own truth (issue 16; never from the diagnosis).

The generator drives the structure with the continuous half-sine of impulse
``I = 2 P w / pi`` and records its samples.  Other half-sines pass through the same
samples (they start after the sample before the pulse and end before the sample after
it): their impulses span ``[I_lo, I_hi]`` around ``I``.  When the force channel reads
``g`` times the true force, the half-sines through its samples deliver ``g [I_lo, I_hi]``,
and no fault is needed to explain the records when the structure's ``I`` is among them,
i.e. when ``g`` is in ``[I / I_hi, I / I_lo]``: such a gain cannot be identified from the
records (up to the few-% difference in what those half-sines put into higher modes).
On a 1-DOF model an accelerometer gain ``a`` is the force gain ``1 / a``.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

#: start/end points tried per sample interval, and how closely (of the peak, on top of
#: the force channel's own noise) a half-sine must pass through the true samples: the
#: diagnosis's own shape tolerance (a hammer's pulse is not an exact half-sine)
GRID = 201
SHAPE_TOL = 0.01


def pulse_impulses(width: float, fs: float, t0: float, noise: float = 0.0
                   ) -> dict[str, float]:
    """The true impulse, the samples' sum x dt and the range of impulses of the half-sines
    consistent with the samples, all per unit peak; and the number of samples."""
    first = math.ceil(t0 * fs - 1e-9)
    k = np.arange(first, math.floor((t0 + width) * fs + 1e-9) + 1, dtype=float)
    if first == t0 * fs:  # the sample at the start is zero: not part of the pulse
        k = k[1:]
    y = np.sin(np.pi * np.clip((k / fs - t0) / width, 0.0, 1.0))
    k, y = k[y > 0], y[y > 0]
    true = 2.0 * width / math.pi
    u = np.linspace(0.0, 1.0, GRID, endpoint=False)
    v = np.linspace(1.0 / GRID, 1.0, GRID)
    ts = k[0] - u[:, None, None]
    te = k[-1] + v[None, :, None]
    s = np.sin(np.pi * np.clip((k - ts) / (te - ts), 0.0, 1.0))
    p = np.sum(s * y, axis=-1) / np.sum(s * s, axis=-1)
    rms = np.sqrt(np.mean((p[..., None] * s - y) ** 2, axis=-1))
    imp = 2.0 * p * (te - ts)[..., 0] / math.pi / fs
    ok = rms <= SHAPE_TOL + 3.0 * noise
    return {"true": true, "sum": float(np.sum(y)) / fs, "low": float(np.min(imp[ok])),
            "high": float(np.max(imp[ok])), "samples": int(len(k))}


def gain_reading(fault: tuple[str, str, float] | None, n_dof: int, width: float, fs: float,
                 t0: float, force_noise: float) -> dict[str, Any] | None:
    """For a force gain (or a 1-DOF model's accelerometer gain) fault: its force-channel
    equivalent, the range of gains the pulse reading explains and whether it is inside;
    None for other faults."""
    if fault is None:
        return None
    kind, channel, value = fault
    if not (kind == "force_gain" or (kind == "accelerometer_gain" and n_dof == 1)):
        return None
    g = value if kind == "force_gain" else 1.0 / value
    imp = pulse_impulses(width, fs, t0, force_noise)
    low, high = imp["true"] / imp["high"], imp["true"] / imp["low"]
    return {"gain": g, "low": low, "high": high, "within": bool(low <= g <= high),
            "samples": imp["samples"], "sum_over_true": imp["sum"] / imp["true"]}
