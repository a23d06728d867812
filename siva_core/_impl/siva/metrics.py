"""How each estimate simulates the records (``fit_metrics``) and the baselines fitted next
to SIVA for comparison (``baseline_estimates``)."""
from __future__ import annotations

import time
from typing import Any, Callable, Sequence

import numpy as np

from ..processing import Processing, States
from ..recording import Recording
from ..structure import Structure


def fit_metrics(structure: Structure, ests: dict[str, np.ndarray], train: Sequence[Recording],
                val: Sequence[Recording], proc: Processing) -> dict[str, Any]:
    """Displacement MSE [mm^2] and output error of each estimate on the training and the
    validation records."""
    from ..refine import displacement_mse, output_error

    names = list(ests)
    thetas = np.stack([ests[n] for n in names])
    out: dict[str, Any] = {"units": {"disp_mse_mm2": "mm^2", "output_error": "normalised MSE"}}
    for split, recs in (("train", train), ("validation", val)):
        if not recs:
            continue
        mse = displacement_mse(structure, thetas, recs, proc)
        oe = output_error(structure, thetas, recs, proc)
        out[split] = {n: {"disp_mse_mm2": float(m * 1e6), "output_error": float(o)}
                      for n, m, o in zip(names, mse, oe)}
    return out


def baseline_estimates(structure: Structure, states: Sequence[States], timing: dict[str, float],
                       say: Callable[[str], None]) -> dict[str, dict[str, float]]:
    """Plain least squares and SINDy on the same processed states (for comparison; a
    baseline that fails is reported through ``say`` and left out).  Adds their times to
    ``timing``."""
    from .. import baselines as bl

    out: dict[str, dict[str, float]] = {}
    for name in ("least_squares", "sindy"):
        t0 = time.perf_counter()
        try:
            out[name] = getattr(bl, name)(structure, states)
        except Exception as exc:  # noqa: BLE001 - a failed baseline must not sink the run
            say(f"baseline {name} failed: {exc}")
            continue
        timing[f"baseline_{name}"] = time.perf_counter() - t0
    return out
