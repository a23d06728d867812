"""Bias of each processing step on an equation-error least-squares fit (LO-NO rig).

The paper's chain (band-pass 4-50 Hz, integrate with 3 Hz high-pass, decimate to 256 Hz,
start after the impact) is applied step by step to the exact accelerations of
``impact_<A>N_clean.csv`` and then in full to the noisy ``impact_<A>N.csv``; after each step
the LO-NO model (examples/models/lono.toml) is fitted by least squares
(:func:`siva_core.least_squares`) and the % error against truth.json is
printed.  Two fits per chain: every parameter free, and ``beta`` fixed at its true value
(the setting of the data README's figures: b2 -68 %, k2 +32 %, alpha -18 %).

Leave-one-out rows then switch single steps off/on from the paper's chain, and the last
rows show :meth:`Processing.auto` on the same data.

    .venv/bin/python benchmarks/bench_processing_bias.py [--amp 530] [--json out.json]
"""
from __future__ import annotations

import argparse
import copy
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from siva_core import Processing, Recording, Structure, least_squares  # noqa: E402
from _common import data_dir  # noqa: E402




def with_channels(rec: Recording, keep: tuple[str, ...], extra: dict[str, np.ndarray],
                  name: str) -> Recording:
    """A copy of ``rec`` with only the ``keep`` quantities, plus ``extra`` channels."""
    ch = {k: v.copy() for k, v in rec.channels.items() if k.split("_", 1)[0] in keep}
    ch.update(extra)
    return Recording(rec.time.copy(), ch, name)


def pct(fit: dict[str, float], truth: dict[str, float]) -> dict[str, float]:
    return {k: 100.0 * (fit[k] / truth[k] - 1.0) for k in truth if k in fit}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--amp", type=int, default=530, help="impact record: 37, 530 or 899 N")
    ap.add_argument("--json", type=Path, help="also write the table as JSON")
    args = ap.parse_args()
    warnings.simplefilter("ignore")

    data = data_dir() / "lono"
    model = Structure.from_file(ROOT / "examples" / "models" / "lono.toml")
    spec = copy.deepcopy(model.spec)
    truth = json.loads((data / "truth.json").read_text())["truth"]
    spec.setdefault("parameters", {})["beta"] = {"fixed": truth["beta"]}
    model_bfix = Structure.from_dict(spec)
    dofs = model.dofs

    clean = Recording.read(data / f"impact_{args.amp}N_clean.csv", dofs)
    noisy = Recording.read(data / f"impact_{args.amp}N.csv", dofs)
    force = {k: v for k, v in noisy.channels.items() if k.startswith("force_")}
    exact = with_channels(clean, ("disp", "vel", "acc"), force, "exact states")
    exact_acc = with_channels(clean, ("acc",), force, "exact acc + force")

    paper = Processing.paper()
    whole = dict(start="start")
    rows: list[tuple[str, str, Recording, Processing]] = [
        ("a", "exact states, whole record, force gated to its pulse", exact,
         Processing(gate_force=True)),
        ("a'", "exact states from the end of the impact (free response, F = 0)", exact,
         Processing(gate_force=True, start="impact")),
        ("b", "(a) + band-pass 4-50 Hz on acc (q, v exact)", exact,
         Processing(bandpass=(4.0, 50.0), gate_force=True)),
        ("c", "(b) + q, v by integration with 3 Hz high-pass", exact_acc,
         paper.with_(decimate_to=None, **whole)),
        ("d", "(c) + decimation to 256 Hz", exact_acc, paper.with_(**whole)),
        ("e", "(d) + start after impact = paper chain, exact acc", exact_acc, paper),
        ("f", "paper chain on noisy acc + force", noisy, paper),
        # leave-one-out from (e): which step carries the bias
        ("e-lp", "(e) without the 50 Hz low-pass (band 4 Hz-)", exact_acc,
         paper.with_(bandpass=(4.0, 0.8 * 1024))),
        ("e-bp", "(e) without the band-pass (only the 3 Hz high-pass)", exact_acc,
         paper.with_(bandpass=None)),
        ("e-hp1", "(e) with band-pass 1-50 Hz and high-pass 1 Hz", exact_acc,
         paper.with_(bandpass=(1.0, 50.0), highpass=1.0)),
        ("e-dec", "(e) without decimation", exact_acc, paper.with_(decimate_to=None)),
        ("e+cons", "(e) with consistent filtering (F, q, v, a: one filter)", exact_acc,
         paper.with_(consistent=True)),
        ("e+simp", "(e) with Simpson integration", exact_acc,
         paper.with_(integrator="simpson")),
    ]
    auto_noisy = Processing.auto(noisy, dofs)
    auto_clean = Processing.auto(exact_acc, dofs)
    rows += [
        ("g", f"auto on noisy: {auto_noisy.describe()}", noisy, auto_noisy),
        ("h", f"auto on exact acc: {auto_clean.describe()}", exact_acc, auto_clean),
    ]

    names = list(truth)
    out = []
    print(f"LO-NO impact {args.amp} N; equation-error least squares; % error vs truth.json")
    header = f"{'step':7s}" + "".join(f"{n:>9s}" for n in names) + "   | beta fixed:" + \
        "".join(f"{n:>9s}" for n in names if n != "beta") + f"{'s':>7s}"
    print(header)
    for tag, what, rec, proc in rows:
        t0 = time.perf_counter()
        states = proc.apply(rec, dofs)
        e_free = pct(least_squares(model, [states]), truth)
        e_fix = pct(least_squares(model_bfix, [states]), truth)
        dt = time.perf_counter() - t0
        line = f"{tag:7s}" + "".join(f"{e_free[n]:+9.1f}" for n in names) + "   |" + \
            " " * 11 + "".join(f"{e_fix[n]:+9.1f}" for n in names if n != "beta") + \
            f"{dt:7.2f}"
        print(line + f"   {what}")
        out.append({"step": tag, "what": what, "chain": proc.describe(),
                    "error_pct_all_free": e_free, "error_pct_beta_fixed": e_fix,
                    "samples": len(states), "seconds": dt})
    if args.json:
        args.json.write_text(json.dumps({"amp_N": args.amp, "rows": out}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
