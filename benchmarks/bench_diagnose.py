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

Usage: ``python benchmarks/bench_diagnose.py [--cases a,b] [--json FILE]``
"""
from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from siva_core import (Recording, Structure, diagnose, synthetic_impacts,  # noqa: E402
                       with_effect)

DATA = ROOT.parent / "shared" / "data"
MODEL = ROOT / "examples" / "models" / "lono.toml"

SYNTHETIC = {
    "syn_quadratic_damper_LO_ground": ("quadratic_damper", ("LO", "ground"), {"c2": 4.0}),
    "syn_clearance_LO_ground": ("clearance", ("LO", "ground"), {"k": 2.0e4, "gap": 2.0e-3}),
    "syn_cubic_spring_NO_ground": ("cubic_spring", ("NO", "ground"), {"k3": -3.0e6}),
}
CASES = ["coulomb_NO_ground", "cubic_damper_LO_NO", "null_lono", *SYNTHETIC,
         "duffing_without_cubic_damper"]


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
        return train, val, ("cubic_damper", ("x", "ground"))
    if name in ("coulomb_NO_ground", "cubic_damper_LO_NO"):
        folder = DATA / "gap_examples" / name
        train = [Recording.read(folder / f"impact_{a}N.csv", dofs) for a in (250, 530)]
        val = [Recording.read(folder / f"impact_{a}N.csv", dofs) for a in (37, 899)]
        eff = json.loads((folder / "effect.json").read_text())["effect"]
        return train, val, (eff["kind"], tuple(eff["between"]))
    if name == "null_lono":
        folder = DATA / "lono"
        train = [Recording.read(folder / "impact_530N.csv", dofs)]
        val = [Recording.read(folder / f"impact_{a}N.csv", dofs) for a in (37, 899)]
        return train, val, None
    kind, between, coeffs = SYNTHETIC[name]
    truth = json.loads((DATA / "lono" / "truth.json").read_text())["truth"]
    gen = with_effect(structure, kind, between, coeffs)
    theta = gen.vector(truth)
    train = synthetic_impacts(gen, theta, [150.0, 450.0], dof="NO", seed=11)
    val = synthetic_impacts(gen, theta, [50.0, 800.0], dof="NO", seed=12)
    return train, val, (kind, tuple(between))


def run(name: str, quiet: bool = True) -> dict[str, Any]:
    structure = duffing_without_cubic_damper() if name.startswith("duffing") \
        else Structure.from_file(MODEL)
    train, val, expected = load_case(name, structure)
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        diag = diagnose(structure, train, val, "auto",
                        progress=None if quiet else (lambda m: print("   ", m, flush=True)))
    elapsed = time.perf_counter() - t0
    out = diag.to_json()
    v = out["verdict"]
    got = (v["kind"], tuple(v["between"])) if v else None
    top = out["ranking"][0] if out["ranking"] else None
    shown = diag.verdict or (diag.ranking[0] if diag.ranking else None)
    return {
        "case": name,
        "expected": None if expected is None else f"{expected[0]} {'-'.join(expected[1])}",
        "verdict": None if got is None else f"{got[0]} {'-'.join(got[1])}",
        "correct": got == expected,
        "closure": None if shown is None else shown.closure,
        "gap_before": out["nominal"]["gap"],
        "gap_after": None if shown is None else shown.gap_after,
        "coefficients": None if top is None else (v or top)["coefficients"],
        "reason": out["rule"].get("reason"),
        "time_s": elapsed,
        "timing_s": out["timing_s"],
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default=",".join(CASES), help="comma-separated: " + ", ".join(CASES))
    ap.add_argument("--json", metavar="FILE", help="also write the rows as JSON")
    ap.add_argument("--verbose", action="store_true", help="progress of each diagnosis")
    args = ap.parse_args()
    rows = []
    head = (f"{'case':32s} {'expected':24s} {'verdict':24s} ok  {'closure':>8s} "
            f"{'gap_before':>10s} {'gap_after':>10s} {'time_s':>7s}")
    print(head)
    for name in args.cases.split(","):
        row = run(name.strip(), quiet=not args.verbose)
        rows.append(row)
        fmt = lambda x: "-" if x is None else f"{x:.4g}"  # noqa: E731
        print(f"{row['case']:32s} {str(row['expected']):24s} {str(row['verdict']):24s} "
              f"{'yes' if row['correct'] else 'NO ':3s} {fmt(row['closure']):>8s} "
              f"{fmt(row['gap_before']):>10s} {fmt(row['gap_after']):>10s} "
              f"{row['time_s']:7.1f}", flush=True)
        if args.verbose:
            print(f"    coefficients {row['coefficients']}; rule: {row['reason']}")
    n_ok = sum(r["correct"] for r in rows)
    print(f"{n_ok}/{len(rows)} verdicts as expected; total {sum(r['time_s'] for r in rows):.0f} s")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2, default=float) + "\n")
    return 0 if n_ok == len(rows) else 1


if __name__ == "__main__":
    sys.exit(main())
