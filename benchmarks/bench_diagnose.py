"""Benchmark of `siva diagnose`: verdict, closure, gaps and time per case.

Cases (the model is always the nominal LO-NO, examples/models/lono.toml):

* ``coulomb_NO_ground``, ``cubic_damper_LO_NO``: the shipped gap examples (noisy acc + force
  only), train 250 + 530 N, validate 37 + 899 N.  The folder's effect.json is read ONLY to
  print the expected answer next to the verdict.
* ``null_lono``: the lono/ impact records, whose generator is exactly the nominal model:
  train 530 N, validate 37 + 899 N; the expected verdict is null.
* ``duffing_without_cubic_damper``: another model: the paper's Duffing (duffing/, free
  decays, noise-free disp/vel/acc, no force) diagnosed with the model *minus* its cubic
  damper; train 5 m/s, validate 3 + 8 m/s.
* ``syn_*``: synthetic records never shipped (another effect, location, magnitude, seed):
  the nominal truth (lono/truth.json) plus one element, simulated with the project's own
  simulator, 4 s at 2048 Hz, 0.3 % acceleration / 0.2 % force noise; train 150 + 450 N,
  validate 50 + 800 N.

* ``syn2_*``: two elements at once in the generator; both must be named (``verdicts``).
* ``sensor_*``: the nominal generator with one faulty sensor (an accelerometer's or the
  force transducer's gain scaled after simulation); the verdict must be that sensor.

* ``--matrix full|reduced`` (``matrix.py``): the confusion-matrix cases on two structures,
  LO-NO (hammer on NO) and a 3-DOF chain (hammer on the middle mass): every candidate kind
  at every place the model lacks it, two magnitudes sized from the structure itself, the
  null, sensor faults (accelerometer gain, channel delay, force gain) and two-effect cases;
  ``reduced`` takes every kind once per structure (places and sizes rotating) plus the
  null, the sensor faults and one two-effect case.  Matrix case names
  (``lono:coulomb:LO-ground:small``) can also be given to ``--cases``.

Columns: the named effect(s), identified size / true size of each named expected effect,
closure, gaps, wall time and CPU time of the process (on a shared machine the wall time
grows with the other jobs' load; the CPU time is close to an idle machine's wall time).  At the end: a confusion matrix of kinds, and per structure the
share right (kind and place), false verdicts on nulls and the time per case.

Usage: ``python benchmarks/bench_diagnose.py [--cases a,b] [--matrix full|reduced]
[--structures lono,chain3] [--rotate N] [--json FILE] [--verbose]``; ``--json`` is
rewritten after every case, and ``--summarise a.json,b.json`` prints the matrix of saved
runs (the full matrix split over processes with ``--cases``).
(``SIVA_SHARED_DATA`` points at the shared data when it is not at ../shared/data)
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import statistics
import sys
import time
import warnings
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from siva_core import (DiagnoseSettings, Recording, Structure, diagnose,  # noqa: E402
                       synthetic_impacts, with_effect)

sys.path.insert(0, str(Path(__file__).resolve().parent))
import matrix  # noqa: E402

DATA = Path(os.environ.get("SIVA_SHARED_DATA") or ROOT.parent / "shared" / "data")
MODEL = ROOT / "examples" / "models" / "lono.toml"
#: the verdict rule's relevance floor (DiagnoseSettings.gap_min)
GAP_MIN = 0.005

SYNTHETIC = {
    "syn_quadratic_damper_LO_ground": ("quadratic_damper", ("LO", "ground"), {"c2": 4.0}),
    "syn_quadratic_damper_LO_NO": ("quadratic_damper", ("LO", "NO"), {"c2": 2.0}),
    "syn_cubic_damper_NO_ground": ("cubic_damper", ("NO", "ground"), {"c3": 1.0e4}),
    "syn_coulomb_LO_NO": ("coulomb", ("LO", "NO"), {"fc": 0.3}),
    "syn_coulomb_LO_ground": ("coulomb", ("LO", "ground"), {"fc": 0.15}),
    "syn_damper_NO_ground": ("damper", ("NO", "ground"), {"c": 1.0}),
    "syn_clearance_LO_ground": ("clearance", ("LO", "ground"), {"k": 2.0e4, "gap": 2.0e-3}),
    "syn_cubic_spring_NO_ground": ("cubic_spring", ("NO", "ground"), {"k3": -3.0e6}),
    "syn_cubic_spring_NO_ground_hard": ("cubic_spring", ("NO", "ground"), {"k3": 2.0e7}),
    "syn_quadratic_spring_LO_NO": ("quadratic_spring", ("LO", "NO"), {"k2": 1.6e5}),
}
#: two effects at once: both elements in the generator
TWO_EFFECTS = {
    "syn2_coulomb_NO_ground+quadratic_damper_LO_ground": [
        ("coulomb", ("NO", "ground"), {"fc": 0.2}),
        ("quadratic_damper", ("LO", "ground"), {"c2": 3.0})],
}
#: sensor faults on the nominal generator: (fault kind, channel, value = measured/true)
SENSOR = {
    "sensor_accelerometer_gain_LO": ("accelerometer_gain", "acc_LO", 0.85),
    "sensor_force_gain_NO": ("force_gain", "force_NO", 1.15),
}
CASES = ["coulomb_NO_ground", "cubic_damper_LO_NO", "null_lono", *SYNTHETIC, *TWO_EFFECTS,
         *SENSOR, "duffing_without_cubic_damper"]


def duffing_without_cubic_damper() -> Structure:
    """The Duffing model of examples/models with its cubic damper (b_nl) withheld."""
    spec = Structure.from_file(ROOT / "examples" / "models" / "duffing.toml").spec
    spec["elements"] = [e for e in spec["elements"] if e["kind"] != "cubic_damper"]
    return Structure.from_dict(spec)


def load_case(name: str, structure: Structure) -> tuple[list[Recording], list[Recording], Any]:
    """(train, val, expected verdict as (kind, between) or None)."""
    dofs = structure.dofs
    if name == "duffing_without_cubic_damper":
        folder = DATA / "duffing"
        train = [Recording.read(folder / "train_v5.csv", dofs)]
        val = [Recording.read(folder / f, dofs) for f in ("val_v3.csv", "val_v8.csv")]
        return train, val, [("cubic_damper", ("x", "ground"))]
    if name in ("coulomb_NO_ground", "cubic_damper_LO_NO"):
        folder = DATA / "gap_examples" / name
        train = [Recording.read(folder / f"impact_{a}N.csv", dofs) for a in (250, 530)]
        val = [Recording.read(folder / f"impact_{a}N.csv", dofs) for a in (37, 899)]
        eff = json.loads((folder / "effect.json").read_text())["effect"]
        return train, val, [(eff["kind"], tuple(eff["between"]))]
    if name == "null_lono":
        folder = DATA / "lono"
        train = [Recording.read(folder / "impact_530N.csv", dofs)]
        val = [Recording.read(folder / f"impact_{a}N.csv", dofs) for a in (37, 899)]
        return train, val, []
    truth = json.loads((DATA / "lono" / "truth.json").read_text())["truth"]
    if name in SENSOR:
        fault, channel, value = SENSOR[name]
        theta = structure.vector(truth)
        train = synthetic_impacts(structure, theta, [150.0, 450.0], dof="NO", seed=11)
        val = synthetic_impacts(structure, theta, [50.0, 800.0], dof="NO", seed=12)
        faulty = [dataclasses.replace(r, channels={**r.channels,
                                                   channel: r.channels[channel] * value})
                  for r in [*train, *val]]
        return faulty[:2], faulty[2:], [(fault, (channel,))]
    elements = TWO_EFFECTS.get(name) or [SYNTHETIC[name]]
    gen = structure
    for kind, between, coeffs in elements:
        gen = with_effect(gen, kind, between, coeffs)
    theta = gen.vector(truth)
    train = synthetic_impacts(gen, theta, [150.0, 450.0], dof="NO", seed=11)
    val = synthetic_impacts(gen, theta, [50.0, 800.0], dof="NO", seed=12)
    return train, val, [(k, tuple(b)) for k, b, _ in elements]


def truth_of(name: str) -> list[dict[str, float]]:
    """The generator's coefficients of each expected effect (size recovery)."""
    if name in SENSOR:
        return [{"gain": SENSOR[name][2]}]
    return [c for _, _, c in (TWO_EFFECTS.get(name) or [SYNTHETIC[name]])] \
        if name in SYNTHETIC or name in TWO_EFFECTS else []


def run(name: str, quiet: bool = True, budget: float | None = None) -> dict[str, Any]:
    """One case; ``budget``: the diagnosis's time budget (None, the default here: the
    matrix measures the rules, not the machine's load on a given day)."""
    if ":" in name:  # a confusion-matrix case
        mc = matrix.parse(name)
        structure = mc.nominal()
        train, val = mc.records()
        expected, truths = mc.expected(), mc.truths()
    else:
        structure = duffing_without_cubic_damper() if name.startswith("duffing") \
            else Structure.from_file(MODEL)
        train, val, expected = load_case(name, structure)
        truths = truth_of(name)
    t0, c0 = time.perf_counter(), time.process_time()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        diag = diagnose(structure, train, val, "auto",
                        settings=DiagnoseSettings(budget_s=budget),
                        progress=None if quiet else (lambda m: print("   ", m, flush=True)))
    elapsed, cpu = time.perf_counter() - t0, time.process_time() - c0
    out = diag.to_json()
    got = [(v["kind"], tuple(v["between"])) for v in out["verdicts"]]
    shown = diag.verdict or (diag.ranking[0] if diag.ranking else None)
    sizes = []
    for (kind, where), coeffs in zip(expected, truths):
        v = next((v for v in out["verdicts"] if (v["kind"], tuple(v["between"])) == (kind, where)),
                 None)
        if v is not None:
            sizes += [v["coefficients"][k] / x for k, x in coeffs.items()
                      if k in v["coefficients"] and v["coefficients"][k] is not None and k != "gap"]
    fmt = lambda e: " + ".join(f"{k} {'-'.join(b)}" for k, b in e) or None  # noqa: E731
    return {
        "case": name,
        "expected": fmt(expected),
        "verdict": fmt(got),
        "correct": sorted(got) == sorted(expected),
        "first_right": (got[:1] == expected[:1]) if expected else not got,
        "size_ratio": sizes,
        "closure": None if shown is None else shown.closure,
        "gap_before": out["nominal"]["gap"],
        "gap_after": None if shown is None else shown.gap_after,
        "coefficients": [v["coefficients"] for v in out["verdicts"]],
        "reason": out["rule"].get("reason"),
        "budget_reached": bool((out["rule"].get("budget") or {}).get("reached")),
        "time_s": elapsed,
        "cpu_s": cpu,
        "timing_s": out["timing_s"],
    }


def _kinds(label: str | None) -> str:
    """'coulomb NO-ground + damper LO-ground' -> 'coulomb+damper' (the kind part only)."""
    if not label:
        return "none"
    return "+".join(sorted(part.split()[0] for part in label.split(" + ")))


def print_confusion(rows: list[dict[str, Any]]) -> None:
    """Expected kind(s) (rows) against named kind(s) (columns), counting cases; a '*'
    marks a right kind at a wrong place."""
    exp = sorted({_kinds(r["expected"]) for r in rows})
    got = sorted({_kinds(r["verdict"]) for r in rows} | set(exp))
    width = max(len(g) for g in got) + 1
    print("\nconfusion (rows expected, columns named; * = right kind, wrong place)")
    print(" " * width + "".join(f"{g[:12]:>13s}" for g in got))
    for e in exp:
        cells = []
        for g in got:
            hit = [r for r in rows if _kinds(r["expected"]) == e and _kinds(r["verdict"]) == g]
            wrong_place = any(e == g and not r["correct"] for r in hit)
            cells.append(f"{(str(len(hit)) + ('*' if wrong_place else '')) if hit else '.':>13s}")
        print(f"{e:{width}s}" + "".join(cells))


def print_summary(rows: list[dict[str, Any]]) -> None:
    """Per structure (the part of a matrix case name before ':'): right kind and place,
    false verdicts on null cases, mean and largest time per case."""
    groups: dict[str, list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault(r["case"].split(":")[0] if ":" in r["case"] else "named", []).append(r)
    print(f"\n{'structure':10s} {'cases':>5s} {'right':>6s} {'share':>6s} {'null false':>10s} "
          f"{'mean s':>7s} {'median s':>8s} {'max s':>7s} {'mean cpu s':>10s}")
    for g, rs in groups.items():
        nulls = [r for r in rs if not r["expected"]]
        false = sum(1 for r in nulls if r["verdict"])
        ok = sum(r["correct"] for r in rs)
        times = [r["time_s"] for r in rs]
        cpu = [r.get("cpu_s", 0.0) for r in rs]
        print(f"{g:10s} {len(rs):5d} {ok:6d} {100 * ok / len(rs):5.0f}% {false:4d} of {len(nulls):<3d} "
              f"{sum(times) / len(times):7.1f} {statistics.median(times):8.1f} "
              f"{max(times):7.1f} {sum(cpu) / len(cpu):10.1f}")
        # effects whose records show no gap above the relevance floor (gap_min): null is
        # the right answer to what the records show; counted apart as well as in "right"
        faint = [r for r in rs if r["expected"] and (r["gap_before"] or 0.0) < GAP_MIN]
        if faint:
            vis = [r for r in rs if r not in faint]
            print(f"{'':10s} {sum(r['correct'] for r in vis):5d} right of {len(vis)} with a "
                  f"visible gap; {len(faint)} below gap_min {GAP_MIN}: "
                  + ", ".join(r["case"] for r in faint))

def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default=",".join(CASES), help="comma-separated: " + ", ".join(CASES))
    ap.add_argument("--matrix", choices=("full", "reduced", "issue16", "pairs"),
                    help="run the confusion-matrix cases instead of --cases")
    ap.add_argument("--structures", default="lono,chain3",
                    help="structures of --matrix: " + ", ".join(matrix.STRUCTURES))
    ap.add_argument("--rotate", type=int, default=0,
                    help="--matrix reduced: shift places, sizes and sensor channels by this")
    ap.add_argument("--json", metavar="FILE", help="also write the rows as JSON")
    ap.add_argument("--verbose", action="store_true", help="progress of each diagnosis")
    ap.add_argument("--budget", type=float, default=0.0,
                    help="the diagnosis's time budget in wall seconds (default 0: none; "
                         "the library's default is DiagnoseSettings.budget_s)")
    ap.add_argument("--force-interp", default=None, choices=("moments", "linear"),
                    help="how the diagnosis's fits read a measured force between samples "
                         "(default: the library's, 'moments'); 'linear' is how "
                         "synthetic_impacts, the matrix's generator, drives its simulation, "
                         "so with it the truth model reproduces the matrix records exactly "
                         "(an ablation: see docs/diagnosis.md, branch faint3)")
    ap.add_argument("--summarise", metavar="FILES",
                    help="no runs: the matrix and summary of rows saved by --json (comma-"
                         "separated files, e.g. of runs split over several processes)")
    args = ap.parse_args()
    if args.summarise:
        rows = [r for f in args.summarise.split(",") for r in json.loads(Path(f).read_text())]
        print(f"{len(rows)} cases from {args.summarise}")
        print_confusion(rows)
        print_summary(rows)
        return 0
    if args.force_interp:
        from siva_core import set_measured_force_interp

        set_measured_force_interp(args.force_interp)
    rows = []
    head = (f"{'case':32s} {'expected':24s} {'verdict':24s} {'size/true':12s} ok  {'closure':>8s} "
            f"{'gap_before':>10s} {'gap_after':>10s} {'time_s':>7s} {'cpu_s':>7s}")
    print(head)
    names = (matrix.case_names(args.matrix, args.structures.split(","), args.rotate)
             if args.matrix
             else args.cases.split(","))
    print(f"{len(names)} cases", flush=True)
    for name in names:
        try:
            row = run(name.strip(), quiet=not args.verbose, budget=args.budget or None)
        except Exception as exc:  # noqa: BLE001 - a case that fails counts as wrong
            row = {"case": name.strip(), "expected": "?", "verdict": f"ERROR {exc}"[:60],
                   "correct": False, "first_right": False, "size_ratio": [],
                   "closure": None, "gap_before": None, "gap_after": None,
                   "coefficients": None, "reason": str(exc), "time_s": 0.0, "cpu_s": 0.0,
                   "timing_s": {}}
        rows.append(row)
        fmt = lambda x: "-" if x is None else f"{x:.4g}"  # noqa: E731
        print(f"{row['case']:32s} {str(row['expected']):24s} {str(row['verdict']):24s} "
              f"{' '.join(f'{x:.3f}' for x in row['size_ratio']) or '-':12s} "
              f"{'yes' if row['correct'] else 'NO ':3s} {fmt(row['closure']):>8s} "
              f"{fmt(row['gap_before']):>10s} {fmt(row['gap_after']):>10s} "
              f"{row['time_s']:7.1f} {row.get('cpu_s', 0.0):7.1f}", flush=True)
        if args.verbose:
            print(f"    coefficients {row['coefficients']}; rule: {row['reason']}")
        if args.json:  # after every case: a run stopped at a deadline keeps what it did
            Path(args.json).write_text(json.dumps(rows, indent=2, default=float) + "\n")
    n_ok = sum(r["correct"] for r in rows)
    print(f"{n_ok}/{len(rows)} verdicts as expected; total {sum(r['time_s'] for r in rows):.0f} s")
    print_confusion(rows)
    print_summary(rows)
    return 0 if n_ok == len(rows) else 1


if __name__ == "__main__":
    sys.exit(main())
