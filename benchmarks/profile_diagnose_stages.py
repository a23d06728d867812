"""CPU seconds per diagnosis stage on scenario seeds (issue 16, docs/perf.md 8.4).

Runs the public ``siva_core.diagnose`` under ``cProfile`` with a process-CPU clock and
reports, per step (nominal fit and band, noise floor, screening, magnitude scans,
candidate fits, judgements, polish, bootstrap, backward step, set search with its pair
fits, where/signatures), the *inclusive* CPU of the diagnosis functions of that step,
found by name in the profile (steps can nest -- a polish refits -- so they need not sum
to the total).  cProfile sees the calling thread only: run it with
``SIVA_DIAGNOSE_WORKERS=1`` so every fit runs there.

Usage: ``OMP_NUM_THREADS=1 SIVA_DIAGNOSE_WORKERS=1 python benchmarks/profile_diagnose_stages.py
--seeds 13004 --json out.json [--verbose]``; ``--cases lono:two:0,...`` profiles
confusion-matrix rows (``matrix.py``, as ``bench_diagnose.py --cases``) instead of seeds
(``SIVA_SHARED_DATA`` as for that bench).  Each row also reports the set stage's parts
(``SET_PARTS``: pair fits, swaps, the nominal-identification check, ...), which the
``where`` entry of ``timing_s`` lumps together.
"""
from __future__ import annotations

import argparse
import cProfile
import json
import os
import pstats
import sys
import time
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import matrix  # noqa: E402
import scenarios  # noqa: E402
from bench_scenarios import parse_seeds  # noqa: E402

from siva_core import diagnose  # noqa: E402

#: the diagnosis' functions (by name, in siva_core's diagnose package) charged to each step
STEPS = {"fit_nominal": "nominal_fit", "fit_nominal_in_band": "band",
         "spectral_noise_floor": "noise_floor", "screen": "screen", "ee_screen": "screen",
         "scan_candidate": "scans", "scan_sensor": "scans", "fit_candidate": "candidate_fits",
         "fit_sensor": "candidate_fits", "continue_fit": "candidate_fits", "_judge": "judge",
         "validation_gap": "judge", "polish": "polish", "bootstrap_intervals": "bootstrap",
         "without_first": "backward", "choose_set": "sets_pair_fits",
         "where_analysis": "where_signatures", "amplitude_signatures": "where_signatures"}


#: the set stage's parts (all inside ``timing_s['where']``), by function name
SET_PARTS = {"fit_all": "pair_fits", "swap_members": "swaps", "grow_sets": "grow",
             "refit_from_lead": "lookalike_refits", "break_tie": "ties",
             "prefer_simpler": "nested", "check_named": "nominal_identification",
             "contributions": "contributions"}


def set_parts_cpu(prof: cProfile.Profile) -> dict[str, float]:
    """Inclusive CPU of each of ``SET_PARTS`` (0 when it did not run)."""
    out = {v: 0.0 for v in SET_PARTS.values()}
    for (file, _line, name), (_cc, _n, _tt, ct, _callers) in \
            pstats.Stats(prof).stats.items():  # type: ignore[attr-defined]
        if name in SET_PARTS and "diagnose" in Path(file).parts:
            out[SET_PARTS[name]] = round(out[SET_PARTS[name]] + ct, 2)
    return out


def step_cpu(prof: cProfile.Profile) -> dict[str, dict[str, float]]:
    """Inclusive CPU and calls per step, summed over the functions named in ``STEPS``
    (a function's recursive calls are counted once by pstats' cumulative time)."""
    out: dict[str, dict[str, float]] = {}
    for (file, _line, name), (_cc, calls, _tt, ct, _callers) in \
            pstats.Stats(prof).stats.items():  # type: ignore[attr-defined]
        if name in STEPS and "diagnose" in Path(file).parts:
            e = out.setdefault(STEPS[name], {"cpu_s": 0.0, "calls": 0})
            e["cpu_s"] = round(e["cpu_s"] + ct, 2)
            e["calls"] += calls
    return out


def compile_cpu(prof: cProfile.Profile) -> float:
    """Inclusive CPU of numba compiling kernels during the run (a new structure signature
    -- every candidate place of a fresh scenario -- compiles its RK4 kernel once, then it
    is cached on disk): a before/after comparison run second sees a warm cache, so this
    share is reported apart (``cpu_s_no_compile``)."""
    return round(sum(ct for (file, _line, name), (_cc, _n, _tt, ct, _callers)
                     in pstats.Stats(prof).stats.items()  # type: ignore[attr-defined]
                     if name == "_compile_for_args" and "numba" in Path(file).parts), 2)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="")
    ap.add_argument("--cases", default="",
                    help="comma-separated confusion-matrix rows (lono:two:0) instead of seeds")
    ap.add_argument("--json", metavar="FILE")
    ap.add_argument("--verbose", action="store_true")
    ap.add_argument("--pstats", metavar="PREFIX",
                    help="also dump each seed's profile to PREFIX<seed>.pstats")
    ap.add_argument("--force-reading", choices=scenarios.FORCE_READINGS, default="continuous",
                    help="as bench_scenarios.py's (linear: the batches reported before)")
    args = ap.parse_args()
    rows = []
    jobs: list[tuple[object, str, object, list, list]] = []
    for seed in parse_seeds(args.seeds) if args.seeds else []:
        sc = scenarios.draw(seed, args.force_reading)
        jobs.append((seed, scenarios.describe(sc), sc.nominal, sc.train, sc.val))
    for name in [n for n in args.cases.split(",") if n]:
        mc = matrix.parse(name)
        jobs.append((name, name, mc.nominal(), *mc.records()))
    for seed, text, nominal, train, val in jobs:
        print(text, flush=True)
        prof = cProfile.Profile(time.process_time)
        c0, w0 = time.process_time(), time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            prof.enable()
            d = diagnose(nominal, train, val, "auto",
                         progress=(lambda m: print("   ", m, flush=True))
                         if args.verbose else None)
            prof.disable()
        if args.pstats:
            prof.dump_stats(f"{args.pstats}{str(seed).replace(':', '_')}.pstats")
        out = d.to_json()
        row = {"seed": seed, "describe": text,
               "named": sorted(f"{v['kind']} {'-'.join(v['between'])}"
                               for v in out["verdicts"]),
               "reason": out["rule"].get("reason"), "load1": os.getloadavg()[0],
               "cpu_s": time.process_time() - c0, "wall_s": time.perf_counter() - w0,
               "steps": step_cpu(prof), "set_parts": set_parts_cpu(prof),
               "timing_s": out["timing_s"], "numba_compile_s": compile_cpu(prof)}
        row["cpu_s_no_compile"] = row["cpu_s"] - row["numba_compile_s"]
        rows.append(row)
        print(json.dumps({k: row[k] for k in ("seed", "named", "cpu_s", "numba_compile_s",
                                                   "cpu_s_no_compile", "wall_s")}), flush=True)
        print("   CPU s per step:", {k: v["cpu_s"] for k, v in row["steps"].items()}, flush=True)
        print("   CPU s of the set stage's parts:", row["set_parts"], flush=True)
        if args.json:
            Path(args.json).write_text(json.dumps(rows, indent=1, default=float) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
