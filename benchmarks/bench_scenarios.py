"""Diagnosis on random scenarios (issue 16): `scenarios.draw(seed)` for each seed, then
`siva_core.diagnose`, scored against the scenario's truth.

A case is *complete* when the named effects are exactly the expected ones (kind and place,
or fault and channel; nothing missing, nothing more).  Rates are reported per category
(null, single, two effects) and for the faint effects (visibility < 5 x the noise) and
those at >= 5 x; and the same two classes by the visibility *after the nominal refit*
(``visibility_after.py``: what the refitted nominal model cannot absorb, i.e. what the
records can identify; a missing spring or a coulomb is largely absorbed by the refit).  A force gain (or a 1-DOF model's accelerometer gain) that the hammer
pulse's reading explains -- the generator's truth, ``pulse_truth.py``: a fault-free hammer
with another half-sine through the same samples gives the same records -- is counted as
its own class, "gain within the pulse reading", beside the strict count (never instead).
Each row has the wall time, the process CPU time and the 1-minute load average at the end
of the case (the machine is shared: the wall time depends on the load).

Usage: ``python benchmarks/bench_scenarios.py --seeds 2000-2059 [--json FILE] [--verbose]
[--limit WALL_S | --cpu-limit CPU_S] [--budget-share 0.75] [--force-reading continuous|linear|dop853]``
(a limit gives the diagnosis a time budget of ``--budget-share`` x it, on the same clock:
a case near the limit returns its anytime verdict, counted as ``budget_reached``, instead
of a timeout)
(``--force-reading linear``: the records driven as before issue 16's fifth round, to
reproduce the batches reported up to 15000-15159; the default drives them with the
continuous hammer pulse, ``scenarios.FORCE_READINGS``; ``--force-reading dop853``: the
same scenarios with the records made by an independent simulator, scipy's DOP853, as the
issue's withheld sets were)
(``--seeds`` takes ranges and commas; ``--summarise a.json,b.json`` prints saved runs;
``--add-after a.json`` fills the visibility after the nominal refit into saved runs).
Seeds used for development are listed in docs/diagnosis.md; a reported rate must come from
seeds never run before the rules were frozen.
"""
from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import signal
import sys
import time
import traceback
import warnings
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from siva_core import DiagnoseSettings, diagnose  # noqa: E402

import scenarios  # noqa: E402
import visibility_after  # noqa: E402


class CaseTimeout(BaseException):  # not swallowed by the diagnosis's per-candidate guards
    pass


def _timeout(signum: int, frame: Any) -> None:
    raise CaseTimeout("over the time limit")


def _disarm() -> None:
    signal.alarm(0)
    signal.setitimer(signal.ITIMER_PROF, 0.0)


def parse_seeds(text: str) -> list[int]:
    out: list[int] = []
    for part in text.split(","):
        if "-" in part:
            a, b = part.split("-")
            out += list(range(int(a), int(b) + 1))
        elif part.strip():
            out.append(int(part))
    return out


def _label(kind: str, between: Any) -> str:
    return f"{kind} {'-'.join(between)}"


def budget_settings(limit: float, cpu_limit: float, share: float) -> DiagnoseSettings:
    """The diagnosis's budget below the case's limit, on the limit's clock (CPU seconds
    for ``--cpu-limit``: the process's CPU time, which ``budget_cpu`` measures too); the
    library default without a limit.  ``share`` < 1 leaves the work in flight when the
    budget is reached (one stage or set fit) room to end before the limit."""
    if cpu_limit:
        return DiagnoseSettings(budget_s=share * cpu_limit, budget_cpu=True)
    if limit:
        return DiagnoseSettings(budget_s=share * limit)
    return DiagnoseSettings()


def run(sc: scenarios.Scenario, verbose: bool = False,
        settings: DiagnoseSettings | None = None) -> dict[str, Any]:
    seed = sc.seed
    t0, c0 = time.perf_counter(), time.process_time()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        diag = diagnose(sc.nominal, sc.train, sc.val, "auto", settings=settings,
                        progress=(lambda m: print("   ", m, flush=True)) if verbose else None)
    elapsed, cpu = time.perf_counter() - t0, time.process_time() - c0
    _disarm()  # the limits are the diagnosis': the row's own refits (``_after``) are not
    out = diag.to_json()
    got = sorted(_label(v["kind"], v["between"]) for v in out["verdicts"])
    exp = sorted(_label(k, b) for k, b in sc.expected)
    if len(sc.nominal.dofs) == 1:  # one accelerometer: its gain *is* a force gain (1/g)
        same = {_label("accelerometer_gain", [f"acc_{sc.nominal.dofs[0]}"]),
                _label("force_gain", [f"force_{sc.force_dof}"])}
        exp = sorted(_label("force_gain", [f"force_{sc.force_dof}"]) if e in same else e
                     for e in exp)
        got = sorted(_label("force_gain", [f"force_{sc.force_dof}"]) if g in same else g
                     for g in got)
    sizes = []
    for (kind, where), truth in zip(sc.expected, sc.truths):
        v = next((v for v in out["verdicts"]
                  if (v["kind"], tuple(v["between"])) == (kind, tuple(where))), None)
        if v is not None:
            sizes += [v["coefficients"][k] / x for k, x in truth.items()
                      if k != "gap" and v["coefficients"].get(k) is not None and x]
    # a gain fault within the pulse reading (the generator's truth, pulse_truth.py): its
    # own class beside the strict count -- the rest named exactly, the gain not
    gr = sc.info.get("gain_reading")
    rest = None
    if gr is not None and gr["within"]:
        fault = _label(sc.fault[0], [sc.fault[1]])
        if len(sc.nominal.dofs) == 1:
            fault = _label("force_gain", [f"force_{sc.force_dof}"])
        rest = sorted(e for e in exp if e != fault)
    return {"seed": seed, "category": sc.category, "describe": scenarios.describe(sc),
            "gain_reading": gr, "rest_complete": rest is not None and got == rest,
            "reading_limit": out["rule"].get("pulse_reading_limit"),
            "expected": exp, "named": got, "complete": got == exp,
            "missing": [e for e in exp if e not in got], "extra": [g for g in got if g not in exp],
            "visibility": sc.visibility, "size_ratio": sizes,
            **_after(sc),
            # the look-alikes the data cannot separate, per named effect (the verdict
            # entries' ``rivals``; the top-level key never existed)
            "rivals": {_label(v["kind"], v["between"]): [r["candidate"] for r in v["rivals"]]
                       for v in out["verdicts"] if v.get("rivals")},
            "gap_before": out["nominal"]["gap"], "reason": out["rule"].get("reason"),
            # the anytime verdict: the budget stopped the search (``rule["budget"]``)
            "budget_reached": bool((out["rule"].get("budget") or {}).get("reached")),
            "budget": out["rule"].get("budget"),
            # the sensor fault was named on the gap above the noise (verdict.sensor_above_noise)
            "sensor_above_noise": bool(out["rule"].get("sensor_above_noise")),
            "closures": {_label(v["kind"], v["between"]): v.get("closure")
                         for v in out["verdicts"]},
            "noise_floor": out["where"].get("noise_floor"),
            "time_s": elapsed, "cpu_s": cpu, "load1": os.getloadavg()[0],
            "dofs": sc.info["dofs"], "samples": len(sc.train[0].time),
            "force_reading": sc.info["force_reading"],
            "timing_s": out.get("timing_s", {})}


def _after(sc: scenarios.Scenario) -> dict[str, list[float]]:
    """Each effect's visibility after the nominal refit on the validation records
    (``visibility_after``) and on the train records (``visibility_after_train``), measured
    after the case's clock (not part of its time)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        val, train = visibility_after.after(sc)
    return {"visibility_after": val, "visibility_after_train": train}


def add_after(files: list[str]) -> None:
    """Fill ``visibility_after`` into saved runs that lack it (the scenario is redrawn
    from its seed; nothing is diagnosed)."""
    for f in files:
        rows = json.loads(Path(f).read_text())
        for r in rows:
            if "visibility_after_train" not in r and r.get("force_reading", "continuous") \
                    in scenarios.FORCE_READINGS and r["category"] != "error":
                r.update(_after(scenarios.draw(r["seed"],
                                               r.get("force_reading", "continuous"))))
        Path(f).write_text(json.dumps(rows, indent=2, default=float) + "\n")


def _vis(r: dict[str, Any], key: str) -> list[float] | None:
    """A row's visibilities (``key``), None when the row has none measured."""
    v = r.get(key)
    return None if v is None else [float(x) for x in v]


def summarise(rows: list[dict[str, Any]]) -> None:
    def rate(rs: list[dict[str, Any]]) -> str:
        return f"{sum(r['complete'] for r in rs)} of {len(rs)}" if rs else "-"
    cats = {c: [r for r in rows if r["category"] == c] for c in ("null", "single", "two", "three")}
    nulls = cats["null"]
    false = sum(bool(r["named"]) for r in nulls)
    effect_rows = [r for r in rows if r["category"] != "null"]
    strong = [r for r in effect_rows if r["visibility"] and min(r["visibility"]) >= 5.0
              or not r["visibility"]]
    faint = [r for r in effect_rows if r["visibility"] and min(r["visibility"]) < 5.0]
    print(f"\n{len(rows)} scenarios: complete {rate(rows)}")
    for c, rs in cats.items():
        if rs:
            print(f"  {c:7s} complete {rate(rs)}")
    print(f"  false verdicts on nulls: {false} of {len(nulls)}")
    cut = [r for r in rows if r.get("budget_reached")]
    timed_out = sum("time limit" in str(r.get("error", "")) for r in rows)
    print(f"  time budget reached (anytime verdict): {len(cut)}, complete {rate(cut)}; "
          f"over the time limit: {timed_out}")
    print(f"  effects all >= 5 x noise (or sensor only): complete {rate(strong)}; "
          f"with an effect < 5 x noise: {rate(faint)}")
    # the same classes by the visibility after the nominal refit (visibility_after.py):
    # what the refitted nominal model leaves, i.e. what the records can identify
    measured = [r for r in effect_rows if _vis(r, "visibility_after") is not None]
    if measured:
        strong_a = [r for r in measured if not r["visibility_after"]
                    or min(r["visibility_after"]) >= 5.0]
        faint_a = [r for r in measured if r["visibility_after"]
                   and not min(r["visibility_after"]) >= 5.0]
        print(f"  effects all >= 5 x noise after the nominal refit (or sensor only): "
              f"complete {rate(strong_a)}; with an effect < 5 x after it (or unmeasured): "
              f"{rate(faint_a)}")
        # per category: the must-show 2 asks the rates of what can be named
        by_cat = ", ".join(f"{c} {rate([r for r in strong_a if r['category'] == c])}"
                           for c in ("single", "two", "three")
                           if any(r["category"] == c for r in strong_a))
        print(f"    of which, per category: {by_cat}")
    within = [r for r in rows if (r.get("gain_reading") or {}).get("within")]
    if within:
        said = sum(bool(r.get("reading_limit")) for r in within)
        print(f"  gain within the pulse reading (from the generator's truth): {len(within)} "
              f"scenarios, strictly complete {rate(within)}; the rest named exactly and the "
              f"gain not: {sum(bool(r.get('rest_complete')) for r in within)}; the verdict "
              f"says such a gain cannot be told: {said} of {len(within)}")
        for r in within:
            g = r["gain_reading"]
            print(f"    seed {r['seed']}: gain {g['gain']:.3g} within {g['low']:.3g}-"
                  f"{g['high']:.3g} ({g['samples']}-sample pulse, samples' sum "
                  f"{g['sum_over_true']:.3f} x the impulse); named {r['named']}")
    times = sorted(r["time_s"] for r in rows)
    cpus = sorted(r["cpu_s"] for r in rows)
    if times:
        med = times[len(times) // 2]
        print(f"  wall s median {med:.0f} max {times[-1]:.0f}; CPU s median "
              f"{cpus[len(cpus) // 2]:.0f} max {cpus[-1]:.0f}; load average "
              f"{min(r['load1'] for r in rows):.1f}-{max(r['load1'] for r in rows):.1f}")
    for r in rows:
        if not r["complete"]:
            tag = " [gain within the pulse reading]" if r.get("rest_complete") else ""
            after, on_train = _vis(r, "visibility_after"), _vis(r, "visibility_after_train")
            shown = "" if after is None else \
                f", after the nominal refit {[round(v, 1) for v in after]}" + (
                    "" if on_train is None else
                    f" (train {[round(v, 1) for v in on_train]})")
            print(f"  miss seed {r['seed']}{tag}: expected {r['expected']} named {r['named']} "
                  f"(visibility {[round(v, 1) for v in r['visibility']]}{shown}; "
                  f"{r['reason']})")


def _case(seed: int, args: argparse.Namespace) -> dict[str, Any]:
    """One scenario drawn and diagnosed under the time limits; a failure is a wrong row."""
    signal.signal(signal.SIGALRM, _timeout)
    signal.signal(signal.SIGPROF, _timeout)
    sc = None
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        sc = scenarios.draw(seed, args.force_reading)
        print(scenarios.describe(sc), flush=True)
        if args.limit:
            signal.alarm(int(args.limit))
        if args.cpu_limit:
            signal.setitimer(signal.ITIMER_PROF, args.cpu_limit)
        row = run(sc, args.verbose,
                  budget_settings(args.limit, args.cpu_limit,
                                  getattr(args, "budget_share", 0.75)))
        _disarm()
    except (Exception, CaseTimeout) as exc:  # noqa: BLE001 - a failed case counts as wrong
        _disarm()
        if not isinstance(exc, CaseTimeout):
            traceback.print_exc()
        row = _failed_row(seed, sc, f"{type(exc).__name__}: {exc}", str(exc),
                          time.perf_counter() - t0, time.process_time() - c0)
    return row


def _failed_row(seed: int, sc: Any, error: str, reason: str, time_s: float,
                cpu_s: float) -> dict[str, Any]:
    """The row of a case that ended without a diagnosis: counted wrong, with what was
    drawn (when the draw itself got that far) and why."""
    return {"seed": seed, "category": sc.category if sc is not None else "error",
            "expected": sorted(_label(k, b) for k, b in sc.expected) if sc else [],
            "named": [], "error": error, "complete": False,
            "visibility": sc.visibility if sc else [], **(_after(sc) if sc else {}),
            "time_s": time_s, "cpu_s": cpu_s, "load1": os.getloadavg()[0],
            "reason": reason}


def _preload() -> list[str]:
    """Every siva_core module and the benchmark's own, for the case server to import once.
    Why: a case's process imports what it needs late, from the files as they are then; a
    commit during a batch once gave the cases after it a new module beside an old one it
    calls (17470-17489 and 17505-17519 of the 17460 batch: the nominal fit failed on a
    keyword the old module lacked). Preloaded, every case runs the code the batch started
    with."""
    import pkgutil

    import siva_core
    return ["siva_core", *(m.name for m in pkgutil.walk_packages(siva_core.__path__,
                                                                  "siva_core.")),
            "scenarios", "visibility_after", "bench_scenarios"]


_CASES: Any = None  # the multiprocessing context whose server forks the cases


def _cases_context() -> Any:
    """A forkserver context, its server started once with ``_preload``'s modules: cases
    are forked from a process that has run nothing (GNU OpenMP terminates a child forked
    from a process that used its threads, as a test suite's process has)."""
    global _CASES
    if _CASES is None:
        _CASES = mp.get_context("forkserver")
        _CASES.set_forkserver_preload(_preload())
    return _CASES


def _case_child(seed: int, args: argparse.Namespace, conn: Any) -> None:
    conn.send(_case(seed, args))
    conn.close()


def _case_in_child(seed: int, args: argparse.Namespace) -> dict[str, Any]:
    """``_case`` in a process of its own, forked from the case server. Why: the time limit
    raises wherever the case happens to be, and a library interrupted mid-way can be left
    broken for every later case in the same process (17454-17456 of the 17400 batch failed
    to draw after 17452 hit the limit; which library was not pinned down); a fresh process
    per case has nothing to inherit."""
    ctx = _cases_context()
    parent, child = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_case_child, args=(seed, args, child))
    t0 = time.perf_counter()
    proc.start()
    child.close()
    try:
        row = parent.recv()
    except EOFError:  # the child died without a row (killed, out of memory)
        row = None
    proc.join()
    if row is None:
        row = _failed_row(seed, None,
                          f"the case's process ended with code {proc.exitcode} and no row",
                          "process died", time.perf_counter() - t0, float("nan"))
    return row


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="2000-2009")
    ap.add_argument("--json", metavar="FILE")
    ap.add_argument("--verbose", action="store_true")
    ap.add_argument("--summarise", metavar="FILES")
    ap.add_argument("--add-after", metavar="FILES",
                    help="fill the visibility after the nominal refit into saved runs "
                         "(comma-separated JSON files, rewritten; nothing is diagnosed)")
    ap.add_argument("--force-reading", choices=scenarios.FORCE_READINGS,
                    default="continuous",
                    help="how the hammer drives the records: the continuous pulse (default) "
                         "or straight lines between its samples (the batches reported up "
                         "to 15000-15159)")
    ap.add_argument("--limit", type=float, default=0.0,
                    help="seconds of wall time per case; a case over it counts as wrong")
    ap.add_argument("--cpu-limit", type=float, default=0.0,
                    help="CPU seconds of the process per case (every thread counted; fair on a "
                         "shared machine, where wall time depends on the others' load); a case "
                         "over it counts as wrong")
    ap.add_argument("--budget-share", type=float, default=0.75,
                    help="the diagnosis's time budget as this share of --limit or "
                         "--cpu-limit (on that clock); a case past it returns the verdict "
                         "of what was checked (row's budget_reached) instead of a timeout")
    ap.add_argument("--no-isolate", dest="isolate", action="store_false",
                    help="run every case in this process (default: a process per case, "
                         "forked from a server that imported every module at the start, so "
                         "a case stopped by the time limit leaves nothing behind)")
    args = ap.parse_args()
    if args.add_after:
        add_after(args.add_after.split(","))
        if not args.summarise:
            return 0
    if args.summarise:
        rows = [r for f in args.summarise.split(",") for r in json.loads(Path(f).read_text())]
        summarise(rows)
        return 0
    rows: list[dict[str, Any]] = []
    for seed in parse_seeds(args.seeds):
        row = _case_in_child(seed, args) if args.isolate else _case(seed, args)
        rows.append(row)
        print(f"  -> {'OK ' if row['complete'] else 'NO '} named {row['named']} "
              f"{'[budget reached] ' if row.get('budget_reached') else ''}"
              f"({row['time_s']:.0f} s wall, {row['cpu_s']:.0f} s CPU, load {row['load1']:.1f}; "
              f"{row.get('reason')})", flush=True)
        if args.json:
            Path(args.json).write_text(json.dumps(rows, indent=2, default=float) + "\n")
    summarise(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
