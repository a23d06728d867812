"""The fleet benchmark's report: the side-by-side table, memory slopes, the must-show
line, the machine, and the JSON (benchmarks/bench_fleet.py measures; this prints)."""
from __future__ import annotations

import argparse
import json
import math
import platform
import statistics
import time
from pathlib import Path
from typing import Any, Callable

import psutil


def fnum(x: Any, spec: str = ".1f") -> str:
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else format(x, spec)


def acknowledged(r: dict[str, Any]) -> int:
    return r.get("records_acknowledged", r["records_sent"])


ROWS: list[tuple[str, Callable[[dict[str, Any]], str]]] = [
    ("epochs/s (all systems)", lambda r: fnum(r["epochs_per_s"])),
    ("epochs/s per system min", lambda r: fnum(r["epochs_per_s_per_system"]["min"], ".2f")),
    ("record->estimate p50 [s]", lambda r: fnum(r["record_to_estimate_s"]["p50"])),
    ("record->estimate p95 [s]", lambda r: fnum(r["record_to_estimate_s"]["p95"])),
    ("  records seen / acknowledged",
     lambda r: f"{r['record_to_estimate_s']['n']}/{acknowledged(r)}"),
    ("  same, snapshot's own time p50",
     lambda r: fnum(r["record_to_estimate_s"]["published_p50"])),
    ("  same, snapshot's own time p95",
     lambda r: fnum(r["record_to_estimate_s"]["published_p95"])),
    ("record->monitored p50 [s]", lambda r: fnum(r["record_to_monitored_s"]["p50"])),
    ("record->monitored p95 [s]", lambda r: fnum(r["record_to_monitored_s"]["p95"])),
    ("  monitored / acknowledged",
     lambda r: f"{r['record_to_monitored_s']['n']}/{acknowledged(r)}"),
    ("  fitted ok (drift report) / ackn.",
     lambda r: f"{r['record_to_monitored_s'].get('fitted_ok', '-')}/{acknowledged(r)}"),
    ("  per-record fit p50 [s]",
     lambda r: fnum(r["record_to_monitored_s"].get("fit_seconds_p50"), ".2f")),
    ("onboarded (first best) [s]",
     lambda r: f"{fnum(r.get('onboarding_s'), '.0f')} ({r.get('onboarded', '-')}/{r['n_systems']})"),
    ("max gap between updates [s]", lambda r: fnum(r["max_update_gap_s"])),
    ("upload 202 p50 [s]", lambda r: fnum(r["upload_ack_s"]["p50"], ".2f")),
    ("upload 202 p95 [s]", lambda r: fnum(r["upload_ack_s"]["p95"], ".2f")),
    ("memory base [MB]", lambda r: fnum(r["memory_mb"]["base_rss"], ".0f")),
    ("memory per system RSS [MB]", lambda r: fnum(r["memory_mb"]["per_system_rss"], ".0f")),
    ("memory per system PSS [MB]", lambda r: fnum(r["memory_mb"]["per_system_pss"], ".0f")),
    ("trainer processes", lambda r: str(r["memory_mb"]["trainer_hosts"] or "1 (server)")),
    ("CPU cores used", lambda r: fnum(r["cpu"]["cores"], ".2f")),
    ("machine busy cores (all users)", lambda r: fnum(r["cpu"]["machine_busy_cores"], ".2f")),
    ("CPU-s per epoch", lambda r: fnum(r["cpu"]["cpu_s_per_epoch"], ".3f")),
    ("CPU-s per record", lambda r: fnum(r["cpu"]["cpu_s_per_record"], ".1f")),
    ("idle share", lambda r: fnum(r["idle_share"], ".2f")),
    ("load avg (1 min) start", lambda r: fnum(r["loadavg"]["start"][0], ".2f")),
]


def table(results: list[dict[str, Any]]) -> str:
    cols = sorted({(r["n_systems"], r["executor"]) for r in results if "error" not in r},
                  key=lambda c: (c[0], c[1] != "threads"))
    by = {(r["n_systems"], r["executor"]): r for r in results if "error" not in r}
    head = [f"N={n} {ex}" for n, ex in cols]
    w0 = max(len(name) for name, _ in ROWS)
    lines = [" | ".join([" " * w0] + [f"{h:>14s}" for h in head])]
    lines.append("-" * len(lines[0]))
    for name, get in ROWS:
        lines.append(" | ".join([f"{name:<{w0}s}"] + [f"{get(by[c]):>14s}" for c in cols]))
    for r in results:
        if "error" in r:
            lines.append(f"{r['executor']} N={r['n_systems']}: FAILED - {r['error']}")
    return "\n".join(lines)


def marginal_memory(results: list[dict[str, Any]]) -> dict[str, dict[str, float]]:
    """MB per added system, per executor: the slope of the peak RSS (and of the PSS) between
    the smallest and the largest N (free of one-time costs such as torch's first use)."""
    out = {}
    for ex in sorted({r["executor"] for r in results if "error" not in r}):
        rs = sorted((r for r in results if r["executor"] == ex and "error" not in r),
                    key=lambda r: r["n_systems"])
        if len(rs) < 2:
            continue
        a, b = rs[0], rs[-1]
        dn = b["n_systems"] - a["n_systems"]
        out[ex] = {"from_n": a["n_systems"], "to_n": b["n_systems"],
                   "rss_mb_per_system": (b["memory_mb"]["peak_rss"]
                                         - a["memory_mb"]["peak_rss"]) / dn,
                   "pss_mb_per_system": (b["memory_mb"]["end_pss"]
                                         - a["memory_mb"]["end_pss"]) / dn}
    return out


def must_show(results: list[dict[str, Any]], limit_s: float = 60.0) -> list[str]:
    out: list[str] = []
    largest = max((x["n_systems"] for x in results), default=0)
    for r in results:
        if "error" in r or r["n_systems"] < largest:
            continue
        gap = r["max_update_gap_s"]
        ok = gap is not None and gap <= limit_s and r["all_trainers_started"]
        out.append(f"{r['executor']} N={r['n_systems']}: every system's estimate updated at "
                   f"least once per {limit_s:.0f} s: {'yes' if ok else 'NO'} "
                   f"(longest gap {fnum(gap)} s)")
        out.append(monitoring_verdict(r, limit_s))
    return out


def monitoring_verdict(r: dict[str, Any], limit_s: float = 60.0) -> str:
    """Issue 18's must-show 5: record -> monitored p95 <= ``limit_s`` and every acknowledged
    record fitted by the monitoring (its fit ok in the drift report)."""
    m = r["record_to_monitored_s"]
    n_ack = acknowledged(r)
    every = n_ack > 0 and m["n"] == n_ack and m.get("fitted_ok") == n_ack
    ok = every and m["p95"] is not None and m["p95"] <= limit_s
    return (f"{r['executor']} N={r['n_systems']}: every record monitored, p95 <= "
            f"{limit_s:.0f} s: {'yes' if ok else 'NO'} (record -> monitored p50 "
            f"{fnum(m['p50'])} s, p95 {fnum(m['p95'])} s; {m['n']}/{n_ack} seen monitored, "
            f"{m.get('fitted_ok', '-')}/{n_ack} fitted ok)")


def machine() -> dict[str, Any]:
    return {"cpus_logical": psutil.cpu_count(), "cpus_physical": psutil.cpu_count(False),
            "memory_gib": psutil.virtual_memory().total / 2**30,
            "processor": platform.processor() or platform.machine(),
            "python": platform.python_version(), "date_utc": time.strftime("%Y-%m-%d %H:%M",
                                                                           time.gmtime())}


def sparse_table(sparse: list[dict[str, Any]]) -> str:
    lines = []
    for r in sparse:
        if "error" in r:
            lines.append(f"  {r['executor']}: FAILED - {r['error']}")
            continue
        ob = r["onboarding"]
        fits = [x["fit_s"] for x in r["records"] if x["fit_s"] is not None]
        lines.append(
            f"  {r['executor']:7s} ({r.get('prefill', 2)} records first): onboarding "
            f"{ob['cpu_s']:.0f} CPU-s ({ob['wall_s']:.0f} s, "
            f"{ob['epochs']} epochs); idle {r['idle_cores']:.3f} cores; per record "
            f"{fnum(r['cpu_s_per_record'])} CPU-s, {fnum(r['epochs_per_record'], '.0f')} epochs, "
            f"{fnum(r['wall_s_per_record'])} s to idle (median of {len(r['records'])}); "
            f"monitoring fit {fnum(statistics.median(fits) if fits else None)} s")
    return "\n".join(lines)


def write_json(path: str, results: list[dict[str, Any]], sparse: list[dict[str, Any]],
               period: float, args: argparse.Namespace, server_env: dict[str, str]) -> None:
    Path(path).write_text(json.dumps({
        "machine": machine(), "model": "LO-NO (examples/models/lono.toml)",
        "period_s": period, "server_env": server_env, "args": vars(args),
        "marginal_memory": marginal_memory(results), "sparse": sparse,
        "results": results}, indent=1) + "\n")
