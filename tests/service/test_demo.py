"""`siva serve --demo`: the simulated LO-NO rig streams, the service trains, drift is seen."""
from __future__ import annotations

import json
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
SHARED = ROOT.parent / "shared" / "data" / "lono"
sys.path.insert(0, str(ROOT))

from clients import SivaClient  # noqa: E402
from service.demo import (LONO_SPEC, LONO_TRUTH, DemoConfig, ServerThread, half_sine,  # noqa: E402
                          lono_structure, simulate_impact, start_demo, to_csv)
from service.settings import Settings  # noqa: E402


def test_embedded_rig_is_the_examples_model_and_the_shared_truth() -> None:
    with open(ROOT / "examples" / "models" / "lono.toml", "rb") as fh:
        assert tomllib.load(fh) == LONO_SPEC
    truth = SHARED / "truth.json"
    if truth.exists():
        assert json.loads(truth.read_text())["truth"] == LONO_TRUTH


def test_impact_record_looks_like_the_instrumented_rig() -> None:
    cfg = DemoConfig()
    rng = np.random.default_rng(0)
    cols = simulate_impact(LONO_TRUTH, 530.0, rng, cfg)
    assert list(cols) == ["time", "acc_LO", "acc_NO", "force_NO"]
    t = cols["time"]
    assert len(t) == int(cfg.duration_s * cfg.fs) + 1 and t[1] - t[0] == pytest.approx(1 / cfg.fs)
    f = cols["force_NO"]
    assert f.max() == pytest.approx(530.0, rel=0.02)
    pulse = t[np.abs(f) > 0.1 * 530]
    assert pulse[0] >= cfg.impact_at_s - 1e-9 and pulse[-1] <= cfg.impact_at_s + cfg.pulse_s
    clean = SHARED / "impact_530N_clean.csv"
    if clean.exists():  # same rig, same hammer: within the noise of the reference record
        ref = np.genfromtxt(clean, delimiter=",", names=True)
        n = len(t)
        for ch in ("acc_LO", "acc_NO"):
            err = np.sqrt(np.mean((cols[ch] - ref[ch][:n]) ** 2)) / np.abs(ref[ch][:n]).max()
            assert err < 0.015, (ch, err)
    # noise: 0.3 % of the peak, white, plus a 60 Hz hum; the force carries 0.2 %
    rng2 = np.random.default_rng(0)
    quiet = simulate_impact(LONO_TRUTH, 530.0, rng2, DemoConfig(acc_noise=0, hum_amplitude=0,
                                                                force_noise=0))
    noise = cols["acc_NO"] - quiet["acc_NO"]
    assert np.std(noise) == pytest.approx(0.003 * np.abs(quiet["acc_NO"]).max(), rel=0.1)
    hum_only = simulate_impact(LONO_TRUTH, 530.0, np.random.default_rng(0),
                               DemoConfig(acc_noise=0, force_noise=0))["acc_LO"]
    hum = hum_only - quiet["acc_LO"]
    basis = np.column_stack([np.sin(2 * np.pi * 60 * t), np.cos(2 * np.pi * 60 * t)])
    coef, *_ = np.linalg.lstsq(basis, hum, rcond=None)
    assert np.hypot(*coef) == pytest.approx(cfg.hum_amplitude, rel=1e-6)
    assert np.allclose(basis @ coef, hum, atol=1e-9)
    assert np.std(cols["force_NO"] - quiet["force_NO"]) == pytest.approx(0.002 * 530, rel=0.1)


def test_half_sine_pulse_shape() -> None:
    t = np.linspace(0, 0.2, 4001)
    p = half_sine(t, 100.0, 0.1, 6.2e-3)
    assert p.max() == pytest.approx(100.0, rel=1e-3)
    assert t[np.argmax(p)] == pytest.approx(0.1 + 3.1e-3, abs=1e-4)
    assert np.all(p[t < 0.1] == 0) and np.all(p[t > 0.1062] == 0)


def test_stiffness_drop_changes_the_response() -> None:
    s = lono_structure()
    a = simulate_impact(LONO_TRUTH, 400.0, np.random.default_rng(1), structure=s)
    b = simulate_impact({**LONO_TRUTH, "k1": 0.85 * LONO_TRUTH["k1"]}, 400.0,
                        np.random.default_rng(1), structure=s)
    fa = np.fft.rfftfreq(len(a["time"]), 1 / 2048)
    peak = lambda x: fa[np.argmax(np.abs(np.fft.rfft(x))[fa > 5]) + np.sum(fa <= 5)]
    assert peak(b["acc_LO"]) < peak(a["acc_LO"])  # a softer support lowers the LO mode
    assert to_csv(a).startswith(b"time,acc_LO,acc_NO,force_NO\n")


def test_demo_streams_into_a_running_service_and_it_trains(tmp_path: Path) -> None:
    """The default-suite check: a short demo against the real server (HTTP, client)."""
    cfg = DemoConfig(seed=3, n_records=3, interval_s=0.2, min_epochs_between=0,
                     duration_s=1.5, validation_every=2, system="demo")
    with ServerThread(Settings(data_dir=tmp_path, snapshot_every=1)) as url:
        streamer = start_demo(url, cfg=cfg)
        streamer.join(120)
        assert not streamer.is_alive() and streamer.error is None, streamer.error
        assert [e.role for e in streamer.events] == ["train", "validation", "train"]
        amps = [e.amplitude_n for e in streamer.events]
        assert all(30 <= a <= 900 for a in amps) and len(set(amps)) == 3
        with SivaClient(url) as c:
            deadline = time.monotonic() + 180
            while True:
                est = c.estimate("demo")
                if est["epoch"] >= 3 and sum(est["n_recordings"].values()) == 3:
                    break
                assert time.monotonic() < deadline, est
                time.sleep(0.2)
            recs = c.recordings("demo")["recordings"]
    assert len(recs) == 3 and all(r["columns"] == ["time", "acc_LO", "acc_NO", "force_NO"]
                                  for r in recs)
    assert set(est["parameters"]) == {"b1", "k1", "b2", "k2", "alpha", "beta"}
    logs = list((tmp_path / "logs" / "demo").glob("*.mcap"))
    assert len(logs) == 1


def run_demo_until_alarm(data_dir: Path, cfg: DemoConfig, timeout: float = 1500.0,
                         records_after_alarm: int = 6) -> dict:
    """The full demo; returns what a newcomer would see (used by the slow test and docs):
    the headline just before the drop, the first k1 alarm, and the headline
    ``records_after_alarm`` records after it."""
    settings = Settings(data_dir=data_dir)
    out: dict = {}
    t0 = time.monotonic()
    with ServerThread(settings) as url, SivaClient(url) as c:
        streamer = start_demo(url, cfg=cfg)
        try:
            while time.monotonic() - t0 < timeout:
                time.sleep(0.5)
                try:
                    drift = c.drift(cfg.system)
                    est = c.estimate(cfg.system)
                except Exception:  # noqa: BLE001 - not registered yet
                    continue
                if streamer.drop_index is None and est.get("estimate_source") == "best":
                    out["before"] = est
                alarms = [a for a in drift["alarms"] if a["parameter"] == cfg.drop_parameter]
                if alarms and "alarm" not in out:
                    out["alarm"] = alarms[0]
                    out["alarm_drift"] = drift
                if "alarm" in out and drift["processed_index"] >= (
                        out["alarm"]["raised_index"] + records_after_alarm):
                    break
                if not streamer.is_alive() and drift["processed_index"] >= len(streamer.events):
                    break
            out["estimate"] = c.estimate(cfg.system)
            out["drift"] = c.drift(cfg.system)
        finally:
            streamer.stop()
            streamer.join(60)
    out["events"] = streamer.events
    out["drop_index"] = streamer.drop_index
    out["error"] = streamer.error
    out["elapsed_s"] = time.monotonic() - t0
    if "alarm" in out:  # store indices are 1-based, one per record sent
        out["records_after_drop"] = out["alarm"]["raised_index"] - streamer.drop_index
    return out


@pytest.mark.slow
def test_full_demo_converges_then_alarms_on_the_stiffness_drop(tmp_path: Path) -> None:
    cfg = DemoConfig(seed=11, interval_s=0.5, n_records=60)
    res = run_demo_until_alarm(tmp_path, cfg)
    print("\ndemo:", {k: v for k, v in res.items()
                      if k not in ("events", "drift", "estimate", "before", "alarm_drift")})
    assert res["error"] is None
    assert res["drop_index"] is not None and res["drop_index"] >= cfg.drop_after
    assert res["drift"]["reference"] is not None
    # before the drop: the headline (best) within 3 % (stiffnesses, alpha, beta) and 10 %
    # (dampers) of the truth, intervals covering it; no alarm
    before = res["before"]
    for p, tol in (("k1", .03), ("k2", .03), ("alpha", .03), ("beta", .03), ("b1", .1),
                   ("b2", .1)):
        s = before["parameters"][p]
        assert abs(s["mean"] / LONO_TRUTH[p] - 1) < tol, (p, s)
        assert s["ci95"][0] <= LONO_TRUTH[p] <= s["ci95"][1], (p, s)
    first_alarm = min(a["raised_index"] for a in res["drift"]["alarm_history"])
    assert first_alarm > res["drop_index"], "alarm before the drop"
    # the drop: a k1 alarm within 8 records, naming no other parameter
    assert "alarm" in res, "no drift alarm after the stiffness drop"
    alarm = res["alarm"]
    assert alarm["direction"] == "decrease" and alarm["change_rel"] == pytest.approx(-0.15, abs=.02)
    assert 1 <= res["records_after_drop"] <= 8, res["records_after_drop"]
    assert alarm["change_point"]["record_index"] == res["drop_index"] + 1
    params = set(res["estimate"]["parameters"])
    assert {a["parameter"] for a in res["drift"]["alarms"]} & params == {"k1"}
    # after: the headline's k1 within 3 % of the new value, its interval covering it
    k1 = res["estimate"]["parameters"]["k1"]
    new = LONO_TRUTH["k1"] * (1 - cfg.drop)
    assert abs(k1["mean"] / new - 1) < 0.03 and k1["ci95"][0] <= new <= k1["ci95"][1], k1
