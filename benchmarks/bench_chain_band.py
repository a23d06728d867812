"""Does the band ``Processing.auto`` picks per record make chain3_end_1k's c3 interval
narrow? (issue 20, docs/perf.md 6.7 "What makes c3's interval narrow").

For each development seed, the benchmark's training record (``bench_chain_bias``: same
amplitude, noise draws, hit phase) is refined from the truth as ``best`` refines (force
multiplier and kick fitted, ``best``'s block-bootstrap se) through

* ``auto``: the chain ``Processing.auto`` chooses from that noisy record (as ``Siva`` does);
* ``fixed-noisy``: one chain for every seed, the one auto chooses on the first seed's noisy
  record (same kind of band, held fixed);
* ``fixed-clean``: one chain for every seed, the one auto chooses on the first seed's
  noise-free record.

Printed per variant and parameter: mean and sd of the error over the seeds, the RMS
reported se, and sd(error)/rms(se) (1 = the se is right); per seed the chosen band.  If the
band's variation across noise draws matters, ``auto``'s sd is larger than ``fixed-noisy``'s.

    OMP_NUM_THREADS=1 nice -n 10 python benchmarks/bench_chain_band.py [--seeds 11150:11170]
        [--variant auto --variant fixed-noisy ...] [--out results.json]
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_chain_bias import training_record  # noqa: E402

from siva_core import choose_processing, refine  # noqa: E402


def band(proc: Any) -> str:
    """A short description of a chain's band (what auto varies)."""
    return (f"bp={tuple(round(float(x), 2) for x in proc.bandpass) if proc.bandpass else None} "
            f"hp={proc.highpass and round(float(proc.highpass), 2)} "
            f"notch={list(proc.notch or [])} dec={proc.decimate_to} trim={proc.trim}")


def fit(case: Any, rec: Any, truth: dict[str, float], proc: Any
        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(relative error, relative bootstrap se, relative Gauss-Newton se) of ``refine`` from
    the truth through ``proc``."""
    st = case.structure()
    th = st.vector(truth)
    res = refine(st, th, [rec], proc, fit_force_scale=True, uncertainty="bootstrap")
    return res.theta / th - 1, res.std / np.abs(th), res.std_gauss_newton / np.abs(th)


def compare(path: Path, rows: list[dict], names: list[str]) -> None:
    """The full fits' error / se (Approach II, ``best``) against the refit from the truth's
    on the same training records: sd of each and their correlation, per parameter."""
    full = {r["seed"]: r for r in json.loads(path.read_text())["runs"]}
    mine = [r for r in rows if r["stream"] == 0 and r["seed"] in full]
    if not mine:
        return
    zr = np.array([np.array(r["rel_err"]) / r["rel_se"] for r in mine])
    for key in ("approach_II", "best"):
        zf = np.array([np.array(full[r["seed"]][key]["rel_err"]) / full[r["seed"]][key]["rel_se"]
                       for r in mine])
        for i, n in enumerate(names):
            print(f"  vs {key:11s} {n:4s} ({len(mine)} seeds): sd(z) full {zf[:, i].std(ddof=1):.2f}"
                  f" refit {zr[:, i].std(ddof=1):.2f}  mean z full {zf[:, i].mean():+.2f} refit "
                  f"{zr[:, i].mean():+.2f}  corr {np.corrcoef(zf[:, i], zr[:, i])[0, 1]:+.2f}"
                  f"  sd(z_full - z_refit) {(zf[:, i] - zr[:, i]).std(ddof=1):.2f}", flush=True)


#: --sources -> training_record keywords
SOURCES: dict[str, dict[str, Any]] = {
    "all": {}, "acc": dict(force=False, hum=False), "force": dict(acc=False, hum=False),
    "no-hum": dict(hum=False)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="11150:11170", help="first:stop (development seeds)")
    ap.add_argument("--variant", action="append",
                    choices=["auto", "fixed-noisy", "fixed-clean"])
    ap.add_argument("--draws", type=int, default=1,
                    help="noise draws per seed: the training record, then streams [seed, k]")
    ap.add_argument("--sources", default="all", choices=list(SOURCES),
                    help="which noise sources the records carry")
    ap.add_argument("--out", type=Path, default=None, help="per-seed rows (JSON)")
    ap.add_argument("--compare", type=Path, default=None,
                    help="a bench_coverage partial JSON: its full-fit errors on the same seeds")
    a = ap.parse_args(argv)
    src = SOURCES[a.sources]
    lo, hi = (int(x) for x in a.seeds.split(":"))
    case0, rec0, _ = training_record(lo)
    dofs = case0.structure().dofs
    fixed = {"fixed-noisy": choose_processing("auto", [rec0], dofs),
             "fixed-clean": choose_processing("auto", [training_record(lo, noise=0.0)[1]], dofs)}
    names = case0.structure().free
    out: dict[str, Any] = {}
    for v in a.variant or ["auto", "fixed-noisy", "fixed-clean"]:
        if v in fixed:
            print(f"{v}: {band(fixed[v])}", flush=True)
        rows = []
        for s in range(lo, hi):
            for k in range(a.draws):
                case, rec, th = training_record(s, stream=k, **src)
                proc = fixed.get(v) or choose_processing("auto", [rec], dofs)
                e, se, gn = fit(case, rec, th, proc)
                rows.append({"seed": s, "stream": k, "band": band(proc), "rel_err": e.tolist(),
                             "rel_se": se.tolist(), "rel_se_gn": gn.tolist()})
                print(f"  {v} {s}/{k} {band(proc)} c1 {100*e[1]:+.3f}/{100*se[1]:.3f} "
                      f"c3 {100*e[5]:+.3f}/{100*se[5]:.3f}", flush=True)
        E = 100 * np.array([r["rel_err"] for r in rows])
        S = 100 * np.array([r["rel_se"] for r in rows])
        G = 100 * np.array([r["rel_se_gn"] for r in rows])
        rms, rms_gn = np.sqrt((S ** 2).mean(0)), np.sqrt((G ** 2).mean(0))
        sd = E.std(0, ddof=1)
        cov = (np.abs(E) <= 1.96 * S).mean(0)
        print(f"{v} {a.sources}: {len(rows)} records; sd(z) +- {1 / np.sqrt(2 * (len(rows) - 1)):.2f}")
        for i, n in enumerate(names):
            print(f"{v:12s} {n:4s} mean {E[:, i].mean():+.3f} sd {sd[i]:.3f} rms se {rms[i]:.3f} "
                  f"(GN {rms_gn[i]:.3f}) sd/se {sd[i] / rms[i]:.2f} "
                  f"sd(z) {(E[:, i] / S[:, i]).std(ddof=1):.2f} "
                  f"(GN {(E[:, i] / G[:, i]).std(ddof=1):.2f}) covers {100 * cov[i]:.0f} %",
                  flush=True)
        if a.compare:
            compare(a.compare, rows, names)
        C = np.corrcoef(E.T)
        print(f"{v:12s} corr(c1, c3) {C[1, 5]:+.2f}  corr(c2, c3) {C[3, 5]:+.2f}", flush=True)
        out[v] = rows
        if a.out:
            a.out.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
