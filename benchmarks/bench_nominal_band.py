"""CPU of `siva diagnose` with the poor nominal's widest-band refit and without, side by side.

Branch nomspeed (issue 16, must-show 3): a poor nominal fit (train cost above
``nominal_poor``, 0.1) is fitted again in the widest band only when it does not show that
its band holds the structure (``band.shows_its_modes``: it failed, above
``DiagnoseSettings.nominal_widest`` = 0.5, or lacks a mode per DOF, or has one cut), no
longer whenever it is poor.  Each case is diagnosed twice in
this one process -- ``before`` (``nominal_widest = nominal_poor``: the rule before the
branch) and ``after`` (the default) -- in alternating order (the first run of a case can
pay numba compiles the second loads from the cache), and the row reports both runs' CPU
seconds, their ratio, the nominal stage's wall, and whether the processing band, the
nominal parameters and the verdicts (kinds, places and coefficients) are identical.

Usage (one worker, as the project's CPU measurements)::

    SIVA_SHARED_DATA=../shared/data OMP_NUM_THREADS=1 SIVA_DIAGNOSE_WORKERS=1 \\
        python benchmarks/bench_nominal_band.py --cases lono:two:0,25903 --json out.json

A case is a confusion-matrix row (``matrix.py``: ``lono:two:0``) or a scenario seed
(``scenarios.draw``: ``25903``).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import matrix  # noqa: E402
import scenarios  # noqa: E402

from siva_core import DiagnoseSettings, diagnose  # noqa: E402


def load(case: str) -> tuple[Any, list, list]:
    """(nominal structure, train, val) of a matrix row or a scenario seed."""
    if ":" in case:
        mc = matrix.parse(case)
        return (mc.nominal(), *mc.records())
    sc = scenarios.draw(int(case))
    return sc.nominal, sc.train, sc.val


def one(case: str, settings: DiagnoseSettings) -> dict[str, Any]:
    structure, train, val = load(case)
    c0 = time.process_time()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        d = diagnose(structure, train, val, "auto", settings=settings)
    cpu = time.process_time() - c0
    out = d.to_json()
    return {"cpu_s": round(cpu, 2), "nominal_s": round(d.timing.get("nominal_fit", 0.0), 2),
            "band": [float(x) for x in (d.processing.bandpass or ())],
            "theta": [float(x) for x in d.theta_nominal],
            "verdicts": [(v["kind"], list(v["between"]), v["coefficients"])
                         for v in out["verdicts"]]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", required=True, help="comma-separated matrix rows or seeds")
    ap.add_argument("--json", metavar="FILE")
    args = ap.parse_args()
    base = DiagnoseSettings(budget_s=None)  # no time budget: the rules, not the load
    variants = {"before": dataclasses.replace(base, nominal_widest=base.nominal_poor),
                "after": base}
    rows = []
    for i, case in enumerate(c for c in args.cases.split(",") if c):
        order = ["before", "after"] if i % 2 == 0 else ["after", "before"]
        res = {name: one(case, variants[name]) for name in order}
        b, a = res["before"], res["after"]
        row = {"case": case, "order": order, "before": b, "after": a,
               "ratio": round(a["cpu_s"] / b["cpu_s"], 3) if b["cpu_s"] else None,
               "same_band": b["band"] == a["band"],
               "same_nominal": bool(np.array_equal(b["theta"], a["theta"])),
               "same_verdicts": b["verdicts"] == a["verdicts"]}
        rows.append(row)
        named = " + ".join(f"{k} {'-'.join(w)}" for k, w, _ in a["verdicts"]) or "nothing"
        print(f"{case:40s} before {b['cpu_s']:7.1f} CPU s (nominal {b['nominal_s']:5.1f} s)"
              f"  after {a['cpu_s']:7.1f} (nominal {a['nominal_s']:5.1f})  ratio "
              f"{row['ratio']}  band/nominal/verdicts same: {row['same_band']}/"
              f"{row['same_nominal']}/{row['same_verdicts']}  [{named}]", flush=True)
        if args.json:
            Path(args.json).write_text(json.dumps(rows, indent=1))
    tb, ta = sum(r["before"]["cpu_s"] for r in rows), sum(r["after"]["cpu_s"] for r in rows)
    print(f"total before {tb:.1f} CPU s, after {ta:.1f} (ratio {ta / tb:.3f}); "
          f"verdicts identical on {sum(r['same_verdicts'] for r in rows)} of {len(rows)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
