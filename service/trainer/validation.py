"""The service's validation verdict: ``siva identify``'s held-out test, not D's loss.

Why: the discriminator's loss near ln 4 cannot tell a right model from a wrong one in the
output-error phase (docs/method.md, "A validation test that discriminates").  The test
that can is ``siva_core.validation_score``: each validation record is simulated with the
model through the same chain (only the nuisance fitted) and its residual power compared
with the measured noise power, T = 1 meaning "explains everything but the noise"; H0
"unexplained power <= tolerance x noise", accepted when p >= alpha.  The service runs it
for the headline and for the ensemble mean, per record and overall, off the trainer
thread (the refiner), once per data set and headline/ensemble.
"""
from __future__ import annotations

import time
from typing import Any, Literal, Mapping, Sequence

import numpy as np

from siva_core import Processing, Recording, Structure

from .types import RecordVerdict, Verdict

MEANING = ("T = held-out residual power / measurement-noise power (1 = the model explains "
           "everything but the noise), per validation record and pooled; p_value of H0 "
           "'unexplained power <= tolerance x noise power'; rejected when p < alpha. "
           "The discriminator's numbers (loss_D, AUC) are reported beside it for what they "
           "are: how well D separates measured from simulated samples, not a validation.")


def validate(structure: Structure, theta: np.ndarray, records: Sequence[Recording],
             processing: Processing, of: Literal["headline", "ensemble"]) -> Verdict:
    """``validation_score`` of ``theta`` on ``records`` as a :class:`Verdict`."""
    from siva_core import validation_score

    t0 = time.perf_counter()
    res = validation_score(structure, np.asarray(theta, dtype=float), list(records), processing)
    per = tuple(_record(name, r, res["alpha"]) for name, r in res["records"].items())
    return Verdict(of=of, theta=structure.as_dict(np.asarray(theta, dtype=float)),
                   verdict="accepted" if res["accepted"] else "rejected",
                   T=_num(res["statistic"]), p_value=_num(res["p_value"]),
                   alpha=float(res["alpha"]), tolerance=float(res["tolerance"]),
                   per_record=per, records=tuple(r.name for r in records), time=time.time(),
                   seconds=time.perf_counter() - t0)


def _record(name: str, r: Mapping[str, Any], alpha: float) -> RecordVerdict:
    p = _num(r.get("p_value"))
    return RecordVerdict(record=name, T=_num(r.get("statistic")), p_value=p,
                         verdict=None if p is None else ("accepted" if p >= alpha else "rejected"),
                         n_eff=_num(r.get("n_eff")), error=r.get("error"))


def _num(x: Any) -> float | None:
    try:
        v = float(x)
    except (TypeError, ValueError):
        return None
    return v if np.isfinite(v) else None


def validation_view(headline: Verdict | None, ensemble: Verdict | None,
                    discriminator: Mapping[str, Any] | None, pending: str | None) -> dict[str, Any]:
    """``estimate["validation"]``: the verdict (the headline's test when there is one, else
    the ensemble's), T, p-value and per-record results at the top; both tests under
    ``headline`` and ``ensemble``; the discriminator's numbers labelled as such."""
    main = headline or ensemble
    disc = dict(discriminator or {})
    out: dict[str, Any] = {
        "verdict": None if main is None else main.verdict,
        "of": None if main is None else main.of,
        "T": None if main is None else main.T,
        "p_value": None if main is None else main.p_value,
        "per_record": [] if main is None else main.to_json()["per_record"],
        "headline": None if headline is None else headline.to_json(),
        "ensemble": None if ensemble is None else ensemble.to_json(),
        "agree": (None if headline is None or ensemble is None
                  else headline.verdict == ensemble.verdict),
        "status": "pending" if main is None else "done",
        # the names of ``siva identify``'s JSON, for readers of both
        "accepted": None if main is None else main.verdict == "accepted",
        "statistic": None if main is None else main.T,
        "meaning": MEANING,
        "discriminator": {"what": "the discriminator's own numbers: not a validation test",
                          **{k: disc.get(k) for k in ("loss_d", "ln4_distance", "auc")
                             if k in disc}},
    }
    if main is None:
        out["reason"] = pending or "the test runs once the model has converged"
    return out
