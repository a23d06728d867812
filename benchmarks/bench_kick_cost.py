"""What the kick and the sampled-force acceleration cost ``siva identify`` (issue 20).

Runs ``bench_identify_time``'s cases (output-error SIVA only) twice each in one process,
alternating: as main (``set_pulse_reading(False, False)``) and as now (both on), and prints the CPU seconds
(``time.process_time``), their ratio and the largest relative error of Approach II and
``best`` where the truth is known.

    OMP_NUM_THREADS=1 nice -n 5 .venv/bin/python benchmarks/bench_kick_cost.py [--cases lono]
"""
from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_identify_time import _case  # noqa: E402

from siva_core import Siva, set_pulse_reading, warmup  # noqa: E402


def _fit(name: str, on: bool) -> tuple[float, str]:
    set_pulse_reading(kick=on, acc_at_force_samples=on)
    st, train, val, truth = _case(name)
    c0 = time.process_time()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = Siva(st, baselines=False, progress=None).fit(train, val).result_
    cpu = time.process_time() - c0
    if truth is None:
        return cpu, "(truth unknown)"
    ii = np.array([r.approach_II[p]["mean"] for p in st.free])
    return cpu, (f"II {100 * np.max(np.abs(ii / truth - 1)):.2f} %, best "
                 f"{100 * np.max(np.abs(r.best / truth - 1)):.2f} %")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default="lono,duffing,cantilever")
    a = ap.parse_args(argv)
    for name in a.cases.split(","):
        warmup(_case(name)[0])
        t_off, e_off = _fit(name, False)
        t_on, e_on = _fit(name, True)
        print(f"{name:>10}: main {t_off:6.1f} cpu s ({e_off}) | kick {t_on:6.1f} cpu s "
              f"({e_on}) | ratio {t_on / t_off:.3f}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
