"""The equation-error phase's data: records' samples stacked as torch tensors (``Pool``)
and the batches drawn from them (``Batch``)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import torch

from ..processing import States
from ..structure import Structure


@dataclass
class Pool:
    """Samples of several records stacked as torch tensors, with per-record offsets.

    For a model linear in every free parameter the acceleration is ``a0 + phi @ theta``
    per sample; ``phi`` and ``a0`` are precomputed once so a training step costs one
    small product instead of a walk over the elements (3-4x faster per step).
    """

    q: torch.Tensor
    v: torch.Tensor
    a: torch.Tensor
    f: torch.Tensor
    names: list[str]
    bounds: list[tuple[int, int]] = field(default_factory=list)
    phi: torch.Tensor | None = None  # (N, n_dof, n_free)
    a0: torch.Tensor | None = None  # (N, n_dof)

    @classmethod
    def of(cls, states: Sequence[States], structure: Structure) -> "Pool":
        cat = lambda attr: torch.from_numpy(np.concatenate([getattr(s, attr) for s in states]))
        bounds, start = [], 0
        for s in states:
            bounds.append((start, start + len(s)))
            start += len(s)
        pool = cls(cat("q"), cat("v"), cat("a"), cat("f"), [s.name for s in states], bounds)
        free = structure.free
        if set(structure.linear_parameters()) == set(free):
            zero = torch.zeros(len(free), dtype=torch.float64)
            pool.a0 = structure.accelerations(zero, pool.q, pool.v, pool.f)
            cols = []
            for k in range(len(free)):
                unit = zero.clone()
                unit[k] = 1.0
                cols.append(structure.accelerations(unit, pool.q, pool.v, pool.f) - pool.a0)
            pool.phi = torch.stack(cols, dim=-1)
        return pool

    def __len__(self) -> int:
        return self.q.shape[0]

    def draw(self, n: int, rng: torch.Generator) -> "Batch":
        idx = torch.randint(0, len(self), (n,), generator=rng)
        return Batch(self.q[idx], self.v[idx], self.a[idx], self.f[idx],
                      None if self.phi is None else self.phi[idx],
                      None if self.a0 is None else self.a0[idx], idx)


@dataclass
class Batch:
    """Samples drawn from a pool (rows ``idx``), with their precomputed linear terms."""

    q: torch.Tensor
    v: torch.Tensor
    a: torch.Tensor
    f: torch.Tensor
    phi: torch.Tensor | None
    a0: torch.Tensor | None
    idx: torch.Tensor | None = None  # the samples' rows in their pool

    def model_acc(self, structure: Structure, theta: torch.Tensor) -> torch.Tensor:
        """Model accelerations at this batch's states, one parameter set per sample."""
        if self.phi is not None:
            return self.a0 + (self.phi * theta[:, None, :]).sum(-1)
        return structure.accelerations(theta, self.q, self.v, self.f)
