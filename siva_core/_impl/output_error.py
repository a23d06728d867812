"""The output-error problem: records simulated from their force and initial state and
passed through the same processing chain as the measurement (see ``refine`` for the fit)."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from .processing import Processing, States
from .recording import Recording
from .simulate import OMEGA_H, _choose_backend, auto_substeps, initial_state_and_force, simulate, stage_force
from .simulate import grid as _grid
from .simulate.grid import adjusted_stage_force
from .pulse_kick import (KICK_BOUNDS, KICK_STEP_TOL, KICK_STEPS, default_force_kick,
                         force_kick_patterns, kick_mask, sampled_force_acceleration,
                         single_pulse)
#: the name tests use for the accelerations at the force samples
_sampled_force_acceleration = sampled_force_acceleration


_QTY_ATTR = {"disp": "q", "vel": "v", "acc": "a"}

# ---------------------------------------------------------------------------- problem
@dataclass
class _Record:
    """One measured record, prepared once: processed targets, initial state, force."""

    rec: Recording
    q0: np.ndarray
    v0: np.ndarray
    force: np.ndarray | None
    quantities: list[str]        # compared quantity per DOF
    target: np.ndarray           # (T', n_dof) processed measured values of those quantities
    rms: np.ndarray              # (n_dof,) RMS of each target column
    substeps: int = 1
    state_rms: np.ndarray | None = None  # (2 n_dof,) RMS of processed q then v (scales)
    _staged: tuple[int, str, np.ndarray] | None = None
    #: (T,) the hit's force samples on its DOF (``hit_dof``) when the record is one short
    #: pulse, else None: the shape the kick's patterns are made of (``kick_basis``)
    kick_pulse: np.ndarray | None = None
    hit_dof: int = 0
    _kick: tuple[int, str, np.ndarray] | None = None

    def staged(self, interp: str) -> np.ndarray | None:
        """The force on the RK4 stage grid, computed once per (substeps, interp)."""
        if self.force is None:
            return None
        if self._staged is None or self._staged[:2] != (self.substeps, interp):
            self._staged = (self.substeps, interp, stage_force(self.force, self.substeps, interp))
        return self._staged[2]

    def kick_basis(self, interp: str) -> np.ndarray:
        """(rows, 2) the kick's two patterns on the RK4 stage grid: the pulse itself
        (an impulse in units of the hit's) and its central difference (a doublet, in
        samples): see ``force_kick_patterns``."""
        if self.kick_pulse is None:
            raise ValueError(f"{self.rec.name}: no single short pulse to kick with")
        if self._kick is None or self._kick[:2] != (self.substeps, interp):
            self._kick = (self.substeps, interp,
                          stage_force(force_kick_patterns(self.kick_pulse), self.substeps,
                                      interp))
        return self._kick[2]


@dataclass
class OutputErrorProblem:
    """Residuals of the output error for fixed records, chain and simulation settings.

    Build once, evaluate many times (``refine`` does).  The substeps per record are fixed
    at construction so that the residuals are a smooth function of theta (a step count that
    changed with theta would make finite differences meaningless).
    """

    structure: Any
    records: list[_Record]
    processing: Processing
    backend: str = "numpy"
    interp: str = "moments"

    @property
    def chain(self) -> Processing:
        """The processing run on measured and simulated records."""
        return self.processing

    @property
    def n_residuals(self) -> int:
        return sum(r.target.size for r in self.records)

    @property
    def n_groups(self) -> int:
        return sum(r.target.shape[1] for r in self.records)

    @classmethod
    def build(cls, structure: Any, records: Recording | Sequence[Recording],
              processing: Processing | None = None, *, quantity: str | Sequence[str] = "auto",
              theta_ref: Any | None = None, substeps: int | str | None | Sequence[int] = "auto",
              backend: str = "auto", omega_h: float = OMEGA_H, force_gate: str | None = "auto",
              initial: str = "auto", interp: str | None = None) -> "OutputErrorProblem":
        """Prepare the records.  ``substeps``: an int, one int per record, or "auto" (then
        ``theta_ref``, (n_free,) or (B, n_free), sets them: fastest rate over those sets).
        ``interp``: the measured force between samples (``stage_force``; None =
        ``simulate.grid.MEASURED_FORCE_INTERP``, read at call time)."""
        processing = processing or Processing()
        chain = processing
        interp = interp or _grid.MEASURED_FORCE_INTERP
        recs = [records] if isinstance(records, Recording) else list(records)
        if not recs:
            raise ValueError("output error needs at least one record")
        use = _choose_backend(structure, backend)
        per_rec: list[int | None]
        if isinstance(substeps, (list, tuple)):
            if len(substeps) != len(recs):
                raise ValueError("substeps: one value per record expected")
            per_rec = [int(m) for m in substeps]
        elif isinstance(substeps, (int, np.integer)):
            per_rec = [int(substeps)] * len(recs)
        else:
            per_rec = [None] * len(recs)
        prepared = []
        for rec, m in zip(recs, per_rec):
            q0, v0, force = initial_state_and_force(structure, rec, processing,
                                                    initial=initial, force_gate=force_gate)
            meas = chain.apply(rec, structure.dofs)
            qtys = _quantities(rec, structure.dofs, quantity)
            target = _extract(meas, qtys)
            rms = np.sqrt(np.mean(target ** 2, axis=0))
            if np.any(rms <= 0):
                bad = [d for d, r in zip(structure.dofs, rms) if r <= 0]
                raise ValueError(f"{rec.name}: processed {qtys} of DOF(s) {bad} is identically 0")
            if m is None:
                if theta_ref is None:
                    raise ValueError("substeps='auto' needs theta_ref")
                th = np.atleast_2d(np.asarray(theta_ref, dtype=float))
                m = auto_substeps(structure, th, rec.dt, q0, v0, force, n_samples=len(rec),
                                  omega_h=omega_h, backend=use, interp=interp)
            state_rms = np.concatenate([np.sqrt(np.mean(meas.q ** 2, axis=0)),
                                        np.sqrt(np.mean(meas.v ** 2, axis=0))])
            pulse, hit = single_pulse(force)
            prepared.append(_Record(rec, q0, v0, force, qtys, target, rms, m, state_rms,
                                    kick_pulse=pulse, hit_dof=hit))
        return cls(structure, prepared, processing, use, interp)

    def simulated_states(self, thetas: np.ndarray, k: int,
                         force_scale: np.ndarray | None = None, need: str = "qva"
                         ) -> list[States | None]:
        """Record ``k`` simulated for each set and passed through the chain, one States per
        set (None if the simulation diverged; quantities not in ``need`` are NaN)."""
        st, ok = self._processed(np.atleast_2d(thetas), k, force_scale, need=need)
        out: list[States | None] = []
        for b in range(len(ok)):
            if not ok[b]:
                out.append(None)
                continue
            out.append(States(st.t, st.q[b], st.v[b], st.a[b], st.f, st.name, st.has_force,
                              st.start_index, st.decimation))
        return out

    def weight(self, k: int) -> np.ndarray:
        """(n_dof,) normalisation of record ``k``'s residuals: 1 / (RMS sqrt(T * groups)),
        so the sum of squares over all records is the mean NMSE."""
        r = self.records[k]
        return 1.0 / (r.rms * math.sqrt(r.target.shape[0] * self.n_groups))

    def record_residuals(self, thetas: np.ndarray, k: int, force_scale: np.ndarray | None = None,
                         dq0: np.ndarray | None = None, dv0: np.ndarray | None = None,
                         record: _Record | None = None, force_shift: np.ndarray | None = None,
                         force_spread: np.ndarray | None = None,
                         force_kick: np.ndarray | None = None
                         ) -> tuple[np.ndarray, np.ndarray]:
        """((B, T' * n_dof) normalised residuals of record ``k``, (B,) finite mask);
        ``record`` replaces the stored one (e.g. the same record with another force);
        ``force_shift`` (B,): delay of the force per set [samples]; ``force_spread`` (B,):
        change of its spread [samples^2] (``adjusted_stage_force``); ``force_kick``
        (B, 2, n_dof): impulse and doublet added at the pulse per DOF (``_Record.kick_basis``)."""
        r = record or self.records[k]
        need = "".join(sorted({_QTY_ATTR[q] for q in r.quantities}))
        st, ok = self._processed(thetas, k, force_scale, dq0, dv0, record=r, need=need,
                                 force_shift=force_shift, force_spread=force_spread,
                                 force_kick=force_kick)
        sim = np.stack([getattr(st, _QTY_ATTR[q])[..., j] for j, q in enumerate(r.quantities)],
                       axis=-1)
        return ((sim - r.target) * self.weight(k)).reshape(sim.shape[0], -1), ok

    def _processed(self, thetas: np.ndarray, k: int, force_scale: np.ndarray | None = None,
                   dq0: np.ndarray | None = None, dv0: np.ndarray | None = None,
                   record: _Record | None = None, need: str = "qva",
                   force_shift: np.ndarray | None = None,
                   force_spread: np.ndarray | None = None,
                   force_kick: np.ndarray | None = None) -> tuple[States, np.ndarray]:
        """Batched: simulate record ``k`` (or ``record``) for all sets, run the chain once
        on (B, T, n) arrays (``Processing.apply_simulated``; only the ``need``ed
        quantities are processed).  Returns (States with (B, T', n) arrays, (B,) mask of
        sets whose simulation stayed finite)."""
        r = record or self.records[k]
        q0 = r.q0 if dq0 is None else r.q0 + dq0
        v0 = r.v0 if dv0 is None else r.v0 + dv0
        force, staged = r.force, r.staged(self.interp)
        if (force_shift is not None or force_spread is not None) and force is not None:
            B = np.atleast_2d(thetas).shape[0]
            if force.ndim == 2:
                force = np.broadcast_to(force, (B,) + force.shape)
            staged = adjusted_stage_force(force, r.substeps, self.interp, force_shift,
                                          force_spread)
        if force_kick is not None and force is not None and np.any(force_kick):
            kick = np.asarray(force_kick, dtype=float)
            B = kick.shape[0]
            if force.ndim == 2:
                force = np.broadcast_to(force, (B,) + force.shape)
            basis = r.kick_basis(self.interp)
            rows = np.flatnonzero(np.any(basis != 0, axis=1))   # the pulse's stage rows
            lo, hi = int(rows[0]), int(rows[-1]) + 1
            staged = np.array(np.broadcast_to(staged, (B,) + staged.shape[-2:]))
            staged[:, lo:hi] += (kick[:, 0, None, :] * basis[None, lo:hi, 0, None]
                                 + kick[:, 1, None, :] * basis[None, lo:hi, 1, None])
        sim = simulate(self.structure, thetas, r.rec.time, q0, v0, force,
                       substeps=r.substeps, backend=self.backend, interp=self.interp,
                       force_scale=force_scale, staged_force=staged)
        q, v, a = sim.q, sim.v, sampled_force_acceleration(
            self.structure, sim.a, force, staged, r.substeps, force_scale)
        ok = (np.all(np.isfinite(q), axis=(1, 2)) & np.all(np.isfinite(v), axis=(1, 2))
              & np.all(np.isfinite(a), axis=(1, 2)))
        if not np.all(ok):  # keep NaN out of the filters; those rows are discarded anyway
            q, v, a = (np.where(ok[:, None, None], x, 0.0) for x in (q, v, a))
        st = self.chain.apply_simulated(r.rec, self.structure.dofs, q, v, a, need)
        return st, ok

    def residuals(self, thetas: Any, force_scales: np.ndarray | None = None,
                  dq0: np.ndarray | None = None, dv0: np.ndarray | None = None,
                  force_shifts: np.ndarray | None = None,
                  force_spreads: np.ndarray | None = None,
                  force_kicks: np.ndarray | None = None) -> np.ndarray:
        """(B, n_residuals) normalised residuals, NaN where a simulation diverged.  The sum of
        squares is the mean NMSE over records and DOFs (each DOF of each record divided by
        its measured RMS, so records and DOFs of different amplitude weigh the same).
        ``force_scales`` (B, n_records): optional per-record force multipliers;
        ``dq0``, ``dv0`` (B, n_records, n_dof): optional offsets of each initial state;
        ``force_shifts``, ``force_spreads`` (B, n_records): optional delay [samples] and
        spread change [samples^2] of each record's force (``adjusted_stage_force``);
        ``force_kicks`` (B, n_records, 2, n_dof): each record's kick (``record_residuals``)."""
        th = np.atleast_2d(np.asarray(thetas, dtype=float))
        B = th.shape[0]
        out = np.empty((B, self.n_residuals))
        col = 0
        for k, r in enumerate(self.records):
            fs = None if force_scales is None else force_scales[:, k]
            res, ok = self.record_residuals(th, k, fs, None if dq0 is None else dq0[:, k],
                                            None if dv0 is None else dv0[:, k],
                                            force_shift=None if force_shifts is None
                                            else force_shifts[:, k],
                                            force_spread=None if force_spreads is None
                                            else force_spreads[:, k],
                                            force_kick=None if force_kicks is None
                                            else force_kicks[:, k])
            size = r.target.size
            out[:, col:col + size] = res
            out[~ok, col:col + size] = np.nan
            col += size
        return out

    def cost(self, thetas: Any) -> np.ndarray:
        """(B,) sum of squared residuals (inf for diverged simulations)."""
        c = np.sum(self.residuals(thetas) ** 2, axis=1)
        c[~np.isfinite(c)] = np.inf
        return c

    def head(self, n_keep: Sequence[int]) -> "OutputErrorProblem":
        """The same problem on the first ``n_keep[k]`` processed samples of each record
        (the raw record is cut after the matching raw sample, then re-processed)."""
        recs = []
        for r, nk in zip(self.records, n_keep):
            st = self.chain.apply(r.rec, self.structure.dofs)
            stop = st.start_index + st.decimation * int(nk)
            rec = r.rec.slice(0, min(len(r.rec), stop + 1))
            meas = self.chain.apply(rec, self.structure.dofs)
            target = _extract(meas, r.quantities)
            force = None if r.force is None else r.force[:len(rec)]
            pulse = None if r.kick_pulse is None else r.kick_pulse[:len(rec)]
            recs.append(_Record(rec, r.q0, r.v0, force, r.quantities, target,
                                np.sqrt(np.mean(target ** 2, axis=0)), r.substeps,
                                r.state_rms, kick_pulse=pulse, hit_dof=r.hit_dof))
        return OutputErrorProblem(self.structure, recs, self.processing, self.backend,
                                  self.interp)


def _quantities(rec: Recording, dofs: Sequence[str], quantity: str | Sequence[str]) -> list[str]:
    """Quantity compared per DOF: 'auto' = the lowest derivative that was *measured*
    (disp, else vel, else acc), so nothing the chain derived is preferred to a measurement."""
    if isinstance(quantity, str) and quantity != "auto":
        if quantity not in _QTY_ATTR:
            raise ValueError(f"quantity must be 'auto', 'disp', 'vel' or 'acc', got {quantity!r}")
        return [quantity] * len(dofs)
    if not isinstance(quantity, str):
        q = list(quantity)
        if len(q) != len(dofs) or any(x not in _QTY_ATTR for x in q):
            raise ValueError(f"quantity per DOF must be {len(dofs)} of disp/vel/acc, got {q}")
        return q
    out = []
    for d in dofs:
        for qty in ("disp", "vel", "acc"):
            if rec.get(qty, d) is not None:
                out.append(qty)
                break
        else:
            raise ValueError(f"{rec.name}: DOF {d!r} has no measured disp/vel/acc")
    return out


def _extract(st: States, qtys: Sequence[str]) -> np.ndarray:
    return np.stack([getattr(st, _QTY_ATTR[q])[:, k] for k, q in enumerate(qtys)], axis=-1)


# ---------------------------------------------------------------------------- metrics
def output_error(structure: Any, thetas: Any, records: Recording | Sequence[Recording],
                 processing: Processing | None = None, *, quantity: str | Sequence[str] = "auto",
                 **kw: Any) -> np.ndarray:
    """(B,) normalised output-error cost of each parameter set: the mean over records and
    DOFs of MSE / (measured RMS)^2 (0 = perfect, 1 = as bad as predicting zero).

    Each record is simulated (``simulate``), rebuilt as a Recording with the measured
    channels, put through the same chain and compared with the processed measurement on
    the measured quantities.  ``kw``: substeps ("auto"), backend, force_gate, initial,
    interp, omega_h (see ``OutputErrorProblem.build``).
    """
    th = np.atleast_2d(np.asarray(thetas, dtype=float))
    prob = OutputErrorProblem.build(structure, records, processing, quantity=quantity,
                                    theta_ref=th, **kw)
    return prob.cost(th)


#: fit the pulse's spread only when the top linear mode has fewer than 4 pi (~12.6) samples
#: per period (omega dt >= 0.5): its effect on a mode's amplitude is ~ (omega dt)^2 x the
#: spread change, so at 30x sampling it is ~0.3 % and not identifiable -- fitted there it
#: absorbed other errors and moved the dampings (chain3_end_1k, docs/perf.md 6.4).  Set
#: after seeing chain3_end_1k (30x: worse) and chain4_inner_disp (5.8x: fixed).
SPREAD_MIN_OMEGA_DT = 0.5


#: ``best`` and the output-error phase fit the spread (where identifiable) only when True.
#: Off: on fresh seeds 10000-10019 it fixed chain4_inner_disp (c1 coverage 30 -> 95 %) but
#: broke twodof_end_slow (k1, k2 shifted ~3 se) and chain3_end_1k (docs/perf.md 6.4).
FIT_FORCE_SPREAD_BY_DEFAULT = False


def default_force_spread(structure: Any, theta: Any, records: Sequence[Recording],
                         interp: str | None = None) -> bool:
    """Whether ``best`` and ``linearize`` fit the force's spread when not told."""
    return FIT_FORCE_SPREAD_BY_DEFAULT and force_spread_identifiable(structure, theta, records,
                                                                     interp)


def force_spread_identifiable(structure: Any, theta: Any, records: Sequence[Recording],
                              interp: str | None = None) -> bool:
    """Whether ``best`` and the output-error phase fit the force's spread per record:
    a piecewise-linear force reading and omega_max dt >= ``SPREAD_MIN_OMEGA_DT`` for the
    linearised model at ``theta`` on some record (False when that cannot be computed)."""
    if (interp or _grid.MEASURED_FORCE_INTERP) not in ("linear", "moments"):
        return False
    try:
        f_hz = np.asarray(structure.linear_modes(theta)["frequency_hz"], dtype=float)
    except (KeyError, ValueError, np.linalg.LinAlgError, ZeroDivisionError):
        return False
    f_hz = f_hz[np.isfinite(f_hz)]
    if f_hz.size == 0:
        return False
    dt = max(float(r.dt) for r in records)
    return bool(2 * math.pi * float(f_hz.max()) * dt >= SPREAD_MIN_OMEGA_DT)


def force_profiled_output_error(structure: Any, thetas: Any,
                                records: Recording | Sequence[Recording],
                                processing: Processing | None = None, *, iterations: int = 4,
                                fit_spread: bool = False, fit_kick: bool | str = "auto",
                                **kw: Any) -> np.ndarray:
    """(B,) ``output_error`` with one force multiplier per record fitted for each parameter
    set: the cost the refinement minimises when it fits force scales (``refine(...,
    fit_force_scale=True)``), so a refined estimate and its start are compared on the same
    footing.  Why: a force read from a few samples of a hammer pulse can be off by a few %
    in what it puts into the modes (a 4-sample pulse at 1 kHz: -2.2 %, docs/perf.md); with
    the measured force taken as exact, a wrong basin that absorbs that error (dampings off
    by 10-30 %) can simulate the training record better than the right one, and the right
    refinement was discarded (issue 20: 7 of 20 runs of a chain hit on its end mass).
    ``fit_spread``: the force's spread is profiled too (``refine(...,
    fit_force_spread=True)``), within +-0.5 samples^2.

    Per record, ``iterations`` Gauss-Newton steps on the multiplier (and spread)
    (central-difference slopes; one batched simulation per step), the multiplier kept within
    [0.5, 2]; each record contributes the smallest cost met, multiplier 1 (spread 0)
    included (so never more than ``output_error``).  Records without force keep multiplier 1.
    ``fit_kick``: the kick (``force_kick_patterns``) is profiled with the multiplier, as
    ``refine(..., fit_force_kick=True)`` fits it; "auto": ``force_kick_applicable``."""
    th = np.atleast_2d(np.asarray(thetas, dtype=float))
    prob = OutputErrorProblem.build(structure, records, processing, theta_ref=th, **kw)
    if fit_kick == "auto":
        fit_kick = default_force_kick(structure, prob.records)
    B, h, hs = th.shape[0], 1e-3, 1e-3
    total = np.zeros(B)
    for k, r in enumerate(prob.records):
        if r.force is None:
            res, ok = prob.record_residuals(th, k)
            total += np.where(ok, np.sum(res ** 2, axis=1), np.inf)
            continue
        if fit_kick and r.kick_pulse is not None:
            total += _profiled_with_kick(prob, th, k, iterations, fit_spread)
            continue
        s = np.ones(B)
        w = np.zeros(B)
        best = np.full(B, np.inf)
        n_p = 5 if fit_spread else 3
        for it in range(iterations + 1):
            scales = np.concatenate([s, s * (1 + h), s * (1 - h)] + ([s, s] if fit_spread else []))
            spreads = (np.concatenate([w, w, w, w + hs, w - hs]) if fit_spread else None)
            res, ok = prob.record_residuals(np.concatenate([th] * n_p), k, scales,
                                            force_spread=spreads)
            parts = [res[i * B:(i + 1) * B] for i in range(n_p)]
            oks = [ok[i * B:(i + 1) * B] for i in range(n_p)]
            r0 = parts[0]
            c0 = np.where(oks[0], np.sum(r0 ** 2, axis=1), np.inf)
            best = np.minimum(best, c0)
            if it == iterations:
                break
            fine = np.logical_and.reduce(oks)
            cols = [(parts[1] - parts[2]) / (2 * h * s[:, None])]
            if fit_spread:
                cols.append((parts[3] - parts[4]) / (2 * hs))
            if not fit_spread:  # the multiplier alone: a scalar step
                g = cols[0]
                gg = np.sum(g * g, axis=1)
                with np.errstate(all="ignore"):
                    step = np.where(gg > 0, np.sum(r0 * g, axis=1) / gg, 0.0)[:, None]
            else:
                J = np.stack(cols, axis=-1)                      # (B, R, 2)
                JtJ = np.einsum("brp,brq->bpq", J, J)
                Jtr = np.einsum("brp,br->bp", J, r0)
                step = np.zeros((B, 2))
                for b in np.flatnonzero(fine):
                    try:
                        step[b] = np.linalg.lstsq(JtJ[b], Jtr[b], rcond=1e-12)[0]
                    except np.linalg.LinAlgError:
                        fine[b] = False
            fine &= np.all(np.isfinite(step), axis=1)
            s = np.where(fine, np.clip(s - step[:, 0], 0.5, 2.0), s)
            if fit_spread:
                w = np.where(fine, np.clip(w - step[:, 1], -0.5, 0.5), w)
        total += best
    total[~np.isfinite(total)] = np.inf
    return total


def _profiled_with_kick(prob: OutputErrorProblem, th: np.ndarray, k: int, iterations: int,
                        fit_spread: bool) -> np.ndarray:
    """(B,) record ``k``'s smallest cost met over Gauss-Newton steps on its multiplier,
    (spread) and kick, central-difference slopes from one batched simulation per step."""
    r = prob.records[k]
    B, n = th.shape[0], prob.structure.n_dof
    mask = kick_mask(r, n, with_scale=True)
    comps = np.argwhere(mask)                      # (p_kick, 2): (kind, dof)
    p = 1 + int(fit_spread) + len(comps)
    lo = np.array([0.5] + ([-0.5] if fit_spread else []) + [KICK_BOUNDS[c[0]][0] for c in comps])
    hi = np.array([2.0] + ([0.5] if fit_spread else []) + [KICK_BOUNDS[c[0]][1] for c in comps])
    z = np.zeros((B, p))
    z[:, 0] = 1.0
    hz = np.full(p, 1e-3)
    best = np.full(B, np.inf)

    def split(Z: np.ndarray) -> dict[str, np.ndarray]:
        kick = np.zeros((len(Z), 2, n))
        j0 = 1 + int(fit_spread)
        for j, (kind, d) in enumerate(comps):
            kick[:, kind, d] = Z[:, j0 + j]
        return {"force_scale": Z[:, 0], "force_spread": Z[:, 1] if fit_spread else None,
                "force_kick": kick}

    # first the multiplier (and spread) alone, with their slopes at every step, as without
    # a kick; then KICK_STEPS Gauss-Newton steps on all of them with the kick: from a
    # multiplier far off (a strongly nonlinear response is not linear in the impulse) a
    # joint step overshoots into a kicked minimum that is not the best (a 3 % force error
    # on LO-NO: cost 1e-3 instead of 0)
    q = 1 + int(fit_spread)
    last = False  # the joint steps have converged: one more evaluation, for the cost there
    for it in range(iterations + KICK_STEPS + 1):
        cols = range(0) if last else range(q) if it < iterations else range(p)
        Z = np.concatenate([z] + [z + hz[j] * np.eye(p)[j] for j in cols]
                           + [z - hz[j] * np.eye(p)[j] for j in cols])
        m = len(cols)
        kw = split(Z)
        res, ok = prob.record_residuals(np.concatenate([th] * (2 * m + 1)), k,
                                        kw["force_scale"], force_spread=kw["force_spread"],
                                        force_kick=kw["force_kick"])
        res = res.reshape(2 * m + 1, B, -1)
        ok = ok.reshape(2 * m + 1, B)
        r0 = res[0]
        best = np.minimum(best, np.where(ok[0], np.sum(r0 ** 2, axis=1), np.inf))
        if it == iterations + KICK_STEPS or last:
            break
        J = np.stack([(res[1 + j] - res[1 + m + j]) / (2 * hz[j]) for j in range(m)], axis=-1)
        fine = np.all(ok, axis=0)
        step = np.zeros((B, p))
        for b in np.flatnonzero(fine):
            Jb = np.where(np.isfinite(J[b]), J[b], 0.0)
            step[b, :m] = np.linalg.lstsq(Jb, r0[b], rcond=1e-10)[0]
        fine &= np.all(np.isfinite(step), axis=1)
        z = np.where(fine[:, None], np.clip(z - step, lo, hi), z)
        last = it >= iterations and bool(np.all(np.abs(step[fine]) < KICK_STEP_TOL))
    return best


def displacement_mse(structure: Any, thetas: Any, records: Recording | Sequence[Recording],
                     processing: Processing | None = None, *, chain: bool = True,
                     dof_reduce: str = "mean", **kw: Any) -> np.ndarray:
    """(B,) the paper's metric: MSE [m^2] between simulated and measured (processed)
    displacement, averaged over DOFs and records (paper Sec. 3.1 / 3.2).

    ``chain=True`` (default) passes the simulated record through the same chain as the
    measurement (unbiased); ``chain=False`` compares the raw simulated displacement, taken
    where the chain kept samples, with the processed measurement, as the paper did.
    ``dof_reduce="sum"`` is the paper's LO-NO definition (x and y errors added).  inf for a
    diverged simulation.
    """
    if dof_reduce not in ("mean", "sum"):
        raise ValueError("dof_reduce must be 'mean' or 'sum'")
    th = np.atleast_2d(np.asarray(thetas, dtype=float))
    prob = OutputErrorProblem.build(structure, records, processing, quantity="disp",
                                    theta_ref=th, **kw)
    total = np.zeros(th.shape[0])
    for k, r in enumerate(prob.records):
        if chain:
            sims = [None if st is None else st.q
                    for st in prob.simulated_states(th, k, need="q")]
        else:
            meas = prob.chain.apply(r.rec, structure.dofs)
            sim = simulate(structure, th, r.rec.time, r.q0, r.v0, r.force, substeps=r.substeps,
                           backend=prob.backend, interp=prob.interp)
            sl = slice(meas.start_index, meas.start_index + meas.decimation * len(meas),
                       meas.decimation)
            sims = [sim.q[b, sl] for b in range(th.shape[0])]
        for b, q in enumerate(sims):
            if q is None or not np.all(np.isfinite(q)):
                total[b] = np.inf
                continue
            mse = np.mean((q - r.target) ** 2, axis=0)
            total[b] += mse.mean() if dof_reduce == "mean" else mse.sum()
    return total / len(prob.records)



def _state_derived(rec: Recording, dofs: Sequence[str]) -> bool:
    """Some DOF's displacement or velocity is not measured (the chain derives it)."""
    return any(rec.get("disp", d) is None or rec.get("vel", d) is None for d in dofs)


