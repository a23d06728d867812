"""Where chain3_end_1k's c1 shift comes from (issue 20, docs/perf.md 6.7): small controlled
refits of the coverage benchmark's own training records.

For each seed, the training record ``bench_coverage.one_run`` draws (same amplitude, the
hit at the benchmark's sampling phase 0.4), made again under one change at a time, and
refined from the truth as ``best`` refines (force multiplier and kick fitted, Gauss-Newton
errors); printed per variant: mean error and its scatter over the seeds, per parameter.
A statistical bias keeps mean/scatter fixed as the noise scales; a deterministic one shows
noise-free and makes mean/scatter grow as the noise shrinks.

    OMP_NUM_THREADS=1 nice -n 5 python benchmarks/bench_chain_bias.py [--seeds 11150:11170]
        [--variant clean --variant x1 ...] [--old]

``--old``: the fits as before 6.7 (the hit's accelerations at the pulse samples scaled by
the force multiplier, ``set_sample_gain_profiling(False)``).
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cases import CASES  # noqa: E402

from siva_core import choose_processing, refine, set_sample_gain_profiling  # noqa: E402

CASE = "chain3_end_1k"


def training_record(seed: int, noise: float = 1.0, acc: bool = True, force: bool = True,
                    hum: bool = True, truth: dict[str, float] | None = None,
                    fs: float | None = None, gain: float = 1.0, stream: int = 0
                    ) -> tuple[Any, Any, dict]:
    """(case, the benchmark's training record of ``seed`` with its noise sources scaled by
    ``noise`` / switched off, truth) -- same amplitude and noise draws as the benchmark.
    ``stream`` > 0: the same recipe from ``default_rng([seed, stream])`` instead, an extra
    draw no benchmark seed makes."""
    base = CASES[CASE]
    rng = np.random.default_rng([seed, stream] if stream else seed)
    amp = float(rng.uniform(*base.amplitudes))
    kw: dict[str, Any] = dict(noise=base.noise * noise * acc,
                              force_noise=base.force_noise * noise * force,
                              hum=base.hum * noise * hum)
    if fs is not None:  # the same hit instant and pulse, sampled faster
        kw["fs"] = fs
    case = replace(base, **kw)
    th = dict(case.truth, **(truth or {}))
    rec = case.record(amp, rng, name=f"train{seed}_0", truth=th)
    if gain != 1.0:  # a force sensor reading `gain` x the true force
        key = f"force_{case.force_dof}"
        rec.channels[key] = rec.channels[key] * gain
    return case, rec, th


def refit(case: Any, rec: Any, truth: dict[str, float],
          chain: Callable[[Any], Any] | None = None) -> np.ndarray:
    """Relative errors (absolute for a zero truth) of ``refine`` from the truth."""
    st = case.structure()
    th = st.vector(truth)
    proc = choose_processing("auto", [rec], st.dofs)
    if chain is not None:
        proc = chain(proc)
    res = refine(st, th, [rec], proc, fit_force_scale=True, uncertainty="gauss-newton")
    return np.where(th == 0, res.theta, res.theta / np.where(th == 0, 1, th) - 1)


def _lowpass(hz: float) -> Callable[[Any], Any]:
    return lambda p: replace(p, bandpass=(p.bandpass[0], hz), decimate_to=None)


#: name -> (record keywords, chain change or None)
VARIANTS: dict[str, tuple[dict[str, Any], Callable[[Any], Any] | None]] = {
    "clean": (dict(noise=0.0), None),
    "x0.25": (dict(noise=0.25), None),
    "x1": (dict(noise=1.0), None),
    "x4": (dict(noise=4.0), None),
    "acc noise only": (dict(force=False, hum=False), None),
    "force noise only": (dict(acc=False, hum=False), None),
    "hum only": (dict(acc=False, force=False), None),
    "clean, knl /1000": (dict(noise=0.0, truth={"knl": 3.0e6}), None),
    "x1, knl /1000": (dict(noise=1.0, truth={"knl": 3.0e6}), None),
    "clean, 4096 Hz": (dict(noise=0.0, fs=4096.0), None),
    "x1, 4096 Hz": (dict(noise=1.0, fs=4096.0), None),
    "clean, low-pass 60 Hz": (dict(noise=0.0), _lowpass(60.0)),
    "clean, low-pass 95 Hz": (dict(noise=0.0), _lowpass(95.0)),
    "clean, low-pass 300 Hz": (dict(noise=0.0), _lowpass(300.0)),
    "x1, force gain 1.03": (dict(noise=1.0, gain=1.03), None),
}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="11150:11170", help="first:stop (development seeds)")
    ap.add_argument("--variant", action="append", choices=list(VARIANTS))
    ap.add_argument("--old", action="store_true", help="the multiplier at the pulse samples")
    a = ap.parse_args(argv)
    lo, hi = (int(x) for x in a.seeds.split(":"))
    previous = set_sample_gain_profiling(not a.old)
    names = CASES[CASE].structure().free
    try:
        for v in a.variant or list(VARIANTS):
            kw, chain = VARIANTS[v]
            E = 100 * np.array([refit(*training_record(s, **kw), chain=chain)
                                for s in range(lo, hi)])
            cells = "  ".join(f"{n} {m:+.3f}/{sd:.3f}" for n, m, sd
                              in zip(names, E.mean(0), E.std(0)))
            print(f"{'old' if a.old else 'new'} {v:22s} mean/sd % | {cells}", flush=True)
    finally:
        set_sample_gain_profiling(previous)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
