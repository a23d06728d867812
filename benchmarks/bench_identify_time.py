"""How long `siva identify` takes end to end, side by side in one run (issues 6 and 20).

Cases: LO-NO as measured (train 530 N, validate 37 N + 899 N), the paper's Duffing (train
v5, validate v3 + v8) and the measured cantilever free decay (real, 1 kHz, 2.5 s windows
of ``Strain_0``: train from 12.2 s, validate from 14.7 s; model m x'' + c x' + k x +
k3 x^3 = 0, mass-normalised).  Each is run as SIVA with the default output-error phase,
as the paper's equation-error preset (``fit_target="equation"``, same networks and
settings otherwise) and as pysindy on the same processed states, each timed in this
process after a warm-up of the simulation kernel.  Prints each case's seconds, the
ratios to the equation-error preset and to pysindy, the largest relative error of
Approach II and ``best`` where the truth is known, and the 1-minute load average at the
start and the end of the run (every other load on this 2-core machine stretches these
times: the issue-20 targets -- Duffing <= 10 s, LO-NO <= 20 s, cantilever <= 8 s -- are
for an otherwise idle machine).  ``--diagnose`` adds the time of ``siva diagnose`` on
LO-NO as measured (the nominal model, 530 N train, 37 N + 899 N validation).

    .venv/bin/python benchmarks/bench_identify_time.py [--cases lono,duffing,cantilever]
        [--no-equation] [--diagnose]
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import data_dir  # noqa: E402

from siva_core import (Recording, Siva, Structure, choose_processing, diagnose,  # noqa: E402
                       sindy, warmup)

#: issue 20's targets on an idle machine (seconds)
TARGET_S = {"duffing": 10.0, "lono": 20.0, "cantilever": 8.0}


def _read_lvm(path: Path) -> dict[str, np.ndarray]:
    """Columns of a LabVIEW text file (header ends at the second ***End_of_Header***)."""
    lines = path.read_text(errors="replace").splitlines()
    ends = [i for i, ln in enumerate(lines) if ln.startswith("***End_of_Header***")]
    names = lines[ends[1] + 1].split("\t")
    rows = [ln.split("\t") for ln in lines[ends[1] + 2:] if ln.strip()]
    return {name: np.array([float(r[k]) if k < len(r) and r[k] else np.nan for r in rows])
            for k, name in enumerate(names[:9])}


def _case(name: str) -> tuple[Structure, list[Recording], list[Recording], np.ndarray | None]:
    d = data_dir()
    if name == "cantilever":
        cols = _read_lvm(d / "real" / "magnetomechanical_decay" / "decay_f_42p05_ampl_2p0_0.lvm")
        t, x = cols["X_Value"], cols["Strain_0"]
        ok = np.isfinite(t) & np.isfinite(x)
        t, x = t[ok], x[ok]
        x = (x - np.median(x[t > 25])) * 1e3  # strain -> milli-strain, offset from the tail
        fs = 1.0 / np.median(np.diff(t))

        def rec(t0: float, dur: float = 2.5) -> Recording:
            m = (t >= t0) & (t < t0 + dur)
            return Recording.from_columns({"time": np.arange(m.sum()) / fs, "disp_x": x[m]},
                                          ["x"], name=f"decay_{t0:g}s")

        st = Structure.from_dict({
            "name": "cantilever", "dofs": ["x"], "mass": {"x": 1.0},
            "elements": [{"kind": "damper", "between": ["x", "ground"], "params": {"c": "c"}},
                         {"kind": "spring", "between": ["x", "ground"], "params": {"k": "k"}},
                         {"kind": "cubic_spring", "between": ["x", "ground"],
                          "params": {"k3": "k3"}}]})
        return st, [rec(12.2)], [rec(14.7)], None
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


def _load() -> float:
    return os.getloadavg()[0]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default="lono,duffing,cantilever")
    ap.add_argument("--no-equation", action="store_true", help="skip the equation-error preset")
    ap.add_argument("--diagnose", action="store_true", help="also time siva diagnose on LO-NO")
    args = ap.parse_args(argv)
    load0 = _load()
    print(f"load average (1 min) at start: {load0:.2f} on {os.cpu_count()} CPUs", flush=True)
    rows = []
    for name in args.cases.split(","):
        st, train, val, truth = _case(name)
        warmup(st)
        times: dict[str, float] = {}
        errs: dict[str, float] = {}
        targets = ("output",) if args.no_equation else ("output", "equation")
        for target in targets:
            t0 = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                est = Siva(st, baselines=False, progress=None, fit_target=target).fit(train, val)
            times[target] = time.perf_counter() - t0
            r = est.result_
            if truth is not None:
                ii = np.array([r.approach_II[p]["mean"] for p in st.free])
                errs[f"{target} II"] = float(np.max(np.abs(ii / truth - 1)))
                errs[f"{target} best"] = float(np.max(np.abs(r.best / truth - 1)))
            print(f"  {name} {target}: {times[target]:.1f} s  (load {_load():.2f})", flush=True)
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            proc = choose_processing("auto", train + val, st.dofs)
            states = [proc.apply(rec, st.dofs) for rec in train]
            sindy(st, states)
        times["pysindy"] = time.perf_counter() - t0
        rows.append((name, times, errs))
    diag_s = None
    if args.diagnose:
        st, train, val, _ = _case("lono")
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            diagnose(st, train, val, "auto")
        diag_s = time.perf_counter() - t0
    load1 = _load()
    print(f"\n{'case':>10} | {'SIVA (output)':>13} {'SIVA (equation)':>15} {'pysindy':>8} | "
          f"{'x equation':>10} {'x pysindy':>9} | target | max |err| II / best")
    for name, t, e in rows:
        eq, t_out = t.get("equation"), t["output"]
        err = (f"{100 * e['output II']:.2f} % / {100 * e['output best']:.2f} %"
               if e else "(truth unknown)")
        print(f"{name:>10} | {t['output']:12.1f}s "
              f"{(f'{eq:14.1f}s' if eq else '             -')} {t['pysindy']:7.2f}s | "
              f"{(f'{t_out / eq:10.2f}' if eq else '         -')} "
              f"{t['output'] / t['pysindy']:9.0f} | {TARGET_S.get(name, float('nan')):5.0f}s | {err}")
    if diag_s is not None:
        print(f"{'diagnose':>10} | {diag_s:12.1f}s  (LO-NO as measured, nominal model)")
    print(f"load average (1 min): start {load0:.2f}, end {load1:.2f} on {os.cpu_count()} CPUs"
          + ("" if max(load0, load1) < 1.5 else
             "  -- the machine was not idle: the seconds above are stretched by that load"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
