"""The SIVA engine: networks, uncertainty read-outs, convergence, the trainer loop."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from siva_core import Processing, Recording, SivaSettings, SivaTrainer, States, Structure
from synthetic import SDOF, TRUE, free_decay
from siva_core import ConvergenceMonitor, Ensemble, effective_sample_size, normal_summary
from siva_core._impl.networks import LN4, Discriminator, ParameterGenerator

ROOT = Path(__file__).resolve().parents[1]


def _free_decay(v0: float, n: int = 4000, fs: float = 2000.0) -> States:
    """The exact decay as processed States (nothing to derive: all three are given)."""
    return Processing().apply(free_decay(v0, n, fs), ["x"])


@pytest.fixture(scope="module")
def sdof() -> Structure:
    return Structure.from_dict(SDOF)


def test_generator_scientific_notation_starts_at_reference():
    gen = ParameterGenerator(3, latent_dim=8)
    gen.set_reference(torch.tensor([3e8, 0.5, 2.0], dtype=torch.float64))
    assert torch.allclose(gen.e0, torch.tensor([8.0, -1.0, 0.0], dtype=torch.float64))
    out = gen(torch.randn(500, 8))
    assert out.shape == (500, 3) and out.dtype == torch.float64
    rel = out.mean(0) / torch.tensor([3e8, 0.5, 2.0], dtype=torch.float64)
    # small head weights: every output starts within a few percent of its reference
    assert torch.all((rel - 1).abs() < 0.2)


def test_generator_layer_widths_are_the_papers():
    gen = ParameterGenerator(4, latent_dim=16)
    widths = [m.out_features for m in gen.modules() if isinstance(m, torch.nn.Linear)]
    assert widths == [64, 32, 16, 8]  # 64 -> 32 -> 16 -> n (x2: mantissa and exponent)
    disc = Discriminator(6)
    assert [m.out_features for m in disc.modules() if isinstance(m, torch.nn.Linear)] == [64, 32, 1]
    assert 0 < float(disc.prob(torch.randn(3, 6)).detach().min()) < 1


def test_ess_of_white_noise_and_ar1():
    rng = np.random.default_rng(0)
    white = rng.normal(size=4000)
    assert effective_sample_size(white) > 3000
    phi = 0.9
    ar = np.zeros(4000)
    for i in range(1, 4000):
        ar[i] = phi * ar[i - 1] + rng.normal()
    expected = 4000 * (1 - phi) / (1 + phi)  # about 211
    assert expected / 2 < effective_sample_size(ar) < expected * 2


def test_normal_summary_and_bounded_ensemble():
    rng = np.random.default_rng(1)
    x = rng.normal([1.0, -3.0], [0.1, 2.0], size=(5000, 2))
    s = normal_summary(x, ["a", "b"])
    assert s["a"]["mean"] == pytest.approx(1.0, abs=0.01)
    assert s["b"]["std"] == pytest.approx(2.0, rel=0.05)
    lo, hi = s["b"]["ci95"]
    assert lo == pytest.approx(-3 - 1.96 * 2, abs=0.2) and hi == pytest.approx(-3 + 1.96 * 2, abs=0.2)
    ens = Ensemble(maxlen=10)
    for e in range(25):
        ens.add(np.array([e, 2 * e]), e)
    assert len(ens) == 10 and ens.epochs[0] == 15
    clone = Ensemble()
    clone.load_state_dict(ens.state_dict())
    assert np.array_equal(clone.samples, ens.samples)


def test_convergence_monitor_waits_for_a_plateau():
    mon = ConvergenceMonitor(window=10, min_epochs=20, patience=3)
    for e in range(60):  # steady drift: never converged
        assert not mon.update(e, np.array([1.0 + 0.05 * e]))
    mon.reset()
    rng = np.random.default_rng(2)
    hits = [mon.update(e, np.array([5.0 + 1e-4 * rng.normal()])) for e in range(60)]
    assert not hits[18] and hits[-1]
    assert 20 <= mon.converged_at < 60


@pytest.mark.heavy
def test_trainer_identifies_linear_oscillator_and_is_deterministic(sdof):
    train, val = [_free_decay(1.0)], [_free_decay(0.4), _free_decay(2.0)]
    settings = SivaSettings.fast(max_epochs=150, conv_min_epochs=30, ensemble_epochs=30)

    def run() -> SivaTrainer:
        tr = SivaTrainer(sdof, settings)
        tr.set_data(train, val)
        while tr.epoch < settings.max_epochs and not (tr.converged and len(tr.ensemble) >= 30):
            tr.run_epoch()
        return tr

    tr = run()
    assert tr.converged
    mean = tr.ensemble.samples.mean(0)
    assert mean[0] == pytest.approx(TRUE["k"], rel=0.01)
    assert mean[1] == pytest.approx(TRUE["c"], rel=0.05)
    scores = tr.discriminator_scores()
    assert set(scores["records"]) == {"decay_v0.4.csv", "decay_v2.csv"}
    assert scores["ln4_distance"] < 0.05 and scores["ln4"] == pytest.approx(LN4)
    # same seed, same data -> the same trajectory, bit for bit
    again = run()
    assert np.array_equal(np.array(tr.history["theta"]), np.array(again.history["theta"]))


def test_trainer_checkpoint_resumes_exactly(sdof):
    train, val = [_free_decay(1.0, n=1500)], [_free_decay(0.5, n=1500)]
    settings = SivaSettings.fast(max_epochs=50)
    a = SivaTrainer(sdof, settings)
    a.set_data(train, val)
    for _ in range(6):
        a.run_epoch()
    b = SivaTrainer(sdof, settings)
    b.set_data(train, val)
    b.load_state_dict(a.state_dict())
    la, lb = a.run_epoch(), b.run_epoch()
    assert la.epoch == lb.epoch == 6
    assert np.array_equal(la.theta, lb.theta)


def test_trainer_rejects_missing_data(sdof):
    tr = SivaTrainer(sdof)
    with pytest.raises(RuntimeError, match="set_data"):
        tr.run_epoch()
    with pytest.raises(ValueError, match="training record"):
        tr.set_data([], [])


def test_trainer_on_duffing_records_uses_scales():
    model = Structure.from_file(ROOT / "examples/models/duffing.toml")
    rec = Recording.read(ROOT.parent / "shared/data/duffing/train_v5.csv", model.dofs)
    st = Processing().apply(rec, model.dofs)
    tr = SivaTrainer(model)
    tr.set_data([st], [st])
    # exponents follow the least-squares orders of magnitude: b~1e-1, b_nl~1e3, k~1e2, k_nl~1e8
    assert tr.generator.e0.tolist() == [-1.0, 3.0, 2.0, 8.0]
