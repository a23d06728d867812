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
