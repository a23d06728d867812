"""A set grown by one member (issue 16: three effects, two structural + a sensor fault).

The pair search names at most two effects; a third one (the generator draws up to two
structural effects and a sensor fault) was named only when the greedy stages happened to
find all three in turn.  Here a fitted set (a pair) gets one more member -- a structural
single at a place the set does not use, or a sensor fault when it has none -- and the
whole set is re-fitted jointly from the set's fit and the member's single fit, the same
way ``pair_fit.fit_pair`` fits a pair: a sensor fault's value is re-tuned with the structural
model (``joint_sensor``), a structural member joins the model on the records the set's
sensor member corrects.  Also here: which singles the pair search pairs beyond the
combinations of its members (``partners``: the lead with other kinds by train cost;
``joiners``: sensor faults, fitted or only scanned; ``worth_pairing``: a later stage's
fits paired with the effect named before it).  How a set is judged against its
sub-sets is ``sets.choose_set``'s business.
"""
from __future__ import annotations

import math
import time
from typing import Sequence

import numpy as np

from ..processing import Processing
from ..recording import Recording
from ..structure import Structure
from .joint_sensor import retune_sensor
from .model_edit import augmented
from .budget import clock_of
from .outputs import Progress, _say
from .parallel import run_each, worker_count
from .results import Candidate
from .set_rules import can_pair
from .set_fit import SetFit, _refit, finish_set, mark_stopped, refit_stopped, set_stop
from .settings import DiagnoseSettings


def can_grow(base: SetFit, c: Candidate) -> bool:
    """``c`` can join ``base``: a sensor fault when the set has none, a structural effect
    that every structural member can be paired with (``set_rules.can_pair``)."""
    if any(m.key == c.key for m in base.members):
        return False
    if c.category == "sensor":
        return base.sensor is None
    return all(can_pair(m, c) for m in base.members)


def grow(base: SetFit, c: Candidate, structure: Structure, train: Sequence[Recording],
         val: Sequence[Recording], proc: Processing, gap_before: float,
         before_blocks: np.ndarray, settings: DiagnoseSettings,
         progress: Progress | None = None, against: float = math.inf) -> SetFit | None:
    """``base`` plus the fitted single ``c``, re-fitted jointly and judged on the
    validation records; None when it cannot be built or simulated.  ``against``: the
    best train cost known (``set_fit.set_stop``, as ``pair_fit.fit_pair``)."""
    if not can_grow(base, c) or base.structure is None or base.theta is None:
        return None
    t0 = time.perf_counter()
    nfev = settings.fit_nfev
    stop = set_stop(against, settings, min(base.train_cost, c.train_cost))
    stopped = False
    try:
        vals = base.structure.as_dict(base.theta)
        if c.category == "sensor":  # the set's model on the records c corrects
            aug, names = base.structure, dict(base.names)
            starts = [np.asarray(base.theta, float)]
            nom_c = {p: v for p, v in (c.parameters or {}).items()
                     if p in vals and p in structure.free}
            if nom_c:
                starts.append(aug.vector({**vals, **nom_c}))
            theta, cost, res = _refit(aug, starts, c.correct(train), proc, nfev, stop)
            sensor = c
            effect, loc, shape, amps = base.effect, base.loc, dict(base.shape), base.amplitudes
        else:  # c joins the model, on the records the set's sensor member corrects
            scales = {k: max(abs(v), 1e-12) for k, v in c.coefficients.items()}
            aug, names = augmented(base.structure, c.effect, c.loc, scales)
            start = {**vals, **{names[k]: v for k, v in c.coefficients.items()}}
            theta, cost, res = _refit(aug, [aug.vector(start)], base.correct(train), proc,
                                      nfev, stop)
            sensor = base.sensor
            effect, loc, shape, amps = c.effect, c.loc, dict(c.shape), c.amplitudes
        stopped = bool(getattr(res, "stopped", False))
        if sensor is not None and not stopped:  # the fault's value re-fitted with it
            again = retune_sensor(sensor, aug, theta, train, proc, max(10, nfev // 2))
            if again is not None:
                sensor, theta, cost, res = again
    except Exception as exc:  # noqa: BLE001 - a set that cannot be fitted is not a set
        _say(progress, f"set {base.label()} + {c.label()}: fit failed ({exc})")
        return None
    members = [sensor if m.category == "sensor" else m for m in base.members]
    members += [sensor] if c.category == "sensor" else [c]
    out = SetFit(effect, loc, shape, structure=aug, names=names, theta=theta, fitted=True,
                 amplitudes=amps, members=members, sensor=sensor)
    mark_stopped(out, stopped, cost, against, settings)
    finish_set(out, cost, res, val, proc, gap_before, before_blocks, progress)
    out.fit_time_s = time.perf_counter() - t0
    return out


def partners(ranking: Sequence[Candidate], members: Sequence[Candidate],
             settings: DiagnoseSettings) -> tuple[Candidate | None, list[Candidate]]:
    """The lead to pair and structural singles of *other kinds* paired with it only.

    The lead is the first structural member, or when none closes anything alone the best
    structural fit by train cost (dev seed 16639: a missing spring m2-ground lowered the
    train cost by 42 % but made the validation records 3 x worse without the force gain
    and the quadratic spring also present; every single closed < 0.05, nothing was
    paired).  Its partners: the best fit by train cost of every kind none of ``members``
    has, at a place other than the lead's, at most ``pair_partners`` of them.  The
    members by validation closure at distinct places are often one law at three places
    (a leader and its look-alike places, rivals rather than complements), while the
    second effect of a pair, its single fit judged without the first, closes little of
    the validation gap (dev seed 16615: clearance m1-ground 0.54, clearance m2- and
    m3-ground 0.35 and 0.34 were paired; the true coulomb m2-m3, 0.26, fifth, never
    was).  Its train cost still shows it."""
    fits = sorted((c for c in ranking if c.category == "structure" and c.fitted
                   and not c.stopped and np.isfinite(c.train_cost)
                   and np.isfinite(c.closure)), key=lambda c: c.train_cost)
    struct = [c for c in members if c.category == "structure"]
    lead = struct[0] if struct else (fits[0] if fits else None)
    if lead is None or settings.pair_partners < 1:
        return lead, []
    kinds = {c.effect.kind for c in [*struct, lead]}
    out: list[Candidate] = []
    for c in fits:
        if c.effect.kind in kinds or c.loc.between == lead.loc.between:
            continue
        kinds.add(c.effect.kind)
        out.append(c)
        if len(out) >= settings.pair_partners:
            break
    return lead, out


def second_leads(ranking: Sequence[Candidate], lead: Candidate | None,
                 settings: DiagnoseSettings) -> list[Candidate]:
    """Look-alike laws fitted at the lead's place (``verdict.look_alike``), best train
    cost first: the first ``settings.lookalike_leads`` are fitted again from the lead's
    force (``refit_from_lead``) and paired with the lead's best mates
    (``sets.choose_set``).  A wrong-law lead blocks the right pair otherwise
    (issue 16, chain3:two:0: a linear damper m3-ground led where a quadratic one was
    true; the quadratic damper m3-ground was never paired)."""
    from .verdict import look_alike

    if lead is None or lead.category != "structure" or settings.lookalike_leads < 1:
        return []
    out = sorted((c for c in ranking if c.category == "structure" and c.fitted
                  and c.key != lead.key and c.loc.between == lead.loc.between
                  and look_alike(lead.effect.kind, c.effect.kind)
                  and c.structure is not None and c.theta is not None),
                 key=lambda c: c.train_cost if np.isfinite(c.train_cost) else math.inf)
    return out


def law_swap(c: Candidate, lead: Candidate, train: Sequence[Recording],
             proc: Processing) -> list[np.ndarray]:
    """Starts for ``c`` (a look-alike law at the lead's place) in its own model: the lead's
    nominal parameters and the magnitude whose force matches the lead's along the lead's
    simulated train runs at that place (least squares), and the magnitudes whose force
    equals the lead's at the place's RMS and at its largest amplitude.  A look-alike's own
    single fit can stall near zero (measured: a quadratic damper m3-ground beside a linear
    one, c2 = 1.2e-5, at the nominal's train cost) where the lead's force, expressed in
    its law, is a start near the truth."""
    from .law_match import matched_magnitudes, motion_points, place_motion

    if (c.structure is None or c.theta is None or not c.names or lead.structure is None
            or lead.theta is None):
        return []
    try:  # the lead's own motion at its place, on the train records
        d, v = place_motion(lead.structure, lead.theta, lead.loc, train, proc)
        pts = motion_points(d, v)
    except Exception:  # noqa: BLE001 - the amplitudes alone
        d = v = None
        amp = c.amplitudes or lead.amplitudes
        pts = [] if amp is None else [(amp.d_rms, amp.v_rms), (amp.d_max, amp.v_max)]
    mags = matched_magnitudes(lead.effect, lead.coefficients, c.effect, c.coefficients,
                              d, v, pts)
    base = {**c.structure.as_dict(c.theta), **dict(lead.parameters or {})}
    out = []
    for mag in mags:
        try:
            out.append(c.structure.vector({**base, c.names[c.effect.magnitude]: mag}))
        except (KeyError, ValueError):
            continue
    return out


def refit_from_lead(c: Candidate, lead: Candidate, structure: Structure,
                    train: Sequence[Recording], val: Sequence[Recording], proc: Processing,
                    gap_before: float, before_blocks: np.ndarray,
                    settings: DiagnoseSettings, progress: Progress | None = None
                    ) -> list[np.ndarray]:
    """Fit the look-alike ``c`` alone again from its own fit and the lead's force in its
    law (``law_swap``); kept (and judged again) when the train cost drops.  Returns the
    law-swap starts (in ``c``'s model) for the pairs it leads.

    ``c``'s model is rebuilt with its magnitude's scale at the lead's force (a single fit
    that stalled near zero set it from a vanishing estimate: measured, a joint fit then
    cannot move the magnitude).  Alone, a look-alike can still fit no better than the
    nominal model on the train records (the other effect of the pair is what the lead
    was absorbing): the starts, not its single fit, are what its pairs need."""
    from .scoring import judge

    if c.structure is None or c.theta is None or not c.names:
        return []
    starts = law_swap(c, lead, train, proc)
    if not starts:
        return []
    mag_p = c.names[c.effect.magnitude]
    mags = [float(c.structure.as_dict(t)[mag_p]) for t in starts]
    try:  # same parameter names and order: the nominal model plus the same element
        scales = {**{k: max(abs(v), 1e-12) for k, v in c.coefficients.items()},
                  c.effect.magnitude: max(abs(mags[0]), 1e-300)}
        aug, names = augmented(structure, c.effect, c.loc, scales)
        if names == c.names and aug.free == c.structure.free:
            c.structure = aug
    except Exception:  # noqa: BLE001 - the old scale stands
        pass
    try:  # past the budget its single fit stands and only the starts serve its pairs
        got = clock_of(settings).run(
            "look-alike refit", c.label(),
            lambda: _refit(c.structure, [np.asarray(c.theta, float), *starts], train,
                           proc, settings.fit_nfev))
    except Exception as exc:  # noqa: BLE001 - its single fit stands
        _say(progress, f"{c.label()}: refit from the lead's force failed ({exc})")
        return starts
    if got is None:
        return starts
    theta, cost, _ = got
    at = ", ".join(f"{m:.4g}" for m in mags)
    if not (np.isfinite(cost) and cost < c.train_cost):
        _say(progress, f"{c.label()}: refit from {lead.label()}'s force (starts {at}): "
                       f"train {cost:.4g}, not below its fit's {c.train_cost:.4g}")
        return starts
    _say(progress, f"{c.label()}: refit from {lead.label()}'s force (starts {at})")
    c.theta, c.train_cost, c.stopped = np.asarray(theta, float), float(cost), False
    vals = c.structure.as_dict(c.theta)
    c.coefficients = {k: vals[p] for k, p in c.names.items()}
    c.parameters = {p: v for p, v in vals.items() if p not in c.names.values()}
    c.intervals = {}
    c.note = ((c.note + "; ") if c.note else "") + f"refitted from {lead.label()}'s force"
    judge(c, val, proc, gap_before, before_blocks, progress)
    return starts


def joiners(ranking: Sequence[Candidate], verdicts: Sequence[Candidate],
            scanned: Sequence[Candidate] = ()) -> list[Candidate]:
    """Sensor faults that may join a structural effect (as its pair's second member or a
    pair's third): the best fitted one by train cost (its validation closure alone says
    little when a structural effect is also present), the one a greedy stage named, and
    the best one the stage only *scanned* (its value from the scan; the joint fit re-fits
    it with the structural model, ``joint_sensor``).  A fault the structural effect hides
    can miss the stage's ``sensor_gain`` (dev seed 16634: an 11 % accelerometer gain
    beside a cubic damper lowered the nominal train cost by 17 %, not 20 %, was never
    fitted, and no pair held it)."""
    sens = sorted((c for c in ranking if c.category == "sensor" and c.fitted
                   and np.isfinite(c.train_cost)), key=lambda c: c.train_cost)
    out = [*sens[:1], *[v for v in verdicts if v.category == "sensor"]]
    rest = sorted((c for c in scanned if c.category == "sensor" and not c.fitted
                   and np.isfinite(c.scan_cost) and c.effect.magnitude in c.coefficients),
                  key=lambda c: c.scan_cost)
    out += rest[:1]
    return [c for k, c in enumerate(out) if all(c.key != o.key for o in out[:k])]


def grow_sets(options: Sequence[SetFit], joining: Sequence[Candidate], structure: Structure,
              train: Sequence[Recording], val: Sequence[Recording], proc: Processing,
              gap_before: float, before_blocks: np.ndarray, noise: float | None,
              settings: DiagnoseSettings, progress: Progress | None = None,
              against: float = math.inf) -> list[SetFit]:
    """Sets of three: the ``set_beam`` best pairs by validation gap (each closing at least
    ``step_min``) grown by every candidate in ``joining`` that can join them
    (``grow.can_grow``), each fitted jointly.  None when at most two effects are allowed
    or the best pair already leaves no more than ``kind_check_noise`` x the noise floor
    (nothing left for a third effect to explain).  ``against``: the best train cost
    known, each joint fit's early stop (``set_fit.set_stop``)."""
    if settings.max_effects < 3 or settings.set_beam < 1:
        return []
    twos = sorted((o for o in options if len(o.members) == 2 and np.isfinite(o.gap_after)
                   and o.closure >= settings.step_min and not o.stopped),
                  key=lambda o: o.gap_after)
    if not twos or (noise is not None
                    and twos[0].gap_after <= settings.kind_check_noise * noise):
        return []
    seen = {frozenset(m.key for m in o.members) for o in options}
    jobs = []
    for base in twos[:settings.set_beam]:
        for c in joining:
            key = frozenset([*(m.key for m in base.members), c.key])
            if key not in seen and can_grow(base, c):
                seen.add(key)
                jobs.append((base, c))
    def one(bc: tuple[SetFit, Candidate], ref: float) -> SetFit | None:
        return clock_of(settings).run(
            "set of three", f"{bc[0].label()} + {bc[1].label()}",
            lambda: grow(bc[0], bc[1], structure, train, val, proc, gap_before,
                         before_blocks, settings, progress, ref))

    fits = run_each(lambda bc: one(bc, against), jobs, worker_count(settings))
    origin = {id(f): bc for f, bc in zip(fits, jobs) if f is not None}
    return refit_stopped([f for f in fits if f is not None],
                         lambda o: one(origin[id(o)], math.inf), settings)


def worth_pairing(ranking: Sequence[Candidate], train_cost: float,
                 settings: DiagnoseSettings) -> list[Candidate]:
    """A later stage's structural fits worth pairing with the effect named before it
    (a sensor fault, or a structural effect when that stage names nothing): the
    ``pair_members`` best by train cost (one per kind and place) that lower the stage's
    starting train cost by ``step_min`` / 2 at least.  Their *validation* closure says
    little: they were fitted on records corrected with (or a model holding) the first
    effect fitted without them (joint_sensor's doc: the clearance of seed 13010 closed
    -0.37 after a sensor fault; branch second: 17278's damper m2-ground, refused alone,
    completes the pair)."""
    fits = sorted((c for c in ranking if c.category == "structure" and c.fitted
                   and np.isfinite(c.train_cost)
                   and c.train_cost <= (1 - settings.step_min / 2) * train_cost),
                  key=lambda c: c.train_cost)
    return fits[:settings.pair_members]
