"""Shared fixtures: the reference data folder, the example models, small synthetic records.

The reference data lives next to the project, at ``../shared/data`` from the repository root
(data/README.md); ``SIVA_SHARED_DATA`` overrides it.  Tests that need it are skipped, not
failed, when it is absent (e.g. a wheel installed elsewhere).
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import pytest

from siva_core import Recording, Structure

REPO_ROOT = Path(__file__).resolve().parents[1]
MODELS_DIR = REPO_ROOT / "examples" / "models"


def find_shared_data() -> Path | None:
    """``$SIVA_SHARED_DATA``, else ``<repo>/../shared/data`` (symlinks resolved)."""
    candidates = []
    if os.environ.get("SIVA_SHARED_DATA"):
        candidates.append(Path(os.environ["SIVA_SHARED_DATA"]))
    candidates.append(REPO_ROOT.parent / "shared" / "data")
    candidates.append(Path(__file__).parent.parent.parent / "shared" / "data")
    for cand in candidates:
        cand = cand.expanduser().resolve()
        if (cand / "duffing").is_dir() and (cand / "lono").is_dir():
            return cand
    return None


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return REPO_ROOT


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The reference data folder; skips the test when it is not there."""
    path = find_shared_data()
    if path is None:
        pytest.skip("reference data ../shared/data not found (set SIVA_SHARED_DATA)")
    return path


@pytest.fixture(scope="session")
def model_paths() -> dict[str, Path]:
    """The example model specs by name: duffing, lono, silverbox."""
    paths = {p.stem: p for p in sorted(MODELS_DIR.glob("*.toml"))}
    assert {"duffing", "lono", "silverbox"} <= set(paths), paths
    return paths


@pytest.fixture(scope="session")
def duffing_model(model_paths: dict[str, Path]) -> Structure:
    return Structure.from_file(model_paths["duffing"])


@pytest.fixture(scope="session")
def duffing_without_cubic_damper(duffing_model: Structure, shared_data: Path
                                 ) -> tuple[Structure, list[Recording], list[Recording]]:
    """The paper's Duffing with its cubic damper withheld, train 5 m/s, validate 3 + 8 m/s
    (a fast diagnosis case: 1 DOF, free decays, noise-free)."""
    spec = dict(duffing_model.spec)
    spec["elements"] = [e for e in spec["elements"] if e["kind"] != "cubic_damper"]
    model = Structure.from_dict(spec)
    folder = shared_data / "duffing"
    train = [Recording.read(folder / "train_v5.csv", model.dofs)]
    val = [Recording.read(folder / f, model.dofs) for f in ("val_v3.csv", "val_v8.csv")]
    return model, train, val


@pytest.fixture(scope="session")
def lono_model(model_paths: dict[str, Path]) -> Structure:
    return Structure.from_file(model_paths["lono"])


@pytest.fixture(scope="session")
def silverbox_model(model_paths: dict[str, Path]) -> Structure:
    return Structure.from_file(model_paths["silverbox"])


def sdof_impact(*, m: float = 1.0, f_n: float = 10.0, zeta: float = 0.02, fs: float = 1000.0,
                duration: float = 4.0, t_hit: float = 0.1, pulse: float = 0.004,
                peak: float = 50.0, quantities: Sequence[str] = ("disp", "vel", "acc"),
                hum: float = 0.0, noise: float = 0.0, seed: int = 0,
                name: str = "sdof") -> tuple[Recording, dict[str, float]]:
    """Exact response of a linear oscillator (DOF ``x``) to a half-sine hammer pulse.

    Exact: the discrete-time response of the continuous system to the force held between
    samples is not exact for a half-sine, so the pulse is integrated on a 32x finer grid
    and decimated.  Returns the recording and the true {k, c}.
    """
    from scipy import signal

    k = m * (2 * np.pi * f_n) ** 2
    c = 2 * zeta * np.sqrt(k * m)
    up = 32
    n = int(round(duration * fs))
    tf = np.arange(n * up) / (fs * up)
    F = np.where((tf >= t_hit) & (tf < t_hit + pulse),
                 peak * np.sin(np.pi * (tf - t_hit) / pulse), 0.0)
    sys = signal.StateSpace([[0.0, 1.0], [-k / m, -c / m]], [[0.0], [1.0 / m]],
                            [[1.0, 0.0], [0.0, 1.0]], [[0.0], [0.0]])
    _, y, _ = signal.lsim(sys, F, tf)
    q, v = y[::up, 0], y[::up, 1]
    f = F[::up]
    a = (f - c * v - k * q) / m
    t = tf[::up]
    rng = np.random.default_rng(seed)
    cols = {"disp_x": q, "vel_x": v, "acc_x": a}
    channels = {}
    for qty in quantities:
        x = cols[f"{qty}_x"].copy()
        if noise:
            x = x + noise * np.std(x) * rng.standard_normal(n)
        if hum and qty == "acc":
            x = x + hum * np.std(x) * np.sin(2 * np.pi * 60.0 * t)
        channels[f"{qty}_x"] = x
    channels["force_x"] = f
    return Recording(t, channels, name), {"k": k, "c": c}


@pytest.fixture
def make_sdof() -> Callable[..., tuple[Recording, dict[str, float]]]:
    """Factory of synthetic impact records (see :func:`sdof_impact`)."""
    return sdof_impact


SDOF_SPEC = {"name": "sdof", "dofs": ["x"], "mass": {"x": 1.0}, "elements": [
    {"kind": "spring", "between": ["x", "ground"], "params": {"k": "k"}},
    {"kind": "damper", "between": ["x", "ground"], "params": {"c": "c"}}]}


@pytest.fixture
def sdof_model() -> Structure:
    """Linear oscillator x with unit mass (spring k, damper c)."""
    return Structure.from_dict(SDOF_SPEC)


def csv_text(columns: dict[str, Sequence[float]]) -> str:
    """A CSV text from columns (tests edit the text to break it)."""
    names = list(columns)
    rows = zip(*(columns[n] for n in names))
    return ",".join(names) + "\n" + "".join(",".join(repr(float(x)) for x in r) + "\n"
                                          for r in rows)


@pytest.fixture(scope="session")
def to_csv_text() -> Callable[[dict[str, Sequence[float]]], str]:
    """The :func:`csv_text` helper, as a fixture (conftest modules are not importable)."""
    return csv_text


@pytest.fixture
def small_columns() -> dict[str, np.ndarray]:
    """A valid 40-sample record of DOF x: time, disp, acc, force."""
    t = np.arange(40) * 0.01
    return {"time": t, "disp_x": 1e-3 * np.sin(2 * np.pi * 3 * t),
            "acc_x": -(2 * np.pi * 3) ** 2 * 1e-3 * np.sin(2 * np.pi * 3 * t),
            "force_x": np.zeros_like(t)}
