"""Do SIVA's 95 % intervals cover the truth 95 % of the time?  (issues 6 and 20)

For each structure in ``cases.py`` -- by default the issue-20 set ``COVERAGE_SET``: the
force on an end mass and on an inner mass, sampling 6x to 100x the highest mode, hammer
pulses of 3 to 20 samples, acceleration- and displacement-only sensors, 1 to 4 DOFs, every
record driven by the exact continuous pulse and then sampled (as a real test) --
``--runs`` independent noise realisations (seeded): one training and one held-out impact
record of random amplitude each, ``Siva.fit`` end to end, then per parameter whether the
Approach II interval (normal fit to the output-error ensemble) and the ``best`` interval
(bootstrap) contain the truth.  Prints per parameter the coverage, the mean |relative
error|, and the bias in standard errors: mean(estimate - truth) / RMS(reported standard
error) (must stay within +-1), and writes ``benchmarks/results/coverage.json``.

    .venv/bin/python benchmarks/bench_coverage.py [--runs 20] [--cases chain3_end_1k,...]
        [--seed 100] [--force-interp moments|linear]

``--force-interp linear`` reads a measured force between samples as straight lines (the
former default) instead of with its own moments: the ablation of issue 20's chain bias.
With R runs, a true 95 % coverage lands in 85-99 % with probability ~0.6 (R=20),
~0.93 (R=50): read the table with its binomial uncertainty (printed).
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cases import CASES, COVERAGE_SET  # noqa: E402

from siva_core import Siva  # noqa: E402


def run_case(case, runs: int, seed0: int, progress: bool = True,
             partial: Path | None = None) -> dict:
    """``runs`` seeded fits of ``case``; after each, the runs so far go to ``partial``
    (so a long benchmark stopped early still leaves its results)."""
    st = case.structure()
    names = st.free
    truth = case.theta()
    rows = []
    t_case = time.perf_counter()
    for i in range(runs):
        rng = np.random.default_rng(seed0 + i)
        train = case.records(1, rng, prefix=f"train{i}_")
        val = case.records(1, rng, prefix=f"val{i}_")
        t0 = time.perf_counter()
        est = Siva(st, baselines=False, progress=None, seed=seed0 + i).fit(train, val)
        res = est.result_
        out = res.to_json()["parameters"]
        row = {"seed": seed0 + i, "time_s": time.perf_counter() - t0}
        for key, ci_key in (("approach_II", None), ("best", "best_ci95")):
            mean = np.array([out[p][key]["mean"] if ci_key is None else out[p][key] for p in names])
            ci = np.array([out[p][key]["ci95"] if ci_key is None else out[p].get(ci_key, [np.nan] * 2)
                           for p in names])
            row[key] = {"rel_err": (mean / truth - 1).tolist(),
                        "rel_se": ((ci[:, 1] - ci[:, 0]) / (2 * 1.959964) / np.abs(truth)
                                   ).tolist(),
                        "covered": ((ci[:, 0] <= truth) & (truth <= ci[:, 1])).tolist()}
        vt = res.metrics.get("validation_test", {}).get("best", {})
        row["validation_statistic"] = vt.get("statistic")
        rows.append(row)
        if partial is not None:
            partial.parent.mkdir(parents=True, exist_ok=True)
            partial.write_text(json.dumps({"case": case.name, "names": names, "runs": rows},
                                          indent=1))
        if progress:
            done = i + 1
            eta = (time.perf_counter() - t_case) / done * (runs - done)
            cov = np.mean([r["approach_II"]["covered"] for r in rows], axis=0)
            print(f"  {case.name} run {done}/{runs} ({row['time_s']:.0f} s, ETA {eta:.0f} s): "
                  f"II coverage so far {np.round(cov, 2).tolist()}", flush=True)
    return {"case": case.name, "names": names, "runs": rows}


def table(result: dict) -> str:
    names, rows = result["names"], result["runs"]
    R = len(rows)
    lines = [f"\n{result['case']}: {R} runs; coverage of the nominal 95 % interval "
             f"(binomial s.e. at 95 %: {100 * math.sqrt(0.95 * 0.05 / max(R, 1)):.1f} points)",
             f"{'parameter':>10} | {'II cover':>8} {'II |err| mean':>13} {'II bias/se':>10} | "
             f"{'best cover':>10} {'best |err| mean':>15} {'best bias/se':>12}"]

    def bias_se(key: str, k: int) -> float:
        err = np.array([r[key]["rel_err"][k] for r in rows])
        se = np.array([r[key].get("rel_se", [np.nan] * len(names))[k] for r in rows])
        return float(np.mean(err) / np.sqrt(np.nanmean(se ** 2)))

    for k, p in enumerate(names):
        c2 = np.mean([r["approach_II"]["covered"][k] for r in rows])
        e2 = np.mean([abs(r["approach_II"]["rel_err"][k]) for r in rows])
        cb = np.mean([r["best"]["covered"][k] for r in rows])
        eb = np.mean([abs(r["best"]["rel_err"][k]) for r in rows])
        b2, bb = bias_se("approach_II", k), bias_se("best", k)
        lines.append(f"{p:>10} | {100 * c2:7.0f}% {100 * e2:12.3f}% {b2:+10.2f} | "
                     f"{100 * cb:9.0f}% {100 * eb:14.3f}% {bb:+12.2f}")
    t = np.mean([r["time_s"] for r in rows])
    lines.append(f"mean time per fit: {t:.1f} s")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--cases", default=",".join(COVERAGE_SET))
    ap.add_argument("--seed", type=int, default=100)
    ap.add_argument("--force-interp", default=None, choices=("moments", "linear", "cubic"),
                    help="how output-error fits read a measured force between samples")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "coverage.json"))
    args = ap.parse_args(argv)
    if args.force_interp:
        from siva_core import set_measured_force_interp

        set_measured_force_interp(args.force_interp)
    results = []
    for name in args.cases.split(","):
        res = run_case(CASES[name], args.runs, args.seed,
                       partial=Path(args.out).with_suffix(f".{name}.partial.json"))
        res["force_interp"] = args.force_interp or "default"
        results.append(res)
        print(table(res), flush=True)
        out = Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(results, indent=1))
    for res in results:
        print(table(res))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
