"""SIVA on the paper's two-degree-of-freedom LO-NO rig (Sec. 3.2, eq. 7, Table 2).

Trains on the 530 N impact, validates on 37 N and 899 N - the *measured-like* records
(accelerations with noise and 60 Hz hum, noisy force; never the ``*_clean`` files) - with
the processing chain chosen from the data ('auto').  Prints per parameter the reference
value (the paper's Table 2 Approach III), Approaches I / II / III and ``best`` with % errors
and 95 % intervals, and the displacement MSE [mm^2] next to the paper's Table 2.

    .venv/bin/python examples/lono.py [--report DIR] [--epochs N] [--preset paper]
"""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Sequence

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from duffing import (ROOT, SHORT, data_dir, finish, parser, pct, print_mse,  # noqa: E402
                     print_parameters, print_timing, run)

#: Table 2 of the paper: displacement MSE (x and y errors added) on the 530 N record
PAPER_TABLE2_MSE = {"approach_I": 10.703, "approach_II": 5.9052, "approach_III": 1.3934}
PAPER_TABLE2 = {"approach_I": {"b1": 3.7270, "b2": 0.75904, "k1": 18690, "k2": 1920.2,
                               "alpha": 2.5815e7, "beta": 2.0010},
                "approach_II": {"b1": 3.7751, "b2": 0.7751, "k1": 18883, "k2": 1933.8,
                                "alpha": 2.6805e7, "beta": 2.0012}}


def main(argv: Sequence[str] | None = None) -> int:
    args = parser(__doc__.splitlines()[0]).parse_args(argv)
    d = data_dir(args.data) / "lono"
    truth = json.loads((d / "truth.json").read_text())["truth"]
    est, train, val, wall = run(ROOT / "examples" / "models" / "lono.toml",
                                [d / "impact_530N.csv"],
                                [d / "impact_37N.csv", d / "impact_899N.csv"], args)
    res = est.result_
    print(f"processing chain: {est.processing_}")
    print_parameters(est, truth)
    print("\nThe paper's Table 2 (vs its Approach III = the reference here):")
    for a, vals in PAPER_TABLE2.items():
        print(f"  {SHORT[a]:<6}" + "  ".join(f"{p} {pct(v, truth[p]).strip()}"
                                             for p, v in vals.items()))
    # the paper adds the LO and NO errors (Sec. 3.2); the metrics average them
    from siva_core import displacement_mse

    ests = dict(res.estimates())
    for b, vals in res.baselines.items():
        try:
            ests[b] = est.structure.vector(vals)
        except KeyError:
            pass
    names = list(ests)
    mse_sum = displacement_mse(est.structure, np.stack([ests[n] for n in names]), train,
                               est.processing_, dof_reduce="sum") * 1e6
    extra = {n: {"value": float(v)} for n, v in zip(names, mse_sum)}
    print_mse(est, PAPER_TABLE2_MSE, extra, "train x+y (paper)")
    print_timing(est, wall)
    finish(est, train, val, truth, args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
