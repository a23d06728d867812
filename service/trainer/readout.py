"""Reading the running ensemble out of a trainer: the same code live and in replay.

Why "provisional": an interval is only published once it is one.  Before the output-error
phase has converged and harvested ``ENSEMBLE_MIN_SAMPLES`` epochs on its current anchor,
the ensemble is either the equation-error phase's (biased by the processing chain on
measured data: docs/method.md) or a handful of samples; it is then shown with its mean and
spread, marked ``provisional``, and carries no ``ci95``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from siva_core import Structure

#: ensemble epochs on the current data set needed before a refinement starts from them
REFINE_MIN_SAMPLES = 10
#: Approach II samples harvested on the current anchor before the ensemble is final
ENSEMBLE_MIN_SAMPLES = 30
#: never narrower than the simulator's accuracy (as ``Siva.fit``)
NUMERICAL_REL_STD = 1e-6


@dataclass(frozen=True)
class EnsembleReadout:
    """The ensemble summary {p: {mean, std, ci95?, ess, n}}, where it comes from and
    whether it is final."""

    parameters: dict[str, dict[str, Any]]
    source: str | None          # approach_II | generator | None
    phase: str                  # equation_error | output_error
    final: bool
    n_samples: int

    def to_json(self) -> dict[str, Any]:
        return {p: {**v, "provisional": not self.final} for p, v in self.parameters.items()}

    @property
    def state(self) -> str:
        if not self.parameters:
            return "none"
        return "final" if self.final else "provisional"


def output_error_wanted(trainer: Any) -> bool:
    """The trainer's settings ask for the output-error phase (``fit_target="output"``)."""
    return getattr(getattr(trainer, "settings", None), "fit_target", "equation") == "output"


def read_ensemble(structure: Structure, trainer: Any) -> EnsembleReadout:
    from siva_core import normal_summary

    free = structure.free
    phase = "output_error" if getattr(trainer, "oe", None) is not None else "equation_error"
    n = len(trainer.ensemble)
    final = bool(trainer.converged and n >= ENSEMBLE_MIN_SAMPLES
                 and (phase == "output_error" or not output_error_wanted(trainer)))
    if n >= 2:
        params = normal_summary(trainer.ensemble.samples, free, floor_rel=NUMERICAL_REL_STD)
        source: str | None = "approach_II"
    elif trainer.epoch == 0 or not getattr(trainer, "initialised", True):
        return EnsembleReadout({}, None, phase, False, 0)
    else:
        params = normal_summary(trainer.sample(256), free, ess=False)
        source = "generator"
        final = False
    if not final:
        params = {p: {k: v for k, v in s.items() if k not in ("ci95", "percentile95")}
                  for p, s in params.items()}
    return EnsembleReadout(params, source, phase, final, n)


def candidates(tr: Any, data_epoch: int) -> np.ndarray | None:
    """Approach III's candidates: the harvested ensemble of the current data set, else the
    per-epoch samples since convergence (the harvest's burn-in is not worth waiting for:
    the refinement starts from the winner anyway); None while fewer than
    ``REFINE_MIN_SAMPLES``."""
    ens = tr.ensemble
    samples = np.array(ens.samples, dtype=float, copy=True) if len(ens) else np.zeros((0, 0))
    if len(ens):
        current = samples[np.asarray(ens.epochs) >= data_epoch]
        if len(current) >= REFINE_MIN_SAMPLES:
            return current
    conv_at = getattr(getattr(tr, "monitor", None), "converged_at", None)
    hist = getattr(tr, "history", {}).get("theta", [])
    if conv_at is not None and hist:
        first = max(int(conv_at), data_epoch)
        k = len(hist) - (int(tr.epoch) - first)  # history may be trimmed at its start
        since = hist[max(0, k):]
        if len(since) >= REFINE_MIN_SAMPLES:
            return np.array(since, dtype=float)
    return samples if len(samples) >= REFINE_MIN_SAMPLES else None
