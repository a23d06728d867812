"""Where the generator starts: an equation-error least-squares guess of the linear
parameters sets each parameter's order of magnitude (or, ``init="ls"``, its value)."""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np
import torch

from ..processing import States
from ..structure import Structure


def least_squares_guess(structure: Structure, states: Sequence[States]) -> dict[str, float]:
    """Equation-error least squares for the linear parameters (nonlinear ones at their
    scale hint or 1): a first guess for orders of magnitude, not an estimate."""
    free = structure.free
    lin = structure.linear_parameters()
    base = np.array([structure.parameters[p].scale or 1.0 for p in free])
    rows, rhs = [], []
    for st in states:
        step = max(1, len(st) // 5000)
        q, v, a, f = st.q[::step], st.v[::step], st.a[::step], st.f[::step]
        th0 = base.copy()
        th0[[free.index(p) for p in lin]] = 0.0
        a0 = structure.accelerations(th0, q, v, f)
        cols = []
        for p in lin:
            th = th0.copy()
            th[free.index(p)] = 1.0
            cols.append((structure.accelerations(th, q, v, f) - a0).reshape(-1))
        if not cols:
            return {}
        w = 1.0 / np.maximum(np.sqrt((a ** 2).mean(0)), 1e-12)
        rows.append(np.stack(cols, axis=1) * np.tile(w, len(q))[:, None])
        rhs.append(((a - a0) * w).reshape(-1))
    A, b = np.concatenate(rows), np.concatenate(rhs)
    norm = np.maximum(np.linalg.norm(A, axis=0), 1e-300)
    sol = np.linalg.lstsq(A / norm, b, rcond=None)[0] / norm
    out = {p: float(base[free.index(p)]) for p in free if p not in lin}
    out.update({p: float(x) for p, x in zip(lin, sol)})
    return out


def reference(structure: Structure, guess: dict[str, float], init: str
              ) -> tuple[torch.Tensor, torch.Tensor]:
    """(values, exponents) the generator starts from: the exponent of each parameter from
    its scale hint, else from the order of magnitude of ``guess``; the value 10^exponent,
    or the guess itself with ``init="ls"``."""
    s = structure
    hints = s.scales()
    values = torch.ones(len(s.free), dtype=torch.float64)
    exps = torch.zeros(len(s.free), dtype=torch.float64)
    for k, p in enumerate(s.free):
        g = guess.get(p)
        mag = hints[p] if hints[p] is not None else (abs(g) if g and math.isfinite(g) else 1.0)
        exps[k] = math.floor(math.log10(mag))
        if init == "ls" and g is not None and math.isfinite(g):
            values[k] = g
        else:
            values[k] = 10.0 ** exps[k]
    return values, exps
