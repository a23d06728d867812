"""`siva diagnose` on the two real data sets of ../shared/data/real (docs/diagnosis.md).

* Silverbox (electronic Duffing, V1 input "force", V2 output "displacement", 610.35 Hz):
  nominal model = examples/models/silverbox.toml *without* its cubic spring; train on two
  4096-sample windows of the estimation multisine, validate on a low- and a high-amplitude
  window of the "arrow" test.  Offsets of V1 and V2 removed (README.txt).
* Magneto-mechanical cantilever free decay (LabVIEW .lvm, Strain_0, 1 kHz): a linear
  mass-normalised oscillator (damper + spring) as the nominal model; train on the 1 s
  windows from 12.2 and 14.2 s of the decay, validate on those from 13.2 and 15.2 s.

Usage: ``python benchmarks/diagnose_real.py [--case silverbox|magneto] [--html DIR]``
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from siva_core import Recording, Structure, diagnose, html_report  # noqa: E402

DATA = Path(os.environ.get("SIVA_SHARED_DATA") or ROOT.parent / "shared" / "data") / "real"


def read_lvm(path: Path) -> dict[str, np.ndarray]:
    """Columns of a LabVIEW measurement file (text, tab-separated, header ending at the
    second ***End_of_Header***, then a line of column names)."""
    lines = path.read_text(errors="replace").splitlines()
    ends = [i for i, ln in enumerate(lines) if ln.startswith("***End_of_Header***")]
    if len(ends) < 2:
        raise ValueError(f"{path}: not a LabVIEW .lvm file (no second ***End_of_Header***)")
    names = lines[ends[1] + 1].split("\t")
    rows = [ln.split("\t") for ln in lines[ends[1] + 2:] if ln.strip()]
    out = {}
    for k, name in enumerate(names[:9]):
        out[name] = np.array([float(r[k]) if k < len(r) and r[k] else np.nan for r in rows])
    return out


def silverbox() -> tuple[Structure, list[Recording], list[Recording], str]:
    raw = np.loadtxt(DATA / "silverbox" / "SNLS80mV.csv", delimiter=",", skiprows=1,
                     usecols=(0, 1))
    u, y = raw[:, 0] - raw[:, 0].mean(), raw[:, 1] - raw[:, 1].mean()
    fs = 1e7 / 2 ** 14

    def rec(a: int, n: int = 4096) -> Recording:
        t = np.arange(n) / fs
        return Recording.from_columns({"time": t, "disp_y": y[a:a + n], "force_y": u[a:a + n]},
                                      ["y"], name=f"silverbox_{a}")

    spec = Structure.from_file(ROOT / "examples" / "models" / "silverbox.toml").spec
    spec["elements"] = [e for e in spec["elements"] if e["kind"] != "cubic_spring"]
    return (Structure.from_dict(spec), [rec(50000), rec(80000)], [rec(8000), rec(30000)],
            "cubic_spring y-ground (hardening), withheld from the model")


def magneto() -> tuple[Structure, list[Recording], list[Recording], str]:
    cols = read_lvm(DATA / "magnetomechanical_decay" / "decay_f_42p05_ampl_2p0_0.lvm")
    t, x = cols["X_Value"], cols["Strain_0"]
    ok = np.isfinite(t) & np.isfinite(x)
    t, x = t[ok], x[ok]
    x = (x - np.median(x[t > 25])) * 1e3  # strain -> milli-strain, offset from the tail
    fs = 1.0 / np.median(np.diff(t))

    def rec(t0: float, dur: float = 1.0) -> Recording:
        m = (t >= t0) & (t < t0 + dur)
        tt = np.arange(m.sum()) / fs
        return Recording.from_columns({"time": tt, "disp_x": x[m]}, ["x"], name=f"decay_{t0:g}s")

    spec = {"name": "cantilever", "dofs": ["x"], "mass": {"x": 1.0},
            "elements": [{"kind": "damper", "between": ["x", "ground"], "params": {"c": "c"}},
                         {"kind": "spring", "between": ["x", "ground"], "params": {"k": "k"}}]}
    return (Structure.from_dict(spec), [rec(12.2), rec(14.2)], [rec(13.2), rec(15.2)],
            "unknown; frequency falls 42 -> 36.7 Hz with amplitude (hardening)")


CASES = {"silverbox": silverbox, "magneto": magneto}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", default="silverbox,magneto")
    ap.add_argument("--html", metavar="DIR")
    args = ap.parse_args()
    for name in args.case.split(","):
        structure, train, val, expect = CASES[name]()
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            diag = diagnose(structure, train, val, "auto",
                            progress=lambda m: print("   ", m, flush=True))
        out = diag.to_json()
        print(f"== {name} ({expect}): {time.perf_counter() - t0:.0f} s")
        print(json.dumps({"verdicts": out["verdicts"], "reason": out["rule"].get("reason"),
                          "gap_before": out["nominal"]["gap"],
                          "ranking": [(c["kind"], c["between"], c["closure"], c["coefficients"])
                                      for c in out["ranking"]],
                          "signatures": out["signatures"].get("reading")}, indent=1, default=str))
        if args.html:
            Path(args.html).mkdir(parents=True, exist_ok=True)
            (Path(args.html) / f"{name}.html").write_text(html_report(diag))
    return 0


if __name__ == "__main__":
    sys.exit(main())
