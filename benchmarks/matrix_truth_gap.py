"""What a *right* model can close on a confusion-matrix case (no diagnosis is run).

Why: a faint row's reason says "the gap is N x the noise floor", and a perfect fit would
close about 1 - 1/N of it.  That holds only when the truth itself leaves the noise on the
validation records.  This prints, per validation record, what the generator's truth leaves
(at its own values, and refitted on the train records from there: the best the right
candidate can do) and what it leaves on *noise-free* records under each reading of the
sampled hammer pulse (``set_measured_force_interp``): the part of the gap no model of the
structure can remove.  Measured at 0ea9808 on chain3 (docs/diagnosis.md, branch faint3):
the matrix generator drives its simulation with straight lines between the force samples,
the fits read them as "moments"; on the hardening chain that leaves 1.7e-4 NMSE on the
400 N validation record (5e-7 on the 40 N one), 2 x the noise, so the right candidate's
closure stops where the truth's does (0.61 against 0.64 on quadratic_spring:m1-m2:small).

Usage: ``python benchmarks/matrix_truth_gap.py CASE [CASE...] [--no-refit]``
(e.g. ``chain3:quadratic_spring:m1-m2:small``).
"""
from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import matrix  # noqa: E402
from siva_core import (choose_processing, output_error, refine,  # noqa: E402
                       set_measured_force_interp, synthetic_impacts, with_effect)


def truth_gaps(name: str, refit: bool = True) -> dict[str, Any]:
    """Per-record gaps of the truth on the case's records (see the module doc)."""
    mc = matrix.parse(name)
    st = mc.nominal()
    rig = matrix.STRUCTURES[mc.rig]
    gen = st
    for kind, place, size in mc._elements():
        gen = with_effect(gen, kind, matrix._between(place),
                          matrix.coefficients(mc.rig, kind, place, size))
    th = gen.vector(rig.truth())
    train, val = mc.records()
    proc = choose_processing("auto", [*train, *val], st.dofs)

    def per(theta: np.ndarray, recs: list, interp: str | None = None,
            model: Any = None) -> list[float]:
        kw = {"interp": interp} if interp else {}
        return [float(output_error(model or gen, theta[None], [r], proc, **kw)[0])
                for r in recs]

    clean = synthetic_impacts(gen, th, list(rig.val_peaks), dof=rig.force_dof, seed=12,
                              acc_noise=0.0, force_noise=0.0)
    out: dict[str, Any] = {
        "case": name, "val_peaks": list(rig.val_peaks),
        "nominal_at_truth": (per(st.vector(rig.truth()), val, model=st)
                             if mc._elements() else None),
        "truth": per(th, val),
        "noise_free_moments": per(th, clean, "moments"),
        "noise_free_linear": per(th, clean, "linear")}
    if refit:
        res = refine(gen, th, list(train), proc, max_nfev=40)
        out["truth_refitted"] = per(np.asarray(res.theta), val)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cases", nargs="+")
    ap.add_argument("--no-refit", action="store_true", help="skip the truth's refit (fast)")
    args = ap.parse_args()
    set_measured_force_interp("moments")
    def fmt(xs: list[float]) -> str:
        return "[" + ", ".join(f"{x:.3g}" for x in xs) + f"] mean {np.mean(xs):.3g}"

    for name in args.cases:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            row = truth_gaps(name, refit=not args.no_refit)
        print(f"{name} (validation peaks {row['val_peaks']} N)")
        for key in ("nominal_at_truth", "truth", "truth_refitted", "noise_free_moments",
                    "noise_free_linear"):
            if row.get(key) is not None:
                print(f"  {key:20s} {fmt(row[key])}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
