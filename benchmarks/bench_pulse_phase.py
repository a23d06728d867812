"""Deterministic shift of the refined estimate with the hit's sub-sample instant (issue 20).

Noise-free records (no response, force or hum noise) of a coverage structure, hit with the
exact half-sine pulse starting ``phase`` samples after the sample at 0.1 s; refined from the truth with the
force multiplier fitted per record (as ``best``), once as before and once with the force's
sub-sample delay fitted too (``refine(..., fit_force_shift=True)``), its spread, or the
kick at the pulse (``--mode kick``: ``refine(..., fit_force_kick=True)``, docs/perf.md 6.5;
the other modes pin the kick off).  ``--no-sample-gain``: the hit's accelerations at the
pulse samples scaled by the multiplier, as before docs/perf.md 6.7.  With no noise, any error left is the model's reading
of the force between its samples (docs/perf.md 6.3).

    OMP_NUM_THREADS=1 nice -n 5 .venv/bin/python benchmarks/bench_pulse_phase.py \\
        [--case chain3_end_1k --case chain4_inner_disp] [--phase 0 --phase 0.5] [--amp A]
        [--mode kick] [--no-sample-gain]
"""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cases import CASES  # noqa: E402

from siva_core import choose_processing, refine, set_sample_gain_profiling  # noqa: E402

#: the amplitude of the 6.3 table per case (the low end of its range: weakest nonlinearity)
AMPLITUDE = {"chain3_end_1k": 50.0, "chain4_inner_disp": 125.0, "twodof_end_slow": 75.0,
             "chain3_exact": 50.0, "lono_exact": 500.0}


def run(case_name: str, phase: float, amplitude: float, mode: str) -> dict:
    base = CASES[case_name]
    case = replace(base, noise=0.0, force_noise=0.0, hum=0.0,
                   impact_at_s=(round(0.1 * base.fs) + phase) / base.fs)
    st = case.structure()
    rec = case.record(amplitude, np.random.default_rng(0), name=f"{case_name}_{phase}")
    proc = choose_processing("auto", [rec], st.dofs)
    c0 = time.process_time()
    res = refine(st, case.theta(), [rec], proc, fit_force_scale=True,
                 fit_force_shift="delay" in mode, fit_force_spread="spread" in mode,
                 fit_force_kick="kick" in mode,
                 uncertainty="gauss-newton")
    return {"names": list(st.free), "err": res.theta / case.theta() - 1,
            "scale": float(np.ravel(res.force_scale)[0]),
            "shift": None if res.force_shift is None else float(np.ravel(res.force_shift)[0]),
            "spread": None if res.force_spread is None else float(np.ravel(res.force_spread)[0]),
            "cpu_s": time.process_time() - c0}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", action="append")
    ap.add_argument("--phase", action="append", type=float)
    ap.add_argument("--amp", type=float)
    ap.add_argument("--mode", action="append", choices=["before", "delay", "spread",
                                                        "delay+spread", "kick"],
                    help="nuisances fitted besides the multiplier (default: all four)")
    ap.add_argument("--no-sample-gain", action="store_true",
                    help="the multiplier at the pulse samples, as before docs/perf.md 6.7")
    a = ap.parse_args(argv)
    set_sample_gain_profiling(not a.no_sample_gain)
    cases = a.case or ["chain3_end_1k", "chain4_inner_disp"]
    phases = a.phase or [0.0, 0.5]
    for name in cases:
        amp = a.amp or AMPLITUDE.get(name, float(np.mean(CASES[name].amplitudes)))
        for phase in phases:
            for mode in a.mode or ["before", "delay", "spread", "delay+spread"]:
                r = run(name, phase, amp, mode)
                errs = "  ".join(f"{n} {100 * e:+.2f}%" for n, e in zip(r["names"], r["err"]))
                sh = "" if r["shift"] is None else f" delay {r['shift']:+.3f} smp"
                sp = "" if r["spread"] is None else f" spread {r['spread']:+.3f} smp^2"
                print(f"{name} {amp:g} N phase {phase:.2f} {mode:12s} | {errs} | scale "
                      f"{r['scale']:.4f}{sh}{sp} | {r['cpu_s']:.1f} cpu s", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
