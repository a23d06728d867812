"""The diagnosis's processing band keeps the fitted model's modes (issue 16: a band that
cut modes of the structure left the nominal fit unable to follow its own records)."""
from __future__ import annotations

import numpy as np

from siva_core import Processing, Recording, Structure
from siva_core._impl.diagnose import DiagnoseSettings, synthetic_impacts
from siva_core._impl.diagnose.band import EDGE, cut_modes, fit_nominal_in_band

CHAIN2 = {"name": "chain2", "dofs": ["a", "b"], "mass": {"a": 1.0, "b": 1.0},
          "elements": [{"kind": "spring", "between": ["a", "ground"], "params": {"k": "k1"}},
                       {"kind": "damper", "between": ["a", "ground"], "params": {"c": "c1"}},
                       {"kind": "spring", "between": ["a", "b"], "params": {"k": "k2"}},
                       {"kind": "damper", "between": ["a", "b"], "params": {"c": "c2"}}]}
TRUTH = {"k1": 4000.0, "c1": 0.4, "k2": 30000.0, "c2": 3.0}


def _records() -> tuple[Structure, list]:
    st = Structure.from_dict(CHAIN2)
    recs = synthetic_impacts(st, st.vector(TRUTH), [50.0, 150.0, 100.0], dof="a",
                             fs=1024.0, duration=2.0, acc_noise=2e-3, force_noise=1e-3)
    return st, recs


def test_cut_modes_names_the_modes_at_or_beyond_the_band_edges():
    assert cut_modes([10.0, 40.0], (4.0, 100.0)) == []
    assert cut_modes([10.0, 90.0], (4.0, 100.0)) == [90.0]      # within 1.25 of fl
    assert cut_modes([4.5, 40.0], (4.0, 100.0)) == [4.5]        # within 1.25 of fh
    assert cut_modes([10.0, 160.0], (4.0, 100.0)) == [160.0]    # beyond fl


def test_auto_band_keeps_the_modes_it_is_told_to_cover():
    st, recs = _records()
    modes = st.linear_modes(st.vector(TRUTH))["frequency_hz"]
    narrow = Processing.auto(recs, st.dofs, bandpass=(4.0, 1.3 * modes[0]))
    assert cut_modes(modes, narrow.bandpass)
    covered = Processing.auto(recs, st.dofs, cover=(modes[0], modes[-1]))
    assert not cut_modes(modes, covered.bandpass), (modes, covered.bandpass)


def test_a_band_that_cuts_a_mode_is_widened_before_the_nominal_fit():
    """Given a band that cuts the second mode, the nominal fit is redone in a band that
    keeps the first fit's modes and that fit is kept (its train cost is lower)."""
    st, recs = _records()
    modes = st.linear_modes(st.vector(TRUTH))["frequency_hz"]
    auto = Processing.auto(recs, st.dofs)
    narrow = Processing.auto(recs, st.dofs, bandpass=(auto.bandpass[0], 1.3 * modes[0]),
                             decimate_to=None, notch=())
    train = recs[:2]
    proc, fit = fit_nominal_in_band(st, train, recs, narrow, DiagnoseSettings(), None)
    assert proc.bandpass[1] > EDGE * modes[-1], (proc.bandpass, modes)
    fitted = st.linear_modes(fit.theta)["frequency_hz"]
    assert np.allclose(fitted, modes, rtol=0.05), (fitted, modes)






def test_the_linear_part_of_a_start_zeroes_only_the_nonlinear_forces():
    """The fallback start when every nominal start diverges (issue 16: least squares gave
    a known cubic spring k3 = -1.1e10 that escapes): springs and dampers kept, the cubic
    spring's k3 set to zero; a linear model has no such start."""
    from siva_core._impl.diagnose.nominal import linear_part

    spec = {**CHAIN2, "elements": [*CHAIN2["elements"], {
        "kind": "cubic_spring", "between": ["a", "ground"], "params": {"k3": "knl"}}]}
    st = Structure.from_dict(spec)
    th = st.vector({**TRUTH, "knl": -1.1e10})
    lin = st.as_dict(linear_part(st, th))
    assert lin["knl"] == 0.0 and all(lin[k] == v for k, v in TRUTH.items())
    assert linear_part(Structure.from_dict(CHAIN2), Structure.from_dict(CHAIN2).vector(TRUTH)) is None


def test_a_mode_too_slow_for_the_records_is_not_kept_in_the_band():
    from siva_core._impl.diagnose.band import resolvable

    t = np.arange(0, 2.0, 1 / 256)
    rec = Recording(t, {"acc_x": np.zeros_like(t)})
    assert resolvable([0.08, 1.9, 2.5, 40.0], [rec]) == [2.5, 40.0]


def test_a_mode_too_slow_for_the_record_has_no_track():
    from siva_core._impl.diagnose.signatures import _mode_track

    fs = 256.0
    t = np.arange(0, 2.0, 1 / fs)
    x = np.sin(2 * np.pi * 20 * t) * np.exp(-t)
    assert _mode_track(x, fs, 20.0) is not None
    assert _mode_track(x, fs, 0.08) is None  # fresh seed 13007 crashed here (IndexError)


def test_the_widest_band_only_when_a_poor_nominal_does_not_show_its_modes():
    """Branch nomspeed: a poor nominal fit (above ``nominal_poor``) that shows a mode per
    DOF inside the band is what a strong missing effect leaves and is not fitted again in
    the widest band (never kept there, a second nominal fit with its restarts); a failed
    one (above ``nominal_widest``), one that lost a mode, or none is;
    ``nominal_widest = nominal_poor`` gives the rule before."""
    from siva_core._impl.diagnose.band import _covers
    from siva_core._impl.diagnose.nominal import NominalFit

    st, recs = _records()
    proc = Processing.auto(recs, st.dofs)
    settings = DiagnoseSettings()
    th = st.vector(TRUTH)
    whys = lambda cost, s=settings: [w for w, _ in _covers(  # noqa: E731
        recs, NominalFit(th, cost, "test"), st, proc, s)]
    assert "the widest band" not in whys(0.3)
    assert "the widest band" in whys(0.7)
    assert "the widest band" in [w for w, _ in _covers(recs, None, st, proc, settings)]
    old = DiagnoseSettings(nominal_widest=settings.nominal_poor)
    assert "the widest band" in whys(0.3, old)
    # a poor fit that made a mode overdamped (a band hiding it: fresh-style 25936)
    lost = st.vector({**TRUTH, "c2": 2000.0})
    assert len(st.linear_modes(lost)["frequency_hz"]) == 1
    assert "the widest band" in [w for w, _ in _covers(
        recs, NominalFit(lost, 0.3, "test"), st, proc, settings)]
