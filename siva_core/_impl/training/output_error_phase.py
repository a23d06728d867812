"""The output-error phase's problem: the output error linearised at an anchor
(``OutputErrorPhase``, see linearized.py) and D's view of the validation records in it
(``ValidationSurrogate``)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..linearized import Linearization


class ValidationSurrogate:
    """D's view of the validation records in the output-error phase: real = the processed
    measured quantities, fake = the linearised processed simulation at the generator's x,
    both next to the measured processed state (as in the equation-error phase)."""

    def __init__(self, lin: Linearization) -> None:
        ys, r0s, js, qs, vs = [], [], [], [], []
        n = lin.J.shape[1]
        for k, ser in enumerate(lin.series):
            sl = slice(ser.start, ser.start + ser.T * ser.width)
            w = lin.weight[k]
            ys.append(lin.targets[k])
            r0s.append(lin.r[sl].reshape(ser.T, ser.width) / w)
            js.append(lin.J[sl].reshape(ser.T, ser.width, n) / w[None, :, None])
            qs.append(lin.states[k].q)
            vs.append(lin.states[k].v)
        cat = lambda xs: torch.from_numpy(np.ascontiguousarray(np.concatenate(xs)))
        self.y, self.r0, self.J, self.q, self.v = (cat(x) for x in (ys, r0s, js, qs, vs))
        rms = lambda x: x.pow(2).mean(0).sqrt().clamp_min(1e-12)
        self.sy, self.sq, self.sv = rms(self.y), rms(self.q), rms(self.v)
        self.n = self.y.shape[0]
        self.names = [r.name for r in lin.records]
        # the real features of every sample (elementwise, so indexing them is bit-identical
        # to computing them for the drawn rows)
        self.real = torch.cat([self.q / self.sq, self.v / self.sv, self.y / self.sy], -1).float()
        edges = np.cumsum([0] + [ser.T for ser in lin.series])
        self.bounds = list(zip(edges[:-1].tolist(), edges[1:].tolist()))

    def features(self, idx: torch.Tensor, x: torch.Tensor | None) -> torch.Tensor:
        if x is None:
            return self.real[idx]
        y = self.y[idx]
        if x is not None:
            y = y + self.r0[idx] + (self.J[idx] * x[:, None, :]).sum(-1)
        return torch.cat([self.q[idx] / self.sq, self.v[idx] / self.sv, y / self.sy], -1).float()


@dataclass
class OutputErrorPhase:
    """The linearised output error the generator is judged by in that phase (``J``, ``r``
    at the anchor ``theta``; ``x``: local coordinates, one unit = one standard error)."""

    lin: Linearization
    A: torch.Tensor          # J^T J
    Jt: torch.Tensor         # J^T
    g0: torch.Tensor         # J^T r
    s2: float                # residual variance per row at the anchor (chi^2 scale)
    noise: torch.Tensor | None
    val: ValidationSurrogate | None
    start_epoch: int
    is_log: torch.Tensor
    theta: torch.Tensor
    scale: torch.Tensor

    @classmethod
    def of(cls, train: Linearization, val: Linearization | None, epoch: int) -> "OutputErrorPhase":
        J = torch.from_numpy(train.J)
        r = torch.from_numpy(train.r)
        dof = max(1, train.r.size - train.J.shape[1])
        noise = torch.from_numpy(train.noise) if train.noise.size else None
        return cls(train, J.T @ J, J.T.contiguous(), J.T @ r, max(train.cost / dof, 1e-300),
                   noise, ValidationSurrogate(val) if val is not None else None, epoch,
                   torch.from_numpy(train.is_log), torch.from_numpy(train.theta),
                   torch.from_numpy(train.scale))

    def to_x(self, theta: torch.Tensor) -> torch.Tensor:
        ratio = (theta / self.theta).clamp_min(1e-12)
        return torch.where(self.is_log, torch.log(ratio), (theta - self.theta) / self.scale)
