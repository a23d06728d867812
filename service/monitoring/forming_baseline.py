"""A change while the drift baseline is still forming: one mean shift, best split.

Why: the CUSUM (``detector.py``) needs a reference, and the first records form it; a
change during those records would become the reference and never be alarmed.  So each new
record tests, per quantity, one mean shift at the best split of the baseline records so
far, at least ``YOUNG_MIN_SEGMENT`` records on each side: precision-weighted means, each
record's scatter ``max(YOUNG_SE_FACTOR * se_i, min_rel_scatter * |median|)`` (its own fit
error's calibration is not known yet), inflated by the within-segment chi-square when the
records scatter more than that.  |z| >= ``YOUNG_Z`` raises a confirmed alarm (the records
after the split are its confirmation); the detector then restarts the baseline after the
change.  With fewer than two records before a change nothing can be judged.
"""
from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

#: |z| of a mean shift (best split) that raises an alarm
YOUNG_Z = 6.0
#: records needed on each side of the split
YOUNG_MIN_SEGMENT = 2
#: a record's own fit error counts this many times
YOUNG_SE_FACTOR = 2.0


def young_change(base: Mapping[str, Sequence[Sequence[float | None]]],
                 records: Sequence[Mapping[str, Any]], kinds: Mapping[str, str],
                 min_rel: float, first_id: int) -> tuple[int, list[dict[str, Any]]] | None:
    """(split position, alarms) when a quantity shifted inside the baseline, else None.
    ``base[q]``: [value, error] per baseline record, aligned with ``records``."""
    quantities = list(base)
    m = len(base[quantities[0]]) if quantities else 0
    if m < 2 * YOUNG_MIN_SEGMENT:
        return None
    best: tuple[float, str, int] | None = None
    stats: dict[str, dict[int, dict[str, float]]] = {}
    for q in quantities:
        stats[q] = split_tests(base[q], min_rel)
        for t, st in stats[q].items():
            if best is None or abs(st["z"]) > best[0]:
                best = (abs(st["z"]), q, t)
    if best is None or best[0] < YOUNG_Z:
        return None
    t = best[2]
    alarms: list[dict[str, Any]] = []
    for q in quantities:
        st = stats[q].get(t)
        if st is None or abs(st["z"]) < YOUNG_Z:
            continue
        alarms.append(_alarm(q, kinds.get(q, "parameter"), st, t, m, records,
                             first_id + len(alarms)))
    return t, alarms


def _alarm(q: str, kind: str, st: Mapping[str, float], t: int, m: int,
           records: Sequence[Mapping[str, Any]], alarm_id: int) -> dict[str, Any]:
    cp_rec, last = records[t], records[-1]
    direction = "increase" if st["z"] > 0 else "decrease"
    rel = st["change"] / abs(st["before"]) if st["before"] else None
    ci = [st["change"] - 1.96 * st["se"], st["change"] + 1.96 * st["se"]]
    alarm: dict[str, Any] = {
        "id": alarm_id, "parameter": q, "kind": kind, "state": "confirmed", "active": True,
        "direction": direction, "young": True,
        "raised_record": cp_rec.get("id"), "raised_index": cp_rec.get("index"),
        "raised_time": cp_rec.get("time"), "records_above": m - t,
        "confirmed_record": last.get("id"), "confirmed_index": last.get("index"),
        "confirmed_time": last.get("time"), "cleared_record": None,
        "threshold": YOUNG_Z, "z": st["z"], "reference": st["before"], "value": st["after"],
        "cusum": [0.0, 0.0], "change_rel": rel,
        "change_rel_ci95": None if rel is None else [x / abs(st["before"]) for x in ci],
        "change_point": {"index": t, "interval": [t, t], "record": cp_rec.get("id"),
                         "record_index": cp_rec.get("index"),
                         "interval_records": [cp_rec.get("index"), cp_rec.get("index")],
                         "change": st["change"], "change_ci95": ci,
                         "before_mean": st["before"], "after_mean": st["after"],
                         "n_before": t, "n_after": m - t}}
    what = f"{q} {direction}d"
    if rel is not None:
        lo, hi = sorted(abs(x) * 100 for x in alarm["change_rel_ci95"])
        what += f" by {abs(rel) * 100:.1f} % (95 % CI {lo:.1f}-{hi:.1f} %)"
    alarm["message"] = (f"{what} at record {cp_rec.get('index')}, while the baseline was "
                        f"still forming ({t} record(s) before, {m - t} after, "
                        f"z = {st['z']:.1f}); confirmed; the baseline restarts after the change")
    return alarm


def split_tests(pairs: Sequence[Sequence[float | None]],
                min_rel: float) -> dict[int, dict[str, float]]:
    """Mean-shift z at every split of baseline values; keys are the split positions in
    ``pairs`` (the first record after the change)."""
    ok = [i for i, (v, _) in enumerate(pairs) if v is not None]
    if len(ok) < 2 * YOUNG_MIN_SEGMENT:
        return {}
    x = np.array([pairs[i][0] for i in ok], dtype=float)
    e = np.array([pairs[i][1] if pairs[i][1] is not None else np.nan for i in ok], dtype=float)
    floor = min_rel * abs(float(np.median(x)))
    sc = np.where(np.isfinite(e) & (e > 0), YOUNG_SE_FACTOR * np.nan_to_num(e), 0.0)
    sc = np.maximum(sc, floor)
    if not np.all(sc > 0):
        return {}
    w = 1.0 / sc ** 2
    out: dict[int, dict[str, float]] = {}
    for t in range(YOUNG_MIN_SEGMENT, len(x) - YOUNG_MIN_SEGMENT + 1):
        wb, wa = w[:t], w[t:]
        mb = float(np.sum(wb * x[:t]) / np.sum(wb))
        ma = float(np.sum(wa * x[t:]) / np.sum(wa))
        chi = float(np.sum(wb * (x[:t] - mb) ** 2) + np.sum(wa * (x[t:] - ma) ** 2))
        phi = max(1.0, chi / max(1, len(x) - 2))
        se = math.sqrt(phi * (1.0 / np.sum(wb) + 1.0 / np.sum(wa)))
        out[ok[t]] = {"z": (ma - mb) / se, "change": ma - mb, "se": se, "before": mb,
                      "after": ma}
    return out
