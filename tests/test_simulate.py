"""Batched simulation: both backends against scipy's DOP853, the reference data, every
element kind, batch consistency, the kernel cache and the force handling."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.interpolate import CubicSpline

from siva_core import (ELEMENT_KINDS as REGISTRY, ElementKind, Processing, Recording, Structure,
                       auto_substeps, detect_impulse, gate_force, initial_state_and_force,
                       Simulation, register_element, simulate, stage_force)
from siva_core._impl.simulate import compiled_kernel  # the kernel cache is private behaviour

DUFFING_TRUTH = np.array([0.5, 4000.0, 300.0, 3e8])  # b, b_nl, k, k_nl (paper eq. 5)


def reference(structure: Structure, theta: np.ndarray, t: np.ndarray, q0, v0,
              force: np.ndarray | None = None) -> np.ndarray:
    """(T, n) displacement by solve_ivp(DOP853, rtol 1e-10), the force interpolated linearly
    as the simulator does; integrated sample interval by sample interval wherever the force
    is non-zero (its kinks would otherwise be stepped over)."""
    n = structure.n_dof

    def rhs(x: float, y: np.ndarray) -> np.ndarray:
        f = None if force is None else np.array([np.interp(x, t, force[:, k]) for k in range(n)])
        return np.concatenate([y[n:], structure.accelerations(theta, y[:n], y[n:], f)])

    breaks = [t[0], t[-1]]
    if force is not None:
        nz = np.flatnonzero(np.any(force != 0, axis=1))
        if nz.size:
            breaks = np.unique(np.r_[t[0], t[max(nz[0] - 1, 0):nz[-1] + 2], t[-1]])
    out = np.empty((len(t), n))
    y = np.concatenate([np.asarray(q0, float), np.asarray(v0, float)])
    for a, b in zip(breaks[:-1], breaks[1:]):
        sel = (t >= a) & (t <= b)
        sol = solve_ivp(rhs, (a, b), y, method="DOP853", rtol=1e-10, atol=1e-14, t_eval=t[sel])
        assert sol.success, sol.message
        out[sel] = sol.y[:n].T
        y = sol.y[:, -1]
    return out


def simulate_record(structure: Structure, theta: np.ndarray, rec: Recording,
                    processing: Processing | None = None, **kw) -> Simulation:
    """Simulate what ``rec`` recorded, from the initial state and force the chain implies."""
    q0, v0, force = initial_state_and_force(structure, rec, processing or Processing())
    return simulate(structure, theta, rec.time, q0, v0, force, **kw)


def rel_err(x: np.ndarray, ref: np.ndarray) -> float:
    return float(np.max(np.abs(x - ref)) / np.max(np.abs(ref)))


def half_sine(t: np.ndarray, n_dof: int, dof: int, peak: float, t0: float = 0.1,
              width: float = 0.0062) -> np.ndarray:
    F = np.zeros((len(t), n_dof))
    tau = t - t0
    on = (tau >= 0) & (tau <= width)
    F[on, dof] = peak * np.sin(np.pi * tau[on] / width)
    return F


# ------------------------------------------------------------------ accuracy vs DOP853
def test_duffing_free_response_matches_dop853_numba(duffing_model: Structure) -> None:
    t = np.arange(10001) * 1e-4
    ref = reference(duffing_model, DUFFING_TRUTH, t, [0.0], [5.0])
    sim = simulate(duffing_model, DUFFING_TRUTH, t, [0.0], [5.0], substeps="auto", backend="numba")
    assert sim.backend == "numba"
    # the tangent (not the linear) frequency sets the step: 1 substep would be 2e-5 off
    assert sim.substeps >= 3
    assert rel_err(sim.q, ref) < 1e-6
    assert sim.q.shape == sim.v.shape == sim.a.shape == (len(t), 1)


def test_duffing_free_response_matches_dop853_numpy(duffing_model: Structure) -> None:
    t = np.arange(2001) * 1e-4  # the generic backend is slow: the violent first 0.2 s
    ref = reference(duffing_model, DUFFING_TRUTH, t, [0.0], [5.0])
    sim = simulate(duffing_model, DUFFING_TRUTH, t, [0.0], [5.0], substeps="auto", backend="numpy")
    assert sim.backend == "numpy"
    assert rel_err(sim.q, ref) < 1e-6


def test_duffing_truth_reproduces_train_v5(duffing_model: Structure, shared_data: Path) -> None:
    truth = json.loads((shared_data / "duffing" / "truth.json").read_text())
    assert duffing_model.mass["x"] == truth["mass"]["x"]
    theta = duffing_model.vector(truth["truth"])
    rec = Recording.read(shared_data / "duffing" / "train_v5.csv", duffing_model.dofs)
    sim = simulate_record(duffing_model, theta, rec, substeps="auto")
    x = rec.channels["disp_x"]
    assert rel_err(sim.q[:, 0], x) < 1e-6
    assert rel_err(sim.v[:, 0], rec.channels["vel_x"]) < 1e-6
    assert rel_err(sim.a[:, 0], rec.channels["acc_x"]) < 1e-6


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_lono_forced_response_matches_dop853(lono_model: Structure, shared_data: Path,
                                             backend: str) -> None:
    truth = json.loads((shared_data / "lono" / "truth.json").read_text())
    theta = lono_model.vector(truth["truth"])
    # the nonlinear part and the start of the decay (shorter for the slow generic backend)
    t = np.arange((2 if backend == "numba" else 1) * 2048 + 1) / 2048.0
    F = half_sine(t, 2, lono_model.dofs.index("NO"), 530.0)
    ref = reference(lono_model, theta, t, np.zeros(2), np.zeros(2), F)
    sim = simulate(lono_model, theta, t, np.zeros(2), np.zeros(2), F, substeps="auto",
                   backend=backend)
    assert rel_err(sim.q, ref) < 1e-6
    assert np.max(np.abs(ref[:, 1])) > 0.01  # really the strongly nonlinear regime (> 1 cm)


def test_backends_agree_to_rounding(lono_model: Structure) -> None:
    theta = np.array([3.8, 19000.0, 0.8, 1950.0, 2.7e7, 2.0])
    t = np.arange(1025) / 2048.0
    F = half_sine(t, 2, 1, 400.0, t0=0.05)
    a = simulate(lono_model, theta, t, np.zeros(2), np.zeros(2), F, substeps=3, backend="numba")
    b = simulate(lono_model, theta, t, np.zeros(2), np.zeros(2), F, substeps=3, backend="numpy")
    for x, y in ((a.q, b.q), (a.v, b.v), (a.a, b.a)):
        assert rel_err(x, y) < 1e-12


# ------------------------------------------------------------------ every element kind
KIND_VALUES = {"k": 4000.0, "c": 2.0, "k3": 4e7, "k2": 2e4, "alpha": 3e7, "beta": 2.0,
               "c3": 2e3, "c2": 20.0, "fc": 0.5, "gap": 0.004}
#: force laws with a kink (clearance at |d| = gap, dv|dv| at dv = 0) cost fixed-step RK4 its
#: order at each crossing: at the automatic step up to ~3e-4 off, at 4x the step far closer
KINKED = {"clearance", "quadratic_damper"}


def kind_structure(kind: str) -> tuple[Structure, np.ndarray]:
    """Two DOFs: x grounded by a spring and damper, y on x through the kind under test and
    a weak spring (so that every kind, even a dead zone, leaves a well-posed system)."""
    coeffs = REGISTRY[kind].coefficients
    spec = {"name": f"kind_{kind}", "dofs": ["x", "y"], "mass": {"x": 1.0, "y": 0.5},
            "elements": [
                {"kind": "spring", "between": ["x", "ground"], "params": {"k": "kg"}},
                {"kind": "damper", "between": ["x", "ground"], "params": {"c": "cg"}},
                {"kind": "spring", "between": ["y", "x"], "params": {"k": "kw"}},
                {"kind": kind, "between": ["y", "x"], "params": {c: f"p_{c}" for c in coeffs}}],
            "forces": {"y": {"gain": 1.0}}}
    s = Structure.from_dict(spec)
    values = {"kg": 6000.0, "cg": 3.0, "kw": 500.0,
              **{f"p_{c}": KIND_VALUES.get(c, 1.0) for c in coeffs}}
    return s, s.vector(values)


@pytest.mark.parametrize("kind", sorted(REGISTRY))
def test_every_registered_kind(kind: str) -> None:
    s, theta = kind_structure(kind)
    fs = 1000.0
    t = np.arange(801) / fs
    F = half_sine(t, 2, 1, 60.0, t0=0.02, width=0.005)
    q0, v0 = np.array([0.0, 0.01]), np.array([0.0, 0.0])
    ref = reference(s, theta, t, q0, v0, F)
    sim_nb = simulate(s, theta, t, q0, v0, F, substeps="auto", backend="numba")
    head = slice(0, 301)  # the generic backend is slow at coulomb's many substeps
    sim_np = simulate(s, theta, t[head], q0, v0, F[head], substeps=sim_nb.substeps,
                      backend="numpy")
    assert rel_err(sim_nb.q[head], sim_np.q) < 1e-11
    if kind in KINKED:
        assert rel_err(sim_nb.q, ref) < 1e-3
        fine = simulate(s, theta, t, q0, v0, F, substeps=4 * sim_nb.substeps)
        assert rel_err(fine.q, ref) < 2e-5
    else:
        assert rel_err(sim_nb.q, ref) < 1e-6
    assert np.max(np.abs(sim_nb.q[:, 1] - sim_nb.q[:, 0])) > 1e-3  # the element was loaded


# ------------------------------------------------------------------ batching
def test_batch_equals_per_set_results(duffing_model: Structure) -> None:
    rng = np.random.default_rng(3)
    thetas = DUFFING_TRUTH * (1 + 0.1 * rng.uniform(-1, 1, (6, 4)))
    q0 = rng.uniform(-1e-3, 1e-3, (6, 1))
    v0 = rng.uniform(2.0, 6.0, (6, 1))
    t = np.arange(1501) * 1e-4
    for backend, sets in (("numba", range(6)), ("numpy", (0, 5))):
        batch = simulate(duffing_model, thetas, t, q0, v0, substeps=4, backend=backend)
        assert batch.q.shape == (6, len(t), 1)
        for b in sets:
            one = simulate(duffing_model, thetas[b], t, q0[b], v0[b], substeps=4, backend=backend)
            assert one.q.shape == (len(t), 1)
            np.testing.assert_allclose(batch.q[b], one.q, rtol=1e-13, atol=1e-16)
            np.testing.assert_allclose(batch.a[b], one.a, rtol=1e-13, atol=1e-12)


def test_diverging_set_is_nan_and_isolated(duffing_model: Structure) -> None:
    thetas = np.stack([DUFFING_TRUTH, DUFFING_TRUTH * np.array([1, 1, 1, -1])])  # softening
    t = np.arange(2001) * 1e-4
    sim = simulate(duffing_model, thetas, t, [0.0], [5.0], substeps=3)
    assert np.all(np.isfinite(sim.q[0]))
    assert np.isnan(sim.q[1, -1, 0])
    ref = simulate(duffing_model, thetas[0], t, [0.0], [5.0], substeps=3)
    np.testing.assert_array_equal(sim.q[0], ref.q)


def test_force_scale_and_gain_scale_a_linear_response(sdof_model: Structure) -> None:
    t = np.arange(2001) / 1000.0
    F = half_sine(t, 1, 0, 10.0, t0=0.05, width=0.004)
    theta = np.array([(2 * np.pi * 10) ** 2, 1.0])
    base = simulate(sdof_model, theta, t, [0.0], [0.0], F, substeps=2)
    scaled = simulate(sdof_model, np.stack([theta, theta]), t, [0.0], [0.0], F, substeps=2,
                      force_scale=[1.0, 2.5])
    np.testing.assert_allclose(scaled.q[0], base.q, rtol=1e-14, atol=1e-18)
    np.testing.assert_allclose(scaled.q[1], 2.5 * base.q, rtol=1e-12, atol=1e-18)


# ------------------------------------------------------------------ substeps, force
def test_auto_substeps_sees_amplitude_not_only_linear_modes(duffing_model: Structure) -> None:
    dt = 1e-4
    linear_only = auto_substeps(duffing_model, DUFFING_TRUTH[None], dt, np.zeros((1, 1)),
                                np.full((1, 1), 5.0), None, n_samples=10001, pilot=False)
    with_pilot = auto_substeps(duffing_model, DUFFING_TRUTH[None], dt, np.zeros((1, 1)),
                               np.full((1, 1), 5.0), None, n_samples=10001, backend="numba")
    assert linear_only == 1  # 77 rad/s * 1e-4 s
    assert with_pilot >= 3   # ~1300 rad/s at 1 cm
    small = auto_substeps(duffing_model, DUFFING_TRUTH[None], dt, np.zeros((1, 1)),
                          np.full((1, 1), 0.01), None, n_samples=10001, backend="numba")
    assert small == 1


def test_stage_force_interpolation() -> None:
    rng = np.random.default_rng(0)
    F = rng.standard_normal((50, 2))
    m = 3
    x = np.arange(2 * m * 49 + 1) / (2 * m)
    lin = stage_force(F, m, "linear")
    assert lin.shape == (len(x), 2)
    for k in range(2):
        np.testing.assert_allclose(lin[:, k], np.interp(x, np.arange(50), F[:, k]), atol=1e-14)
    np.testing.assert_allclose(stage_force(F, m, "cubic"), CubicSpline(np.arange(50), F)(x),
                               atol=1e-13)
    np.testing.assert_allclose(stage_force(F, 1, "linear")[1::2], 0.5 * (F[1:] + F[:-1]))
    with pytest.raises(ValueError, match="interpolation"):
        stage_force(F, m, "sinc")


def test_impulse_gating_and_rest_start(lono_model: Structure, shared_data: Path) -> None:
    rec = Recording.read(shared_data / "lono" / "impact_530N.csv", lono_model.dofs)
    F = rec.stack("force", lono_model.dofs, fill=0.0)
    lo, hi = detect_impulse(F).window(margin=2)
    assert 0.095 < rec.time[lo] < 0.1 < 0.1062 < rec.time[hi] < 0.112
    g = gate_force(F)
    assert np.all(g[:lo] == 0) and np.all(g[hi:] == 0)
    np.testing.assert_array_equal(g[lo:hi], F[lo:hi])
    multisine = np.sin(np.arange(1000) * 0.3)[:, None]
    assert detect_impulse(multisine) is None
    np.testing.assert_array_equal(gate_force(multisine), multisine)
    # a pre-triggered impact starts at rest, whatever the band-pass smears into row 0
    sim = simulate_record(lono_model, lono_model.vector(json.loads(
        (shared_data / "lono" / "truth.json").read_text())["truth"]), rec, Processing.paper(),
        substeps=3)
    assert np.all(sim.q[:lo] == 0.0)


# ------------------------------------------------------------------ kernels and backends
def test_kernel_cached_per_signature(lono_model: Structure) -> None:
    k1 = compiled_kernel(lono_model)
    spec = dict(lono_model.spec)
    spec["mass"] = {"LO": 2.0, "NO": 0.5}  # masses are arguments, not part of the signature
    other = Structure.from_dict(spec)
    assert compiled_kernel(other) is k1
    spec["elements"] = spec["elements"][:-1]  # drop the power spring (and beta's settings)
    spec["parameters"] = {}
    assert compiled_kernel(Structure.from_dict(spec)) is not k1


def test_kind_without_expr_falls_back_to_numpy() -> None:
    name = "test_sim_tanh_spring"
    register_element(ElementKind(name=name, coefficients=("k",),
                                 force=lambda d, dv, k: k * np.tanh(d)), replace=True)
    try:
        s = Structure.from_dict({"name": "u", "dofs": ["x"], "mass": {"x": 1.0}, "elements": [
            {"kind": name, "between": ["x", "ground"], "params": {"k": "k"}},
            {"kind": "damper", "between": ["x", "ground"], "params": {"c": "c"}}]})
        t = np.arange(501) * 1e-3
        sim = simulate(s, [100.0, 0.5], t, [0.5], [0.0], substeps="auto")
        assert sim.backend == "numpy"
        ref = reference(s, np.array([100.0, 0.5]), t, [0.5], [0.0])
        assert rel_err(sim.q, ref) < 1e-6
        with pytest.raises(ValueError, match="numba backend unavailable"):
            simulate(s, [100.0, 0.5], t, [0.5], [0.0], backend="numba")
    finally:
        REGISTRY.pop(name, None)


def test_bad_inputs_are_refused(duffing_model: Structure) -> None:
    t = np.arange(100) * 1e-4
    with pytest.raises(ValueError, match="free parameters"):
        simulate(duffing_model, [1.0, 2.0], t, [0.0], [1.0])
    with pytest.raises(ValueError, match="uniformly"):
        simulate(duffing_model, DUFFING_TRUTH, np.r_[t, 1.0], [0.0], [1.0])
    with pytest.raises(ValueError, match="force must have shape"):
        simulate(duffing_model, DUFFING_TRUTH, t, [0.0], [1.0], np.zeros((99, 1)))
    with pytest.raises(ValueError, match="backend"):
        simulate(duffing_model, DUFFING_TRUTH, t, [0.0], [1.0], backend="cuda")


def test_large_model_compiles_and_matches_numpy():
    """A 6-DOF chain with 18 parameters: the kernel has no per-call argument limit."""
    dofs = [f"m{i}" for i in range(6)]
    elements = []
    for i, a in enumerate(dofs):
        b = "ground" if i == 0 else dofs[i - 1]
        elements += [{"kind": "spring", "between": [a, b], "params": {"k": f"k{i}"}},
                     {"kind": "damper", "between": [a, b], "params": {"c": f"c{i}"}},
                     {"kind": "cubic_spring", "between": [a, b], "params": {"k3": f"g{i}"}}]
    st = Structure.from_dict({"name": "chain6", "dofs": dofs, "mass": {d: 1.0 for d in dofs},
                              "elements": elements})
    theta = np.array([{"k": 1e4, "c": 5.0, "g": 1e6}[p[0]] for p in st.free])
    t = np.arange(1500) / 1000.0
    force = np.zeros((len(t), 6))
    force[5:10, -1] = 100.0
    fast = simulate(st, np.stack([theta, 1.1 * theta]), t, np.zeros(6), np.zeros(6), force,
                    substeps=4, backend="numba")
    slow = simulate(st, np.stack([theta, 1.1 * theta]), t, np.zeros(6), np.zeros(6), force,
                    substeps=4, backend="numpy")
    assert fast.backend == "numba"
    scale = np.abs(slow.q).max()
    assert scale > 1e-4
    assert np.abs(fast.q - slow.q).max() < 1e-9 * scale + 1e-12


def test_moments_reading_keeps_the_samples_impulse_centroid_and_spread() -> None:
    # a 4-sample hammer pulse: straight lines widen it by dt^2/6 in variance, the
    # moment-matched reading has exactly the samples' first three moments (issue 20)
    dt, m = 1.0 / 1024, 64  # fine stage grid: its sums are the integrals to ~1e-5
    t = np.arange(40) * dt
    x = (t - 10.3 * dt) / 4e-3
    F = np.where((x >= 0) & (x <= 1), 300 * np.sin(np.pi * np.clip(x, 0, 1)), 0.0)[:, None]
    h = dt / (2 * m)
    ts = np.arange(2 * m * (len(t) - 1) + 1) * h

    def moments(f: np.ndarray, tt: np.ndarray, w: float) -> np.ndarray:
        i0 = np.sum(f) * w
        c = np.sum(tt * f) * w / i0
        return np.array([i0, c, np.sum((tt - c) ** 2 * f) * w / i0])

    samples = moments(F[:, 0], t, dt)
    lines = moments(stage_force(F, m, "linear")[:, 0], ts, h)
    matched = moments(stage_force(F, m, "moments")[:, 0], ts, h)
    assert np.allclose(matched, samples, rtol=1e-4, atol=1e-12)
    assert lines[2] - samples[2] == pytest.approx(dt ** 2 / 6, rel=1e-2)


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_a_force_per_parameter_set_equals_separate_runs(lono_model: Structure,
                                                        backend: str) -> None:
    theta = lono_model.vector({"b1": 3.8, "b2": 0.8, "k1": 19273.0, "k2": 1947.6,
                               "alpha": 2.76e7, "beta": 2.0012})
    t = np.arange(600) / 2048.0
    rng = np.random.default_rng(0)
    F = np.zeros((3, len(t), 2))
    F[:, 100:113, 1] = 300 * np.sin(np.pi * np.arange(13) / 12) + rng.standard_normal((3, 13))
    z = np.zeros(2)
    both = simulate(lono_model, np.repeat(theta[None], 3, 0), t, z, z, F, substeps=3,
                    backend=backend)
    for i in range(3):
        one = simulate(lono_model, theta, t, z, z, F[i], substeps=3, backend=backend)
        # numba: the same scalar code per set; numpy: batched ufuncs may round differently
        assert np.allclose(both.a[i], one.a, rtol=1e-12, atol=0) if backend == "numpy" \
            else np.array_equal(both.a[i], one.a)
    with pytest.raises(ValueError, match="integer substeps"):
        simulate(lono_model, np.repeat(theta[None], 3, 0), t, z, z, F, substeps="auto")
