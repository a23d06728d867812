"""How exact a replay is: ``identical``, ``reproduced`` within a tolerance, or ``differs``.

Why a verdict and not just "identical": bit-identity of training holds only on the platform
that logged it (service/fingerprint.py); elsewhere rounding differs and training amplifies
it.  So the replay compares its estimate with the last logged snapshot, says which verdict
the platform calls for (``platform.expected``) and which one it got, with the measured
difference in units of the published std and, when it differs, where (docs/logs.md,
"Exactness", justifies the default tolerance).
"""
from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

from ..storage.eventlog import SnapshotEvent
from ..storage.eventlog.fingerprint import fingerprint_differences, platform_fingerprint

#: a replay on another platform "reproduces" the log when every parameter mean is within
#: this many of its published std of the logged one (docs/logs.md justifies the value)
REPRODUCED_TOLERANCE_IN_STD = 0.1


def platform_comparison(platforms: Sequence[Mapping[str, str] | None]) -> dict[str, Any]:
    """The current fingerprint against those of the replayed files (all must match for a
    bit-identical replay: a resumed run carries the earlier file's arithmetic)."""
    current = platform_fingerprint()
    diffs: dict[str, list[Any]] = {}
    for fp in platforms:
        for k, v in fingerprint_differences(fp, current).items():
            diffs.setdefault(k, v)
    return {"matches": not diffs, "differences": diffs, "current": current,
            "logged": platforms[-1] if platforms else None}


def compare_to_log(out: dict[str, Any], snap: SnapshotEvent | None,
                   platform: dict[str, Any], tolerance: float) -> dict[str, Any] | None:
    """The replay against the last logged snapshot: bits, the worst difference in std,
    and the verdict (``identical``: the same bits; ``reproduced``: every mean within
    ``tolerance`` of its published std; ``differs``: ``where`` lists what is off)."""
    if snap is None:
        return None
    est = snap.estimate_dict()
    logged = est.get("ensemble") or est.get("parameters") or {}
    worst = 0.0
    identical = snap.epoch == out["epoch"]
    where: list[dict[str, Any]] = []
    if snap.epoch != out["epoch"]:
        where.append({"epoch": {"replayed": out["epoch"], "logged": snap.epoch}})
    for p, s in (out.get("ensemble") or out["parameters"]).items():
        ref = logged.get(p)
        if not ref or ref.get("mean") is None or s.get("mean") is None:
            identical = False
            where.append({"parameter": p, "problem": "not in both the replay and the log"})
            continue
        d = abs(float(s["mean"]) - float(ref["mean"]))
        identical &= d == 0.0 and s.get("std") == ref.get("std")
        std = max(float(ref.get("std") or 0.0), 1e-300)
        rel = d / std if d else 0.0
        worst = max(worst, rel)
        if not rel <= tolerance:
            where.append({"parameter": p, "replayed": float(s["mean"]),
                          "logged": float(ref["mean"]), "logged_std": ref.get("std"),
                          "diff_in_std": rel if math.isfinite(rel) else None})
    verdict = "identical" if identical else "differs" if where else "reproduced"
    expected = "identical" if platform["matches"] else "reproduced"
    out_cmp: dict[str, Any] = {
        "epoch": snap.epoch, "identical": bool(identical),
        "max_diff_in_std": worst if math.isfinite(worst) else None,
        "verdict": verdict, "tolerance_in_std": tolerance,
        "platform": {"matches": platform["matches"], "expected": expected,
                     "differences": platform["differences"],
                     "logged": platform["logged"], "current": platform["current"]}}
    if where:
        out_cmp["where"] = where
    if verdict != "identical" and platform["matches"]:
        out_cmp["note"] = ("the platform matches the log's, so bit-identity was expected: "
                           "the training code changed since the log was written, or it is "
                           "not deterministic")
    return out_cmp


def summary_line(result: dict[str, Any]) -> str:
    """One line for stderr: the verdict, the measured difference, why."""
    cmp = (result.get("replay") or {}).get("compared_to_log")
    if not cmp:
        return "replay: no logged snapshot to compare with"
    plat = cmp["platform"]
    why = ("platform matches the log's" if plat["matches"] else
           "platform differs from the log's in " + ", ".join(
               f"{k} ({a} -> {b})" for k, (a, b) in plat["differences"].items()))
    diff = cmp["max_diff_in_std"]
    diff_s = "n/a" if diff is None else f"{diff:.3g}"
    return (f"replay: {cmp['verdict']} at epoch {cmp['epoch']}: max difference {diff_s} std "
            f"(tolerance {cmp['tolerance_in_std']:g} std); {why}")
