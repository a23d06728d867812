"""The simulation kernel of two source trees side by side: compile CPU and per-call CPU
(branch speed6: the serial kernel against the ``prange`` one).

Each tree runs in its own subprocess (``PYTHONPATH=<tree>``) with an empty kernel cache
(``SIVA_CACHE_DIR``), on structures a diagnosis meets (the LO-NO rig, a 3-DOF chain with a
coulomb, a 4-DOF frame with a clearance and a cubic damper, a 3-DOF chain with every
registered kind): the CPU of the first call (compiling the kernel), then the best of
three per-call CPU for one set (refine) and a batch of 16 (pilots, Jacobians), and the
accelerations, compared across the trees (largest difference relative to each channel's
peak).

Usage: ``OMP_WAIT_POLICY=PASSIVE python benchmarks/bench_kernels.py --before TREE
[--after TREE] [--json F]`` (``TREE``: e.g. a ``git archive`` of the old commit).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

KINDS = {"spring": {"k": 2000.0}, "damper": {"c": 0.5}, "cubic_spring": {"k3": 3e6},
         "quadratic_spring": {"k2": 1e4}, "cubic_damper": {"c3": 50.0},
         "quadratic_damper": {"c2": 5.0}, "coulomb": {"fc": 0.3},
         "clearance": {"k": 500.0, "gap": 2e-4}, "power_spring": {"alpha": 1e4, "beta": 0.6}}


def chain(n: int, frame: bool, extra: list[tuple[str, tuple[str, str]]]) -> dict[str, Any]:
    """Spec of an n-DOF chain (frame: every DOF grounded), linear springs and dampers free,
    plus ``extra`` (kind, place) elements with fixed coefficients."""
    dofs = [f"m{i + 1}" for i in range(n)]
    links = [(dofs[0], "ground")] + [(dofs[i], dofs[i + 1]) for i in range(n - 1)]
    if frame:
        links += [(d, "ground") for d in dofs[1:]]
    elements: list[dict[str, Any]] = []
    for a, b in links:
        elements.append({"kind": "spring", "between": [a, b], "params": {"k": f"k_{a}{b}"}})
        elements.append({"kind": "damper", "between": [a, b], "params": {"c": f"c_{a}{b}"}})
    for kind, place in extra:
        elements.append({"kind": kind, "between": list(place), "params": dict(KINDS[kind])})
    return {"name": f"bench_{n}", "dofs": dofs, "elements": elements,
            "mass": {d: 1.0 + 0.3 * i for i, d in enumerate(dofs)}}


CASES = {"lono": None,
         "chain3+coulomb": chain(3, False, [("coulomb", ("m2", "m3"))]),
         "frame4+clearance+cubic_damper": chain(4, True, [("clearance", ("m2", "ground")),
                                                          ("cubic_damper", ("m1", "m3"))]),
         "chain3+every kind": chain(3, False, [(k, ("m1", "m2")) for k in list(KINDS)[2:]])}


def run_here(out: Path) -> None:
    """Measure in this process (the tree on ``sys.path``); write rows and accelerations."""
    from siva_core import Structure, simulate

    rows, arrays = [], {}
    for name, spec in CASES.items():
        st = (Structure.from_file(ROOT / "examples" / "models" / "lono.toml") if spec is None
              else Structure.from_dict(spec))
        lono = {"k1": 5.0e4, "k2": 1.3e4, "b1": 2.0, "b2": 0.4, "alpha": 3e6, "beta": 0.7}
        base = np.array([lono.get(p, 4.0e4 if p.startswith("k") else 2.0) for p in st.free])
        T, m = 4096, 3
        t = np.arange(T) / 2048.0
        F = np.zeros((T, st.n_dof))
        F[100:108, 0] = 200.0 * np.sin(np.linspace(0, np.pi, 8))
        z = np.zeros(st.n_dof)
        rng = np.random.default_rng(0)
        row: dict[str, Any] = {"case": name}
        for B in (1, 16):
            th = base * rng.uniform(0.8, 1.2, size=(B, len(base)))
            c0 = time.process_time()
            sim = simulate(st, th, t, z, z, F, substeps=m, backend="numba")
            if B == 1:
                row["compile_cpu_s"] = round(time.process_time() - c0, 3)
            arrays[f"{name}:{B}"] = sim.a
            best = np.inf
            for _ in range(3):
                c0 = time.process_time()
                for _ in range(10):
                    simulate(st, th, t, z, z, F, substeps=m, backend="numba")
                best = min(best, (time.process_time() - c0) / 10)
            row[f"cpu_ms_per_call_B{B}"] = round(1e3 * best, 3)
        rows.append(row)
    np.savez(out.with_suffix(".npz"), **arrays)
    out.write_text(json.dumps(rows))


def run_tree(tree: Path, tmp: Path, tag: str) -> tuple[list[dict[str, Any]], Any]:
    out = tmp / f"{tag}.json"
    env = dict(os.environ, PYTHONPATH=str(tree), SIVA_CACHE_DIR=str(tmp / f"cache_{tag}"))
    subprocess.run([sys.executable, __file__, "--child", str(out)], env=env, check=True,
                   cwd=tree)
    return json.loads(out.read_text()), np.load(out.with_suffix(".npz"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", type=Path, help="the old source tree")
    ap.add_argument("--after", type=Path, default=ROOT, help="the new tree (default: this one)")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--child", type=Path, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        run_here(args.child)
        return
    if args.before is None:
        ap.error("--before TREE is required")
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        before, a_before = run_tree(args.before.resolve(), tmp, "before")
        after, a_after = run_tree(args.after.resolve(), tmp, "after")
        rows = []
        for rb, ra in zip(before, after):
            row: dict[str, Any] = {"case": ra["case"]}
            for key in ("compile_cpu_s", "cpu_ms_per_call_B1", "cpu_ms_per_call_B16"):
                row[key] = [rb[key], ra[key], round(ra[key] / max(rb[key], 1e-9), 3)]
            diffs = []
            for B in (1, 16):
                ref, new = a_before[f"{ra['case']}:{B}"], a_after[f"{ra['case']}:{B}"]
                peak = np.max(np.abs(ref), axis=-2, keepdims=True)
                diffs.append(float(np.max(np.abs(new - ref) / peak)))
            row["max_rel_diff_acc"] = max(diffs)
            rows.append(row)
            print(json.dumps(row), flush=True)
    print("columns: [before, after, after/before]")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
