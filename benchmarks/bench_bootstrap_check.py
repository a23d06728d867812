"""Is ``refine``'s block-bootstrap standard error biased low? (issue 20, docs/perf.md 6.8).

Each draw is a coverage case's training record (``case.records(1, rng)``, rng =
``default_rng(seed)`` for stream 0, ``default_rng([seed, k])`` for stream k: draws no
coverage run makes), refined from the truth as ``best`` refines (force multiplier and kick
fitted, ``uncertainty="bootstrap"``).  From the public result (``jac``, ``residuals``,
``dtheta_dx``, ``block_length``) the script recomputes the moving-block pairs bootstrap
and variants of it with its own code (only the public API):

* ``reported``: ``res.std`` (the wider of the block and the parametric bootstrap);
* ``MBB L`` / ``2L`` / ``4L``: the pairs moving-block bootstrap at the rule's block length
  and longer blocks;
* ``CBB L``: circular blocks (every time equally likely: no lighter record ends);
* ``CBB PW``: circular blocks at the Politis & White (2004) / Patton et al. (2009) automatic
  length, computed on each parameter's influence series (the largest over the parameters);
* ``lin MBB L``: the block bootstrap of the linearised step with the Jacobian held fixed.

Printed per variant and parameter: sd(z) with z = error / se (1.00 when the se is right;
its own sampling error ~ 1/sqrt(2n)) and the coverage of +-1.96 se.

    OMP_NUM_THREADS=1 nice -n 10 python benchmarks/bench_bootstrap_check.py \
        --case chain3_end_1k --seeds 11400:11500 --draws 4
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cases import CASES  # noqa: E402

from siva_core import choose_processing, refine  # noqa: E402


def block_counts(T: int, L: int, n_boot: int, rng: np.random.Generator,
                 circular: bool = False) -> np.ndarray:
    """(n_boot, T) how often each time is drawn: ceil(T/L) blocks of L consecutive times,
    scaled to total T (as siva's moving-block bootstrap)."""
    k = math.ceil(T / L)
    starts = rng.integers(0, T if circular else T - L + 1, size=(n_boot, k))
    idx = (starts[:, :, None] + np.arange(L)).reshape(n_boot, -1) % T
    W = np.stack([np.bincount(i, minlength=T) for i in idx]).astype(float)
    return W * (T / W.sum(1, keepdims=True))


def pairs_var(J: np.ndarray, r: np.ndarray, T: int, w: int, L: int, circular: bool = False,
              n_boot: int = 400, seed: int = 0) -> np.ndarray:
    """Variance of the weighted linearised refits -(J^T W J)^-1 J^T W r (fitted variables)."""
    norm = np.linalg.norm(J, axis=0)
    norm[norm == 0] = 1.0
    Js = J / norm
    W = np.repeat(block_counts(T, L, n_boot, np.random.default_rng(seed), circular), w, axis=1)
    xb = np.stack([-np.linalg.lstsq(Js.T @ (Js * wb[:, None]), Js.T @ (wb * r), rcond=1e-12)[0]
                   for wb in W]) / norm
    return xb.var(0, ddof=1)


def influence(J: np.ndarray, r: np.ndarray, T: int, w: int) -> np.ndarray:
    """(T, n_x) each time's share of the linearised step (fitted variables)."""
    norm = np.linalg.norm(J, axis=0)
    norm[norm == 0] = 1.0
    Js = J / norm
    Ainv = np.linalg.pinv(Js.T @ Js, rcond=1e-13)
    return -((Js * r[:, None]).reshape(T, w, -1).sum(1) @ Ainv) / norm


def politis_white(x: np.ndarray) -> float:
    """Automatic circular-block length of one series (Politis & White 2004, corrected by
    Patton, Politis & White 2009): flat-top lag window, b = (2 G^2 / D)^(1/3) n^(1/3)."""
    n = len(x)
    x = x - x.mean()
    K = max(5, math.ceil(math.sqrt(math.log10(n))))
    mmax = math.ceil(math.sqrt(n)) + K
    acv = np.array([x[:n - k] @ x[k:] / n for k in range(mmax + 1)])
    if acv[0] <= 0:
        return 1.0
    rho = np.abs(acv[1:] / acv[0])
    c = 2 * math.sqrt(math.log10(n) / n)
    m = next((i for i in range(mmax - K + 1) if np.all(rho[i:i + K] < c)), mmax - K)
    M = min(2 * max(m, 1), mmax)
    k = np.arange(-M, M + 1)
    lam = np.where(np.abs(k / M) <= 0.5, 1.0, 2 * (1 - np.abs(k / M)))
    R = acv[np.abs(k)]
    g0, G = float((lam * R).sum()), float((lam * np.abs(k) * R).sum())
    return max(1.0, (2 * G ** 2 / ((4 / 3) * g0 ** 2)) ** (1 / 3) * n ** (1 / 3))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", default="chain3_end_1k", choices=sorted(CASES))
    ap.add_argument("--seeds", default="11400:11500", help="first:stop (development seeds)")
    ap.add_argument("--draws", type=int, default=1, help="noise draws per seed")
    a = ap.parse_args(argv)
    case = CASES[a.case]
    st = case.structure()
    th = case.theta()
    nf = len(th)
    lo, hi = (int(x) for x in a.seeds.split(":"))
    err, S = [], {}
    for s in range(lo, hi):
        for k in range(a.draws):
            rec = case.records(1, np.random.default_rng([s, k] if k else s), prefix=f"train{s}_")
            res = refine(st, th, rec, choose_processing("auto", rec, st.dofs),
                         fit_force_scale=True, uncertainty="bootstrap")
            w = sum(1 for c in rec[0].channels if c.split("_")[0] in ("acc", "vel", "disp"))
            J, r = np.asarray(res.jac, float), np.asarray(res.residuals, float)
            T, L, dth = r.size // w, int(res.block_length), np.asarray(res.dtheta_dx)[:nf]
            err.append(res.theta / th - 1)
            rel = lambda v: np.sqrt(v[:nf]) * np.abs(dth) / np.abs(th)  # noqa: E731
            psi = influence(J, r, T, w)
            Lpw = math.ceil(max(politis_white(psi[:, j]) for j in range(nf)))
            for name, v in (("reported", (res.std / np.abs(th)) ** 2),
                            ("MBB L", rel(pairs_var(J, r, T, w, L)) ** 2),
                            ("MBB 2L", rel(pairs_var(J, r, T, w, 2 * L)) ** 2),
                            ("MBB 4L", rel(pairs_var(J, r, T, w, 4 * L)) ** 2),
                            ("CBB L", rel(pairs_var(J, r, T, w, L, circular=True)) ** 2),
                            ("CBB PW", rel(pairs_var(J, r, T, w, Lpw, circular=True)) ** 2),
                            ("lin MBB L", rel(np.var(block_counts(T, L, 400, np.random.default_rng(0))
                                                     @ psi, 0, ddof=1)) ** 2)):
                S.setdefault(name, []).append(np.sqrt(v))
            S.setdefault("L rule / PW", []).append(np.array([L, Lpw]))
            print(f"  {s}/{k} L {L} PW {Lpw} z " + " ".join(
                f"{e / se:+.2f}" for e, se in zip(err[-1], S["reported"][-1])), flush=True)
    E = np.array(err)
    n = len(E)
    Ls = np.array(S.pop("L rule / PW"))
    print(f"{a.case}: {n} records, seeds {lo}-{hi - 1} x {a.draws} draws; sd(z) +- "
          f"{1 / math.sqrt(2 * max(n - 1, 1)):.3f}; block length rule median {np.median(Ls[:, 0]):.0f}, "
          f"Politis-White median {np.median(Ls[:, 1]):.0f}")
    print(f"{'variant':10s} " + " ".join(f"{p:>12s}" for p in st.free) + "   (sd(z) [covered %])")
    for name, V in S.items():
        z = E / np.array(V)
        print(f"{name:10s} " + " ".join(
            f"{z[:, j].std(ddof=1):6.2f} [{100 * np.mean(np.abs(z[:, j]) <= 1.96):3.0f}]"
            for j in range(nf)), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
