"""Is one set better than a smaller one on the held-out records?  A test of the
difference of their validation gaps against the noise (issue 16: "compare sets by a
validation statistic that knows the noise, not fixed floor margins").

Both sets are simulated on the same validation records, so the measurement noise is the
same in both residuals.  With ``r`` the larger set's residual and ``d`` the change of
the outputs between the two sets, the smaller set's residual is ``r + d`` and the gain
is ``|r + d|^2 - |r|^2 = |d|^2 + 2 r.d``: the part ``|d|^2`` is systematic, the cross
term ``2 r.d`` is what the noise (and what both sets miss) makes of it by chance.  Its
spread is measured on the records themselves: the cross term summed over contiguous
time blocks of every record, each block's sum a nearly independent draw, gives the
standard error ``2 sqrt(sum of their squares)`` (coloured noise, mains hum and the
nominal model's own misfit count).  The statistic is the gain over that error.  A fixed
multiple of the spectral noise floor compares the gain with the *whole* noise energy,
which both sets share and which cancels in their difference (fresh seed 17241: a 7 %
accelerometer gain beside a clearance removed 0.00107 of the gap, 0.88 x the floor, at a
statistic of 12.8).

A paired t statistic of the block gains was tried first and dropped: a second effect's
gain is not spread evenly over a hammer record (a coulomb acts in the decaying tail), so
the blocks' spread is large for a large, obvious gain (2-DOF test records: a coulomb
removing 99.9 % of the gap scored t = 1.3).
"""
from __future__ import annotations

import math
from typing import Callable, Sequence

import numpy as np

from ..processing import Processing
from ..recording import Recording
from .outputs import _Outputs
from .results import Candidate


def residual(c: Candidate, val: Sequence[Recording], proc: Processing
             ) -> tuple[np.ndarray, list[int]] | None:
    """``c``'s validation residual (the vector whose squared norm is its gap) and the
    number of time samples of each record in it (all DOFs of a sample together); None
    when it cannot be simulated."""
    if c.structure is None or c.theta is None:
        return None
    try:
        outs = _Outputs(c.structure, c.correct(val), proc, c.theta)
        res = outs.residuals(c.theta)[0]
    except Exception:  # noqa: BLE001 - a set that cannot be simulated is not judged
        return None
    if not np.all(np.isfinite(res)):
        return None
    return res, [r.target.shape[0] for r in outs.records]


def block_sums(x: np.ndarray, lengths: Sequence[int], n_blocks: int) -> np.ndarray:
    """``x`` (sample-major, all DOFs of a sample together) summed over ``n_blocks``
    contiguous time blocks of each record, flattened over the records."""
    out, col = [], 0
    for n in lengths:
        rows = x[col:col + x.size * n // sum(lengths)]
        col += rows.size
        per = rows.reshape(n, -1).sum(axis=1)
        out += [float(p.sum()) for p in np.array_split(per, n_blocks)]
    return np.asarray(out)


def gain_z(small: tuple[np.ndarray, list[int]] | None,
           big: tuple[np.ndarray, list[int]] | None, n_blocks: int) -> float:
    """The larger set's gain over its noise error (module doc); nan when unknown."""
    if small is None or big is None or small[0].shape != big[0].shape:
        return math.nan
    r, d = big[0], small[0] - big[0]
    gain = float(small[0] @ small[0] - r @ r)
    cross = block_sums(r * d, big[1], n_blocks)
    err = 2.0 * math.sqrt(float(cross @ cross))
    if err <= 0.0:
        return math.inf if gain > 0 else (-math.inf if gain < 0 else math.nan)
    return gain / err


class BlockTest:
    """``gain_z`` between fitted candidates on one set of validation records, each
    candidate simulated once; the statistics computed are kept for the report."""

    def __init__(self, val: Sequence[Recording], proc: Processing, n_blocks: int) -> None:
        self.val, self.proc, self.n_blocks = list(val), proc, n_blocks
        self._res: dict[int, tuple[Candidate, tuple[np.ndarray, list[int]] | None]] = {}
        self._z: dict[int, dict[str, float]] = {}

    def residual(self, c: Candidate | None) -> tuple[np.ndarray, list[int]] | None:
        if c is None:
            return None
        if id(c) not in self._res:  # the candidate is kept so that its id stays its own
            self._res[id(c)] = (c, residual(c, self.val, self.proc))
        return self._res[id(c)][1]

    def z(self, small: Candidate | None, big: Candidate) -> float:
        """``big``'s gain over ``small`` (nan when ``small`` is unknown: the nominal)."""
        if small is None:
            return math.nan
        z = gain_z(self.residual(small), self.residual(big), self.n_blocks)
        self._z.setdefault(id(big), {})[small.label()] = round(float(z), 2)
        return z

    def known(self, big: Candidate) -> dict[str, float]:
        """The statistics computed for ``big`` so far, by the smaller set's label."""
        return dict(self._z.get(id(big), {}))


def without_fits(members: Sequence[Candidate], singles: dict[tuple, Candidate],
                 sets: dict[frozenset, Candidate]) -> list[Candidate | None]:
    """For each member of a set, the fitted set without it whose validation gap
    ``sets.choose_set`` compares with (its ``without``): the fitted set of the other
    members, else the best of their single fits that closes anything; None for none
    (the nominal)."""
    keys = [m.key for m in members]
    out: list[Candidate | None] = []
    for k in range(len(keys)):
        rest = keys[:k] + keys[k + 1:]
        if len(rest) > 1 and frozenset(rest) in sets:
            out.append(sets[frozenset(rest)])
            continue
        alone = [singles[x] for x in rest if x in singles
                 and singles[x].gap_after < singles[x].gap_before]
        out.append(min(alone, key=lambda c: c.gap_after, default=None))
    return out


def one_value_separation(train: Sequence[Recording], val: Sequence[Recording],
                         proc: Processing, n_blocks: int
                         ) -> Callable[[Candidate, Candidate], float]:
    """The verdict's separation statistic for a sensor fault against a structural rival
    (``verdict.decide``'s ``separated``): the fault's gain over the rival on the train
    *and* validation records, in standard errors of the noise (``gain_z``); nan when not
    applicable.

    A sensor fault has one value and changes its channel by one factor (or shift) at
    every frequency, the rest of the model as it was; a structural law reshapes the modes
    of every channel with at least as many coefficients.  Near the noise floor both leave
    the same noise, so the bare ratio of their validation gaps is pulled towards 1
    whatever the evidence (fresh seed 17359: an accelerometer gain on acc_m2 alone left
    0.0112, a spring m2-ground 0.0139 of a gap 0.0189 whose spectral floor is 0.0060:
    ratio 0.80, refused; on the one validation record the gain's lead is 2.75 standard
    errors).  Validation guards against a model that fits better for its freedom; a
    rival with at least the fault's freedom that fits the train records worse has no such
    excuse, so the train records count as evidence too (as ``ties`` compares laws with as
    many coefficients on all records).  The residuals compare: a corrected channel's
    residual in refine's normalisation is ``(g sim - y) / rms(y)``, the raw records'
    residual of the model read through the fault."""
    test = BlockTest([*train, *val], proc, n_blocks)

    def z(top: Candidate, rival: Candidate) -> float:
        if top.category != "sensor" or rival.category == "sensor" \
                or len(rival.effect.coefficients) < 1:
            return math.nan
        return test.z(rival, top)

    return z
