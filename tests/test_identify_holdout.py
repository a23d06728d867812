"""`siva identify` without --val: a held-out part of the training data validates, and it says so."""
from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from siva_core import Recording
from siva_core._impl.commands import hold_out

ROOT = Path(__file__).resolve().parents[1]


def _rec(n: int, name: str) -> Recording:
    t = np.arange(n) * 1e-3
    return Recording(t, {"disp_x": np.sin(40 * t)}, name)


def test_hold_out_last_record_or_last_quarter():
    train, val, said = hold_out([_rec(500, "a.csv"), _rec(500, "b.csv"), _rec(500, "c.csv")])
    assert [r.name for r in train] == ["a.csv", "b.csv"] and [r.name for r in val] == ["c.csv"]
    assert "c.csv" in said
    train, val, said = hold_out([_rec(1000, "one.csv")])
    assert len(train[0]) == 750 and len(val[0]) == 250
    assert val[0].time[0] == pytest.approx(0.75) and "last 25%" in said
    with pytest.raises(ValueError, match="too few to hold out"):
        hold_out([_rec(100, "short.csv")])


def test_identify_with_one_record_and_no_val(shared_data, tmp_path):
    out = tmp_path / "r.json"
    proc = subprocess.run(
        [sys.executable, "-m", "siva_core.cli", "identify", str(ROOT / "examples/models/duffing.toml"),
         "--train", str(shared_data / "duffing" / "train_v5.csv"), "--epochs", "2",
         "--no-baselines", "--out", str(out)],
        capture_output=True, text=True, cwd=tmp_path, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert "no --val: validating on the last 25% of train_v5.csv" in proc.stderr
    assert re.search(r"epoch 1/2 \(50 %\), .* epochs/s, ETA \d+ s", proc.stderr), proc.stderr
    res = json.loads(out.read_text())
    assert any("held out automatically" in n for n in res["notes"])
    assert np.isfinite(res["parameters"]["k"]["best"])


def _impact(n: int, hits: list[int], fs: float = 1000.0, name: str = "hit.csv",
            noise: float = 1e-3) -> Recording:
    """A decaying 20 Hz response to each hit (a 5-sample pulse), with white noise."""
    rng = np.random.default_rng(0)
    t = np.arange(n) / fs
    f = np.zeros(n)
    a = np.zeros(n)
    for h in hits:
        f[h:h + 5] = 100.0 * np.sin(np.pi * np.arange(5) / 5)
        tt = t[h:] - t[h]
        a[h:] += np.exp(-1.5 * tt) * np.sin(2 * np.pi * 20 * tt)
    return Recording(t, {"acc_x": a + noise * rng.standard_normal(n),
                         "force_x": f + 0.01 * rng.standard_normal(n)}, name)


def test_hold_out_keeps_a_late_hit_in_training():
    """Issue 17 finding 1: the held-out part never takes the excitation away from training."""
    rec = _impact(4000, [3500])  # the hit is in the last 25 %
    train, val, said = hold_out([rec])
    assert len(train[0]) > 3505 and np.max(np.abs(train[0].channels["force_x"])) > 50
    assert np.max(np.abs(val[0].channels["force_x"])) < 1.0 and "after the hit" in said


def test_hold_out_splits_across_hits():
    rec = _impact(6000, [200, 3000])
    train, val, said = hold_out([rec])
    assert 200 < len(train[0]) < 3000 and "last of 2 hits" in said
    assert np.max(np.abs(val[0].channels["force_x"])) > 50  # the last hit validates


def test_hold_out_leaves_the_noise_tail_out_and_predicts_from_the_start():
    rec = _impact(8000, [100])  # decays into the noise after ~4 s
    train, val, said = hold_out([rec])
    stop = len(train[0]) + len(val[0])
    assert stop < 8000 and "noise level" in said
    whole, t_from = val[0].meta["held_out_of"]
    assert len(whole) == stop and t_from == pytest.approx(val[0].time[0])


@pytest.mark.slow
def test_identify_one_impact_record_without_val(tmp_path):
    """Issue 17 finding 1 end to end, small: one generated LO-NO-like impact, no --val, a
    couple of epochs: exits 0 (before: theta0 must be finite), no negative damping."""
    from siva_core import Structure, synthetic_impacts

    st = Structure.from_file(ROOT / "examples/models/lono.toml")
    rec = synthetic_impacts(st, [3.0, 21000.0, 0.6, 2200.0, 2.0e7, 2.0], [500.0], dof="NO",
                            fs=1024.0, duration=3.0, seed=5)[0]
    rec.write(tmp_path / "one.csv")
    out = tmp_path / "r.json"
    proc = subprocess.run(
        [sys.executable, "-m", "siva_core.cli", "identify", str(ROOT / "examples/models/lono.toml"),
         "--train", str(tmp_path / "one.csv"), "--epochs", "3", "--no-baselines",
         "--out", str(out)], capture_output=True, text=True, cwd=tmp_path, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    res = json.loads(out.read_text())
    lo = dict(zip(st.free, st.physical_bounds()[0]))
    for p, e in res["parameters"].items():
        assert np.isfinite(e["best"]) and e["best"] >= lo[p], (p, e["best"])
    assert res["assessment"]["status"] in ("accepted", "rejected", "untested")
    assert ("ACCEPTED" in proc.stderr or "REJECTED" in proc.stderr
            or "NOT VALIDATED" in proc.stderr)
