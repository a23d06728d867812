"""CPU seconds per diagnosis stage on scenario seeds (issue 16, docs/perf.md 8.4).

Wraps the driver's steps (nominal fit and band, noise floor, screening, magnitude scans,
candidate fits, judgements, polish, bootstrap, backward step, set search with its pair
fits, where/signatures) and charges each call's process CPU and wall time to its step;
the outermost wrapped call wins (a polish's refit counts as polish).  Run it with
``SIVA_DIAGNOSE_WORKERS=1`` for a clean split: with more workers the calls made inside the
pool's threads are not charged to a step (their CPU stays in the total), except inside
``choose_set``, which is charged as a whole.  ``--part FILE`` rewrites FILE after every
charged call (a profile of a case that does not finish).

Usage: ``OMP_NUM_THREADS=1 SIVA_DIAGNOSE_WORKERS=1 python benchmarks/profile_diagnose_stages.py
--seeds 13004 --json out.json [--part FILE] [--verbose]``
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import threading
import time
import warnings
from pathlib import Path
from typing import Any, Callable

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import scenarios  # noqa: E402
from bench_scenarios import parse_seeds  # noqa: E402

from siva_core._impl.diagnose import band, run, stage  # noqa: E402

STEPS = [(band, "fit_nominal", "nominal_fit"), (run, "fit_nominal", "nominal_fit"),
         (run, "fit_nominal_in_band", "band"), (run, "spectral_noise_floor", "noise_floor"),
         (stage, "screen", "screen"), (stage, "ee_screen", "screen"),
         (stage, "scan_candidate", "scans"), (stage, "scan_sensor", "scans"),
         (stage, "fit_candidate", "candidate_fits"), (stage, "fit_sensor", "candidate_fits"),
         (stage, "continue_fit", "candidate_fits"), (stage, "_judge", "judge"),
         (run, "validation_gap", "judge"), (run, "_polish", "polish"),
         (run, "bootstrap_intervals", "bootstrap"), (run, "without_first", "backward"),
         (run, "choose_set", "sets_pair_fits"), (run, "where_analysis", "where_signatures"),
         (run, "amplitude_signatures", "where_signatures")]


class Profile:
    def __init__(self, part: str | None) -> None:
        self.acc: dict[str, list[float]] = {}
        self.part, self.t0 = part, (0.0, 0.0)
        self._tl = threading.local()

    def wrap(self, mod: Any, name: str, label: str) -> None:
        f: Callable[..., Any] = getattr(mod, name)

        def g(*a: Any, **k: Any) -> Any:
            if getattr(self._tl, "inside", False) \
                    or threading.current_thread() is not threading.main_thread():
                return f(*a, **k)
            self._tl.inside = True
            c0, w0 = time.process_time(), time.perf_counter()
            try:
                return f(*a, **k)
            finally:
                self._tl.inside = False
                e = self.acc.setdefault(label, [0.0, 0.0, 0])
                e[0] += time.process_time() - c0
                e[1] += time.perf_counter() - w0
                e[2] += 1
                if self.part:
                    Path(self.part).write_text(json.dumps(self.snapshot()))
        setattr(mod, name, g)

    def snapshot(self) -> dict[str, Any]:
        return {"cpu_s": time.process_time() - self.t0[0],
                "wall_s": time.perf_counter() - self.t0[1],
                "steps": {k: {"cpu_s": round(v[0], 2), "wall_s": round(v[1], 2),
                              "calls": int(v[2])} for k, v in self.acc.items()}}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", required=True)
    ap.add_argument("--json", metavar="FILE")
    ap.add_argument("--part", metavar="FILE")
    ap.add_argument("--verbose", action="store_true")
    args = ap.parse_args()
    prof = Profile(args.part)
    for mod, name, label in STEPS:
        prof.wrap(mod, name, label)
    rows = []
    for seed in parse_seeds(args.seeds):
        sc = scenarios.draw(seed)
        print(scenarios.describe(sc), flush=True)
        prof.acc.clear()
        prof.t0 = (time.process_time(), time.perf_counter())
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            d = run.diagnose(sc.nominal, sc.train, sc.val, "auto",
                             progress=(lambda m: print("   ", m, flush=True))
                             if args.verbose else None)
        out = d.to_json()
        row = {"seed": seed, "describe": scenarios.describe(sc),
               "named": sorted(f"{v['kind']} {'-'.join(v['between'])}"
                               for v in out["verdicts"]),
               "reason": out["rule"].get("reason"), "load1": os.getloadavg()[0],
               **prof.snapshot()}
        rows.append(row)
        print(json.dumps({k: row[k] for k in ("seed", "named", "cpu_s", "wall_s")}), flush=True)
        print("   CPU s per step:", {k: v["cpu_s"] for k, v in row["steps"].items()}, flush=True)
        if args.json:
            Path(args.json).write_text(json.dumps(rows, indent=1, default=float) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
