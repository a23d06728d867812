"""Structures with known truth, and measured-like records of them, for the trust benchmarks.

Each ``Case`` is a model spec, its true parameters, where the hammer hits, what the sensors
measure and how noisy they are.  ``Case.record`` simulates one impact test with the
project's RK4 simulator (automatic substeps, ~1e-7 accurate) and adds what instruments
add: white noise relative to each channel's peak, a 60 Hz hum on accelerometers, noise
on the force channel.  Used by ``bench_coverage.py``, ``bench_validation.py`` and, at
reduced size, the tests.
"""
from __future__ import annotations

from dataclasses import dataclass, field
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
        force = np.zeros((n, st.n_dof))
        k = st.dofs.index(self.force_dof)
        x = (t - self.impact_at_s) / self.pulse_s
        force[:, k] = np.where((x >= 0) & (x <= 1), amplitude * np.sin(np.pi * np.clip(x, 0, 1)), 0)
        z = np.zeros(st.n_dof)
        sim = simulate(st, th, t, z, z, force, substeps="auto")
        cols: dict[str, np.ndarray] = {}
        for j, d in enumerate(st.dofs):
            y = np.asarray(sim.a if self.sensors == "acc" else sim.q)[:, j]
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

CASES = {c.name: c for c in (LONO, CHAIN3, SDOF_DISP)}
