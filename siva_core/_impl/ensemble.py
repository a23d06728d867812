"""Uncertainty from samples: the Approach II running ensemble, normal fits, ESS.

Per-epoch samples are autocorrelated (each epoch starts where the last ended), so the
number of samples overstates the information; the effective sample size (Geyer's initial
positive sequence) says how many independent draws they are worth.
"""
from __future__ import annotations

from collections import deque
from typing import Sequence

import numpy as np

Z95 = 1.959963984540054


def effective_sample_size(x: np.ndarray) -> float:
    """ESS of a 1-D chain, n / (1 + 2 sum rho_k), Geyer's initial positive sequence."""
    x = np.asarray(x, dtype=float)
    n = len(x)
    if n < 4 or np.ptp(x) == 0:
        return float(n)
    x = x - x.mean()
    f = np.fft.rfft(x, 2 * n)
    acf = np.fft.irfft(f * np.conj(f))[:n]
    acf /= acf[0]
    tau = 1.0
    for k in range(1, n - 1, 2):
        pair = acf[k] + acf[k + 1]
        if pair <= 0:
            break
        tau += 2 * pair
    return float(min(n, n / tau))


def normal_summary(samples: np.ndarray, names: Sequence[str], *, ess: bool = True,
                   floor_rel: float = 0.0) -> dict[str, dict]:
    """Normal fit per parameter: mean, std, 95 % interval mean +- 1.96 std, percentiles, ESS.
    ``floor_rel``: the std is at least this fraction of |mean| (a numerical-accuracy floor)."""
    samples = np.atleast_2d(np.asarray(samples, dtype=float))
    out: dict[str, dict] = {}
    for k, name in enumerate(names):
        col = samples[:, k]
        mean = float(col.mean())
        std = float(col.std(ddof=1)) if len(col) > 1 else 0.0
        std = max(std, floor_rel * abs(mean))
        lo, hi = np.percentile(col, [2.5, 97.5]) if len(col) else (mean, mean)
        out[name] = {"mean": mean, "std": std, "ci95": [mean - Z95 * std, mean + Z95 * std],
                     "percentile95": [float(lo), float(hi)], "n": int(len(col))}
        if ess:
            out[name]["ess"] = effective_sample_size(col)
    return out


def widened_to(summary: dict[str, dict], names: Sequence[str],
               std_floor: np.ndarray) -> dict[str, dict]:
    """``summary`` with each std at least ``std_floor`` (interval recomputed; the samples'
    own std kept as ``std_samples``).  Why: Approach II's per-epoch samples track the
    optimum under parametric-bootstrap replicates (measurement and force noise), which miss
    what the moving-block bootstrap of the same fit holds (misfit, non-stationary noise);
    ``best``'s interval is the wider of the two, and Approach II's may not be narrower
    (docs/method.md, "Uncertainty that holds")."""
    out = {k: dict(v) for k, v in summary.items()}
    for name, floor in zip(names, np.asarray(std_floor, dtype=float)):
        row = out[name]
        if not np.isfinite(floor) or floor <= row["std"]:
            continue
        row["std_samples"], row["std"] = row["std"], float(floor)
        row["ci95"] = [row["mean"] - Z95 * floor, row["mean"] + Z95 * floor]
    return out


class Ensemble:
    """Running Approach II ensemble: per-epoch parameter samples after convergence.

    Bounded by ``maxlen`` (the most recent epochs), so a service that trains forever keeps
    describing the current structure rather than its whole past.
    """

    def __init__(self, maxlen: int | None = None) -> None:
        self.maxlen = maxlen
        self._samples: deque[np.ndarray] = deque(maxlen=maxlen)
        self._epochs: deque[int] = deque(maxlen=maxlen)

    def add(self, theta: np.ndarray, epoch: int) -> None:
        self._samples.append(np.asarray(theta, dtype=float).copy())
        self._epochs.append(int(epoch))

    def reset(self) -> None:
        self._samples.clear()
        self._epochs.clear()

    def drop_nonfinite(self) -> None:
        """Forget samples with a NaN or inf (a diverged epoch must not enter Approach II)."""
        keep = [(t, e) for t, e in zip(self._samples, self._epochs) if np.all(np.isfinite(t))]
        self._samples = deque((t for t, _ in keep), maxlen=self.maxlen)
        self._epochs = deque((e for _, e in keep), maxlen=self.maxlen)

    def __len__(self) -> int:
        return len(self._samples)

    @property
    def samples(self) -> np.ndarray:
        return np.array(self._samples) if self._samples else np.empty((0, 0))

    @property
    def epochs(self) -> np.ndarray:
        return np.array(self._epochs, dtype=int)

    def summary(self, names: Sequence[str]) -> dict[str, dict]:
        if not self._samples:
            return {}
        return normal_summary(self.samples, names)

    def state_dict(self) -> dict:
        return {"maxlen": self.maxlen, "samples": self.samples.tolist(), "epochs": self.epochs.tolist()}

    def load_state_dict(self, d: dict) -> None:
        self.maxlen = d["maxlen"]
        self._samples = deque((np.asarray(s, dtype=float) for s in d["samples"]), maxlen=self.maxlen)
        self._epochs = deque(d["epochs"], maxlen=self.maxlen)
