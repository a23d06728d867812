"""The kick at a hammer pulse: what a pulse of few samples leaves undetermined about the
force -- the structure's state just after it -- as per-record nuisance patterns, and the
accelerations at the force's samples (issue 20, docs/perf.md 6.5).

``refine``, ``linearize`` and ``force_profiled_output_error`` fit the kick ("auto") where
``default_force_kick``; ``OutputErrorProblem`` adds its patterns to the staged force and
takes the force sample in the simulated accelerations (``sampled_force_acceleration``)."""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np

#: a record's force is "one short pulse" (kickable) when its nonzero samples span at most
#: this share of the record (the same 5 % that makes a record impulsive for the replicates)
KICK_MAX_PULSE_SHARE = 0.05
#: ... and at most this many samples (None: any).  No limit: noise-free, the reading of
#: the pulse between its samples shifts estimates at every pulse length tried, 3-5
#: samples by 0.3-10 %, 12.7 samples (LO-NO alpha, a 3-DOF chain's knl) by 0.3-0.5 %,
#: and the kick removes it at all of them (docs/perf.md 6.5).  Set before the fresh
#: coverage seeds 11000+.
KICK_MAX_PULSE_SAMPLES: int | None = None
#: ``refine``/``linearize``/``force_profiled_output_error`` fit the kick by default
#: ("auto") where ``force_kick_applicable``; False: never (main's behaviour, ablation)
FIT_FORCE_KICK_BY_DEFAULT = True


def single_pulse(force: np.ndarray | None) -> tuple[np.ndarray | None, int]:
    """((T,) the force samples of the hit's DOF, that DOF's index) when ``force`` (T, n) is
    one pulse spanning at most ``KICK_MAX_PULSE_SHARE`` of the record (a hammer hit),
    else (None, 0): several hits, a continuous excitation, or no force."""
    if force is None or force.ndim != 2 or not np.all(np.isfinite(force)):
        return None, 0
    rows = np.flatnonzero(np.any(force != 0, axis=1))
    if rows.size == 0:
        return None, 0
    span = int(rows[-1] - rows[0] + 1)
    if span > KICK_MAX_PULSE_SHARE * len(force):
        return None, 0
    hit = int(np.argmax(np.abs(force.sum(axis=0))))
    if force[:, hit].sum() == 0:
        return None, 0
    return force[:, hit].copy(), hit


def pulse_samples(pulse: np.ndarray) -> int:
    """Samples from the first to the last nonzero one of a pulse."""
    rows = np.flatnonzero(pulse)
    return int(rows[-1] - rows[0] + 1) if rows.size else 0


def force_kick_patterns(pulse: np.ndarray) -> np.ndarray:
    """(T, 2): the hit's own samples and their central difference / 2 (per sample).

    Why these two: for a pulse short against the modes, everything its unknown shape
    between the samples does to the rest of the record is the structure's state just after
    it, 2 numbers per DOF.  Added at DOF d, a multiple a_d of the pulse moves that DOF's
    velocity (an impulse, relative to the hit's), a multiple b_d of its derivative moves
    its displacement (a doublet, b_d in samples: a delay of the hit by tau samples is
    b_hit = -tau); over all DOFs they span every state (for a linear structure exactly,
    whenever the pulse's spectrum is not zero at a mode)."""
    p = np.asarray(pulse, dtype=float)
    d = np.zeros_like(p)
    d[1:-1] = 0.5 * (p[2:] - p[:-2])
    return np.stack([p, d], axis=1)


def force_kick_applicable(structure: Any, records: Sequence[Any]) -> bool:
    """Whether ``refine``, ``linearize`` and ``force_profiled_output_error`` fit a kick
    ("auto"), given the prepared records (``OutputErrorProblem.records``): every record is
    one hammer hit (``single_pulse``) of at most ``KICK_MAX_PULSE_SAMPLES`` samples, and
    every DOF has a measured response channel (the free decay after the hit then shows
    each mode at the sensors, so the state the kick sets is observable and the parameters
    stay identifiable from the decay: the kick costs only what the force said about the
    modes' excitation ratios at the hit DOF)."""
    if not records:
        return False
    for r in records:
        if r.kick_pulse is None:
            return False
        if KICK_MAX_PULSE_SAMPLES is not None and pulse_samples(r.kick_pulse) > KICK_MAX_PULSE_SAMPLES:
            return False
        if any(all(r.rec.get(q, d) is None for q in ("disp", "vel", "acc"))
               for d in structure.dofs):
            return False
    return True


def set_pulse_reading(kick: bool | None = None, acc_at_force_samples: bool | None = None
                      ) -> tuple[bool, bool]:
    """Ablation knobs for benchmarks and tests: whether output-error fits fit the kick by
    default (``FIT_FORCE_KICK_BY_DEFAULT``) and whether simulated accelerations take the
    force sample at the samples (``ACC_AT_FORCE_SAMPLES``); None keeps one.  Returns the
    previous (kick, acc_at_force_samples) so a caller can restore them."""
    global FIT_FORCE_KICK_BY_DEFAULT, ACC_AT_FORCE_SAMPLES
    previous = (FIT_FORCE_KICK_BY_DEFAULT, ACC_AT_FORCE_SAMPLES)
    if kick is not None:
        FIT_FORCE_KICK_BY_DEFAULT = bool(kick)
    if acc_at_force_samples is not None:
        ACC_AT_FORCE_SAMPLES = bool(acc_at_force_samples)
    return previous


def default_force_kick(structure: Any, records: Sequence[Any]) -> bool:
    """The "auto" choice: ``FIT_FORCE_KICK_BY_DEFAULT`` and ``force_kick_applicable``."""
    return FIT_FORCE_KICK_BY_DEFAULT and force_kick_applicable(structure, records)


def kick_mask(record: Any, n_dof: int, with_scale: bool) -> np.ndarray:
    """(2, n_dof) which kick components are fitted for ``record``: none without a single
    pulse; else all but the impulse on the hit DOF when the force multiplier is fitted
    (that one is the multiplier)."""
    m = np.zeros((2, n_dof), dtype=bool)
    if record.kick_pulse is not None:
        m[:] = True
        if with_scale:
            m[0, record.hit_dof] = False
    return m


#: bounds of the kick's components: impulse (share of the hit's) and doublet [samples]
KICK_BOUNDS = ((-1.0, 1.0), (-3.0, 3.0))
#: at most this many Gauss-Newton steps on the kick (with the multiplier) after the
#: multiplier's own steps, in ``force_profiled_output_error`` and ``linearize``, fewer when
#: a step moves no component by ``KICK_STEP_TOL`` (of the hit's impulse, or samples):
#: near the multiplier's optimum the response is nearly linear in the kick (one step),
#: but from an anchor 20 % off
#: (``settle``) one step left the profiled cost too rough to accept a descent step
#: (was 1 in the coverage run of docs/perf.md 6.5)
KICK_STEPS = 4
KICK_STEP_TOL = 1e-4


#: the simulated acceleration at a sample takes the force *sample* there, not the model's
#: continuous reading of it (docs/perf.md 6.5); False restores the reading (ablation)
ACC_AT_FORCE_SAMPLES = True


def sampled_force_acceleration(structure: Any, a: np.ndarray, force: np.ndarray | None,
                                staged: np.ndarray | None, m: int,
                                force_scale: np.ndarray | None, inplace: bool = False,
                                at_samples: bool = False) -> np.ndarray:
    """(B, T, n) the simulated accelerations with the force term at each sample set to the
    measured force sample (times the set's multiplier).

    Why: an accelerometer sampled during a hammer pulse reads (F(t_i) - internal forces) / m
    with F(t_i) the force sensor's sample at the same instant; the simulator's force there
    is its continuous reading (the "moments" prefilter moves the samples by D2 F / 12, up to
    1/6 of the peak on a 3-sample pulse; a fitted kick adds its patterns), which the state
    needs but the instantaneous acceleration must not see.  The error sat on the few samples
    of the pulse, spread by the chain's filters, and shifted a cubic stiffness by ~1 %
    (chain hit on its end mass, 4 samples per pulse).  Only with numeric force gains and a
    diagonal mass (the lumped models); otherwise unchanged.  ``inplace``: ``a`` is the
    caller's own (a fresh simulation) and is corrected where it is, not copied;
    ``at_samples``: ``staged`` holds the stage force at the samples only ((B, T, n))."""
    if (not ACC_AT_FORCE_SAMPLES or force is None or staged is None
            or any(not isinstance(structure.force_gain(d), (int, float))
                   for d in structure.dofs)):
        return a
    at = staged if at_samples else staged[..., ::2 * m, :]
    diff = np.asarray(force, dtype=float) - at                  # (T, n) or (B, T, n)
    rows = np.flatnonzero(np.any(diff != 0, axis=tuple(range(diff.ndim - 2)) + (-1,)))
    if rows.size == 0:
        return a
    # only the samples where the reading differs from the sample (a hammer pulse's few,
    # when the force is gated to it); elsewhere the correction is 0 and ``a`` stays
    lo, hi = int(rows[0]), int(rows[-1]) + 1
    gain = np.array([float(structure.force_gain(d)) / float(structure.mass[d])
                     for d in structure.dofs])
    part = a[..., lo:hi, :]
    corr = np.broadcast_to(diff[..., lo:hi, :] * gain, part.shape)
    if force_scale is not None:
        corr = corr * np.broadcast_to(np.asarray(force_scale, float).ravel(), (a.shape[0],)
                                      )[:, None, None]
    out = a if inplace else a.copy()
    out[..., lo:hi, :] = part + corr
    return out
