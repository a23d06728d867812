"""The CUSUM rule of the drift detector: its settings and the decision interval h that gives
the stated in-control average run length (docs in ``detector.py``)."""
from __future__ import annotations

import math
from dataclasses import dataclass

#: |z| below which a value counts as "back to baseline" when clearing a confirmed alarm
CLEAR_Z = 2.0


@dataclass(frozen=True)
class DetectorSettings:
    baseline_records: int = 10        # records whose estimates form the reference
    baseline_guard: int = 10          # a record joins the baseline this many records later ...
    baseline_max: int = 200           # ... while in control, up to this many records
    arl0_records: float = 20000.0     # nominal in-control ARL of the whole detector
    k: float = 0.5                    # CUSUM reference value, in scatter units
    clip: float = 4.0                 # |z| cap: one outlier cannot alarm alone
    centre_inflation: float = 3.0     # the centre's error counts this many times in z
    min_rel_scatter: float = 0.005    # scatter floor relative to |centre|
    confirm_records: int = 3          # records above h after raising -> confirmed
    clear_records: int = 5            # records back within |z| < 2 -> cleared

    def threshold(self, n_quantities: int) -> float:
        """CUSUM decision interval h for the nominal ARL with ``n_quantities`` tested."""
        return cusum_threshold(2.0 * max(1, n_quantities) * self.arl0_records, self.k)


def cusum_threshold(arl: float, k: float) -> float:
    """h such that a one-sided CUSUM with reference k has in-control ARL ``arl``
    (Siegmund's approximation, standard normal increments)."""
    def arl_of(h: float) -> float:
        b = 2 * k * (h + 1.166)
        return (math.exp(b) - b - 1) / (2 * k * k)

    lo, hi = 0.0, 100.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if arl_of(mid) < arl else (lo, mid)
    return hi
