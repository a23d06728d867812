"""Checks before any training (issue 17, findings 3, 4 and 6; must-show 4): a missing force,
wrong or mixed sampling rates, clipping and too-short records are refused by siva_core's
one preflight, from the command line with a message naming the file and the fix."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from siva_core import (PreflightError, Recording, Structure, check_recording, mode_frequencies,
                       preflight, synthetic_impacts)

ROOT = Path(__file__).resolve().parents[1]
# a generated LO-NO-like rig (not the shared reference values)
THETA = np.array([3.0, 21000.0, 0.6, 2200.0, 2.0e7, 2.0])


@pytest.fixture(scope="module")
def lono() -> Structure:
    return Structure.from_file(ROOT / "examples/models/lono.toml")


@pytest.fixture(scope="module")
def impact(lono) -> Recording:
    return synthetic_impacts(lono, THETA, [300.0], dof="NO", fs=2048.0, duration=3.0,
                             seed=7)[0]


@pytest.fixture(scope="module")
def nominal(lono) -> Structure:
    """The rig's spec with ``initial`` values (known modes)."""
    spec = dict(lono.spec)
    spec["parameters"] = {**spec.get("parameters", {}),
                          **{p: {**spec.get("parameters", {}).get(p, {}), "initial": float(v)}
                             for p, v in zip(lono.free, THETA)}}
    return Structure.from_dict(spec)


def _with(rec: Recording, **changes) -> Recording:
    chans = {k: v for k, v in rec.channels.items()}
    for k, v in changes.items():
        if v is None:
            chans.pop(k, None)
        else:
            chans[k] = v
    return Recording(rec.time.copy(), chans, rec.name, dict(rec.meta))


def _checks(problems) -> set[str]:
    return {p.check for p in problems}


def test_good_record_passes(lono, impact):
    assert [p for p in check_recording(lono, impact) if p.fatal] == []
    assert preflight(lono, [impact]).train[0] is impact


def test_missing_force_is_refused(lono, impact):
    rec = _with(impact, force_NO=None)
    problems = check_recording(lono, rec)
    assert "force" in _checks(problems)
    msg = next(p.message for p in problems if p.check == "force")
    assert rec.name in msg and "--map" in msg and "rises from rest" in msg


def test_forces_table_requires_its_column(lono, impact):
    spec = dict(lono.spec)
    spec["forces"] = {"NO": {"gain": 1.0}}
    forced = Structure.from_dict(spec)
    rec = _with(impact, force_NO=None)
    assert any(p.check == "force" and "force_NO" in p.message
               for p in check_recording(forced, rec))


def test_free_decay_without_force_passes(make_sdof, sdof_model):
    rec, _ = make_sdof()
    free = _with(rec, **{k: None for k in rec.channels if k.startswith("force_")})
    free = free.slice(int(0.2 * len(free)))  # starts moving: a free decay
    assert "force" not in _checks(check_recording(sdof_model, free))


def test_nyquist_against_the_spec_modes(nominal, impact):
    top = max(mode_frequencies(nominal, None))
    assert 15 < top < 30
    coarse = impact.slice(0, None)
    step = 64  # 2048 Hz -> 32 Hz: Nyquist 16 Hz, below the ~21 Hz mode
    coarse = Recording(impact.time[::step].copy(),
                       {k: v[::step].copy() for k, v in impact.channels.items()}, "coarse.csv")
    checks = _checks(check_recording(nominal, coarse))
    assert "nyquist" in checks
    mid = Recording(impact.time[::16].copy(),
                    {k: v[::16].copy() for k, v in impact.channels.items()}, "mid.csv")
    assert "samples_per_period" in _checks(check_recording(nominal, mid))  # 128 Hz: ~6/period


def test_coarse_sampling_refused_from_the_data_alone(lono, impact):
    coarse = Recording(impact.time[::64].copy(),
                       {k: v[::64].copy() for k, v in impact.channels.items()}, "coarse.csv")
    problems = check_recording(lono, coarse)  # no spec values: the data must tell
    assert _checks(problems) & {"pulse", "aliased", "force"}
    assert any("record faster" in p.message or "record at" in p.message for p in problems)


def test_mixed_rates_refused_or_resampled(lono, impact):
    other = Recording(impact.time[::2].copy(), {k: v[::2].copy() for k, v in
                                                impact.channels.items()}, "half.csv")
    with pytest.raises(PreflightError) as err:
        preflight(lono, [impact], [other])
    assert "mixed_rates" in _checks(err.value.problems)
    assert "half.csv" in str(err.value) and "--resample" in str(err.value)
    ok = preflight(lono, [impact], [other], resample=True)
    assert ok.train[0].fs == pytest.approx(ok.val[0].fs)
    assert any("resampled" in n for n in ok.notes)


def test_clipping_is_refused(lono, impact):
    a = impact.channels["acc_NO"]
    top = 0.5 * np.max(np.abs(a))
    problems = check_recording(lono, _with(impact, acc_NO=np.clip(a, -top, top)))
    assert "clipping" in _checks(problems)
    assert any("acc_NO" in p.message and "saturated" in p.message for p in problems)


def test_too_short_is_refused(nominal, lono, impact):
    short = impact.slice(0, int(0.25 * impact.fs))  # ~1.3 periods of the ~5 Hz mode
    problems = check_recording(nominal, short)
    assert "too_short" in _checks(problems)
    assert any("lowest mode" in p.message and "record for" in p.message for p in problems)
    assert "too_short" not in _checks(check_recording(nominal, impact))


@pytest.mark.parametrize("case", ["no_force", "mixed_rates", "wrong_rate"])
def test_cli_refuses_before_training(tmp_path, lono, impact, case):
    """Must-show 4 on the command line: exit 2, one message naming the file and the fix,
    and no training started (no epoch line)."""
    train = tmp_path / "train.csv"
    val = tmp_path / "val.csv"
    if case == "no_force":
        _with(impact, force_NO=None).write(train)
        impact.write(val)
    elif case == "mixed_rates":
        impact.write(train)
        Recording(impact.time[::2].copy(), {k: v[::2].copy() for k, v in
                                            impact.channels.items()}, "v").write(val)
    else:
        step = 64
        Recording(impact.time[::step].copy(), {k: v[::step].copy() for k, v in
                                               impact.channels.items()}, "t").write(train)
        Recording(impact.time[::step].copy(), {k: v[::step].copy() for k, v in
                                               impact.channels.items()}, "v").write(val)
    proc = subprocess.run([sys.executable, "-m", "siva_core.cli", "identify",
                           str(ROOT / "examples/models/lono.toml"), "--train", str(train),
                           "--val", str(val), "--epochs", "2", "--no-baselines"],
                          capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert proc.returncode == 2, proc.stderr
    assert "epoch" not in proc.stderr
    assert "train.csv" in proc.stderr or "val.csv" in proc.stderr
    assert any(w in proc.stderr for w in ("--map", "--resample", "record at", "record faster"))


def test_friction_near_nyquist_is_kept_but_an_unresolved_mode_refused(lono, impact):
    """Coulomb friction's jumps put strong broadband content up to Nyquist in a well-sampled
    record (found on a friction rig's 37 N hit, refused as 'aliased' by the service): it is
    reported, not refused, while a record whose dominant resonance is not resolved is."""
    spec = dict(lono.spec)
    spec["elements"] = list(spec["elements"]) + [
        {"kind": "coulomb", "between": ["NO", "ground"], "params": {"fc": 1.0}}]
    rig = Structure.from_dict(spec)
    hit = synthetic_impacts(rig, THETA, [37.0], dof="NO", fs=2048.0, duration=4.0, seed=3)[0]
    found = check_recording(lono, hit)
    assert not [p for p in found if p.fatal], found
    assert [p for p in found if p.check == "aliased" and "friction" in p.message], found
    preflight(lono, [impact], [hit])  # accepted, with the warning
    coarse = Recording(impact.time[::64].copy(),
                       {k: v[::64].copy() for k, v in impact.channels.items()}, "coarse.csv")
    assert [p for p in check_recording(lono, coarse) if p.fatal]
