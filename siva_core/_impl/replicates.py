"""Parametric-bootstrap replicates of an output-error fit: measurement noise with the
residuals' own spectrum, force-sensor noise through the dynamics, and the force's shape
between samples (docs/method.md)."""
from __future__ import annotations

import dataclasses
from typing import Any, Sequence

import numpy as np

from .bootstrap import Series, phase_randomized
from .output_error import OutputErrorProblem, _Record


#: parametric-bootstrap replicates simulated together (each with its own force)
_REPLICATE_CHUNK = 16
#: spread of the force's shape between samples in the parametric replicates, as a
#: fraction of the difference between reading the samples as straight lines and with
#: their own moments (``stage_force``); 0 switches it off.  Measured on a 3-DOF chain hit
#: by 3-5-sample pulses (docs/perf.md): the moment-matched reading leaves 0.3-0.4 of that
#: difference as bias, which the intervals must hold
FORCE_SHAPE_SPREAD = 0.5
#: the force-sensor noise is propagated as a small step (this share of its drawn size) and
#: its response divided by the share: the linear response, which is what the linearised
#: refit (``perturbation_solutions``) can take.  At full size the response of a nonlinear
#: structure carries a second-order part (the squared amplitude change) that lies outside
#: the Jacobian's span; LO-NO's force noise moves its response 25x the measurement noise
#: along the force multiplier and the kick, and the 3 % second-order rest was read as
#: alpha / beta: 30-45x the true effect of the force noise, intervals 1.7-1.9x too wide
#: (docs/perf.md 6.9)
FORCE_NOISE_STEP = 1e-3


def noise_replicates(prob: OutputErrorProblem, theta: np.ndarray, extra: dict[str, np.ndarray],
                     r: np.ndarray, series: Sequence[Series], n_rep: int = 64,
                     seed: int = 1) -> np.ndarray:
    """(n_rep, n_residuals) residual perturbations of parametric-bootstrap replicates.

    Each replicate: the measurement noise as a phase-randomised copy of the residuals
    ``r`` (same spectrum, so the same correlation), plus -- for impulsive records -- the
    linear change (``FORCE_NOISE_STEP``) of the simulated, processed response when the
    force in the pulse gets a new draw of the force sensor's noise (its level read off the
    force channel outside the pulse, where it measures nothing but noise).  The force noise matters because its
    effect is not stationary: it starts a free decay that stays correlated to the end.
    And, for impulsive records, a random share (``FORCE_SHAPE_SPREAD``) of the change
    between reading the sampled force as straight lines and with its own moments: what a
    pulse of a few samples leaves unknown about the force between them."""
    rng = np.random.default_rng(seed)
    shape_rng = np.random.default_rng([seed, 20])  # its own stream: rng's draws unchanged
    E = np.stack([phase_randomized(r, series, rng) for _ in range(n_rep)])
    col = 0
    for k, rec in enumerate(prob.records):
        size = rec.target.size
        sigma, pulse = _force_noise(prob.structure, rec)
        if sigma is not None:
            fs = None if "force_scales" not in extra else extra["force_scales"][:, k]
            dq = None if "dq0" not in extra else extra["dq0"][:, k]
            dv = None if "dv0" not in extra else extra["dv0"][:, k]
            sh = None if "force_shifts" not in extra else extra["force_shifts"][:, k]
            sp = None if "force_spreads" not in extra else extra["force_spreads"][:, k]
            kk = None if "force_kicks" not in extra else extra["force_kicks"][:, k]
            base, ok = prob.record_residuals(theta, k, fs, dq, dv, force_shift=sh,
                                             force_spread=sp, force_kick=kk)
            noisy = np.repeat(rec.force[None], n_rep, axis=0)
            for b in range(n_rep):
                noisy[b][pulse] += FORCE_NOISE_STEP * sigma * rng.standard_normal(
                    (int(pulse.sum()), noisy.shape[2]))
            # one batched simulation (a force per set) per chunk of replicates
            rep = lambda x, c: None if x is None else np.repeat(x, c, axis=0)
            for b0 in range(0, n_rep, _REPLICATE_CHUNK):
                chunk = noisy[b0:b0 + _REPLICATE_CHUNK]
                c = len(chunk)
                alt = dataclasses.replace(rec, force=chunk, _staged=None)
                rb, okb = prob.record_residuals(rep(np.atleast_2d(theta), c), k, rep(fs, c),
                                                rep(dq, c), rep(dv, c), record=alt,
                                                force_shift=rep(sh, c),
                                                force_spread=rep(sp, c),
                                                force_kick=rep(kk, c))
                if ok[0]:
                    good = np.flatnonzero(okb)
                    E[b0 + good, col:col + size] += (rb[good] - base[0]) / FORCE_NOISE_STEP
            # with a fitted kick the state after the pulse is free, which spans whatever
            # its shape between samples does: no shape term then (docs/perf.md 6.5)
            kicked = kk is not None and rec.kick_pulse is not None
            if FORCE_SHAPE_SPREAD > 0 and ok[0] and prob.interp != "linear" and not kicked:
                # the force between its samples is unknown: a replicate's force shape
                # varies by FORCE_SHAPE_SPREAD x (straight lines - the moment-matched
                # reading), the scale of what sampling a short pulse leaves undetermined
                lin = dataclasses.replace(prob, interp="linear")
                rl, okl = lin.record_residuals(theta, k, fs, dq, dv, force_shift=sh,
                                               force_spread=sp)
                if okl[0]:
                    xi = shape_rng.standard_normal(n_rep)
                    E[:, col:col + size] += np.outer(xi, FORCE_SHAPE_SPREAD * (rl - base)[0])
        col += size
    # centred: a nonlinear response to force noise has a small mean shift (second order),
    # which is the estimator's bias estimate, not a spread to sample from
    return E - E.mean(axis=0)


def _force_noise(structure: Any, rec: _Record) -> tuple[np.ndarray | None, np.ndarray]:
    """(per-DOF force-sensor noise std, boolean mask of the pulse samples) of an impulsive
    record; (None, empty) when the force is continuous or absent."""
    if rec.force is None or not rec.rec.has_force(structure.dofs):
        return None, np.zeros(0, dtype=bool)
    raw = rec.rec.stack("force", structure.dofs, fill=0.0)
    pulse = np.any(rec.force != 0, axis=1)
    if raw.shape != rec.force.shape or not pulse.any() or pulse.mean() > 0.05:
        return None, np.zeros(0, dtype=bool)
    quiet = raw[~pulse]
    sigma = 1.4826 * np.median(np.abs(quiet - np.median(quiet, axis=0)), axis=0)
    return sigma, pulse

