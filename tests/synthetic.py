"""Exact synthetic records shared by tests: the closed-form free decay of a linear oscillator,
and the unit oscillator with half-sine hammer pulses the pulse-reading tests use."""
from __future__ import annotations

import numpy as np

from siva_core import Recording, Structure

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


def unit_sdof() -> tuple[Structure, np.ndarray]:
    """A 1 kg oscillator at 10 Hz (c = 1 N s/m) and its parameter vector: the pulse-reading
    tests' structure."""
    spec = {"name": "sdof", "dofs": ["x"], "mass": {"x": 1.0},
            "elements": [{"kind": "spring", "between": ["x", "ground"], "params": {"k": "k"}},
                         {"kind": "damper", "between": ["x", "ground"], "params": {"c": "c"}}]}
    st = Structure.from_dict(spec)
    return st, st.vector({"k": (2 * np.pi * 10.0) ** 2, "c": 1.0})


def half_sine_hit(width_samples: float, phase: float) -> Recording:
    """A 100 N half-sine hammer pulse of ``width_samples`` at 512 Hz, starting ``phase``
    samples after sample 40, with a silent accelerometer: what the pulse reading sees."""
    fs = 512.0
    t = np.arange(1024) / fs
    x = (t - (40 + phase) / fs) / (width_samples / fs)
    f = np.where((x >= 0) & (x <= 1), 100.0 * np.sin(np.pi * np.clip(x, 0, 1)), 0.0)
    return Recording(t, {"force_x": f, "acc_x": np.zeros(len(t))}, "hit")


#: the LO-NO rig's nominal values (benchmarks/matrix.py)
LONO = {"b1": 3.8405, "b2": 0.78563, "k1": 19273.0, "k2": 1947.6, "alpha": 2.7641e7,
        "beta": 2.0012}


def lono_hit(dofs: list[str], peak: float, duration_s: float, fs: float = 2048.0
             ) -> tuple[np.ndarray, np.ndarray]:
    """(t, F): a 6.2 ms half-sine hammer pulse of ``peak`` N on NO at 0.1 s, the LO-NO
    rig's columns in ``dofs`` order."""
    t = np.arange(int(duration_s * fs)) / fs
    F = np.zeros((len(t), len(dofs)))
    on = (t >= 0.1) & (t <= 0.1 + 6.2e-3)
    F[on, dofs.index("NO")] = peak * np.sin(np.pi * (t[on] - 0.1) / 6.2e-3)
    return t, F
