"""The sensor member of a chosen set swapped for its twin fault (issue 16, branch
sensorstruct): an accelerometer gain on the hammered DOF's channel for the force gain of
that DOF's hammer, and back.

With known masses a force gain ``g`` is a common gain ``1/g`` of every response channel;
on the hammered DOF the response is largest, so an accelerometer gain there takes most of
what the force gain does and the other channels (where the structure is weakest) hardly
tell them apart.  The stage that finds the fault fits both against the *nominal* model,
which absorbs part of the structural effects beside it, and the set search then pairs
the structure with whichever fault that stage named: the other was never fitted with the
structural members (fresh batch, issue 16: damper m2-ground + spring m3-ground + force
gain force_m1 named with the accelerometer gain acc_m1; clearance m1-m2 + cubic damper
m1-ground + force gain likewise).  ``swap.member_swaps`` swaps only structural laws; here
the chosen set's structural model is re-fitted with the twin fault (its value read afresh:
a force gain from a free force multiplier, ``joint_sensor.force_scale_retune``; an
accelerometer gain from ``1/g`` re-tuned, ``joint_sensor.retune_sensor``) and judged as
every set.  ``swap.swap_rivals`` then names the twin when its validation gap is lower and
it passes the set's checks, and lists it as the member's rival when the gaps are within
the noise margin: the data cannot separate them, and the verdict says so.
"""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from ..processing import Processing
from ..recording import Recording
from .joint_sensor import force_scale_retune, retune_sensor
from .outputs import Progress, _say
from .pulse_reading import explained_by_reading
from .results import Candidate, Location
from ..structure import Structure
from .sensor_faults import ACC_GAIN, FORCE_GAIN, corrected_cost, response_channel
from .set_fit import SetFit, finish_set, mark_stopped
from .settings import FAST, DiagnoseSettings


def driven_dofs(records: Sequence[Recording], dofs: Sequence[str]) -> list[str]:
    """The DOFs whose force channel carries a force on some record (the hammered ones)."""
    out = []
    for dof in dofs:
        ch = f"force_{dof}"
        if any(ch in r.channels and np.any(np.asarray(r.channels[ch]) != 0) for r in records):
            out.append(dof)
    return out


def twin(m: Candidate, records: Sequence[Recording], dofs: Sequence[str]
         ) -> Candidate | None:
    """The twin fault of sensor member ``m`` (module doc) at the value that does what
    ``m``'s does to the hammered DOF's response, or None when ``m`` has none (a delay, an
    accelerometer gain off the hammered DOFs, a model of one hammered DOF with no own
    response channel)."""
    if m.category != "sensor" or not m.effect.is_gain \
            or m.effect.magnitude not in m.coefficients:
        return None
    g = float(m.coefficients[m.effect.magnitude])
    if not (np.isfinite(g) and g > 0):
        return None
    ch = m.loc.between[0]
    driven = driven_dofs(records, dofs)
    chans = records[0].channels if records else {}
    if m.effect.kind == FORCE_GAIN.kind:
        dof = ch[len("force_"):]
        acc = response_channel(chans, dof) if dof in driven else None
        if acc is None:
            return None
        return Candidate(ACC_GAIN, Location(list(dofs).index(dof), -1, (acc, "sensor")), {},
                         coefficients={ACC_GAIN.magnitude: 1.0 / g}, fitted=True,
                         note=f"swapped from {m.label()} in the set")
    if m.effect.kind == ACC_GAIN.kind:
        dof = next((d for d in driven if response_channel(chans, d) == ch), None)
        if dof is None:
            return None
        return Candidate(FORCE_GAIN, Location(list(dofs).index(dof), -1,
                                              (f"force_{dof}", "sensor")), {},
                         coefficients={FORCE_GAIN.magnitude: 1.0 / g}, fitted=True,
                         note=f"swapped from {m.label()} in the set")
    return None


def _at_value(c: Candidate, aug: Structure, theta: np.ndarray, train: Sequence[Recording],
              proc: Processing, nfev: int
              ) -> tuple[Candidate, np.ndarray, float, Any] | None:
    """``aug`` re-fitted from ``theta`` on the records ``c`` corrects at its own value
    (``retune_sensor``'s result shape), None when the cost is not finite."""
    from ..refine import refine

    res = refine(aug, theta, c.correct(train), proc, max_nfev=nfev, uncertainty=FAST)
    th = np.asarray(res.theta, float)
    cost = corrected_cost(aug, th, train, c.effect, c.loc.between[0],
                          float(c.coefficients[c.effect.magnitude]), proc)
    return (c, th, cost, res) if np.isfinite(cost) else None


def sensor_swaps(chosen: SetFit, train: Sequence[Recording], val: Sequence[Recording],
                 proc: Processing, gap_before: float, before_blocks: np.ndarray,
                 settings: DiagnoseSettings, progress: Progress | None = None
                 ) -> list[tuple[int, SetFit]]:
    """(sensor member index, the set with that member swapped for its twin, fitted and
    judged) for a chosen set whose sensor member is a gain with a twin (module doc); a
    force-gain twin the pulse's reading explains is left out (a nuisance, never named:
    ``pulse_reading``)."""
    if chosen.structure is None or chosen.theta is None or settings.swap_kinds < 1 \
            or chosen.structure.n_dof < 2:  # on one DOF the two are one fault
        return []
    aug = chosen.structure
    out: list[tuple[int, SetFit]] = []
    for k, m in enumerate(chosen.members):
        other = twin(m, train, aug.dofs)
        if other is None or m.reading or explained_by_reading(m, train, aug, chosen.theta):
            continue  # a gain the pulse's reading explains is a nuisance: no twin fault
        nfev = max(10, settings.fit_nfev // 2)
        try:  # the structural model on the raw records, the twin's value fitted with it
            got = None
            if other.effect.kind == FORCE_GAIN.kind:
                got = force_scale_retune(other, aug, np.asarray(chosen.theta, float), train,
                                         proc, nfev)
            if got is None:
                got = retune_sensor(other, aug, np.asarray(chosen.theta, float), train,
                                    proc, nfev)
            if got is None:  # its value stands: the model re-fitted on what it corrects
                got = _at_value(other, aug, np.asarray(chosen.theta, float), train, proc,
                                nfev)
        except Exception as exc:  # noqa: BLE001 - no twin set
            _say(progress, f"swap {m.label()} -> {other.label()}: fit failed ({exc})")
            continue
        if got is None:
            _say(progress, f"swap {m.label()} -> {other.label()}: no fit lowers its cost")
            continue
        sensor, theta, cost, res = got
        if sensor.effect.kind == FORCE_GAIN.kind and explained_by_reading(
                sensor, train, aug, theta):
            _say(progress, f"swap {m.label()} -> {sensor.label()}: within the pulse "
                           "reading (a nuisance, not a rival)")
            continue
        members = [sensor if j == k else o for j, o in enumerate(chosen.members)]
        new = SetFit(chosen.effect, chosen.loc, dict(chosen.shape), structure=aug,
                     names=dict(chosen.names), theta=np.asarray(theta, float), fitted=True,
                     amplitudes=chosen.amplitudes, members=members, sensor=sensor)
        mark_stopped(new, False, cost, chosen.train_cost, settings)
        finish_set(new, cost, res, val, proc, gap_before, before_blocks, progress)
        _say(progress, f"swap {m.label()} -> {sensor.label()}: closes {new.closure:.3f} "
                       f"against {chosen.closure:.3f}")
        out.append((k, new))
    return out
