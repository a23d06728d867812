"""Records of a structure the project has not seen, for ``service_lono.py``: a 3-DOF chain
(grounded spring + damper on A, springs/dampers A-B and B-C, a cubic spring B-C), hammer
impacts on C, accelerometers on every mass (0.3 % noise, 60 Hz hum), force 0.2 % noise.

    python benchmarks/service_chain3_data.py OUT_DIR [--seed 5]
    python benchmarks/service_lono.py --model OUT_DIR/chain3.toml --data OUT_DIR \
        --train impact_400N.csv --val impact_150N.csv impact_800N.csv
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

SPEC = """name = "chain3"
dofs = ["A", "B", "C"]

[mass]
A = 1.2
B = 0.9
C = 0.7

[[elements]]
kind = "damper"
between = ["A", "ground"]
params = { c = "cA" }

[[elements]]
kind = "spring"
between = ["A", "ground"]
params = { k = "kA" }

[[elements]]
kind = "damper"
between = ["A", "B"]
params = { c = "cAB" }

[[elements]]
kind = "spring"
between = ["A", "B"]
params = { k = "kAB" }

[[elements]]
kind = "spring"
between = ["B", "C"]
params = { k = "kBC" }

[[elements]]
kind = "cubic_spring"
between = ["B", "C"]
params = { k3 = "kBC3" }
"""
TRUTH = {"cA": 2.1, "kA": 15000.0, "cAB": 0.9, "kAB": 6000.0, "kBC": 3500.0, "kBC3": 4.0e7}


def main() -> None:
    import tomllib

    from siva_core import Structure, simulate

    from service.demo import half_sine, to_csv

    ap = argparse.ArgumentParser()
    ap.add_argument("out")
    ap.add_argument("--seed", type=int, default=5)
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "chain3.toml").write_text(SPEC)
    (out / "truth.json").write_text(json.dumps({"truth": TRUTH}))
    st = Structure.from_dict(tomllib.loads(SPEC))
    rng = np.random.default_rng(args.seed)
    fs, dur = 2048.0, 4.0
    t = np.arange(int(fs * dur) + 1) / fs
    for peak in (150, 400, 800):
        force = np.zeros((len(t), 3))
        force[:, 2] = half_sine(t, float(peak), 0.1, 0.005)
        z = np.zeros(3)
        acc = np.asarray(simulate(st, st.vector(TRUTH), t, z, z, force, substeps="auto").a)
        cols = {"time": t}
        for k, d in enumerate(st.dofs):
            a = acc[:, k]
            cols[f"acc_{d}"] = (a + 0.003 * np.max(np.abs(a)) * rng.standard_normal(len(t))
                                + 0.002 * np.max(np.abs(a)) * np.sin(2 * np.pi * 60 * t))
        cols["force_C"] = force[:, 2] + 0.002 * peak * rng.standard_normal(len(t))
        (out / f"impact_{peak}N.csv").write_bytes(to_csv(cols))
    print(out)


if __name__ == "__main__":
    main()
