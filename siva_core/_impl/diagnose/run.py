"""The diagnosis driver: nominal fit, screening, candidate fits, where, verdict."""
from __future__ import annotations

import math
import time
from typing import Any, Sequence

import numpy as np

from ..effects import EFFECTS
from ..recording import Recording
from ..structure import Structure
from .fitting import fit_candidate
from .nominal import fit_nominal
from .outputs import Progress, _Outputs, _say
from .results import Diagnosis, _num
from .screening import _pick, ee_screen, screen
from .settings import DiagnoseSettings
from .verdict import decide
from .where import _explain, where_analysis


def diagnose(structure: Structure, train: Sequence[Recording], val: Sequence[Recording],
             processing: Any = "auto", *, settings: DiagnoseSettings | None = None,
             progress: Progress | None = None) -> Diagnosis:
    """Locate and explain the sim-to-real gap of ``structure`` (see the module doc)."""
    from ..siva import choose_processing

    settings = settings or DiagnoseSettings()
    if not train or not val:
        raise ValueError("diagnose needs at least one --train and one --val record")
    t_all = time.perf_counter()
    timing: dict[str, float] = {}
    proc = choose_processing(processing, [*train, *val], structure.dofs)
    _say(progress, f"processing: {proc.describe() if hasattr(proc, 'describe') else proc}")

    t0 = time.perf_counter()
    nominal_fit = fit_nominal(structure, train, proc, settings, progress)
    theta, train_cost, start = nominal_fit.theta, nominal_fit.train_cost, nominal_fit.start
    timing["nominal_fit"] = time.perf_counter() - t0
    val_prob = _Outputs(structure, val, proc, theta)
    res_before = val_prob.residuals(theta)[0]
    gap_before = float(res_before @ res_before)
    before_blocks = val_prob.blocks(res_before)
    _say(progress, f"nominal: train cost {train_cost:.4g}, validation gap {gap_before:.4g} "
                   f"({timing['nominal_fit']:.1f} s)")

    names = list(settings.effects) if settings.effects else list(EFFECTS)
    unknown = [n for n in names if n not in EFFECTS]
    if unknown:
        raise ValueError(f"unknown effect(s) {unknown} (known: {', '.join(EFFECTS)})")
    t0 = time.perf_counter()
    cands, nom = screen(structure, theta, train, proc, [EFFECTS[n] for n in names], progress)
    ee_screen(structure, nominal_fit, train, cands)
    strong = sorted(cands, key=lambda c: -c.ee_score)[:3]
    _say(progress, "equation-error screening: " + ", ".join(
        f"{c.label()} {c.ee_score:.3f}" for c in strong))
    timing["screening"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    chosen = _pick(cands, settings)
    for c in chosen:
        try:
            fit_candidate(c, structure, theta, train, proc, nom.amplitudes[c.loc.between],
                          settings, nom.force_scale)
        except Exception as exc:  # noqa: BLE001 - one failed candidate must not sink the run
            c.note = f"fit failed: {exc}"
            _say(progress, f"{c.label()}: fit failed ({exc})")
            continue
        outs = _Outputs(c.structure, val, proc, c.theta)
        r_after = outs.residuals(c.theta)[0]
        c.gap_before = gap_before
        c.gap_after = float(r_after @ r_after) if np.all(np.isfinite(r_after)) else math.inf
        c.closure = 1.0 - c.gap_after / gap_before if gap_before > 0 else 0.0
        after_blocks = outs.blocks(r_after) if np.all(np.isfinite(r_after)) else \
            np.full_like(before_blocks, np.inf)
        c.per_record = []
        for k, rec in enumerate(val):
            gb, ga = float(before_blocks[k].mean()), float(after_blocks[k].mean())
            c.per_record.append({"record": rec.name, "gap_before": gb,
                                 "gap_after": _num(ga),
                                 "closure": _num(1 - ga / gb) if gb > 0 else None})
        _say(progress, f"{c.label()}: closure {c.closure:.3f} (val gap {gap_before:.4g} -> "
                       f"{c.gap_after:.4g}; {c.fit_time_s:.1f} s) "
                       + ", ".join(f"{k}={v:.4g}" for k, v in c.coefficients.items()))
    timing["candidate_fits"] = time.perf_counter() - t0
    ranking = sorted([c for c in chosen if c.fitted],
                     key=lambda c: -c.closure if np.isfinite(c.closure) else math.inf)

    t0 = time.perf_counter()
    best = ranking[0] if ranking else None
    where, plots = where_analysis(structure, theta, [*train, *val],
                                  ["train"] * len(train) + ["val"] * len(val), proc, best)
    # noise floor: the spectral estimate, capped by the best fit achieved on the train
    # records (a residual that small is reachable, so the noise cannot be larger)
    psd_floor = where.pop("noise_floor")
    fits = [train_cost] + [c.train_cost for c in ranking if np.isfinite(c.train_cost)]
    where["noise_floor"] = float(min([psd_floor, *fits] if psd_floor is not None else fits))
    where["noise_floor_spectral"] = psd_floor
    verdict, rule = decide(ranking, gap_before, where["noise_floor"], settings)
    if verdict is None:
        where["explanation"] = _explain(where, None) + (
            f" No candidate is named: {rule['reason']}."
            + (f" Best tried: {best.label()} (closure {best.closure:.2f})." if best else ""))
    timing["where"] = time.perf_counter() - t0
    timing["total"] = time.perf_counter() - t_all
    nominal = {"parameters": structure.as_dict(theta), "train_cost": train_cost,
               "gap": gap_before, "start": start,
               "gap_per_record": {rec.name: float(before_blocks[k].mean())
                                  for k, rec in enumerate(val)}}
    return Diagnosis(verdict, ranking, cands, where, nominal, rule, proc, timing, structure,
                     theta, list(train), list(val), plots)
