"""Do SIVA's 95 % intervals cover the truth 95 % of the time?  (issues 6 and 20)

For each structure in ``cases.py`` -- by default the issue-20 set ``COVERAGE_SET``: the
force on an end mass and on an inner mass, sampling 6x to 100x the highest mode, hammer
pulses of 3 to 20 samples, acceleration- and displacement-only sensors, 1 to 4 DOFs, every
record driven by the exact continuous pulse and then sampled (as a real test) --
``--runs`` independent noise realisations (seeded): one training and one held-out impact
record of random amplitude each, ``Siva.fit`` end to end, then per parameter whether the
Approach II interval (normal fit to the output-error ensemble) and the ``best`` interval
(bootstrap) contain the truth.  Prints per structure and parameter the coverage with its
binomial 95 % (Wilson) interval, the mean |relative error|, the bias in standard errors:
mean(estimate - truth) / RMS(reported standard error) and, run by run, the mean of
(estimate - truth) / se ("mean z"; both must stay within +-1), and the CPU and wall seconds
per fit; writes ``benchmarks/results/coverage.json`` (runs and summary).

Resumable: every finished fit is saved at once to ``<out>.<case>.partial.json``; a rerun
with the same ``--seed``/``--force-interp`` skips the seeds already there, so a killed
benchmark continues where it stopped (``--fresh`` starts over).

    .venv/bin/python benchmarks/bench_coverage.py [--runs 20] [--cases chain3_end_1k,...]
        [--seed 100] [--force-interp moments|linear] [--out results/coverage.json]

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

Z95 = 1.959964
KEYS = ("approach_II", "best")


def one_run(case, seed: int) -> dict:
    """One seeded impact test of ``case`` (a training and a held-out record), fitted end to
    end; per parameter and approach: relative error, relative standard error, covered."""
    st = case.structure()
    names = st.free
    truth = case.theta()
    rng = np.random.default_rng(seed)
    train = case.records(1, rng, prefix=f"train{seed}_")
    val = case.records(1, rng, prefix=f"val{seed}_")
    t0, c0 = time.perf_counter(), time.process_time()
    est = Siva(st, baselines=False, progress=None, seed=seed).fit(train, val)
    res = est.result_
    out = res.to_json()["parameters"]
    row = {"seed": seed, "time_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0}
    for key, ci_key in (("approach_II", None), ("best", "best_ci95")):
        mean = np.array([out[p][key]["mean"] if ci_key is None else out[p][key] for p in names])
        ci = np.array([out[p][key]["ci95"] if ci_key is None else out[p].get(ci_key, [np.nan] * 2)
                       for p in names], dtype=float)
        row[key] = {"rel_err": (mean / truth - 1).tolist(),
                    "rel_se": ((ci[:, 1] - ci[:, 0]) / (2 * Z95) / np.abs(truth)).tolist(),
                    "covered": ((ci[:, 0] <= truth) & (truth <= ci[:, 1])).tolist()}
    vt = res.metrics.get("validation_test", {}).get("best", {})
    row["validation_statistic"] = vt.get("statistic")
    return row


def load_partial(path: Path, case_name: str, interp: str) -> list[dict]:
    """The runs a previous (possibly killed) invocation saved for this case and reading."""
    if not path.exists():
        return []
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError:
        return []
    if data.get("case") != case_name or data.get("force_interp", "default") != interp:
        return []
    return list(data.get("runs", []))


def run_case(case, runs: int, seed0: int, progress: bool = True,
             partial: Path | None = None, interp: str = "default") -> dict:
    """``runs`` seeded fits of ``case`` (seeds ``seed0 .. seed0 + runs - 1``); after each,
    the runs so far go to ``partial``, and seeds already there are not fitted again."""
    names = case.structure().free
    seeds = list(range(seed0, seed0 + runs))
    done = {r["seed"]: r for r in (load_partial(partial, case.name, interp) if partial else [])}
    if progress and done:
        print(f"  {case.name}: resuming, {sum(s in done for s in seeds)}/{runs} runs on file",
              flush=True)
    t_case, n_new = time.perf_counter(), 0
    for seed in seeds:
        if seed in done:
            continue
        done[seed] = one_run(case, seed)
        n_new += 1
        if partial is not None:
            partial.parent.mkdir(parents=True, exist_ok=True)
            partial.write_text(json.dumps({"case": case.name, "names": names,
                                           "force_interp": interp,
                                           "runs": [done[s] for s in sorted(done)]}, indent=1))
        if progress:
            rows = [done[s] for s in seeds if s in done]
            left = sum(s not in done for s in seeds)
            eta = (time.perf_counter() - t_case) / n_new * left
            cov = np.mean([r["approach_II"]["covered"] for r in rows], axis=0)
            r = done[seed]
            print(f"  {case.name} seed {seed}: {len(rows)}/{runs} ({r['cpu_s']:.0f} CPU s, "
                  f"{r['time_s']:.0f} s wall, ETA {eta / 60:.0f} min): "
                  f"II coverage so far {np.round(cov, 2).tolist()}", flush=True)
    return {"case": case.name, "names": names, "force_interp": interp,
            "runs": [done[s] for s in seeds]}


def wilson(k: int, n: int, z: float = Z95) -> tuple[float, float]:
    """Binomial 95 % interval of a rate k/n (Wilson score): what 20 runs can tell."""
    if n == 0:
        return (float("nan"), float("nan"))
    p = k / n
    den = 1 + z * z / n
    mid = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return (max(0.0, mid - half), min(1.0, mid + half))


def summary(result: dict) -> dict:
    """Per parameter and approach: coverage (with its binomial interval), mean |error|,
    mean bias in standard errors; and the seconds per fit."""
    names, rows = result["names"], result["runs"]
    R = len(rows)
    out: dict = {"runs": R, "seeds": [r["seed"] for r in rows],
                 "cpu_s_mean": float(np.mean([r.get("cpu_s", np.nan) for r in rows])) if R else None,
                 "wall_s_mean": float(np.mean([r["time_s"] for r in rows])) if R else None,
                 "parameters": {}}
    for k, p in enumerate(names):
        entry = {}
        for key in KEYS:
            cov = [bool(r[key]["covered"][k]) for r in rows]
            err = np.array([r[key]["rel_err"][k] for r in rows], dtype=float)
            se = np.array([r[key]["rel_se"][k] for r in rows], dtype=float)
            lo, hi = wilson(sum(cov), R)
            entry[key] = {"coverage": sum(cov) / R if R else None, "coverage_ci95": [lo, hi],
                          "mean_abs_rel_err": float(np.mean(np.abs(err))) if R else None,
                          "mean_rel_err": float(np.mean(err)) if R else None,
                          "bias_se": float(np.mean(err) / np.sqrt(np.nanmean(se ** 2)))
                          if R else None,
                          # the same question run by run: mean of error / that run's se
                          # (differs from bias_se when the se varies from run to run)
                          "mean_z": float(np.mean(err / se)) if R else None}
        out["parameters"][p] = entry
    return out


def table(result: dict) -> str:
    s = summary(result)
    R = s["runs"]
    lines = [f"\n{result['case']}: {R} runs (seeds {s['seeds'][0]}-{s['seeds'][-1]}); "
             f"coverage of the nominal 95 % interval [binomial 95 % interval]",
             f"{'parameter':>10} | {'II cover':>15} {'II |err|':>9} {'II bias/se':>10} "
             f"{'II mean z':>9} | {'best cover':>15} {'best |err|':>10} {'best bias/se':>12} "
             f"{'best mean z':>11}"]
    flags = []
    for p, e in s["parameters"].items():
        cells = []
        for key in KEYS:
            v = e[key]
            lo, hi = v["coverage_ci95"]
            cells.append(f"{100 * v['coverage']:4.0f}% [{100 * lo:3.0f}-{100 * hi:3.0f}]")
            cells.append(f"{100 * v['mean_abs_rel_err']:8.3f}%")
            cells.append(f"{v['bias_se']:+10.2f}")
            cells.append(f"{v['mean_z']:+9.2f}")
            if not 0.85 <= v["coverage"] <= 0.99 and v["coverage"] != 1.0:
                flags.append(f"{p} {key} coverage {100 * v['coverage']:.0f} %")
            if abs(v["bias_se"]) > 1 or abs(v["mean_z"]) > 1:
                flags.append(f"{p} {key} bias {v['bias_se']:+.2f} se (mean z {v['mean_z']:+.2f})")
        lines.append(f"{p:>10} | {cells[0]:>15} {cells[1]:>9} {cells[2]} {cells[3]} | "
                     f"{cells[4]:>15} {cells[5]:>10} {cells[6]:>12} {cells[7]:>11}")
    lines.append(f"per fit: {s['cpu_s_mean']:.1f} CPU s, {s['wall_s_mean']:.1f} s wall"
                 + (f"; outside 85-99 % or |bias| > 1 se: {'; '.join(flags)}" if flags
                    else "; every parameter within 85-100 % and |bias| <= 1 se"))
    return "\n".join(lines)


def markdown(results: list[dict]) -> str:
    """One markdown table for all structures (docs/perf.md): coverage [binomial 95 %] and
    mean bias in standard errors per parameter, for Approach II and ``best``."""
    lines = ["| structure | runs | CPU s / fit | parameter | II covers | II bias/se (mean z) | "
             "`best` covers | `best` bias/se (mean z) |", "|---|---|---|---|---|---|---|---|"]
    for res in results:
        s = summary(res)
        first = True
        for p, e in s["parameters"].items():
            cells = []
            for key in KEYS:
                v = e[key]
                lo, hi = v["coverage_ci95"]
                out = not 0.85 <= v["coverage"] <= 1.0
                cov = f"{100 * v['coverage']:.0f} % [{100 * lo:.0f}-{100 * hi:.0f}]"
                bias = f"{v['bias_se']:+.2f} ({v['mean_z']:+.2f})"
                cells += [f"**{cov}**" if out else cov,
                          f"**{bias}**" if max(abs(v["bias_se"]), abs(v["mean_z"])) > 1
                          else bias]
            head = (f"{res['case']} | {s['runs']} | {s['cpu_s_mean']:.0f}" if first
                    else " | | ")
            lines.append(f"| {head} | {p} | " + " | ".join(cells) + " |")
            first = False
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--cases", default=",".join(COVERAGE_SET))
    ap.add_argument("--seed", type=int, default=100)
    ap.add_argument("--force-interp", default=None, choices=("moments", "linear", "cubic"),
                    help="how output-error fits read a measured force between samples")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "coverage.json"))
    ap.add_argument("--fresh", action="store_true", help="ignore partial results on file")
    ap.add_argument("--table-only", action="store_true",
                    help="fit nothing: print the tables (and a markdown one) of the runs on file")
    args = ap.parse_args(argv)
    interp = args.force_interp or "default"
    if args.force_interp:
        from siva_core import set_measured_force_interp

        set_measured_force_interp(args.force_interp)
    names = args.cases.split(",")
    unknown = [n for n in names if n not in CASES]
    if unknown:
        ap.error(f"--cases: unknown structure(s) {unknown}; known: {sorted(CASES)}")
    out = Path(args.out)
    results = []
    if args.table_only:
        for name in names:
            partial = out.with_suffix(f".{name}.partial.json")
            done = load_partial(partial, name, interp)
            if done:
                results.append({"case": name, "names": CASES[name].structure().free,
                                "force_interp": interp, "runs": done})
                print(table(results[-1]))
        print("\n" + markdown(results))
        return 0
    for name in names:
        partial = out.with_suffix(f".{name}.partial.json")
        if args.fresh and partial.exists():
            partial.unlink()
        res = run_case(CASES[name], args.runs, args.seed, partial=partial, interp=interp)
        res["summary"] = summary(res)
        results.append(res)
        print(table(res), flush=True)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(results, indent=1))
    for res in results:
        print(table(res))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
