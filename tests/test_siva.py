"""SIVA end to end on the paper's cases, and the `siva identify` command."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from siva_core import Recording, Siva, Structure

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
MODELS = ROOT / "examples" / "models"

# Table 1 of the paper: displacement MSE [mm^2] of SIVA's approaches on train_v5
PAPER_MSE = {"approach_I": 0.2835, "approach_II": 3.262e-3, "approach_III": 1.100e-4}


def _fit(model: str, train: list[Path], val: list[Path], **kw) -> tuple[Structure, Siva]:
    st = Structure.from_file(MODELS / model)
    read = lambda ps: [Recording.read(p, st.dofs) for p in ps]
    return st, Siva(st, progress=None, **kw).fit(read(train), read(val))


@pytest.fixture(scope="module")
def duffing_fit():
    d = DATA / "duffing"
    return _fit("duffing.toml", [d / "train_v5.csv"], [d / "val_v3.csv", d / "val_v8.csv"])


@pytest.mark.heavy
def test_duffing_every_approach_beats_table_1(duffing_fit):
    _, est = duffing_fit
    mse = est.result_.metrics["train"]
    for approach, limit in PAPER_MSE.items():
        assert mse[approach]["disp_mse_mm2"] <= limit, (approach, mse[approach])
    assert est.result_.converged_epoch is not None


@pytest.mark.heavy
def test_duffing_best_within_half_percent(duffing_fit):
    st, est = duffing_fit
    truth = json.loads((DATA / "duffing" / "truth.json").read_text())["truth"]
    out = est.result_.to_json()["parameters"]
    for p, exact in truth.items():
        assert out[p]["best"] == pytest.approx(exact, rel=5e-3), p
        lo, hi = out[p]["approach_II"]["ci95"]
        assert lo < out[p]["approach_II"]["mean"] < hi
        assert out[p]["approach_II"]["ess"] > 1


@pytest.mark.heavy
def test_duffing_validation_and_discriminator_reported(duffing_fit):
    _, est = duffing_fit
    res = est.result_
    assert set(res.metrics["validation"]) >= {"approach_I", "approach_II", "approach_III", "best"}
    # the fitted model also reproduces the held-out records (v0 = 3 and 8 m/s)
    assert res.metrics["validation"]["best"]["disp_mse_mm2"] < PAPER_MSE["approach_III"]
    disc = res.discriminator
    assert set(disc["records"]) == {"val_v3.csv", "val_v8.csv"}
    assert disc["ln4_distance"] < 0.05
    assert {"least_squares", "sindy"} <= set(res.baselines)


@pytest.mark.heavy
def test_lono_as_measured_best_within_tolerance():
    d = DATA / "lono"
    st, est = _fit("lono.toml", [d / "impact_530N.csv"], [d / "impact_37N.csv", d / "impact_899N.csv"])
    truth = json.loads((d / "truth.json").read_text())["truth"]
    out = est.result_.to_json()["parameters"]
    for p, exact in truth.items():
        tol = 0.10 if p in ("b1", "b2") else 0.03
        assert out[p]["best"] == pytest.approx(exact, rel=tol), (p, out[p]["best"], exact)
        lo, hi = out[p]["best_ci95"]
        assert lo < exact < hi, (p, lo, exact, hi)  # measured: the truth lies inside every CI
    # SIVA itself (the output-error phase) is unbiased too, with intervals that cover
    covered = 0
    for p, exact in truth.items():
        tol = 0.10 if p in ("b1", "b2") else 0.03
        assert out[p]["approach_II"]["mean"] == pytest.approx(exact, rel=tol), (p, out[p])
        lo, hi = out[p]["approach_II"]["ci95"]
        covered += lo < exact < hi
    assert covered >= 5, {p: out[p]["approach_II"] for p in truth}
    # the equation-error ensemble it started from stays visible under its own key
    assert set(out["alpha"]["approach_II_equation_error"]) >= {"mean", "std", "ci95"}
    # the held-out test accepts the right model for both estimates, on both records
    val = est.result_.metrics["validation_test"]
    for key in ("approach_II", "best"):
        assert val[key]["accepted"] and val[key]["statistic"] < 1.5, val[key]
        assert set(val[key]["records"]) == {"impact_37N.csv", "impact_899N.csv"}


def _siva(*args: str, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "siva_cli", *args], capture_output=True,
                          text=True, cwd=ROOT, timeout=600, **kw)


def test_identify_cli_writes_contract_json(tmp_path):
    d = DATA / "duffing"
    out = tmp_path / "r.json"
    proc = _siva("identify", str(MODELS / "duffing.toml"), "--train", str(d / "train_v5.csv"),
                 "--val", str(d / "val_v3.csv"), "--epochs", "30", "--out", str(out),
                 "--no-baselines")
    assert proc.returncode == 0, proc.stderr
    assert "epoch" in proc.stderr  # progress is shown
    res = json.loads(out.read_text())
    assert set(res) >= {"parameters", "metrics", "discriminator", "timing_s"}
    for p in ("b", "b_nl", "k", "k_nl"):
        entry = res["parameters"][p]
        assert set(entry) >= {"approach_I", "approach_II", "approach_III", "best"}
        for a in ("approach_I", "approach_II"):
            assert set(entry[a]) >= {"mean", "std", "ci95"} and len(entry[a]["ci95"]) == 2
        assert np.isfinite(entry["best"])
    assert res["timing_s"]["total"] > 0


@pytest.mark.parametrize("bad, expect", [
    ("spec", "elements[0].kind: unknown element kind 'sprung'"),
    ("csv", "column 'acc_x', row 3"),
])
def test_identify_cli_rejects_bad_input_clearly(tmp_path, bad, expect):
    spec = MODELS / "duffing.toml"
    rec = DATA / "duffing" / "train_v5.csv"
    if bad == "spec":
        spec = tmp_path / "bad.toml"
        spec.write_text((MODELS / "duffing.toml").read_text().replace('"damper"', '"sprung"', 1))
    else:
        rec = tmp_path / "bad.csv"
        rec.write_text("time,disp_x,vel_x,acc_x\n" + "".join(
            f"{i * 1e-3},{0.0},{0.0},{'nan' if i == 1 else 0.0}\n" for i in range(40)))
    proc = _siva("identify", str(spec), "--train", str(rec), "--val", str(rec), "--epochs", "2")
    assert proc.returncode == 2
    assert expect in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr
