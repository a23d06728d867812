"""The substep pilot's run is taken for the first cost of the same sets (speed): the cost
is the same, bit for bit, as simulating them again, on either backend, for the whole
reference batch, a part of it, or other sets (issue 16 must-show 3)."""
from __future__ import annotations

import numpy as np
import pytest

from siva_core import OutputErrorProblem, Recording, Structure, simulate, with_effect
from siva_core._impl.simulate import pilot_memo

from synthetic import LONO, lono_hit


def _case(lono_model: Structure) -> tuple[Structure, np.ndarray, Recording]:
    gen = with_effect(lono_model, "cubic_damper", ("LO", "NO"), {"c3": 3.0e3})
    theta = gen.vector(LONO)
    t, F = lono_hit(gen.dofs, 20.0, 0.5)
    z = np.zeros(2)
    a = simulate(gen, theta, t, z, z, F, substeps="auto").a
    rec = Recording.from_columns({"time": t, "acc_LO": a[:, 0], "acc_NO": a[:, 1],
                                  "force_NO": F[:, 1]}, gen.dofs, name="r")
    return gen, theta, rec


@pytest.mark.parametrize("backend", ["numba", pytest.param("numpy", marks=pytest.mark.heavy)])
def test_the_pilots_run_gives_the_same_cost_as_simulating_again(lono_model: Structure,
                                                                backend: str) -> None:
    gen, theta, rec = _case(lono_model)
    rng = np.random.default_rng(1)
    batch = theta * (1.0 + 0.05 * rng.standard_normal((4, theta.size)))
    for thetas in (batch, batch[:1], batch[[2, 0]],
                   np.vstack([batch, theta * 1.01])):
        pilot_memo.clear()  # the pilot runs (a remembered choice skips it: test below)
        ref = OutputErrorProblem.build(gen, [rec], theta_ref=batch, backend=backend)
        assert ref.records[0].pilot is not None
        ref.records[0].pilot = None          # simulated again: the cost before this change
        pilot_memo.clear()
        new = OutputErrorProblem.build(gen, [rec], theta_ref=batch, backend=backend)
        a, b = ref.cost(thetas), new.cost(thetas)
        assert np.array_equal(a, b)
        # a second cost simulates (the pilot is taken once) and is the same again
        assert new.records[0].pilot is None or backend == "numpy"
        assert np.array_equal(new.cost(thetas), a)


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_a_remembered_substep_choice_skips_the_pilot_and_changes_no_bit(
        lono_model: Structure, backend: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """The same model, sets and record ask for the substeps again (a fit's cost at its
    result, then the next ``refine`` from it): the pilot is not run again, the substeps
    are the same, and so is every cost and every refined parameter, bit for bit."""
    from siva_core import refine
    from siva_core._impl.simulate import substeps as substeps_mod  # noqa: E501

    gen, theta, rec = _case(lono_model)
    start = theta * 1.03
    pilot_memo.clear()
    first = OutputErrorProblem.build(gen, [rec], theta_ref=start[None], backend=backend)
    # the refine comparison on numba only: the memo is the same code on either backend
    # (the backend is one field of its key) and a numpy refine took 40 s of the suite
    refined = backend == "numba"
    cold = refine(gen, start, [rec], max_nfev=6, backend=backend) if refined else None
    runs: list[int] = []
    real = substeps_mod._pilot
    monkeypatch.setattr(substeps_mod, "_pilot",
                        lambda *a, **k: runs.append(1) or real(*a, **k))
    again = OutputErrorProblem.build(gen, [rec], theta_ref=start[None], backend=backend)
    assert not runs and again.records[0].pilot is None  # remembered: no pilot run
    assert again.records[0].substeps == first.records[0].substeps
    assert np.array_equal(again.cost(start[None]), first.cost(start[None]))
    if refined:
        warm = refine(gen, start, [rec], max_nfev=6, backend=backend)
        assert not runs
        assert np.array_equal(warm.theta, cold.theta)
    # another set is piloted
    OutputErrorProblem.build(gen, [rec], theta_ref=(theta * 1.05)[None], backend=backend)
    assert runs
