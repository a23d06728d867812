"""Structures with known truth, and measured-like records of them, for the trust benchmarks.

Each ``Case`` is a model spec, its true parameters, where the hammer hits, what the sensors
measure and how noisy they are.  ``Case.record`` simulates one impact test with the
project's RK4 simulator (automatic substeps, ~1e-7 accurate) and adds what instruments
add: white noise relative to each channel's peak, a 60 Hz hum on accelerometers, noise
on the force channel.  Used by ``bench_coverage.py``, ``bench_validation.py`` and, at
reduced size, the tests.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from siva_core import Recording, Structure


@dataclass
class Case:
    name: str
    spec: dict[str, Any]
    truth: dict[str, float]
    force_dof: str
    sensors: str = "acc"            # "acc" (accelerometers) or "disp" (displacement)
    fs: float = 2048.0
    duration_s: float = 4.0
    amplitudes: tuple[float, float] = (100.0, 900.0)
    pulse_s: float = 6.2e-3
    impact_at_s: float = 0.1
    noise: float = 0.003            # std relative to each response channel's peak
    force_noise: float = 0.002      # std relative to the pulse peak
    hum: float = 0.02               # m/s^2 at 60 Hz on accelerometers
    # True: the continuous half-sine drives the structure (simulated on a grid fine enough
    # for >= 24 points per pulse) and the instruments sample force and response, as in a
    # real test; False: the sampled force, linearly interpolated, drives it (the model's own
    # assumption, which hides how the model reads a force between its samples)
    exact_pulse: bool = False
    extra: dict[str, Any] = field(default_factory=dict)

    def structure(self) -> Structure:
        return Structure.from_dict(self.spec)

    def theta(self) -> np.ndarray:
        return self.structure().vector(self.truth)

    def record(self, amplitude: float, rng: np.random.Generator, *, name: str = "rec",
               truth: dict[str, float] | None = None, spec: dict[str, Any] | None = None
               ) -> Recording:
        """One impact test (``truth``/``spec`` override the case's: a changed structure)."""
        from siva_core import simulate

        st = Structure.from_dict(spec or self.spec)
        th = st.vector(truth or self.truth)
        n = int(round(self.duration_s * self.fs)) + 1
        t = np.arange(n) / self.fs
        k = st.dofs.index(self.force_dof)

        def pulse(tt: np.ndarray) -> np.ndarray:
            x = (tt - self.impact_at_s) / self.pulse_s
            return np.where((x >= 0) & (x <= 1), amplitude * np.sin(np.pi * np.clip(x, 0, 1)), 0)

        force = np.zeros((n, st.n_dof))
        force[:, k] = pulse(t)
        z = np.zeros(st.n_dof)
        over = max(1, math.ceil(24.0 / (self.pulse_s * self.fs))) if self.exact_pulse else 1
        tf = np.arange((n - 1) * over + 1) / (self.fs * over)
        fine = np.zeros((len(tf), st.n_dof))
        fine[:, k] = pulse(tf)
        sim = simulate(st, th, tf, z, z, fine, substeps="auto")
        response = np.asarray(sim.a if self.sensors == "acc" else sim.q)[::over]
        cols: dict[str, np.ndarray] = {}
        for j, d in enumerate(st.dofs):
            y = response[:, j]
            noisy = y + self.noise * np.max(np.abs(y)) * rng.standard_normal(n)
            if self.sensors == "acc" and self.hum:
                noisy = noisy + self.hum * np.sin(2 * np.pi * 60.0 * t + rng.uniform(0, 2 * np.pi))
            cols[f"{self.sensors}_{d}"] = noisy
        cols[f"force_{self.force_dof}"] = (force[:, k] + self.force_noise * amplitude
                                           * rng.standard_normal(n))
        return Recording(t, cols, name)

    def records(self, n: int, rng: np.random.Generator, prefix: str = "r", **kw: Any
                ) -> list[Recording]:
        lo, hi = self.amplitudes
        return [self.record(float(rng.uniform(lo, hi)), rng, name=f"{prefix}{i}", **kw)
                for i in range(n)]


def _elements(*rows: tuple[str, str, str, dict[str, str]]) -> list[dict[str, Any]]:
    return [{"kind": kind, "between": [a, b], "params": params} for kind, a, b, params in rows]


LONO = Case(
    "lono", {
        "name": "lono", "dofs": ["LO", "NO"], "mass": {"LO": 1.37, "NO": 1.37},
        "elements": _elements(("damper", "LO", "ground", {"c": "b1"}),
                              ("spring", "LO", "ground", {"k": "k1"}),
                              ("damper", "LO", "NO", {"c": "b2"}),
                              ("spring", "LO", "NO", {"k": "k2"}),
                              ("power_spring", "LO", "NO", {"alpha": "alpha", "beta": "beta"})),
        "parameters": {"beta": {"scale": 1}}},
    {"b1": 3.8405, "b2": 0.78563, "k1": 19273.0, "k2": 1947.6, "alpha": 2.7641e7, "beta": 2.0012},
    force_dof="NO", duration_s=8.0)

CHAIN3 = Case(
    "chain3", {
        "name": "chain3", "dofs": ["m1", "m2", "m3"], "mass": {"m1": 2.0, "m2": 1.5, "m3": 1.0},
        "elements": _elements(("spring", "m1", "ground", {"k": "k1"}),
                              ("damper", "m1", "ground", {"c": "c1"}),
                              ("spring", "m1", "m2", {"k": "k2"}),
                              ("damper", "m1", "m2", {"c": "c2"}),
                              ("spring", "m2", "m3", {"k": "k3"}),
                              ("damper", "m2", "m3", {"c": "c3"}),
                              ("cubic_spring", "m2", "m3", {"k3": "knl"}))},
    {"k1": 4.0e4, "c1": 8.0, "k2": 2.5e4, "c2": 3.0, "k3": 1.5e4, "c3": 2.0, "knl": 3.0e9},
    force_dof="m2", duration_s=4.0, amplitudes=(50.0, 400.0))

SDOF_DISP = Case(
    "sdof_disp", {
        "name": "sdof_disp", "dofs": ["x"], "mass": {"x": 0.8},
        "elements": _elements(("spring", "x", "ground", {"k": "k"}),
                              ("damper", "x", "ground", {"c": "c"}),
                              ("cubic_spring", "x", "ground", {"k3": "k3"}))},
    {"k": 2.0e4, "c": 4.0, "k3": 4.0e9},
    force_dof="x", sensors="disp", fs=1024.0, duration_s=4.0, amplitudes=(50.0, 300.0),
    noise=0.005, hum=0.0)

# --- structures unlike the tuned ones (issue 20): every one driven by the exact pulse.
# fs / highest linear mode and samples per pulse in the comments.

#: the chain of the issue: hammer on the END mass, 1024 Hz (30x), 4 ms pulse (4.1 samples)
CHAIN3_END_1K = replace(CHAIN3, name="chain3_end_1k", force_dof="m3", fs=1024.0,
                        pulse_s=4e-3, amplitudes=(50.0, 300.0), exact_pulse=True)

#: 4 DOFs seen by displacement sensors only, hit on an INNER mass, 256 Hz (5.8x the
#: 44 Hz top mode), 3-sample pulse
CHAIN4_INNER_DISP = Case(
    "chain4_inner_disp", {
        "name": "chain4_inner_disp", "dofs": ["m1", "m2", "m3", "m4"],
        "mass": {"m1": 1.0, "m2": 0.8, "m3": 0.6, "m4": 0.5},
        "elements": _elements(("spring", "m1", "ground", {"k": "k1"}),
                              ("damper", "m1", "ground", {"c": "c1"}),
                              ("spring", "m1", "m2", {"k": "k2"}),
                              ("spring", "m2", "m3", {"k": "k3"}),
                              ("damper", "m2", "m3", {"c": "c3"}),
                              ("spring", "m3", "m4", {"k": "k4"}),
                              ("cubic_spring", "m3", "m4", {"k3": "knl"}))},
    {"k1": 3.0e4, "c1": 6.0, "k2": 2.0e4, "k3": 1.5e4, "c3": 2.0, "k4": 1.0e4, "knl": 5.0e8},
    force_dof="m2", sensors="disp", fs=256.0, duration_s=4.0, amplitudes=(50.0, 200.0),
    pulse_s=3 / 256.0, noise=0.005, hum=0.0, exact_pulse=True)

#: 1 DOF, accelerometer only, 800 Hz (50x its 16 Hz mode), 20-sample pulse
SDOF_ACC_FAST = Case(
    "sdof_acc_fast", {
        "name": "sdof_acc_fast", "dofs": ["x"], "mass": {"x": 0.5},
        "elements": _elements(("spring", "x", "ground", {"k": "k"}),
                              ("damper", "x", "ground", {"c": "c"}),
                              ("cubic_spring", "x", "ground", {"k3": "k3"}))},
    {"k": 5.0e3, "c": 1.5, "k3": 3.0e6},
    force_dof="x", fs=800.0, duration_s=4.0, amplitudes=(20.0, 60.0), pulse_s=20 / 800.0,
    exact_pulse=True)

#: 2 DOFs, accelerometers, hit on the END mass, 128 Hz (6.2x its 21 Hz top mode),
#: 3-sample pulse
TWODOF_END_SLOW = Case(
    "twodof_end_slow", {
        "name": "twodof_end_slow", "dofs": ["m1", "m2"], "mass": {"m1": 1.0, "m2": 1.0},
        "elements": _elements(("spring", "m1", "ground", {"k": "k1"}),
                              ("damper", "m1", "ground", {"c": "c1"}),
                              ("spring", "m1", "m2", {"k": "k2"}),
                              ("damper", "m1", "m2", {"c": "c2"}),
                              ("cubic_spring", "m1", "m2", {"k3": "knl"}))},
    {"k1": 1.0e4, "c1": 2.0, "k2": 5.0e3, "c2": 1.0, "knl": 4.0e6},
    force_dof="m2", fs=128.0, duration_s=6.0, amplitudes=(30.0, 120.0), pulse_s=3 / 128.0,
    hum=0.0, exact_pulse=True)

#: the reference rigs with the exact pulse (LO-NO: 2048 Hz, 12.7 samples; chain hit in
#: the middle; 1-DOF displacement sensor, 1024 Hz, 6.3 samples)
LONO_EXACT = replace(LONO, name="lono_exact", exact_pulse=True)
CHAIN3_EXACT = replace(CHAIN3, name="chain3_exact", exact_pulse=True)
SDOF_DISP_EXACT = replace(SDOF_DISP, name="sdof_disp_exact", exact_pulse=True)

CASES = {c.name: c for c in (LONO, CHAIN3, SDOF_DISP, CHAIN3_END_1K, CHAIN4_INNER_DISP,
                             SDOF_ACC_FAST, TWODOF_END_SLOW, LONO_EXACT, CHAIN3_EXACT,
                             SDOF_DISP_EXACT)}
#: the issue-20 coverage set: six structures of the listed kinds, exact pulses
COVERAGE_SET = ("chain3_end_1k", "chain4_inner_disp", "sdof_acc_fast", "twodof_end_slow",
                "lono_exact", "sdof_disp_exact", "chain3_exact")
