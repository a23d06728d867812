"""How long `siva identify` takes end to end, side by side in one run (issue 6, must-show 4).

For LO-NO as measured (train 530 N, validate 37 N + 899 N) and the paper's Duffing
(train v5, validate v3 + v8): SIVA with the default output-error phase, the paper's
equation-error preset (``fit_target="equation"``, same networks and settings otherwise),
and pysindy on the same processed states; each timed in this process after a warm-up of
the simulation kernel.  Prints seconds, the ratios, and the largest relative error of
Approach II and of ``best``.  Target: <= 60 s for each SIVA default run on this 2-core
machine (with the machine otherwise idle: every other load stretches these times).

    .venv/bin/python benchmarks/bench_identify_time.py
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import data_dir  # noqa: E402

from siva_core import Recording, Siva, Structure, choose_processing, sindy, warmup  # noqa: E402

TIME_LIMIT_S = 60.0


def _case(name: str) -> tuple[Structure, list[Recording], list[Recording], np.ndarray]:
    d = data_dir()
    if name == "lono":
        st = Structure.from_file(ROOT / "examples" / "models" / "lono.toml")
        files = ("impact_530N.csv", ("impact_37N.csv", "impact_899N.csv"))
        truth = json.loads((d / "lono" / "truth.json").read_text())["truth"]
        base = d / "lono"
    else:
        st = Structure.from_file(ROOT / "examples" / "models" / "duffing.toml")
        files = ("train_v5.csv", ("val_v3.csv", "val_v8.csv"))
        truth = json.loads((d / "duffing" / "truth.json").read_text())
        truth = truth.get("truth", truth)
        base = d / "duffing"
    read = lambda f: Recording.read((base / f).read_bytes(), st.dofs, name=f, fmt="csv")
    return st, [read(files[0])], [read(f) for f in files[1]], st.vector(truth)


def main() -> int:
    rows = []
    worst = 0
    for name in ("lono", "duffing"):
        st, train, val, truth = _case(name)
        warmup(st)
        times: dict[str, float] = {}
        errs: dict[str, float] = {}
        for target in ("output", "equation"):
            t0 = time.perf_counter()
            est = Siva(st, baselines=False, progress=None, fit_target=target).fit(train, val)
            times[target] = time.perf_counter() - t0
            r = est.result_
            ii = np.array([r.approach_II[p]["mean"] for p in st.free])
            errs[f"{target} II"] = float(np.max(np.abs(ii / truth - 1)))
            errs[f"{target} best"] = float(np.max(np.abs(r.best / truth - 1)))
        t0 = time.perf_counter()
        proc = choose_processing("auto", train + val, st.dofs)
        states = [proc.apply(rec, st.dofs) for rec in train]
        sindy(st, states)
        times["pysindy"] = time.perf_counter() - t0
        rows.append((name, times, errs))
        worst = max(worst, times["output"])
    print(f"{'case':>8} | {'SIVA (output)':>13} {'SIVA (equation)':>15} {'pysindy':>8} | "
          f"{'x equation':>10} {'x pysindy':>9} | max |err| II out / eq, best")
    for name, t, e in rows:
        print(f"{name:>8} | {t['output']:12.1f}s {t['equation']:14.1f}s {t['pysindy']:7.2f}s | "
              f"{t['output'] / t['equation']:10.2f} {t['output'] / t['pysindy']:9.0f} | "
              f"{100 * e['output II']:.2f} % / {100 * e['equation II']:.1f} %, "
              f"{100 * e['output best']:.2f} %")
    ok = worst <= TIME_LIMIT_S
    print(f"{'PASS' if ok else 'FAIL'}: slowest SIVA default run {worst:.1f} s (limit {TIME_LIMIT_S:.0f} s)")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
