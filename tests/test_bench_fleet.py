"""The fleet benchmark's own definitions (benchmarks/bench_fleet.py): what counts as a gap
between estimate updates, and the per-system memory slope.  The
benchmark itself needs minutes and a server; these are its pure parts."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
bench = pytest.importorskip("bench_fleet")


def test_gap_is_the_longest_time_between_published_snapshots():
    times = [90.0, 100.0, 103.0, 110.0, 111.0]
    g = bench.snapshot_gaps(times, 95.0, 115.0, paused_at=[])
    assert g["max_gap"] == pytest.approx(10.0)       # 90 (before the window) -> 100
    assert g["updates"] == 4
    g = bench.snapshot_gaps(times, 95.0, 150.0, paused_at=[])
    assert g["max_gap"] == pytest.approx(39.0)       # nothing after 111: an open gap


def test_time_spent_idle_or_waiting_is_not_a_gap():
    times = [100.0, 105.0, 400.0, 404.0]             # idle from 105 until a record at ~398
    g = bench.snapshot_gaps(times, 99.0, 404.0, paused_at=[110.0, 200.0, 390.0])
    assert g["max_gap"] == pytest.approx(5.0)
    g = bench.snapshot_gaps(times, 99.0, 900.0, paused_at=[500.0])
    assert g["max_gap"] == pytest.approx(295.0)      # 105 -> 400 was not seen paused
    g = bench.snapshot_gaps([], 0.0, 60.0, paused_at=[])
    assert g == {"max_gap": 60.0, "updates": 0}      # never published: the whole window


def _result(ex, n, peak, pss):
    return {"executor": ex, "n_systems": n, "memory_mb": {"peak_rss": peak, "end_pss": pss}}


def test_marginal_memory_is_the_slope_between_smallest_and_largest_fleet():
    res = [_result("threads", 1, 560.0, 500.0), _result("threads", 64, 1820.0, 1700.0),
           _result("threads", 4, 600.0, 530.0), _result("ray", 1, 2000.0, 1500.0),
           {"executor": "ray", "n_systems": 64, "error": "no cluster"}]
    m = bench.marginal_memory(res)
    assert m["threads"]["rss_mb_per_system"] == pytest.approx(20.0)
    assert m["threads"]["pss_mb_per_system"] == pytest.approx(1200.0 / 63)
    assert "ray" not in m                            # one successful case: no slope


def _monitored(n, seen, fitted_ok, p95):
    return {"executor": "threads", "n_systems": 16, "records_sent": n, "records_acknowledged": n,
            "record_to_monitored_s": {"n": seen, "p50": 5.0, "p95": p95, "fitted_ok": fitted_ok}}


def test_monitoring_must_show_needs_every_record_fitted_and_p95_within_the_limit():
    verdict = bench.monitoring_verdict
    assert ": yes" in verdict(_monitored(90, 90, 90, 11.5))
    assert ": NO" in verdict(_monitored(90, 90, 90, 85.4))        # too slow
    assert ": NO" in verdict(_monitored(90, 89, 89, 11.5))        # one never monitored
    assert ": NO" in verdict(_monitored(90, 90, 88, 11.5))        # two fits failed
    assert ": NO" in verdict(_monitored(0, 0, 0, None))           # nothing measured
