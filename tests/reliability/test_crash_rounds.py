"""kill -9 at random moments during concurrent uploads and log writes (crash_rounds.py):
no acknowledged recording is lost from the store or the log, and every log - after each
crash - replays exactly to the estimate the service last published."""
from __future__ import annotations

import os

import pytest
from crash_rounds import run

ROUNDS = int(os.environ.get("SIVA_CRASH_ROUNDS", "4"))
CLIENTS = int(os.environ.get("SIVA_CRASH_CLIENTS", "50"))


@pytest.mark.slow
def test_kill_9_rounds_lose_nothing_and_replay_exactly(tmp_path):
    res = run(ROUNDS, CLIENTS, tmp_path / "data", seed=7)
    print("\ncrash rounds:", {k: v for k, v in res.items() if k != "kill_after_s"})
    assert res["rounds"] == ROUNDS and res["acknowledged"] > 0
    assert res["five_xx"] == 0 and not res["server_logged_bug"]
    assert res["lost_from_store"] == 0, res
    assert res["lost_from_log"] == 0, res
    assert res["duplicate_mismatches"] == 0
    assert res["replay_errors"] == [], res["replay_errors"]
    assert res["replays_compared"] >= 3 and res["replay_mismatches"] == [], res
