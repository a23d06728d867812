"""``best``: the output-error refinement of the running ensemble, computed in the background.

1. On the REAL server: the paper's Duffing record (noise free) gives a ``best`` within
   0.5 % of the truth on every parameter, while reads keep answering fast throughout.
2. ``recommend_best`` (shared by ``Siva.fit`` and the worker) on its own.
3. The settings: ``SIVA_REFINE_EVERY_S`` (0 disables the refiner).
"""
from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np
import pytest

from service.settings import Settings

DUFFING_DIR = Path(os.environ.get("SIVA_SHARED_DATA")
                   or Path(__file__).resolve().parents[2].parent / "shared" / "data") / "duffing"


def _truth() -> dict[str, float]:
    path = DUFFING_DIR / "truth.json"
    if not path.exists():
        pytest.skip(f"shared data not found: {path}")
    return json.loads(path.read_text())["truth"]


@pytest.fixture(scope="module")
def srv(make_server):
    return make_server(env={"SIVA_REFINE_EVERY_S": "2", "SIVA_SNAPSHOT_EVERY": "2"})


@pytest.mark.heavy
def test_best_on_duffing_within_half_a_percent(srv, spec_of, duffing):
    truth = _truth()
    t_start = time.monotonic()
    with srv.client(timeout=10) as c:
        r = c.put("/v1/systems/duffing", json=spec_of("duffing"))
        assert r.status_code in (200, 201), r.text
        for f, role in (("train_v5.csv", "train"), ("val_v3.csv", "validation")):
            r = c.post(f"/v1/systems/duffing/recordings?role={role}&name={f}",
                       content=duffing(f), headers={"content-type": "text/csv"})
            assert r.status_code == 202, r.text
        latencies: list[float] = []
        bests: list[dict] = []

        def read() -> dict:
            t0 = time.perf_counter()
            r = c.get("/v1/systems/duffing/estimate")
            latencies.append(time.perf_counter() - t0)
            assert r.status_code == 200, r.text
            return r.json()

        est = read()
        assert est.get("best") is None  # nothing refined yet
        deadline = time.monotonic() + 75
        while time.monotonic() < deadline:
            est = read()
            if est.get("best") is not None:
                break
            time.sleep(0.2)
        else:
            raise AssertionError(f"no best after 75 s; last estimate: "
                                 f"{ {k: est.get(k) for k in ('epoch', 'state', 'error')} }\n"
                                 f"{srv.log_tail()}")
        t_first = time.monotonic() - t_start
        bests.append(est["best"])
        # keep reading while the per-record fits of the two records update it
        until = time.monotonic() + 6
        while time.monotonic() < until:
            e = read()
            if e["best"]["time"] not in [b["time"] for b in bests]:
                bests.append(e["best"])
            time.sleep(0.1)
    best = est["best"]  # the first seen: recommend_best, or already a per-record fit's
    assert set(best) >= {"parameters", "epoch", "n_records", "time"}
    # (a per-record fit can replace the first best between two reads 0.2 s apart)
    assert best["source"] in ("recommend_best", "records"), best["source"]
    if best["source"] == "recommend_best":
        assert best["n_records"] == 1 and best["refined"] is True
        assert best["output_error"] is not None and best["output_error"] < 1e-6
    # the headline is best from then on; the ensemble stays under its own key
    assert est["estimate_source"] == "best" and est["converged"]
    # (best starts from the samples since convergence; then the output-error phase restarts
    # the ensemble at its anchor, so it may be the generator's spread, provisional, for now)
    assert est["ensemble_source"] in ("approach_II", "generator")
    if est["ensemble_state"] != "final":
        assert all("ci95" not in s for s in est["ensemble"].values())
    assert {p: s["mean"] for p, s in est["parameters"].items()} == \
        {p: b["value"] for p, b in best["parameters"].items()}
    for p, true in truth.items():
        b = best["parameters"][p]
        assert b["value"] == pytest.approx(true, rel=0.005), (p, b)
        assert b["std"] is not None and b["std"] >= 0
        assert b["ci95"][0] <= b["value"] <= b["ci95"][1]
    # reads kept answering while training and refining ran (the first ones included)
    assert max(latencies) < 1.0, sorted(latencies)[-5:]
    assert bests[-1]["source"] == "records", \
        "expected the per-record fits to update best while reading"
    for p, true in truth.items():
        assert bests[-1]["parameters"][p]["value"] == pytest.approx(true, rel=0.005), p
    assert t_first < 80
    # on unchanged data the refinement is not repeated
    assert srv.log_text().count("duffing: best from") == 1
    print(f"\nfirst best after {t_first:.1f} s; {len(latencies)} reads, max "
          f"{max(latencies) * 1e3:.0f} ms; best/truth - 1: "
          + ", ".join(f"{p}={best['parameters'][p]['value'] / t - 1:+.2e}"
                      for p, t in truth.items()))


# --------------------------------------------------------------------------- recommend_best
@pytest.fixture(scope="module")
def duffing_problem(spec_of):
    from siva_core import Recording, Structure

    from service.storage.uploads import processing_for

    st = Structure.from_dict(spec_of("duffing"))
    path = DUFFING_DIR / "train_v5.csv"
    if not path.exists():
        pytest.skip(f"shared data not found: {path}")
    rec = Recording.read(path.read_bytes(), st.dofs, name="train_v5", fmt="csv")
    truth = np.array([_truth()[p] for p in st.free])
    return st, rec, processing_for([rec], st.dofs), truth


def test_recommend_best_refines_the_approach_III_winner(duffing_problem):
    from siva_core import displacement_mse, output_error, recommend_best

    st, rec, proc, truth = duffing_problem
    rng = np.random.default_rng(1)
    cand = truth * (1 + 0.05 * rng.standard_normal((40, len(truth))))
    res = recommend_best(st, cand, [rec], proc)
    # Approach III: the candidate with the smallest displacement MSE
    mse = displacement_mse(st, cand, [rec], proc)
    np.testing.assert_array_equal(res.theta_III, cand[int(np.argmin(mse))])
    # best: the refinement from it, accepted (lower output error), near the truth
    assert res.refined and res.std is not None and res.note is None
    np.testing.assert_allclose(res.theta, truth, rtol=1e-4)
    oe = output_error(st, np.stack([res.theta_III, res.theta]), [rec], proc)
    assert res.output_error == pytest.approx(oe[1]) and oe[1] <= oe[0]
    theta, std, note = res  # the (theta, std, note) form
    assert theta is res.theta and std is res.std and note is None
    assert set(res.timing_s) == {"approach_III", "refine"}
    # inputs untouched
    assert np.all(np.isfinite(cand))


def test_recommend_best_without_refinement_is_approach_III(duffing_problem):
    from siva_core import recommend_best

    st, rec, proc, truth = duffing_problem
    cand = np.stack([truth * 1.2, truth * 1.01, truth * 0.8])
    theta, std, note = recommend_best(st, cand, [rec], proc, refine=False)
    np.testing.assert_array_equal(theta, cand[1])
    assert std is None and note is None
    with pytest.raises(ValueError):
        recommend_best(st, np.empty((0, len(truth))), [rec], proc)


# --------------------------------------------------------------------------- settings
def test_refine_settings(tmp_path):
    s = Settings.from_env({"SIVA_REFINE_EVERY_S": "0", "SIVA_REFINE_MAX_RECORDS": "2"},
                          data_dir=tmp_path)
    assert s.refine_every_s == 0 and s.refine_max_records == 2
    assert Settings(data_dir=tmp_path).refine_every_s == 60.0
    with pytest.raises(ValueError):
        Settings(data_dir=tmp_path, refine_every_s=-1)
    with pytest.raises(ValueError):
        Settings(data_dir=tmp_path, refine_max_records=0)
    from siva_core import Structure

    from service.storage.store import Store
    from service.trainer import SystemWorker

    spec = {"name": "lin", "dofs": ["x"], "mass": {"x": 0.05},
            "elements": [{"kind": "spring", "between": ["x", "ground"], "params": {"k": "k"}}]}
    st = Structure.from_dict(spec)
    off = SystemWorker("lin", st, Store(tmp_path), s)
    on = SystemWorker("lin", st, Store(tmp_path), Settings(data_dir=tmp_path))
    assert off._refiner is None and on._refiner is not None
    assert off.snapshot().best is None
