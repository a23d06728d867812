"""Reading an estimate out of a trainer: the ensemble summary and the headline keys.

Shared by the live worker and ``siva replay`` so both read out the same way.
"""
from __future__ import annotations

import math
import time
from dataclasses import asdict, is_dataclass
from typing import Any, Mapping

import numpy as np

from siva_core import Structure


def jsonable(x: Any) -> Any:
    """Plain JSON types; NaN/inf become None (JSON has no NaN, and a 500 is not an option)."""
    if isinstance(x, Mapping):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, (np.floating, float)):
        x = float(x)
        return x if math.isfinite(x) else None
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    if is_dataclass(x) and not isinstance(x, type):
        return jsonable(asdict(x))
    return x


def estimate_parameters(structure: Structure, tr: Any) -> tuple[dict[str, Any], str | None]:
    """Parameters {mean, std, ci95, ess, n}: the Approach II ensemble once converged,
    before that the spread of the generator's output (Approach I sampling).  Shared by the
    live worker and ``siva replay`` so both read out the same way."""
    free = structure.free
    summary = tr.ensemble.summary(free) if len(tr.ensemble) >= 2 else {}
    if summary:
        return summary, "approach_II"
    if tr.epoch == 0 or not getattr(tr, "initialised", True):
        return {}, None
    from siva_core import normal_summary

    return normal_summary(tr.sample(256), free, ess=False), "generator"


def headline(structure: Structure, ensemble: Mapping[str, Any], ensemble_source: str | None,
             best: Mapping[str, Any] | None) -> dict[str, Any]:
    """The snapshot keys of the one headline estimate a user acts on.

    ``parameters`` ({p: {mean, std, ci95}}) is ``best`` - the per-record output-error
    estimate of the monitor, or before it the first refinement - once one exists, else the
    running ensemble; ``estimate_source`` says which ("best", "ensemble", "generator"),
    ``estimate`` when and from which records.  The ensemble stays under ``ensemble``.
    """
    out: dict[str, Any] = {"ensemble": dict(ensemble), "ensemble_source": ensemble_source}
    if best and best.get("parameters"):
        params = {p: {"mean": s.get("value"), "std": s.get("std"), "ci95": s.get("ci95"),
                      **({"n": s["n"]} if s.get("n") is not None else {})}
                  for p, s in best["parameters"].items()}
        out.update(parameters=params, estimate_source="best", estimate={
            "source": "best", "time": best.get("time"),
            "age_s": None if best.get("time") is None else max(0.0, time.time() - best["time"]),
            "records": best.get("records"), "method": best.get("method"),
            "note": None})
        return out
    source = {"approach_II": "ensemble", "generator": "generator"}.get(ensemble_source or "",
                                                                         ensemble_source)
    out.update(parameters=dict(ensemble), estimate_source=source, estimate={
        "source": source, "time": time.time(), "age_s": 0.0, "records": None,
        "method": "running Approach II ensemble" if source == "ensemble" else
                  "spread of the generator's output (not converged)" if source else None,
        "note": "no output-error estimate (best) yet: this is the running ensemble, biased on "
                "measured data; best follows once training has converged" if source else None})
    return out
