"""The fleet benchmark's own definitions (benchmarks/bench_fleet.py): what counts as a gap
between estimate updates, how /metrics is read, and the per-system memory slope.  The
benchmark itself needs minutes and a server; these are its pure parts."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
bench = pytest.importorskip("bench_fleet")


def test_gap_is_the_longest_time_between_published_snapshots():
    g = bench.GapTracker()
    for t in (100.0, 103.0, 103.0, 110.0, 111.0):   # a repeated time is not an update
        g.observe(t, "training")
    assert g.max_gap == pytest.approx(7.0)
    assert g.updates == 3
    g.close(150.0)                                   # no update since 111: a 39 s gap
    assert g.max_gap == pytest.approx(39.0)


def test_time_spent_idle_or_waiting_is_not_a_gap():
    g = bench.GapTracker()
    g.observe(100.0, "training")
    g.observe(105.0, "idle")                         # published on going idle
    g.observe(105.0, "idle")
    g.observe(400.0, "training")                     # woken by a record 295 s later
    g.observe(404.0, "training")
    assert g.max_gap == pytest.approx(5.0)
    g.observe(404.0, "waiting_for_validation")
    g.close(900.0)                                   # paused at the end: no open gap
    assert g.max_gap == pytest.approx(5.0)


def test_scrape_reads_epoch_and_snapshot_time_per_system():
    text = "\n".join([
        "# HELP siva_epoch trainer epoch of the latest snapshot",
        'siva_epoch{system="s000"} 412.0',
        'siva_epoch{system="s001"} 7.0',
        'siva_snapshot_timestamp_seconds{system="s000"} 1.7955e+09',
        'siva_parameter{system="s000",parameter="k1",source="best"} 19273.0',
    ])

    class Http:
        def get(self, path):
            assert path == "/metrics"
            return type("R", (), {"text": text})()

    out = bench.scrape(type("C", (), {"_http": Http()})())
    assert out == {"s000": {"siva_epoch": 412.0, "siva_snapshot_timestamp_seconds": 1.7955e9},
                   "s001": {"siva_epoch": 7.0}}


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
