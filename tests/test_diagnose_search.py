"""The search widened (issue 16, seventh round): the first stage's shortlist holds each
role's best candidate, and a look-alike law at the lead's place, fitted again from the
lead's force in its own law, leads a pair the wrong-law lead could not."""
from __future__ import annotations

import numpy as np
import pytest

from siva_core import EFFECTS, Structure
from siva_core._impl.diagnose import Candidate, DiagnoseSettings, Location, augmented
from siva_core._impl.diagnose.grow import law_swap, refit_from_lead, second_leads
from siva_core._impl.diagnose.scoring import judge
from siva_core._impl.diagnose.screening import select_for_fit
from siva_core._impl.diagnose.set_fit import _refit
from siva_core._impl.diagnose.pair_fit import fit_pair
from test_diagnose_sets import NOMINAL, two_dof_records

G = Location(0, -1, ("x", "ground"))
XY = Location(0, 1, ("x", "y"))


def _screened(kind: str, loc: Location, score: float) -> Candidate:
    c = Candidate(EFFECTS[kind], loc, {})
    c.score = score
    return c


def test_each_role_gets_its_best_candidate_fitted():
    """lono:two:1's screen: restoring laws first; the one damper far down."""
    restoring = [_screened(k, loc, s) for k, loc, s in [
        ("clearance", XY, 0.41), ("cubic_spring", G, 0.40), ("spring", XY, 0.27),
        ("quadratic_spring", XY, 0.14), ("clearance", G, 0.10)]]
    damper = _screened("cubic_damper", G, 0.03)  # below family_keep x the top (0.041)
    cands = [*restoring, damper]
    chosen = select_for_fit(cands, DiagnoseSettings())
    assert damper in chosen
    assert restoring[0] in chosen and restoring[1] in chosen
    # off: the restoring laws alone, as before
    assert damper not in select_for_fit(cands, DiagnoseSettings(role_keep=0))
    # a role far below the leader (1 %) is not fitted; with no evidence at all neither
    assert all(c.effect.kind != "cubic_damper" for c in select_for_fit(
        [*restoring, _screened("cubic_damper", G, 0.004)], DiagnoseSettings()))
    assert all(c.effect.kind != "cubic_damper"
               for c in select_for_fit(restoring, DiagnoseSettings()))


C2, K3 = 40.0, 2.0e7  # quadratic damper x-ground, cubic spring x-y


def _fitted(st: Structure, kind: str, loc: Location, value: float, train, val, proc, gap,
            blocks, nfev: int = 0) -> Candidate:
    """A single fitted candidate: its magnitude at ``value`` (refined ``nfev`` steps)."""
    eff = EFFECTS[kind]
    aug, names = augmented(st, eff, loc, {eff.magnitude: abs(value)})
    theta = aug.vector({**NOMINAL, names[eff.magnitude]: value})
    if nfev:
        theta, cost, _ = _refit(aug, [theta], train, proc, nfev)
    c = Candidate(eff, loc, {}, fitted=True, structure=aug, names=names, theta=theta)
    vals = aug.as_dict(theta)
    c.coefficients = {k: vals[p] for k, p in names.items()}
    c.parameters = {p: vals[p] for p in st.free}
    from siva_core._impl.refine import output_error

    c.train_cost = float(output_error(aug, np.asarray(theta)[None], list(train), proc)[0])
    judge(c, val, proc, gap, blocks)
    return c


@pytest.fixture(scope="module")
def lookalike_case():
    return two_dof_records([("quadratic_damper", ("x", "ground"), {"c2": C2}),
                            ("cubic_spring", ("x", "y"), {"k3": K3})], 1.5, (5, 6))


def test_a_look_alike_of_the_lead_refitted_from_its_force_leads_the_right_pair(
        lookalike_case):
    st, train, val, proc, gap, blocks = lookalike_case
    s = DiagnoseSettings()
    # the wrong-law lead: a linear damper x-ground, fitted; the true law's own single fit
    # stalled near zero (as chain3:two:0's quadratic damper m3-ground, c2 = 1.2e-5)
    lead = _fitted(st, "damper", G, 2.0, train, val, proc, gap, blocks, nfev=15)
    stalled = _fitted(st, "quadratic_damper", G, C2 * 1e-6, train, val, proc, gap, blocks)
    stalled.structure, _ = augmented(st, EFFECTS["quadratic_damper"], G, {"c2": C2 * 1e-6})
    mate = _fitted(st, "cubic_spring", XY, K3, train, val, proc, gap, blocks)
    assert lead.closure > stalled.closure + 0.05
    assert second_leads([lead, stalled, mate], lead, s) == [stalled]
    # without the refit, the pair on the stalled fit does not reach the truth
    before = fit_pair(stalled, mate, st, train, val, proc, gap, blocks,
                      DiagnoseSettings(fit_nfev=10))
    assert law_swap(stalled, lead, train, proc)  # least squares, RMS and peak matches
    starts = refit_from_lead(stalled, lead, st, train, val, proc, gap, blocks,
                             DiagnoseSettings(fit_nfev=10))
    assert starts
    mags = [stalled.structure.as_dict(t)[stalled.names["c2"]] for t in starts]
    assert min(abs(np.log(np.array(mags) / C2))) < np.log(3.0)  # one within 3 x the truth
    after = fit_pair(stalled, mate, st, train, val, proc, gap, blocks,
                     DiagnoseSettings(fit_nfev=10), starts_a=starts)
    assert after is not None and after.closure > 0.95
    assert after.coefficients.get("k3") == pytest.approx(K3, rel=0.2)
    assert before is None or before.closure < after.closure - 0.05
