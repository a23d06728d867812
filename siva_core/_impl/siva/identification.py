"""What one SIVA run produced (``Identification``) and its JSON form (CONTRACT.md)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..processing import Processing
from ..structure import Structure


@dataclass
class Identification:
    """Everything one SIVA run produced (``to_json`` gives the CONTRACT shape)."""

    structure: Structure
    approach_I: dict[str, dict]
    approach_II: dict[str, dict]
    approach_III: np.ndarray
    best: np.ndarray
    best_std: np.ndarray | None
    samples_I: np.ndarray
    samples_II: np.ndarray
    history: dict[str, list]
    converged_epoch: int | None
    epochs: int
    discriminator: dict[str, Any]
    metrics: dict[str, Any]
    timing_s: dict[str, float]
    baselines: dict[str, dict[str, float]] = field(default_factory=dict)
    processing: Processing | None = None
    notes: list[str] = field(default_factory=list)
    approach_II_equation_error: dict[str, dict] = field(default_factory=dict)
    best_cov: np.ndarray | None = None

    @property
    def names(self) -> list[str]:
        return self.structure.free

    def estimates(self) -> dict[str, np.ndarray]:
        """Each approach's point estimate as a parameter vector."""
        n = self.names
        return {"approach_I": np.array([self.approach_I[p]["mean"] for p in n]),
                "approach_II": np.array([self.approach_II[p]["mean"] for p in n]),
                "approach_III": self.approach_III, "best": self.best}

    def to_json(self) -> dict[str, Any]:
        params: dict[str, Any] = {}
        for k, p in enumerate(self.names):
            entry: dict[str, Any] = {
                "approach_I": _stats(self.approach_I[p]),
                "approach_II": {**_stats(self.approach_II[p]), "ess": self.approach_II[p].get("ess")},
                **({"approach_II_equation_error": _stats(self.approach_II_equation_error[p])}
                   if p in self.approach_II_equation_error else {}),
                "approach_III": float(self.approach_III[k]),
                "best": float(self.best[k]),
            }
            if self.best_std is not None:
                s = float(self.best_std[k])
                entry["best_std"] = s
                entry["best_ci95"] = [float(self.best[k] - 1.96 * s), float(self.best[k] + 1.96 * s)]
            params[p] = entry
        corr: dict[str, Any] = {}
        if len(self.samples_II) > 2:
            corr["approach_II"] = np.corrcoef(self.samples_II, rowvar=False).tolist()
        if self.best_cov is not None:
            s = np.sqrt(np.clip(np.diag(self.best_cov), 1e-300, None))
            corr["best"] = (self.best_cov / np.outer(s, s)).tolist()
        return {"parameters": params, "correlation": {"names": self.names, **corr},
                "validation": self.metrics.get("validation_test", {}),
                "metrics": self.metrics, "discriminator": self.discriminator,
                "timing_s": self.timing_s, "baselines": self.baselines,
                "training": {"epochs": self.epochs, "converged_epoch": self.converged_epoch,
                             "n_ensemble": int(len(self.samples_II))},
                "processing": _processing_json(self.processing), "notes": self.notes,
                "assessment": self.assessment().to_json()}

    def assessment(self, **commands: str) -> Any:
        """The verdict (accepted / rejected, unphysical or undetermined values, what to try
        next): :func:`siva_core._impl.assessment.assess`."""
        from ..assessment import assess

        return assess(self, **commands)


def _stats(d: dict) -> dict:
    return {"mean": d["mean"], "std": d["std"], "ci95": d["ci95"]}


def _processing_json(p: Processing | None) -> dict | None:
    if p is None:
        return None
    from dataclasses import asdict

    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(p).items()}
