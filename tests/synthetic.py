"""Exact synthetic records shared by tests: the closed-form free decay of a linear oscillator."""
from __future__ import annotations

import numpy as np

from siva_core import Recording

SDOF = {"name": "sdof", "dofs": ["x"], "mass": {"x": 2.0}, "elements": [
    {"kind": "spring", "between": ["x", "ground"], "params": {"k": "k"}},
    {"kind": "damper", "between": ["x", "ground"], "params": {"c": "c"}}]}
TRUE = {"k": 5.0e4, "c": 12.0}


def free_decay(v0: float, n: int = 1500, fs: float = 1000.0, *, m: float = 2.0,
               k: float = TRUE["k"], c: float = TRUE["c"]) -> Recording:
    """Exact free decay of a linear oscillator (SDOF by default) from x = 0, x' = v0,
    with disp, vel and acc columns."""
    wn, zeta = np.sqrt(k / m), c / (2 * np.sqrt(k * m))
    wd = wn * np.sqrt(1 - zeta ** 2)
    t = np.arange(n) / fs
    env = np.exp(-zeta * wn * t)
    q = v0 / wd * env * np.sin(wd * t)
    v = v0 * env * (np.cos(wd * t) - zeta * wn / wd * np.sin(wd * t))
    a = -(k * q + c * v) / m
    return Recording(t, {"disp_x": q, "vel_x": v, "acc_x": a}, f"decay_v{v0:g}.csv")
