"""The diagnosis's time budget (branch budget): an anytime search that stops opening work,
says so, and names only what was fitted and checked."""
from __future__ import annotations

import json
import warnings
from pathlib import Path

import pytest

from siva_core import DiagnoseSettings, Structure, diagnose, synthetic_impacts, with_effect
from siva_core._impl.diagnose.budget import Budget, clock_of

ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / "examples" / "models" / "lono.toml"
TRUTH = ROOT.parent / "shared" / "data" / "lono" / "truth.json"


def test_a_unit_is_opened_only_while_its_expected_cost_fits():
    b = Budget(10.0)
    b.start -= 6.0                                   # 6 s spent
    assert b.allows("pair", "a + b")                 # no pair measured yet
    b.took("pair", 3.0)
    assert b.allows("pair", "a + c")                 # 6 + 3 <= 10
    b.took("pair", 5.0)                              # the longest pair so far: 5 s
    assert not b.allows("pair", "b + c")             # 6 + 5 > 10
    assert b.run("pair", "c + d", lambda: 1) is None
    assert b.reached and b.reached_in == "pair: b + c"
    assert b.as_rule()["not_searched"] == {"pair": ["b + c", "c + d"]}
    assert "not searched: 2 pair units" in b.text()


def test_no_budget_allows_everything_and_a_helper_alone_has_none():
    b = Budget(None)
    b.took("stage", 1e9)
    assert b.allows("stage", "stage 2") and not b.reached and b.text() == ""
    assert clock_of(DiagnoseSettings()).seconds is None


def test_the_cli_budget_flag_reaches_the_settings():
    from siva_core._impl.diagnose.command import _settings
    from argparse import Namespace

    assert _settings(Namespace(budget=30.0)).budget_s == 30.0
    assert _settings(Namespace(budget=0.0)).budget_s is None
    assert _settings(Namespace()).budget_s == DiagnoseSettings().budget_s


@pytest.mark.skipif(not TRUTH.is_file(), reason="shared reference data not available")
def test_a_tiny_budget_stops_early_says_so_and_names_nothing_unchecked():
    """Two effects on LO-NO, 1.5 s records, a budget of 1 ms: the nominal fit and the
    screen run (they are never gated), no candidate fit is opened, so the first stage is
    cut and nothing is named (nothing was checked); the report and the reason say where
    it stopped and what was not searched.  ~10 s."""
    lono = Structure.from_file(MODEL)
    truth = json.loads(TRUTH.read_text())["truth"]
    gen = with_effect(with_effect(lono, "coulomb", ("NO", "ground"), {"fc": 0.2}),
                      "quadratic_damper", ("LO", "ground"), {"c2": 3.0})
    theta = gen.vector(truth)
    train = synthetic_impacts(gen, theta, [150.0, 450.0], dof="NO", duration=1.5, seed=11)
    val = synthetic_impacts(gen, theta, [50.0, 800.0], dof="NO", duration=1.5, seed=12)
    s = DiagnoseSettings(budget_s=1e-3, sensors=False, top_k=2,
                         effects=["coulomb", "quadratic_damper"])
    said: list[str] = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = diagnose(lono, train, val, "auto", settings=s, progress=said.append).to_json()
    budget = out["rule"]["budget"]
    assert budget["reached"] and budget["seconds"] == 1e-3 and budget["clock"] == "wall"
    assert budget["reached_in"].startswith("candidate fit: ")
    assert len(budget["not_searched"]["candidate fit"]) >= 2      # none of them fitted
    assert "time budget" in out["rule"]["reason"]
    assert "first stage was cut" in out["rule"]["reason"]
    assert any(m.startswith("time budget") for m in said)         # the progress says it
    assert out["verdict"] is None and out["verdicts"] == []
    assert out["stages"][0]["verdict"] is None and out["stages"][0]["ranking"] == []
