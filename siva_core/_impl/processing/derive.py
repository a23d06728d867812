"""Deriving what a recording lacks, signal by signal, with the filters each went through.

Integration upward from acceleration, differentiation downward from displacement; every
signal keeps a ledger of its filters, and with ``consistent`` each one (the force too) is
topped up to the union of all ledgers, so that M a = -f(q, v) + F still holds for the
linear terms after processing.
"""
from __future__ import annotations

from collections import Counter
from typing import Any, Callable, Protocol, Sequence

import numpy as np

from .calculus import joint_tail_constants
from .filters import acc_keys, dof_ledgers, top_up, union


class ChainSteps(Protocol):
    """What the derivation reads of a chain (``Processing``): its settings and steps."""

    bandpass: tuple[float, float] | None
    highpass: float | None
    lowpass_diff: float | None
    notch: tuple[float, ...]
    notch_q: float
    order: int
    pad: float
    drift: str
    consistent: bool

    def filter_acc(self, a: np.ndarray, fs: float, axis: int = 0) -> np.ndarray: ...

    def integrate(self, x: np.ndarray, fs: float, x0: np.ndarray | None = None,
                  axis: int = 0) -> np.ndarray: ...

    def differentiate(self, x: np.ndarray, fs: float, axis: int = 0) -> np.ndarray: ...


def derive_arrays(chain: ChainSteps, fs: float, dofs: Sequence[str],
                  given: Callable[[str, str], np.ndarray | None],
                  force: np.ndarray | None, need: str = "qva") -> tuple[Any, ...]:
    """Core: per DOF derive what is missing; arrays have time on the last axis.

    Every derived signal records the filters it went through (its ledger); with
    ``consistent`` each signal is then topped up to the union of all ledgers.
    ``need``: which of q, v, a are wanted ("qva" = all).  The ledgers are worked out
    symbolically for every signal (they set the consistent total filter), but only
    the wanted signals and what they derive from are computed (an output-error
    residual on accelerations needs no integration); the others are returned as
    zero-strided NaN arrays.  Wanted signals are computed by exactly the same
    operations as with ``need="qva"`` (bit-identical).  ``force=None``: the force is
    not processed (returned as None; ``apply_simulated`` takes it from the memo).
    """
    npad = int(round(chain.pad * fs))
    if chain.drift == "tail":
        need = "qva"  # the tail constants couple v and q

    def padded(x: np.ndarray, axis: int) -> np.ndarray:
        """The structure at rest before and after the record: zeros, on every signal."""
        if npad <= 0:
            return x
        width = [(0, 0)] * x.ndim
        width[axis] = (npad, npad)
        return np.pad(x, width)

    def source(qty: str, d: str) -> np.ndarray | None:
        x = given(qty, d)
        return None if x is None else padded(np.asarray(x, float), -1)

    qs: list[np.ndarray | None] = []
    vs: list[np.ndarray | None] = []
    as_: list[np.ndarray | None] = []
    ledgers: list[Counter] = []
    for d in dofs:
        dq, dv, da = source("disp", d), source("vel", d), source("acc", d)
        if dq is None and dv is None and da is None:
            raise ValueError(f"DOF {d!r} has no disp, vel or acc")
        lq, lv, la = signal_ledgers(chain, fs, dq is not None, dv is not None, da is not None)
        # what must be computed: the wanted signals and their sources
        want_q = "q" in need
        want_a = "a" in need
        want_v = ("v" in need or (want_q and dq is None)
                  or (want_a and da is None))
        need_fa = want_a or (want_v and dv is None and da is not None)
        a = v = q = None
        if da is not None and need_fa:
            a = chain.filter_acc(np.asarray(da, float), fs, axis=-1)
        if want_v:
            if dv is not None:
                v = np.asarray(dv, float)
            elif da is not None:
                v = chain.integrate(a, fs, axis=-1)
            else:
                v = chain.differentiate(np.asarray(dq, float), fs, axis=-1)
        if want_q:
            if dq is not None:
                q = np.asarray(dq, float)
            else:
                q = chain.integrate(v, fs, axis=-1)
                if chain.drift == "tail" and dv is None and da is not None:
                    v, q = joint_tail_constants(v, q, fs)
        if a is None and want_a:
            a = chain.differentiate(v, fs, axis=-1)
        qs.append(q if want_q else None)
        vs.append(v if "v" in need else None)
        as_.append(a if want_a else None)
        ledgers.extend([lq, lv, la])
    if chain.consistent:
        target = union(ledgers)
        for k in range(len(dofs)):
            for lst, led in ((qs, ledgers[3 * k]), (vs, ledgers[3 * k + 1]),
                             (as_, ledgers[3 * k + 2])):
                if lst[k] is not None:
                    lst[k] = top_up(lst[k], target - led, fs, chain.order, -1)
    f = None if force is None else force_full_rate(chain, force, fs, union(ledgers))
    computed = [x for x in qs + vs + as_ if x is not None]
    shape = np.broadcast_shapes(*(x.shape for x in computed))
    nan = np.broadcast_to(np.float64(np.nan), shape)
    q, v, a = (np.stack([np.broadcast_to(x, shape) if x is not None else nan
                         for x in lst], axis=-1)
               if any(x is not None for x in lst)
               else np.broadcast_to(np.float64(np.nan), shape + (len(dofs),))
               for lst in (qs, vs, as_))
    if npad > 0:
        keep = slice(npad, q.shape[-2] - npad)
        q, v, a = q[..., keep, :], v[..., keep, :], a[..., keep, :]
    return q, v, a, f


def signal_ledgers(chain: ChainSteps, fs: float, has_q: bool, has_v: bool, has_a: bool
                   ) -> tuple[Counter, Counter, Counter]:
    """(q, v, a) ledgers of one DOF: the filters each of its signals goes through,
    given which of them were measured (the rest is derived)."""
    return dof_ledgers(acc_keys(chain.bandpass, chain.notch, chain.notch_q, fs) if has_a else [],
                       chain.highpass, chain.lowpass_diff, has_q, has_v, has_a)


def force_full_rate(chain: ChainSteps, force: np.ndarray, fs: float, target: Counter) -> np.ndarray:
    """The force through the chain at the record's rate (padded, topped up to the
    total filter ``target`` when ``consistent``, unpadded)."""
    npad = int(round(chain.pad * fs))
    f = np.asarray(force, float)
    if npad > 0:
        f = np.pad(f, [(npad, npad)] + [(0, 0)] * (f.ndim - 1))
    if chain.consistent:
        f = top_up(f, target, fs, chain.order, 0)
    if npad > 0:
        f = f[npad:f.shape[0] - npad]
    return f
