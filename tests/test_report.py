"""The report (paper figures + index.html) and the spectral helpers behind it."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from siva_core import Recording, Siva, Structure
from synthetic import SDOF, TRUE, free_decay
from siva_core import cwt, dominant_frequency, fourier_amplitude, frequency_band, write_report


PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
@pytest.fixture(scope="module")


def fitted() -> tuple[Siva, list[Recording], list[Recording]]:
    st = Structure.from_dict(SDOF)
    train, val = [free_decay(1.0)], [free_decay(0.5), free_decay(2.0)]
    est = Siva(st, processing="none", max_epochs=12, n_samples=64, n_candidates=12,
               baselines=False, progress=None).fit(train, val)
    return est, train, val


def _check_png(path: Path) -> None:
    data = path.read_bytes()
    assert data[:8] == PNG_MAGIC, f"{path.name} is not a PNG"
    assert len(data) > 5000, f"{path.name} looks empty ({len(data)} bytes)"
    import matplotlib.image as mpimg

    img = mpimg.imread(path)
    assert img.ndim == 3 and img.shape[0] > 100 and img.shape[1] > 100
    # not a blank canvas: a drawn figure has many distinct colours
    assert len(np.unique(img.reshape(-1, img.shape[-1])[::37], axis=0)) > 20


def test_report_writes_every_figure_and_an_index(fitted, tmp_path):
    est, train, val = fitted
    paths = write_report(est, tmp_path / "rep", truth=TRUE, train=train, val=val, n_sims=16,
                         progress=None)
    assert paths[-1].name == "index.html"
    pngs = paths[:-1]
    names = {p.name for p in pngs}
    assert {"losses.png", "parameters.png", "distributions.png"} <= names
    for kind in ("response", "spectrum", "cwt"):
        per_record = sorted(n for n in names if n.startswith(kind + "_"))
        assert len(per_record) == 3, (kind, per_record)  # 1 training + 2 validation records
    assert any("decay_v2" in n for n in names)
    for p in pngs:
        assert p.exists() and p.parent == tmp_path / "rep"
        _check_png(p)
    page = paths[-1].read_text()
    srcs = set(re.findall(r'<img src="([^"]+)"', page))
    assert srcs == names
    # the summary table carries every parameter, the exact values and the ln 4 reference
    for p, v in TRUE.items():
        assert f"<td>{p}</td>" in page and f"{v:.5g}" in page
    assert "1.3863" in page


def test_report_without_raw_recordings_simulates_the_processed_states(fitted):
    """Without raw recordings (as ``siva identify --report`` may call it) every training and
    validation record is still drawn, from its processed states, and says so."""
    from siva_core._impl.report.simulations import records_to_draw, simulate_record

    est, _, _ = fitted

    class _Bare:  # an estimator that kept only what the processing chain produced
        structure = est.structure
        result_ = est.result_
        processing_ = est.processing_
        train_states_ = est.train_states_
        val_states_ = est.val_states_

    recs, note = records_to_draw(_Bare, None, None)
    assert [role for _, role in recs] == ["training", "validation", "validation"]
    assert note and "processed states" in note
    rs = simulate_record(_Bare, est.result_, recs[2][0], "validation", n_sims=5)
    assert np.allclose(rs.measured, est.val_states_[1].q * 1e3)
    assert rs.band_sims.shape[1:] == rs.measured.shape and len(rs.band_sims) + rs.n_diverged == 5
    assert set(rs.points) == {"approach_I", "approach_II", "approach_III", "best"}


def test_report_simulations_match_the_measurement_at_the_truth(fitted):
    """The simulated and measured displacements are aligned sample by sample: the exact
    parameters reproduce every record (a time shift or a unit slip would not)."""
    from siva_core._impl.report.simulations import simulate_record

    est, train, val = fitted
    res = est.result_
    exact = est.structure.vector(TRUE)

    class _Res:  # the fitted result with every estimate replaced by the truth
        names = res.names
        samples_I = np.repeat(exact[None], 3, axis=0)
        processing = res.processing

        @staticmethod
        def estimates() -> dict[str, np.ndarray]:
            return {k: exact for k in ("approach_I", "approach_II", "approach_III", "best")}

    for rec, role in [(train[0], "training"), (val[1], "validation")]:
        rs = simulate_record(est, _Res, rec, role, n_sims=3)
        scale = np.sqrt(np.mean(rs.measured ** 2))
        assert rs.band_sims.shape == (3, len(rec), 1) and rs.n_diverged == 0
        assert np.isclose(rs.measured[:, 0], rec.get("disp", "x") * 1e3).all()  # in mm
        for key, q in rs.points.items():
            assert np.sqrt(np.mean((q - rs.measured) ** 2)) < 1e-4 * scale, key


def test_fourier_amplitude_of_a_sine_peaks_at_its_frequency_and_amplitude():
    fs, f0, amp = 1000.0, 50.0, 0.7
    t = np.arange(2000) / fs  # an integer number of cycles: no leakage
    f, a = fourier_amplitude(amp * np.sin(2 * np.pi * f0 * t) + 3.0, fs)
    k = int(np.argmax(a))
    assert f[k] == pytest.approx(f0)
    assert a[k] == pytest.approx(amp, rel=1e-9)
    assert a[0] == pytest.approx(0.0, abs=1e-9)  # the offset is removed
    assert f[-1] == pytest.approx(fs / 2)


def test_dominant_frequency_is_sub_bin_accurate():
    fs = 1000.0
    t = np.arange(2000) / fs  # bins 0.5 Hz apart
    for f0 in (37.3, 123.77):
        assert dominant_frequency(np.sin(2 * np.pi * f0 * t + 0.3), fs) == pytest.approx(f0, abs=0.02)


def test_cwt_is_normalised_and_follows_the_frequency():
    fs = 2000.0
    t = np.arange(4000) / fs
    # a chirp from 20 to 120 Hz: the ridge must rise with time
    inst = 20 + 50 * t
    x = np.sin(2 * np.pi * np.cumsum(inst) / fs)
    freqs, mag = cwt(x, fs, np.linspace(5, 200, 120))
    assert mag.shape == (120, len(t))
    assert mag.max() == pytest.approx(1.0) and mag.min() >= 0
    for i in (800, 2000, 3200):
        ridge = freqs[int(np.argmax(mag[:, i]))]
        assert ridge == pytest.approx(inst[i], rel=0.06), (t[i], ridge, inst[i])
    # unnormalised magnitude is the raw one: same shape, max not 1 in general
    _, raw = cwt(10 * x, fs, np.linspace(5, 200, 120), normalise=False)
    assert raw.max() > 2 and np.allclose(raw / raw.max(), mag)


def test_cwt_default_band_covers_the_signal_and_rejects_bad_input():
    fs = 10000.0
    t = np.arange(10000) / fs
    x = np.exp(-3 * t) * np.sin(2 * np.pi * 90 * t)
    lo, hi = frequency_band(x, fs)
    assert lo < 90 < hi < fs / 2
    freqs, mag = cwt(x, fs)
    assert freqs[0] == pytest.approx(lo) and freqs[-1] == pytest.approx(hi)
    assert freqs[int(np.argmax(mag.max(axis=1)))] == pytest.approx(90, rel=0.05)
    with pytest.raises(ValueError):
        cwt(np.zeros((10, 2)), fs)
    with pytest.raises(ValueError):
        cwt(x, fs, np.array([10.0, fs]))  # above Nyquist


def test_frequency_band_includes_a_weak_higher_mode_when_asked():
    """The 37 N LO-NO case: a displacement's energy is in its low mode, so the energy
    criterion alone cuts a weak 19.8 Hz mode off the axis; ``include`` keeps it on."""
    fs = 2048.0
    t = np.arange(8192) / fs
    x = np.exp(-0.3 * t) * np.sin(2 * np.pi * 5.7 * t) + 0.002 * np.exp(-0.5 * t) * np.sin(2 * np.pi * 19.8 * t)
    _, hi = frequency_band(x, fs)
    assert hi < 19.8  # the failure this guards against
    _, hi2 = frequency_band(x, fs, include=[5.7, 19.8])
    assert hi2 >= 1.25 * 19.8 and hi2 <= fs / 2


def test_parameter_units_come_from_the_element_kinds():
    lono = Structure.from_file(Path(__file__).resolve().parents[1] / "examples/models/lono.toml")
    assert lono.parameter_units() == {"b1": "N/(m/s)", "k1": "N/m", "b2": "N/(m/s)", "k2": "N/m",
                                      "alpha": "N/m^(1+beta)", "beta": "-"}


def test_parameters_figure_keeps_best_on_the_axis(fitted):
    """best (and its 95 % interval) far outside what the epochs visited is still drawn
    inside the axis (alpha and beta of LO-NO fell off it)."""
    from siva_core._impl.report.training_figures import fig_parameters

    est, _, _ = fitted
    res = est.result_
    names = list(res.names)
    far = np.array(res.best, dtype=float) * 3.0

    class _Res:
        history = res.history
        converged_epoch = res.converged_epoch
        best = far
        best_std = np.abs(far) * 0.01

    fig = fig_parameters(_Res, names, None, None, est.structure.parameter_units())
    for k, ax in enumerate(fig.axes[:len(names)]):
        lo, hi = ax.get_ylim()
        assert lo <= far[k] * 0.98 and far[k] * 1.02 <= hi, (names[k], (lo, hi), far[k])
        assert "[" in ax.get_title()  # the unit


def test_report_table_says_which_value_to_use_with_units(fitted):
    from siva_core._impl.report.page import page_html

    est, _, _ = fitted
    page = page_html(est, est.result_, list(est.result_.names), None, [], [], None)
    assert "Use <code>best</code>" in page
    assert "N/m" in page and "N/(m/s)" in page
    assert not re.search(r"(\d\S*) \[\1, \1\]", page)  # no "0.5 [0.5, 0.5]"


def test_a_rejected_model_is_shown_rejected_at_the_top(fitted):
    """Issue 17 finding 2: the validation verdict is the first thing on the page, and a
    rejected model's values are not presented as the ones to use."""
    import copy

    from siva_core._impl.report.page import page_html

    est, _, _ = fitted
    res = copy.copy(est.result_)
    res.metrics = {**res.metrics, "validation_test": {"best": {
        "statistic": 6.8, "accepted": False, "p_value": 0.0,
        "records": {"held.csv": {"statistic": 6.8}}}}}
    page = page_html(est, res, list(res.names), None, [], [], None)
    assert "REJECTED" in page and "T = 6.8" in page and "siva diagnose" in page
    assert page.index('id="verdict"') < page.index("<h2>Parameters")
    assert "Use <code>best</code>" not in page and "NOT validated" in page
    res.metrics = {**res.metrics, "validation_test": {"best": {
        "statistic": 1.05, "accepted": True, "p_value": 0.6, "records": {}}}}
    page = page_html(est, res, list(res.names), None, [], [], None)
    assert "ACCEPTED" in page and "Use <code>best</code>" in page
