"""Monitoring benchmark: false alarms, detection delay, change-point error, the demo.

Streams LO-NO impact records made by the project's simulator (``service.demo.simulate_impact``:
half-sine hammer pulses of 30-900 N, 0.3 % accelerometer noise, 60 Hz hum, 0.2 % force
noise) through the service's own monitoring code (``service.monitoring.monitor.RecordMonitor``: one
output-error fit per record, the CUSUM detector, the headline) without a server, for speed.
The monitor is seeded as the service seeds it: one output-error refinement on the first
three records from a start 5 % off the truth (standing in for the first ``best``).

(a) no change: ``--seeds`` runs of ``--records`` records -> false alarms per 1000 records;
(b) k1 drops of 2, 5 and 15 % after ``--drop-at`` records -> detection delay (records
    after the drop until the first alarm on k1), what else alarmed, change-point error;
(c) the demo's scenario (15 % drop after 24 records): headline vs truth before and after.

    python benchmarks/bench_monitoring.py              # full (about 20 min on 2 cores)
    python benchmarks/bench_monitoring.py --quick      # reduced
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from service.demo import LONO_TRUTH, DemoConfig, lono_structure, simulate_impact, to_csv  # noqa: E402
from service.monitoring.monitor import RecordMonitor  # noqa: E402


def make_record(structure: Any, theta: dict[str, float], rng: np.random.Generator,
                cfg: DemoConfig, name: str) -> Any:
    from siva_core import Recording

    cols = simulate_impact(theta, float(rng.uniform(*cfg.amplitude_n)), rng, cfg, structure)
    return Recording.read(to_csv(cols), structure.dofs, name=name, fmt="csv")


def seeded_monitor(structure: Any, records: list[Any], rng: np.random.Generator) -> RecordMonitor:
    """The monitor after the first ``best``: a refinement on three records from 5 % off."""
    from siva_core import refine

    from service.storage.uploads import processing_for

    proc = processing_for(records, structure.dofs)
    truth = np.array([LONO_TRUTH[p] for p in structure.free])
    start = truth * (1 + 0.05 * rng.uniform(-1, 1, len(truth)))
    best = refine(structure, start, records, proc, fit_force_scale=True)
    mon = RecordMonitor(structure)
    mon.seed(best.theta, proc)
    return mon


def run_stream(seed: int, n_records: int, drop: float = 0.0, drop_at: int | None = None,
               parameter: str = "k1", cfg: DemoConfig | None = None) -> dict[str, Any]:
    """Stream ``n_records`` records; after ``drop_at`` of them ``parameter`` loses ``drop``."""
    cfg = cfg or DemoConfig()
    structure = lono_structure()
    rng = np.random.default_rng(seed)
    truth = dict(LONO_TRUTH)
    first = [make_record(structure, truth, rng, cfg, f"s{i}") for i in range(3)]
    mon = seeded_monitor(structure, first, rng)
    events: list[dict[str, Any]] = []
    headlines: list[dict[str, Any]] = []
    t_fit = 0.0
    for i in range(n_records):
        th = dict(truth)
        if drop and drop_at is not None and i >= drop_at:
            th[parameter] *= 1 - drop
        rec = make_record(structure, th, rng, cfg, f"r{i}")
        t0 = time.perf_counter()
        changes = mon.process(f"r{i}", i, rec)
        t_fit += time.perf_counter() - t0
        for a in changes:
            events.append({"record": i, "parameter": a.parameter, "state": a.state,
                           "change_point": a.change_point_index,
                           "change_rel": a.change_rel, "message": a.message})
        hl = mon.headline()
        if hl is not None:
            headlines.append({"record": i, "parameters": {p: dict(v) for p, v in
                                                          hl.parameters.items()}})
    return {"seed": seed, "n_records": n_records, "drop": drop, "drop_at": drop_at,
            "events": events, "headlines": headlines, "seconds_per_record": t_fit / n_records,
            "report": mon.report(limit=0)}


def raised(run: dict[str, Any]) -> list[dict[str, Any]]:
    return [e for e in run["events"] if e["state"] == "raised"]


def summarise_drop(run: dict[str, Any], parameter: str = "k1") -> dict[str, Any]:
    drop_at = run["drop_at"]
    before = [e for e in raised(run) if e["record"] < drop_at]
    after = [e for e in raised(run) if e["record"] >= drop_at]
    first = next((e for e in after if e["parameter"] == parameter), None)
    window = [e for e in after if first and e["record"] <= first["record"]
              + run.get("confirm", 3)]
    return {"seed": run["seed"], "drop": run["drop"],
            "false_before": len(before),
            "delay": None if first is None else first["record"] - drop_at + 1,
            "named": sorted({e["parameter"] for e in window}),
            "change_point_error": None if first is None or first["change_point"] is None
            else first["change_point"] - drop_at,
            "change_rel": None if first is None else first["change_rel"]}


def headline_error(run: dict[str, Any], at: int, truth: dict[str, float]) -> dict[str, Any]:
    hl = next(h for h in reversed(run["headlines"]) if h["record"] <= at)
    out = {}
    for p, s in hl["parameters"].items():
        ci = s.get("ci95")
        out[p] = {"rel_error": s["mean"] / truth[p] - 1,
                  "covers": None if not ci else bool(ci[0] <= truth[p] <= ci[1]),
                  "ci_half_rel": None if not ci else (ci[1] - ci[0]) / 2 / abs(truth[p])}
    return out


def static_server(minutes: float, seed: int = 7, timeout_s: float = 1200.0) -> dict[str, Any]:
    """(d) A real server (uvicorn, in this process) with three static LO-NO records: time to
    the first best and to idle, then alarms and CPU (this process) over ``minutes``."""
    import tempfile

    import psutil

    from clients.client import SivaClient
    from service.demo import LONO_SPEC, ServerThread
    from service.settings import Settings

    cfg = DemoConfig()
    structure = lono_structure()
    rng = np.random.default_rng(seed)
    out: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as d:
        settings = Settings(data_dir=Path(d), torch_threads=1)
        with ServerThread(settings) as url, SivaClient(url) as c:
            c.register("lono", LONO_SPEC)
            for i, role in enumerate(("train", "train", "validation")):
                cols = simulate_impact(LONO_TRUTH, float(rng.uniform(300, 900)), rng, cfg,
                                       structure)
                c.upload("lono", to_csv(cols), role=role)
            t0 = time.monotonic()
            est = c.wait("lono", "best", timeout=timeout_s)
            out["first_best_s"] = time.monotonic() - t0
            while est.get("state") != "idle" and time.monotonic() - t0 < timeout_s:
                time.sleep(2.0)
                est = c.estimate("lono")
            out["idle_after_s"] = time.monotonic() - t0
            out["state"] = est.get("state")
            proc = psutil.Process()
            t1, cpu1 = time.monotonic(), sum(proc.cpu_times()[:2])
            time.sleep(60.0 * minutes)
            out["cpu_fraction_of_a_core"] = ((sum(proc.cpu_times()[:2]) - cpu1)
                                             / (time.monotonic() - t1))
            drift = c.drift("lono")
            out["alarms"] = len(drift["alarm_history"])
            out["minutes"] = minutes
            est = c.estimate("lono")
            out["headline"] = {p: est["parameters"][p]["mean"] / LONO_TRUTH[p] - 1
                               for p in LONO_TRUTH}
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--seeds", type=int, default=None)
    ap.add_argument("--records", type=int, default=None)
    ap.add_argument("--drop-at", type=int, default=20)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--first-seed", type=int, default=100, help="(a) seeds start here")
    ap.add_argument("--no-change-only", action="store_true", help="(a) and detectability only")
    ap.add_argument("--static-minutes", type=float, default=None,
                    help="(d) only: a real server with static data for this many minutes")
    args = ap.parse_args(argv)
    if args.static_minutes is not None:
        res = static_server(args.static_minutes)
        print(f"(d) static data on a real server: first best after {res['first_best_s']:.0f} s, "
              f"idle after {res['idle_after_s']:.0f} s; over {res['minutes']:g} min: "
              f"{res['alarms']} alarm(s), {res['cpu_fraction_of_a_core'] * 100:.2f} % of a core; "
              "headline vs truth: " + ", ".join(f"{p} {e * 100:+.2f} %"
                                                 for p, e in res["headline"].items()))
        if args.out:
            args.out.write_text(json.dumps(res, indent=2, default=float))
        return 0
    seeds = args.seeds or (2 if args.quick else 4)
    n_static = args.records or (60 if args.quick else 100)
    result: dict[str, Any] = {}

    # (a) no change
    t0 = time.perf_counter()
    static = [run_stream(args.first_seed + s, n_static) for s in range(seeds)]
    n = sum(r["n_records"] for r in static)
    fa = sum(len(raised(r)) for r in static)
    spr = float(np.mean([r["seconds_per_record"] for r in static]))
    cover = {p: [] for p in LONO_TRUTH}
    for r in static:  # headline coverage at every 8th record (windows do not overlap)
        for h in r["headlines"][7::8]:
            for p, v in h["parameters"].items():
                ci = v.get("ci95")
                cover[p].append(bool(ci and ci[0] <= LONO_TRUTH[p] <= ci[1]))
    coverage = {p: float(np.mean(c)) for p, c in cover.items() if c}
    print("    headline 95 % CI coverage (every 8th record): " + ", ".join(
        f"{p} {c * 100:.0f} %" for p, c in coverage.items())
        + f" (n = {len(next(iter(cover.values())))})")
    result["no_change"] = {"records": n, "false_alarms": fa, "per_1000": 1000 * fa / n,
                           "headline_coverage": coverage,
                           "seconds_per_record": spr,
                           "alarms": [e for r in static for e in raised(r)]}
    print(f"(a) no change: {fa} false alarm(s) in {n} records ({1000 * fa / n:.2f} per 1000); "
          f"{spr:.2f} s per record fit ({time.perf_counter() - t0:.0f} s)")

    # what can be detected: per-record scatter vs the floor, and the CUSUM's arithmetic
    rule, ref = static[0]["report"].rule, static[0]["report"].reference["quantities"]
    h, k, clip = rule["threshold_h"], rule["k"], rule["clip"]
    result["detectability"] = {}
    print(f"    h = {h:.2f}, k = {k}, |z| <= {clip}: no alarm sooner than "
          f"{int(np.ceil(h / (clip - k)))} records after a change")
    print("    quantity | per-record scatter | floor | smallest change alarmed within "
          "8 / 20 records (expected)")
    for q, b in ref.items():
        s = max(b["scatter"], b["floor"]) / abs(b["centre"])
        within8, within20 = (k + h / 8) * s, (k + h / 20) * s
        result["detectability"][q] = {"scatter_rel": b["scatter"] / abs(b["centre"]),
                                      "floor_rel": b["floor"] / abs(b["centre"]),
                                      "within_8": within8, "within_20": within20}
        print(f"    {q:8s} | {b['scatter'] / abs(b['centre']) * 100:8.3f} % | "
              f"{b['floor'] / abs(b['centre']) * 100:.2f} % | {within8 * 100:.2f} % / "
              f"{within20 * 100:.2f} %")

    if args.no_change_only:
        if args.out:
            args.out.write_text(json.dumps(result, indent=2, default=float))
        return 0

    # (b) drops
    result["drops"] = {}
    print("(b) k1 drop | seed | delay (records) | named | change-point error | change")
    n_after = 12 if args.quick else 20
    for drop in (0.02, 0.05, 0.15):
        rows = []
        for s in range(seeds):
            run = run_stream(200 + s, args.drop_at + n_after, drop, args.drop_at)
            row = summarise_drop(run)
            rows.append(row)
            ch = "-" if row["change_rel"] is None else f"{row['change_rel'] * 100:+.1f} %"
            print(f"    {drop * 100:4.0f} % | {s} | {row['delay']} | {','.join(row['named'])} | "
                  f"{row['change_point_error']} | {ch}")
        result["drops"][str(drop)] = rows

    # (c) the demo scenario
    demo = run_stream(300, 36, 0.15, 24)
    truth_after = dict(LONO_TRUTH, k1=LONO_TRUTH["k1"] * 0.85)
    result["demo"] = {"before": headline_error(demo, 23, LONO_TRUTH),
                      "after": headline_error(demo, 35, truth_after),
                      "alarms": raised(demo)}
    for when in ("before", "after"):
        errs = result["demo"][when]
        print(f"(c) demo headline {when} the drop: " + ", ".join(
            f"{p} {e['rel_error'] * 100:+.2f} % ({'covers' if e['covers'] else 'MISSES'})"
            for p, e in errs.items()))
    if args.out:
        args.out.write_text(json.dumps(result, indent=2, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
