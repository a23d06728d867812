"""The verdict on an identification, stated once for the report, the CLI and the JSON.

Why: a table that says "use best" under a model the validation test rejected, or a
negative damping recommended without a word, misleads.  :func:`assess` reads the
validation test, the physical bounds and the intervals of one :class:`Identification` and
says, in order: is the model accepted on the held-out records, is every recommended value
physical, which parameters these records do not determine, and what to try next.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

#: a parameter whose 95 % interval is wider than this fraction of its value is reported as
#: not determined by the records
UNDETERMINED_REL_HALF_WIDTH = 0.5


@dataclass
class Assessment:
    """``status``: "accepted", "rejected" or "untested" (no validation result)."""

    status: str
    headline: str
    details: list[str] = field(default_factory=list)
    next_steps: list[str] = field(default_factory=list)
    unphysical: list[str] = field(default_factory=list)
    undetermined: list[str] = field(default_factory=list)

    @property
    def usable(self) -> bool:
        """May ``best`` be used as final values?"""
        return self.status == "accepted" and not self.unphysical

    def to_json(self) -> dict[str, Any]:
        return {"status": self.status, "usable": self.usable, "headline": self.headline,
                "details": self.details, "next_steps": self.next_steps,
                "unphysical": self.unphysical, "undetermined": self.undetermined}

    def text(self) -> str:
        """Plain text for a terminal: headline, details, next steps."""
        lines = [self.headline, *("  " + d for d in self.details)]
        if self.next_steps:
            lines.append("  what to try next:")
            lines += [f"    - {s}" for s in self.next_steps]
        return "\n".join(lines)


def assess(result: Any, *, model: str = "MODEL", train: str = "TRAIN...",
           val: str | None = None) -> Assessment:
    """The verdict on ``result`` (an :class:`Identification`); ``model``/``train``/``val``
    fill the suggested commands."""
    st = result.structure
    names = list(st.free)
    best = np.asarray(result.best, dtype=float)
    lo, hi = st.physical_bounds()
    unphysical = [p for p, v, a, b in zip(names, best, lo, hi)
                  if not (np.isfinite(v) and a <= v <= b)]
    undetermined, details = [], []
    if result.best_std is not None:
        for p, v, s in zip(names, best, np.asarray(result.best_std, dtype=float)):
            if np.isfinite(s) and v != 0 and 1.96 * s > UNDETERMINED_REL_HALF_WIDTH * abs(v):
                undetermined.append(p)
                details.append(f"{p} is not determined by these records: its 95 % interval "
                               f"is ±{100 * 1.96 * s / abs(v):.0f} % of the value (the "
                               "records hardly excite what it describes)")
    test = ((result.metrics or {}).get("validation_test") or {}).get("best") or {}
    stat, accepted = test.get("statistic"), test.get("accepted")
    val_cmd = val or "HELD_OUT..."
    steps: list[str] = []
    if accepted is None:
        status = "untested"
        headline = ("NOT VALIDATED: no validation result" +
                    (f" ({test['error']})" if test.get("error") else "") +
                    "; give a separate record with --val")
    elif accepted:
        status = "accepted"
        headline = (f"ACCEPTED: the model explains the held-out records up to the noise "
                    f"(T = {stat:.3g}; 1 = noise only)")
    else:
        status = "rejected"
        worst = sorted(((r.get("statistic") or np.inf, n)
                        for n, r in (test.get("records") or {}).items()), reverse=True)
        where = ", ".join(f"{n} T = {t:.3g}" for t, n in worst[:3])
        headline = (f"REJECTED by the validation test: the held-out records are not explained "
                    f"up to the noise (T = {stat:.3g}, accepted up to about 1.5; {where}); "
                    "do not use these values as final")
        steps += [f"siva diagnose {model} --train {train} --val {val_cmd}  (names the "
                  "missing effect or faulty sensor behind the gap)",
                  "validate on a separate test at another amplitude (--val) rather than a "
                  "part of the training record"]
    if unphysical:
        details.insert(0, f"unphysical value(s) for {', '.join(unphysical)} (e.g. negative "
                          "damping or stiffness): not recommended")
        steps.append("check the model's elements and the records' units and channel mapping")
    if undetermined:
        steps.append("add records that excite what the undetermined parameters describe "
                     "(another amplitude, another hit location), or fix them in the spec "
                     "([parameters.NAME] fixed = value)")
    return Assessment(status, headline, details, steps, unphysical, undetermined)


__all__ = ["Assessment", "assess", "UNDETERMINED_REL_HALF_WIDTH"]
