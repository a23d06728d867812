"""The output-error problem: records simulated from their force and initial state and
passed through the same processing chain as the measurement (see ``refine`` for the fit)."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from ..processing import Processing, States
from ..pulse_kick import sampled_force_acceleration, single_pulse
from ..recording import Recording
from ..simulate import (OMEGA_H, REAL_H_FIT, _choose_backend, auto_substeps,
                        initial_state_and_force, simulate, simulate_split)
from ..simulate import grid as _grid
from ..simulate.grid import adjusted_stage_force
from .pilot_reuse import reuse_pilot
from . import sample_gain
from .records import _QTY_ATTR, _extract, _quantities, _Record


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
              initial: str = "auto", interp: str | None = None,
              real_h: float | None = REAL_H_FIT) -> "OutputErrorProblem":
        """Prepare the records.  ``substeps``: an int, one int per record, or "auto" (then
        ``theta_ref``, (n_free,) or (B, n_free), sets them: fastest rate over those sets;
        ``real_h``: the looser bound for real-axis rates, ``simulate.substeps.REAL_H_FIT`` —
        a fit needs the integration accurate to the noise, not to 1e-7).
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
            pilot = None
            if m is None:
                if theta_ref is None:
                    raise ValueError("substeps='auto' needs theta_ref")
                th = np.atleast_2d(np.asarray(theta_ref, dtype=float))
                # the pilot's run at the chosen substeps is kept: ``cost(theta_ref)``
                # (``output_error``, a candidate's validation gap) simulates those sets
                # again otherwise (about a third of a 3-DOF diagnosis' simulations)
                out: list[Any] = []
                m = auto_substeps(structure, th, rec.dt, q0, v0, force, n_samples=len(rec),
                                  omega_h=omega_h, backend=use, interp=interp, real_h=real_h,
                                  pilot_out=out)
                if out:
                    sets, Qp, Vp, Ap = out[0]
                    pilot = (m, th[sets].copy(), Qp, Vp, Ap)
            state_rms = np.concatenate([np.sqrt(np.mean(meas.q ** 2, axis=0)),
                                        np.sqrt(np.mean(meas.v ** 2, axis=0))])
            pulse, hit = single_pulse(force)
            prepared.append(_Record(rec, q0, v0, force, qtys, target, rms, m, state_rms,
                                    kick_pulse=pulse, hit_dof=hit, pilot=pilot))
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
        res = (sim - r.target) * self.weight(k)
        if force_scale is not None and sample_gain.PROFILE_SAMPLE_GAIN:
            # a fitted multiplier is for the force between the pulse's samples, not at them:
            # the gain of the accelerations at the samples is profiled out (docs/perf.md 6.7)
            pattern = sample_gain.sample_gain_pattern(self, k)
            if pattern is not None:
                res = sample_gain.project_sample_gain(res, pattern, r.hit_dof)
        return res.reshape(sim.shape[0], -1), ok

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
        split = None
        if force_kick is not None and force is not None and np.any(force_kick):
            kick = np.asarray(force_kick, dtype=float)
            B = kick.shape[0]
            if force.ndim == 2:
                force = np.broadcast_to(force, (B,) + force.shape)
            basis = r.kick_basis(self.interp)
            rows = np.flatnonzero(np.any(basis != 0, axis=1))   # the pulse's stage rows
            lo, hi = int(rows[0]), int(rows[-1]) + 1
            m2 = 2 * r.substeps
            w = (hi - 1) // m2 + 1  # the first sample whose intervals are past the kick
            # one force for every set after the kick: only the head is per set
            # (``simulate_split``), else the whole record
            shared = (staged if staged.ndim == 2 and self.backend == "numba"
                      and w < len(r.rec) - 1 else None)
            end = m2 * w + 1 if shared is not None else staged.shape[-2]
            # C order: from a broadcast view numpy's default ("K") puts the set axis
            # innermost, and the kernel then copied it into C order once more (1 s of
            # LO-NO's identify, docs/perf.md 8.3)
            staged = np.array(np.broadcast_to(staged[..., :end, :], (B, end, staged.shape[-1])),
                              order="C")
            staged[:, lo:hi] += (kick[:, 0, None, :] * basis[None, lo:hi, 0, None]
                                 + kick[:, 1, None, :] * basis[None, lo:hi, 1, None])
            if shared is not None:
                split = simulate_split(self.structure, thetas, r.rec.time, q0, v0, staged,
                                       shared, r.substeps, force_scale)
                at = np.empty(force.shape)  # the stage force at the samples, per set
                at[:] = shared[::m2]
                at[:, :w + 1] = staged[:, ::m2]
                staged = at
        plain = (dq0 is None and dv0 is None and force_scale is None and split is None
                 and force_shift is None and force_spread is None and force_kick is None
                 and (record is None or record is self.records[k]))
        reused = reuse_pilot(self, r, np.atleast_2d(thetas), q0, v0) if plain else None
        if split is not None:
            q, v, a = split
            a = sampled_force_acceleration(self.structure, a, force, staged, r.substeps,
                                           force_scale, inplace=True, at_samples=True)
        elif reused is not None:
            q, v, a = reused
            a = sampled_force_acceleration(self.structure, a, force, staged, r.substeps,
                                           force_scale, inplace=True)
        else:
            sim = simulate(self.structure, thetas, r.rec.time, q0, v0, force,
                           substeps=r.substeps, backend=self.backend, interp=self.interp,
                           force_scale=force_scale, staged_force=staged)
            q, v, a = sim.q, sim.v, sampled_force_acceleration(
                self.structure, sim.a, force, staged, r.substeps, force_scale, inplace=True)
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
