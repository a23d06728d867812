"""Do the service's ensemble intervals cover the truth 95 % of the time?  (issue 18, must-show 2)

Each *stream* is one system of a ``SivaService`` -- the object behind the HTTP routes, with
its store, event log and trainer/refiner threads -- driven in-process (no HTTP: the routes
only call ``put_system``/``add_recording`` and read the snapshot, so the estimate is the one
``GET .../estimate`` returns).  Per seed: a fresh structure realisation of records from the
project's simulator (``cases.py``: new force amplitudes, measurement noise, hum phase and
force-sensor noise per seed), ``--train`` training and ``--val`` validation records
uploaded at once, the service seeded with the stream's seed; then the estimate is polled
until the running ensemble is **final** (``ensemble_state: final``, its ``ci95`` published)
and the headline is ``best``; the first final ensemble is read.  Per parameter: whether its
``ci95`` covers the truth, the error in its own standard errors, and seconds (wall and CPU
of this process) per stream.

Prints per parameter the coverage with its exact (Clopper-Pearson) binomial 95 % interval
and the mean bias in standard errors (mean of (mean - truth) / std); writes JSON to
``benchmarks/results/service_coverage_<case>.json`` (rows written as they come, so a stopped
run keeps what it measured).

    OMP_NUM_THREADS=1 python benchmarks/bench_service_coverage.py [--case lono|chain3_end_1k]
        [--streams 20] [--seed 7000] [--train 1] [--val 1] [--later 60 100]

``--later N ...``: also read each stream's ensemble once it holds >= N samples (or the
trainer idles): does waiting for more samples change the coverage?

Target (issue 18): 85-99 % per parameter over >= 20 streams.  With R = 20 a true 95 %
coverage lands in 85-99 % with probability ~0.6; read the intervals.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cases import CASES  # noqa: E402

Z95 = 1.959964


def stream_records(case: Any, seed: int, n_train: int, n_val: int) -> list[tuple[str, bytes]]:
    """(role, CSV bytes) of one stream: every record a new force amplitude and noise draw."""
    from service.demo import to_csv

    rng = np.random.default_rng(seed)
    out = []
    for role, n in (("train", n_train), ("validation", n_val)):
        for rec in case.records(n, rng, prefix=f"{role}{seed}_"):
            out.append((role, to_csv({"time": rec.time, **rec.channels})))
    return out


def _scored(est: dict[str, Any], key: str, names: list[str], truth: dict[str, float]
            ) -> dict[str, Any]:
    ps = est.get(key) or {}
    per: dict[str, Any] = {}
    for p in names:
        s = ps.get(p) or {}
        ci, mean, std = s.get("ci95"), s.get("mean"), s.get("std")
        per[p] = {"mean": mean, "std": std, "ci95": ci, "ess": s.get("ess"),
                  "covered": bool(ci and ci[0] <= truth[p] <= ci[1]),
                  "z": (None if mean is None or not std else (mean - truth[p]) / std)}
    return per


def run_stream(case: Any, seed: int, *, n_train: int = 1, n_val: int = 1,
               timeout_s: float = 900.0, poll_s: float = 0.5, later: tuple[int, ...] = (),
               settings_overrides: dict[str, Any] | None = None) -> dict[str, Any]:
    """One seeded stream through an in-process service; the first final ensemble (and,
    with ``later``, the ensemble again once it holds at least each of those samples)."""
    from service.systems import SivaService
    from service.settings import Settings

    st = case.structure()
    names = list(st.free)
    truth = dict(zip(names, case.theta().tolist()))
    records = stream_records(case, seed, n_train, n_val)
    with tempfile.TemporaryDirectory(prefix="siva-cov-") as tmp:
        settings = Settings(data_dir=Path(tmp), seed=seed, torch_threads=1,
                            **(settings_overrides or {}))
        svc = SivaService(settings)
        svc.start()
        try:
            svc.put_system("cov", st.spec)
            w0, c0 = time.perf_counter(), time.process_time()
            for i, (role, raw) in enumerate(records):
                svc.add_recording("cov", raw, role=role, fmt="csv", filename=f"{role}{i}.csv")
            est: dict[str, Any] = {}
            while time.perf_counter() - w0 < timeout_s:
                time.sleep(poll_s)
                w = svc.worker("cov")
                est = w.snapshot().to_json(svc.counts("cov"))
                if (est.get("ensemble_state") == "final" and est.get("estimate_source") == "best"):
                    break
            wall, cpu = time.perf_counter() - w0, time.process_time() - c0
            seen: dict[str, Any] = {}
            for n in sorted(later):
                while time.perf_counter() - w0 < timeout_s:
                    e2 = svc.worker("cov").snapshot().to_json(svc.counts("cov"))
                    if e2.get("ensemble_state") == "final" and (
                            (e2.get("ensemble_samples") or 0) >= n or e2.get("state") == "idle"):
                        seen[str(n)] = {"samples": e2.get("ensemble_samples"),
                                        "ensemble": _scored(e2, "ensemble", names, truth)}
                        break
                    time.sleep(poll_s)
        finally:
            svc.stop()
    final = est.get("ensemble_state") == "final"
    row: dict[str, Any] = {"seed": seed, "final": final, "wall_s": wall, "cpu_s": cpu,
                           "epoch": est.get("epoch"), "samples": est.get("ensemble_samples"),
                           "anchor_source": (est.get("anchor") or {}).get("source")}
    for key in ("ensemble", "parameters"):
        row[key] = _scored(est, key, names, truth)
    row["later"] = seen
    row["validation"] = {k: (est.get("validation") or {}).get(k) for k in ("verdict", "T")}
    return row


def binomial_ci(k: int, n: int) -> tuple[float, float]:
    """Clopper-Pearson 95 % interval of a proportion k/n."""
    from scipy.stats import beta

    if n == 0:
        return (0.0, 1.0)
    lo = 0.0 if k == 0 else float(beta.ppf(0.025, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(0.975, k + 1, n - k))
    return lo, hi


def summarise(rows: list[dict[str, Any]], names: list[str], key: str = "ensemble"
              ) -> dict[str, dict[str, Any]]:
    """Per parameter over the streams whose ensemble was final: coverage with its binomial
    interval, mean bias in standard errors, mean |relative error|.  A stream that never
    became final counts as not covering (a service that publishes no interval covers nothing)."""
    out = {}
    for p in names:
        cov = [bool(r[key][p]["covered"]) and r["final"] for r in rows]
        z = [r[key][p]["z"] for r in rows if r["final"] and r[key][p]["z"] is not None]
        k, n = sum(cov), len(cov)
        out[p] = {"coverage": k / n if n else float("nan"), "covered": k, "n": n,
                  "ci95": list(binomial_ci(k, n)),
                  "bias_se": float(np.mean(z)) if z else float("nan"),
                  "rms_z": float(np.sqrt(np.mean(np.square(z)))) if z else float("nan")}
    return out


def table(case: str, rows: list[dict[str, Any]], names: list[str]) -> str:
    n = len(rows)
    lines = [f"\n{case}: {n} streams (seeds {rows[0]['seed']}..{rows[-1]['seed']}), "
             f"{sum(r['final'] for r in rows)} final; coverage of the service's 95 % intervals",
             f"{'parameter':>10} | {'ensemble':>8} {'binomial 95 %':>15} {'bias/se':>8} {'rms z':>6}"
             f" | {'headline':>8} {'bias/se':>8}"]
    ens, head = summarise(rows, names), summarise(rows, names, "parameters")
    for p in names:
        e, h = ens[p], head[p]
        lines.append(f"{p:>10} | {100 * e['coverage']:7.0f}% [{100 * e['ci95'][0]:5.1f},"
                     f"{100 * e['ci95'][1]:5.1f}]% {e['bias_se']:+8.2f} {e['rms_z']:6.2f}"
                     f" | {100 * h['coverage']:7.0f}% {h['bias_se']:+8.2f}")
    for n in sorted({k for r in rows for k in r.get("later", {})}, key=int):
        sub = [{**r, "ensemble": r["later"][n]["ensemble"]} for r in rows if n in r.get("later", {})]
        later = summarise(sub, names)
        lines.append(f"ensemble with >= {n} samples ({len(sub)} streams): " + " ".join(
            f"{p} {100 * later[p]['coverage']:.0f}% (z rms {later[p]['rms_z']:.2f})" for p in names))
    lines.append(f"seconds per stream: wall {np.mean([r['wall_s'] for r in rows]):.1f} "
                 f"(max {np.max([r['wall_s'] for r in rows]):.1f}), CPU of this process "
                 f"{np.mean([r['cpu_s'] for r in rows]):.1f}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", default="lono", choices=sorted(CASES))
    ap.add_argument("--streams", type=int, default=20)
    ap.add_argument("--seed", type=int, default=7000, help="first seed; streams use seed..")
    ap.add_argument("--train", type=int, default=1)
    ap.add_argument("--val", type=int, default=1)
    ap.add_argument("--timeout", type=float, default=900.0, help="per stream, seconds")
    ap.add_argument("--later", type=int, nargs="*", default=[],
                    help="also read the ensemble once it holds this many samples (or idles)")
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    import logging

    logging.basicConfig(level=logging.WARNING)
    case = CASES[args.case]
    names = list(case.structure().free)
    out = Path(args.out or Path(__file__).parent / "results" / f"service_coverage_{args.case}.json")
    out.parent.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    for i in range(args.streams):
        seed = args.seed + i
        row = run_stream(case, seed, n_train=args.train, n_val=args.val, timeout_s=args.timeout,
                         later=tuple(args.later))
        rows.append(row)
        covered = [p for p in names if row["ensemble"][p]["covered"]]
        print(f"stream seed {seed}: final={row['final']} {row['wall_s']:.0f} s wall "
              f"{row['cpu_s']:.0f} s CPU, n={row['samples']}, ensemble covers "
              f"{len(covered)}/{len(names)}; z " + " ".join(
                  f"{p}={row['ensemble'][p]['z']:+.1f}" if row['ensemble'][p]['z'] is not None
                  else f"{p}=-" for p in names), flush=True)
        out.write_text(json.dumps({"case": args.case, "names": names, "truth": case.truth,
                                   "train": args.train, "val": args.val, "seeds_from": args.seed,
                                   "summary": summarise(rows, names), "rows": rows}, indent=1))
    print(table(args.case, rows, names))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
