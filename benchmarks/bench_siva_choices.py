"""The choices the paper leaves open, measured on short SIVA runs.

Each row trains :class:`~siva_core.SivaTrainer` with one ``SivaSettings`` field changed from
the project's defaults (``SivaSettings.fast()``: discriminator on (state, acceleration),
gamma 10, magnitude initialisation, lr 1e-3 then 1e-4 once converged):

* ``disc_input``: "state_acc" (D judges the acceleration at a measured state) vs "acc"
  (D sees accelerations alone, which a wrong model can match in histogram);
* ``gamma`` (eq. 4): 1, 10, 100 - the weight of the MSE term against the adversarial term;
* ``init``: "magnitude" (mantissa 1 at the order of magnitude) vs "ls" (start at the
  equation-error least-squares value);
* preset "fast" vs "paper" (the paper's Adam lr 1e-4 throughout), epochs capped.

Every run uses the same convergence rule and a harvest of ``--harvest`` epochs after it
(the last ``--harvest`` epochs when it does not converge within the cap).  Reported: epochs
to convergence, wall time, Approach II (harvest mean) % error per parameter, and the final
discriminator loss's distance from ln 4 on the validation records.

    .venv/bin/python benchmarks/bench_siva_choices.py [--system duffing|lono|both]
        [--max-epochs 400] [--paper-epochs 600] [--harvest 100] [--json out.json]
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

LN4 = float(np.log(4.0))

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from siva_core import (Recording, SivaSettings, SivaTrainer, Structure,  # noqa: E402
                       choose_processing)
from _common import data_dir  # noqa: E402

SYSTEMS = {
    "duffing": ("duffing.toml", "duffing", ["train_v5.csv"], ["val_v3.csv", "val_v8.csv"]),
    "lono": ("lono.toml", "lono", ["impact_530N.csv"], ["impact_37N.csv", "impact_899N.csv"]),
}
#: (label, preset, overrides of the preset)
VARIANTS: list[tuple[str, str, dict[str, Any]]] = [
    ("default (state_acc, g=10, magnitude)", "fast", {}),
    ("disc_input=acc", "fast", {"disc_input": "acc"}),
    ("gamma=1", "fast", {"gamma": 1.0}),
    ("gamma=100", "fast", {"gamma": 100.0}),
    ("init=ls", "fast", {"init": "ls"}),
    ("preset=paper (lr 1e-4)", "paper", {}),
]




@dataclass
class Row:
    system: str
    label: str
    converged_at: int | None
    epochs: int
    time_s: float
    err_pct: dict[str, float]
    d_loss: float
    ln4_distance: float
    d_loss_tail: float
    extra: dict[str, Any] = field(default_factory=dict)


def run_variant(st: Structure, train_states: list, val_states: list, truth: dict[str, float],
                system: str, label: str, preset: str, over: dict[str, Any], max_epochs: int,
                harvest: int, seed: int) -> Row:
    """Train one variant until converged + harvest (or the cap) and measure it."""
    make = SivaSettings.paper if preset == "paper" else SivaSettings.fast
    # the same convergence rule and harvest for all rows: only the studied choice differs
    settings = make(seed=seed, max_epochs=max_epochs, ensemble_epochs=harvest,
                    conv_min_epochs=40, **over)
    trainer = SivaTrainer(st, settings)
    t0 = time.perf_counter()
    trainer.set_data(train_states, val_states)
    while trainer.epoch < settings.max_epochs:
        trainer.run_epoch()
        if trainer.converged and len(trainer.ensemble) >= harvest:
            break
    elapsed = time.perf_counter() - t0
    if len(trainer.ensemble):
        samples = trainer.ensemble.samples
    else:
        samples = np.array(trainer.history["theta"][-harvest:])
    mean = samples.mean(axis=0)
    exact = st.vector(truth)
    err = 100.0 * (mean - exact) / np.abs(exact)
    disc = trainer.discriminator_scores()
    tail = float(np.mean(trainer.history["loss_d"][-20:]))
    return Row(system, label, trainer.monitor.converged_at, trainer.epoch, elapsed,
               dict(zip(st.free, map(float, err))), float(disc["loss_d"]),
               float(disc["ln4_distance"]), tail)


def print_table(rows: list[Row], names: list[str]) -> None:
    head = (f"{'variant':<38}{'conv@':>7}{'epochs':>8}{'time[s]':>9}"
            + "".join(f"{'II ' + p + ' %':>13}" for p in names)
            + f"{'|D-ln4|':>10}{'|tail-ln4|':>12}")
    print(head)
    print("-" * len(head))
    for r in rows:
        conv = "-" if r.converged_at is None else str(r.converged_at)
        print(f"{r.label:<38}{conv:>7}{r.epochs:>8}{r.time_s:>9.1f}"
              + "".join(f"{r.err_pct[p]:>+13.3f}" for p in names)
              + f"{r.ln4_distance:>10.2e}{abs(r.d_loss_tail - LN4):>12.2e}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--system", choices=["duffing", "lono", "both"], default="duffing")
    ap.add_argument("--max-epochs", type=int, default=400, help="cap for the fast-preset rows")
    ap.add_argument("--paper-epochs", type=int, default=600, help="cap for the paper-preset row")
    ap.add_argument("--harvest", type=int, default=100, help="Approach II epochs after convergence")
    ap.add_argument("--seed", type=int, default=42)
    ap.add_argument("--only", help="run only variants whose label contains this text")
    ap.add_argument("--json", metavar="FILE")
    args = ap.parse_args()

    systems = ["duffing", "lono"] if args.system == "both" else [args.system]
    all_rows: list[Row] = []
    t_all = time.perf_counter()
    for system in systems:
        model, sub, tr, va = SYSTEMS[system]
        d = data_dir() / sub
        truth = json.loads((d / "truth.json").read_text())["truth"]
        st = Structure.from_file(ROOT / "examples" / "models" / model)
        train = [Recording.read(d / f, st.dofs) for f in tr]
        val = [Recording.read(d / f, st.dofs) for f in va]
        proc = choose_processing("auto", [*train, *val], st.dofs)
        train_states = [proc.apply(r, st.dofs) for r in train]
        val_states = [proc.apply(r, st.dofs) for r in val]
        print(f"\n== {system}: train {tr}, validate {va}; {len(train_states[0])} training samples;"
              f" cap {args.max_epochs} epochs (paper row {args.paper_epochs}), harvest "
              f"{args.harvest}, seed {args.seed}", flush=True)
        rows = []
        for label, preset, over in VARIANTS:
            if args.only and args.only not in label:
                continue
            cap = args.paper_epochs if preset == "paper" else args.max_epochs
            row = run_variant(st, train_states, val_states, truth, system, label, preset, over,
                              cap, args.harvest, args.seed)
            rows.append(row)
            conv = "not converged" if row.converged_at is None else f"converged at {row.converged_at}"
            print(f"  {label}: {conv}, {row.epochs} epochs, {row.time_s:.1f} s", flush=True)
        print()
        print_table(rows, st.free)
        all_rows += rows
    print(f"\ntotal {time.perf_counter() - t_all:.0f} s.  conv@: epoch the convergence rule fired; "
          "II %: error of the harvest mean; |D-ln4|: final D loss on validation records vs ln 4; "
          "|tail-ln4|: mean D loss of the last 20 epochs (training batches) vs ln 4.")
    if args.json:
        Path(args.json).write_text(json.dumps([r.__dict__ for r in all_rows], indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
