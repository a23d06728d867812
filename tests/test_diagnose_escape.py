"""A start that escapes (a softening cubic past its turning point) is recognised by the
substep pilot at a few substeps instead of being refined to the 4096-substep cap: its
blow-up sample stays put when the step shrinks and its tangent is unstable there (issue 16,
17040's nominal fit).  A stiff hardening run that is merely under-resolved still refines."""
from __future__ import annotations

import numpy as np

from siva_core import Structure, auto_substeps, simulate
from siva_core._impl.simulate.substeps import escaping

SPEC = {"name": "duffing", "dofs": ["m1"], "mass": {"m1": 1.0},
        "elements": [{"kind": "spring", "between": ["m1", "ground"], "params": {"k": "k"}},
                     {"kind": "damper", "between": ["m1", "ground"], "params": {"c": "c"}},
                     {"kind": "cubic_spring", "between": ["m1", "ground"],
                      "params": {"k3": "k3"}}]}


def _case(k3: float) -> tuple[Structure, np.ndarray, np.ndarray, np.ndarray]:
    st = Structure.from_dict(SPEC)
    theta = st.vector({"k": 4e3, "c": 2.0, "k3": k3})
    fs = 1024.0
    t = np.arange(256) / fs
    F = np.zeros((len(t), 1))
    on = (t >= 0.05) & (t <= 0.054)
    F[on, 0] = 400.0 * np.sin(np.pi * (t[on] - 0.05) / 4e-3)
    return st, theta, t, F


def test_an_escaping_start_stops_the_pilot_at_a_few_substeps() -> None:
    st, theta, t, F = _case(-1e9)   # the turning point at 2 mm; the hit reaches further
    z = np.zeros(1)
    m = auto_substeps(st, theta, t[1], z, z, F, n_samples=len(t))
    assert m <= 32                               # was the 4096 cap
    sim = simulate(st, theta, t, z, z, F, substeps=m)
    assert not np.all(np.isfinite(sim.q))        # the model itself escapes: cost infinite


def test_escape_needs_a_blow_up_that_stays_put_on_an_unstable_tangent() -> None:
    st, theta, t, F = _case(-1e9)
    z = np.zeros(1)
    runs = [simulate(st, theta, t, z, z, F, substeps=m) for m in (2, 8, 32)]
    bad = [np.array([int(np.argmin(np.isfinite(r.q[:, 0])))]) for r in runs]
    assert 0 < bad[0][0] and abs(bad[0][0] - bad[2][0]) <= 2
    q, v = runs[2].q[None], runs[2].v[None]
    assert escaping(st, theta[None], q, v, bad[2], bad[:2])[0]
    assert not escaping(st, theta[None], q, v, bad[2], bad[1:2])[0]  # one refinement: unsure
    # the same samples, but a stable (hardening) tangent: not an escape
    hard = st.vector({"k": 4e3, "c": 2.0, "k3": 1e9})
    assert not escaping(st, hard[None], np.abs(q), v, bad[2], bad[:2])[0]
    # an unstable tangent whose blow-up moved with the step: the integrator's, not an escape
    assert not escaping(st, theta[None], q, v, bad[2], [bad[0], bad[2] // 2])[0]
