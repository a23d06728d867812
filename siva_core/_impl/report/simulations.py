"""The report's simulations: each record's point estimates and Approach I band, put
through the same processing chain as the measurement so like is compared with like."""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from ..processing import Processing, States
from ..recording import Recording


#: parameter sets drawn from N(best, best_std) for the 95 % band of the recommended estimate
N_BEST_BAND = 40


@dataclass


class RecordSims:
    """One record: measured processed displacement and the simulated ones (mm)."""

    name: str
    role: str
    t: np.ndarray
    measured: np.ndarray            # (T, n_dof) mm
    band_sims: np.ndarray           # (S, T, n_dof) mm, finite Approach I simulations
    points: dict[str, np.ndarray]   # approach -> (T, n_dof) mm (NaN if diverged)
    n_diverged: int
    fs: float
    best_sims: np.ndarray | None = None  # (S, T, n_dof) mm, sets drawn from N(best, best_std)
    modes_hz: tuple[float, ...] = ()    # natural frequencies of best: the axes must show them


def truth_vector(names: Sequence[str], truth: Mapping[str, float] | None) -> np.ndarray | None:
    if not truth:
        return None
    return np.array([float(truth[p]) if p in truth else np.nan for p in names])


def approach_ii_window(est: Any, res: Any) -> tuple[int, int] | None:
    """First and last epoch of the Approach II samples."""
    ens = getattr(getattr(est, "trainer_", None), "ensemble", None)
    if ens is not None and len(ens):
        ep = ens.epochs
        return int(ep.min()), int(ep.max())
    n_ep = len(res.history.get("theta", []))
    E = len(res.samples_II)
    if n_ep == 0 or E == 0:
        return None
    return max(0, n_ep - E), n_ep - 1


def records_to_draw(est: Any, train: Sequence[Recording] | None, val: Sequence[Recording] | None
             ) -> tuple[list[tuple[Recording, str]], str | None]:
    """(recording, role) pairs: raw recordings when known, else the processed states."""
    train = train if train is not None else getattr(est, "train_recordings_", None)
    val = val if val is not None else getattr(est, "val_recordings_", None)
    note = None
    if train is None:
        train = [_states_as_recording(s, est.structure.dofs) for s in est.train_states_]
        val = [_states_as_recording(s, est.structure.dofs) for s in est.val_states_]
        note = ("raw recordings were not available: each record was simulated from its "
                "processed states (first state, processed force).")
    elif val is None:
        val = []
    return [(r, "training") for r in train] + [(r, "validation") for r in val], note


def _states_as_recording(s: States, dofs: Sequence[str]) -> Recording:
    ch: dict[str, np.ndarray] = {}
    for k, d in enumerate(dofs):
        ch[f"disp_{d}"] = s.q[:, k]
        ch[f"vel_{d}"] = s.v[:, k]
        ch[f"acc_{d}"] = s.a[:, k]
        if s.has_force:
            ch[f"force_{d}"] = s.f[:, k]
    return Recording(s.t, ch, s.name, {"from_states": True})


def simulate_record(est: Any, res: Any, rec: Recording, role: str, n_sims: int,
                     budget_s: float | None = None) -> RecordSims:
    """Simulate the point estimates and the Approach I subset on one record, each through
    the processing chain (``OutputErrorProblem.simulated_states``, batched).  Substeps are
    chosen from the point estimates and the band's 2.5/97.5 % parameter percentiles (one
    odd sample cannot force thousands).  ``budget_s`` caps the time spent on the band (at
    least 20 sets), extrapolated from the point estimates; the count used is shown."""
    from ..refine import OutputErrorProblem

    st = est.structure
    if rec.meta.get("from_states"):
        proc = Processing()  # the states are already processed
    else:
        proc = getattr(est, "processing_", None) or res.processing or Processing()
    ests = res.estimates()
    order = ["approach_I", "approach_II", "approach_III", "best"]
    pts = np.stack([np.asarray(ests[k], dtype=float) for k in order])
    sub = np.asarray(res.samples_I, dtype=float)[:n_sims]
    ref = np.vstack([pts, np.percentile(sub, [2.5, 97.5], axis=0)]) if len(sub) else pts
    prob = OutputErrorProblem.build(st, [rec], proc, quantity="disp", theta_ref=ref)
    target = prob.records[0].target * 1e3
    T, n = target.shape

    def processed(thetas: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
        """Displacement [mm] per set through the chain (NaN when diverged), and the time."""
        out, t = [], None
        for s in prob.simulated_states(thetas, 0):
            if s is not None and t is None:
                t = s.t
            ok = s is not None and s.q.shape == (T, n) and np.all(np.isfinite(s.q))
            out.append(s.q * 1e3 if ok else np.full((T, n), np.nan))
        return out, t

    t0 = time.perf_counter()
    point_q, t_axis = processed(pts)
    per_set = (time.perf_counter() - t0) / len(pts)
    n_band = len(sub)
    if budget_s is not None and per_set > 0:
        # the first batch includes fixed costs, so this errs on the side of fewer sets
        n_band = int(min(n_band, max(20, budget_s / per_set)))
    band_q = processed(sub[:n_band])[0] if n_band else []
    band = np.array([q for q in band_q if np.all(np.isfinite(q))]).reshape(-1, T, n)
    best_band = None
    best_std = getattr(res, "best_std", None)
    if best_std is not None and np.all(np.isfinite(best_std)):
        # the recommended estimate's own band: sets drawn from its normal approximation
        rng = np.random.default_rng(0)
        draws = pts[3] + rng.standard_normal((N_BEST_BAND, len(pts[3]))) * np.asarray(best_std)
        bq = [q for q in processed(draws)[0] if np.all(np.isfinite(q))]
        best_band = np.array(bq).reshape(-1, T, n) if bq else None
    if t_axis is None:  # every point estimate diverged: the chain's time axis of the record
        t_axis = prob.chain.apply(rec, st.dofs).t
    try:
        modes = tuple(float(f) for f in st.linear_modes(pts[3]).get("frequency_hz", [])
                      if np.isfinite(f))
    except Exception:  # noqa: BLE001 - the axes fall back to the energy criterion
        modes = ()
    return RecordSims(rec.name, role, t_axis, target, band, dict(zip(order, point_q)),
                       len(band_q) - len(band), 1.0 / (t_axis[1] - t_axis[0]), best_band, modes)
