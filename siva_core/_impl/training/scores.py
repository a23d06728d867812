"""How well the discriminator tells real from model on each validation record: mean
D(real), D(fake) and the BCE loss against ln 4 (its value when it cannot tell), plus, in
the output-error phase, its AUC separating measured from simulated."""
from __future__ import annotations

from typing import Any, Callable

import numpy as np
import torch

from ..networks import LN4, Discriminator
from ..structure import Structure
from .output_error_phase import OutputErrorPhase
from .pools import Pool

Features = Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor]


@torch.no_grad()
def equation_error_scores(discriminator: Discriminator, structure: Structure, pool: Pool,
                          theta: torch.Tensor, features: Features,
                          n_eval: int) -> dict[str, Any]:
    """D on each record of ``pool``: real accelerations vs the model's at ``theta`` (the
    generator's central estimate), at most ``n_eval`` samples per record."""
    records: dict[str, dict[str, float]] = {}
    tot_real, tot_fake, count = 0.0, 0.0, 0
    for name, (i0, i1) in zip(pool.names, pool.bounds):
        step = max(1, (i1 - i0) // n_eval)
        sl = slice(i0, i1, step)
        q, v, a, f = pool.q[sl], pool.v[sl], pool.a[sl], pool.f[sl]
        fake = structure.accelerations(theta, q, v, f)
        pr = discriminator.prob(features(q, v, a)).clamp(1e-7, 1 - 1e-7)
        pf = discriminator.prob(features(q, v, fake)).clamp(1e-7, 1 - 1e-7)
        lr_, lf_ = -pr.log().mean().item(), -(1 - pf).log().mean().item()
        records[name] = {"d_real": pr.mean().item(), "d_fake": pf.mean().item(),
                         "loss_d": lr_ + lf_}
        tot_real += lr_ * len(pr)
        tot_fake += lf_ * len(pf)
        count += len(pr)
    loss_d = (tot_real + tot_fake) / max(count, 1)
    return {"loss_d": loss_d, "ln4": LN4, "ln4_distance": abs(loss_d - LN4), "records": records}


@torch.no_grad()
def output_error_scores(discriminator: Discriminator, ph: OutputErrorPhase,
                        theta: torch.Tensor, n_eval: int) -> dict[str, Any]:
    """D on each validation record of the output-error phase (``ph.val`` is set): the
    measured processed quantities vs the linearised simulation at ``theta``."""
    assert ph.val is not None
    x = ph.to_x(theta[None])
    records: dict[str, dict[str, float]] = {}
    prs, pfs = [], []
    for name, (i0, i1) in zip(ph.val.names, ph.val.bounds):
        idx = torch.arange(i0, i1, max(1, (i1 - i0) // n_eval))
        pr = discriminator.prob(ph.val.features(idx, None)).clamp(1e-7, 1 - 1e-7)
        pf = discriminator.prob(ph.val.features(idx, x.expand(len(idx), -1))
                                ).clamp(1e-7, 1 - 1e-7)
        records[name] = {"d_real": float(pr.mean()), "d_fake": float(pf.mean()),
                         "loss_d": float(-pr.log().mean() - (1 - pf).log().mean())}
        prs.append(pr)
        pfs.append(pf)
    pr, pf = torch.cat(prs), torch.cat(pfs)
    loss_d = float(-pr.log().mean() - (1 - pf).log().mean())
    # AUC = P(D(real) > D(fake)) (Mann-Whitney): 0.5 = indistinguishable
    both = torch.cat([pr, pf]).numpy()
    ranks = np.argsort(np.argsort(both)) + 1.0
    n1 = len(pr)
    auc = float((ranks[:n1].sum() - n1 * (n1 + 1) / 2) / (n1 * len(pf)))
    return {"loss_d": loss_d, "ln4": LN4, "ln4_distance": abs(loss_d - LN4),
            "d_real": float(pr.mean()), "d_fake": float(pf.mean()), "auc": auc,
            "target": "output", "records": records}
