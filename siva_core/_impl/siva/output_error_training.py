"""SIVA's second training phase: the generator judged by the output error through the
processing chain, linearised at ``best`` (see linearized.py), until converged; then the
Approach II harvest of that phase."""
from __future__ import annotations

from typing import Sequence

import numpy as np

from ..processing import Processing
from ..progress import Eta, Progress
from ..recording import Recording
from ..structure import Structure
from ..training import SivaSettings, SivaTrainer


def train_output_error_phase(trainer: SivaTrainer, structure: Structure,
                             settings: SivaSettings, anchor: np.ndarray,
                             train: Sequence[Recording], val: Sequence[Recording],
                             proc: Processing, notes: list[str],
                             progress: Progress | None, progress_every: int) -> None:
    """Continue training on the output error linearised at ``anchor`` until converged,
    then harvest the Approach II ensemble (see linearized.py)."""
    from ..linearized import linearize

    st = structure
    try:
        lin_tr = linearize(st, anchor, train, proc, n_noise=settings.oe_noise,
                           seed=settings.seed)
        lin_va = linearize(st, anchor, val, proc) if val else None
    except ValueError as exc:
        notes.append(f"output-error phase skipped ({exc}); Approach II is equation error")
        return
    trainer.use_output_error(lin_tr, lin_va)
    start = trainer.epoch
    limit = start + max(settings.oe_min_epochs + 4 * settings.oe_conv_window,
                        settings.max_epochs // 2) + settings.oe_ensemble_epochs
    eta = Eta(limit, start=start)  # an upper bound again
    import copy

    good = copy.deepcopy(trainer.generator.state_dict())
    while trainer.epoch < limit:
        log = trainer.run_epoch()
        if not (np.all(np.isfinite(log.theta)) and np.isfinite(log.loss_mse)):
            # the linearised output error is flat along a direction the records do not
            # determine; the generator ran off along it.  Keep the last finite state.
            trainer.generator.load_state_dict(good)
            trainer.ensemble.drop_nonfinite()
            notes.append(f"output-error phase stopped at epoch {log.epoch}: the generator "
                         "left the finite range (the records do not determine every "
                         "parameter); Approach I/II are from the last finite epoch")
            break
        good = copy.deepcopy(trainer.generator.state_dict())
        if progress and (log.epoch % progress_every == 0):
            rel = ", ".join(f"{p}={v:.5g}" for p, v in zip(st.free, log.theta))
            progress(f"{eta.text(log.epoch + 1)}  [output error]  D={log.loss_d:.4f}  "
                     f"fit={log.loss_mse:.3e}  {'converged ' if log.converged else ''}{rel}")
        if trainer.converged and len(trainer.ensemble) >= settings.oe_ensemble_epochs:
            break
    if not trainer.converged:
        notes.append("output-error phase not converged: Approach II uses its last epochs")
