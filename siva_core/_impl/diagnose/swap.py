"""Look-alike laws inside the chosen set (issue 16): each structural member's law swapped
for its look-alike kinds at the same place, the set re-fitted jointly.

The pair search compares look-alikes only at the first stage's lead (``grow.second_leads``):
a member found in a later stage, or a look-alike never fitted alone at that place, is
never swapped, and the set names a wrong law with confidence (fresh seed 17240: cubic
damper m1-m2 + quadratic damper m2-ground named for two quadratic dampers; the quadratic
damper m1-m2 had no stage-1 fit).  Here, once a set is chosen, each structural member
``m`` is replaced by every look-alike law at its place: the other members and the nominal
parameters start at the set's values, the new law at the magnitudes whose force matches
``m``'s along the set's simulated motion there (``law_match``), its shape coefficients
at its single fit's, its screen's and its shape grid's.  Only the ``swap_kinds`` best
kinds per member by the train cost of those starts are refined (one joint refine each,
stopped early as every set fit, ``set_fit.set_stop``).  ``sets.choose_set`` names the
set with the lowest validation gap among the chosen one and its swaps that pass the set's
checks (consistent, every member above the noise), as the single verdict names the best
of its look-alikes, and lists the laws whose set is within ``swap_noise`` x the noise
floor of it as that member's rivals (the data cannot separate them).

Members are also *moved* (branch place2): each structural member's own kind at every
other place the first stage screened (not one the nominal model already holds), started
at the magnitudes whose force along the set's simulated motion *there* matches the
member's, the ``swap_places`` best by the train cost of their starts refined jointly as
above.  A moved set is named only when it also fits all records (train and validation,
its train fit) better than the chosen set: the same law at two places has the same
freedom, so the fit to all records compares them fairly (``ties``), and the validation
records alone can prefer a wrong place that extrapolates better.
"""
from __future__ import annotations

import math
import time
from dataclasses import replace
from typing import Any, Callable, Collection, Sequence

import numpy as np

from ..effects import EFFECTS, Amplitudes, Effect
from ..processing import Processing
from ..recording import Recording
from ..structure import Structure
from .law_match import matched_magnitudes, motion_points, place_motion
from .model_edit import augmented
from .nested import nested_effect, nested_swap
from .budget import clock_of
from .outputs import Progress, _say
from .results import Candidate, Location
from .set_fit import SetFit, _refit, finish_set, mark_stopped, set_stop
from .set_members import contributions, member_coefficients, members_model, shown
from .sensor_swap import sensor_swaps
from .set_test import residual
from .swap_moves import merge_moved, swapped_members
from .settings import DiagnoseSettings
from .verdict import LOOK_ALIKES, same_law


def _kinds(kind: str, settings: DiagnoseSettings) -> list[Effect]:
    """The registered structural effects whose law looks like ``kind``'s (one group of
    ``verdict.LOOK_ALIKES``), among the effects the diagnosis tries."""
    group = next((g for g in LOOK_ALIKES if kind in g), set())
    allowed = set(settings.effects) if settings.effects else set(EFFECTS)
    return [e for n, e in EFFECTS.items() if n in allowed and e.kind in group
            and e.kind != kind and e.family != "sensor"]


def _shapes(effect: Effect, loc: Location, known: Sequence[Candidate], amp: Amplitudes
            ) -> list[dict[str, float]]:
    """Shape coefficients to start ``effect`` at ``loc`` from: its single fit's and
    its screen's there (``known``), then its shape grid on the amplitudes there; only
    complete ones (every coefficient but the magnitude)."""
    out: list[dict[str, float]] = []
    for c in known:
        if c.effect.kind == effect.kind and c.loc.between == loc.between:
            src = c.coefficients if c.fitted and c.coefficients else c.shape
            out.append({k: float(x) for k, x in src.items() if k != effect.magnitude})
    try:
        out += [dict(s) for s in effect.shape_grid(amp)]
    except Exception:  # noqa: BLE001 - the known shapes alone
        pass
    need = set(effect.coefficients) - {effect.magnitude}
    out = [s for s in out if need <= set(s)]
    return [s for k, s in enumerate(out) if s not in out[:k]]


def _places(m: Candidate, known: Sequence[Candidate]
            ) -> list[Location]:
    """The structural places of ``known`` other than ``m``'s, in their first order."""
    seen = {m.loc.between}
    out = []
    for c in known:
        if c.category == "structure" and c.loc.between not in seen:
            seen.add(c.loc.between)
            out.append(c.loc)
    return out


def member_swaps(chosen: SetFit, structure: Structure, train: Sequence[Recording],
                 val: Sequence[Recording], proc: Processing, gap_before: float,
                 before_blocks: np.ndarray, settings: DiagnoseSettings,
                 known: Sequence[Candidate] = (), progress: Progress | None = None,
                 nested_only: bool = False, moves_only: Collection[int] = ()
                 ) -> list[tuple[int, SetFit]]:
    """(member index, the set with that member's law swapped or moved, fitted jointly and
    judged on the validation records) for every structural member of ``chosen``: its
    ``swap_kinds`` most promising look-alike kinds at its place, and its
    ``swap_places`` most promising moves -- its own kind at another place of
    ``known`` -- by the train cost of their starts (module doc).  ``known``: fitted and
    screened singles, for the places and the laws' shape coefficients.  ``moves_only``:
    only these members, and only moved (``swap_moves``: a law that won its swap)."""
    # (a greedy set whose last stage named a sensor fault carries no train cost: its
    # swaps are then fitted without the early stop)
    if settings.swap_kinds < 1 or chosen.structure is None or chosen.theta is None:
        return []
    from ..refine import output_error

    coeffs = member_coefficients(chosen)
    recs = chosen.correct(train)
    out: list[tuple[int, SetFit]] = []
    for k, m in enumerate(chosen.members):
        if m.category != "structure" or k >= len(coeffs) or not coeffs[k]:
            continue
        if moves_only and k not in moves_only:
            continue
        kinds = [] if moves_only else _kinds(m.effect.kind, settings)
        if nested_only:  # the law nested in m's only (``nested``), at m's place
            kinds = [e for e in kinds if e is nested_effect(m.effect.kind)]
        targets = [(eff, m.loc) for eff in kinds]
        if settings.swap_places > 0 and not nested_only:
            # the screen's candidates there (not one the nominal model already holds,
            # as a linear damper where it has one), not another member's
            taken = {o.key for j, o in enumerate(chosen.members) if j != k}
            there = {c.key for c in known if "already represents" not in c.note}
            targets += [(m.effect, loc) for loc in _places(m, known)
                        if (m.effect.kind, loc.between) in there - taken]
        if not targets:
            continue
        motion: dict[tuple[str, str], tuple[np.ndarray, np.ndarray, Any]] = {}
        spots = [m.loc, *(t[1] for t in targets)]  # m's own place: its amplitudes
        for loc in dict.fromkeys(t.between for t in spots):
            where = next(t for t in spots if t.between == loc)
            try:  # the set's motion at each place
                d, v = place_motion(chosen.structure, chosen.theta, where, recs, proc)
                motion[loc] = (d, v, motion_points(d, v))
            except Exception as exc:  # noqa: BLE001 - no swap to this place
                _say(progress, f"swap {m.label()}: no motion at {'-'.join(loc)} ({exc})")
        if m.loc.between not in motion:
            continue
        pts = motion[m.loc.between][2]
        amp = m.amplitudes or Amplitudes(d_max=pts[1][0], v_max=pts[1][1], d_rms=pts[0][0],
                                         v_rms=pts[0][1])
        # the model without m: the nominal one plus every other structural member, at
        # the set's values (its sensor member, if any, keeps correcting the records)
        base, start, others = members_model(structure, chosen, range(len(chosen.members)), k)
        jobs = []
        for eff, loc in targets:
            if loc.between not in motion:
                continue
            d, v, pl = motion[loc.between]
            at = amp if loc.between == m.loc.between else Amplitudes(
                d_max=pl[1][0], v_max=pl[1][1], d_rms=pl[0][0], v_rms=pl[0][1])
            starts, aug, names = [], None, {}
            for shape in _shapes(eff, loc, known, at):
                # m's force along the motion at the new place: the same element moved
                mags = matched_magnitudes(m.effect, coeffs[k], eff, shape, d, v, pl)
                if not mags:
                    continue
                if aug is None:  # the magnitude's scale at the matched force
                    scales = {**{c: max(abs(x), 1e-12) for c, x in shape.items()},
                              eff.magnitude: max(abs(mags[0]), 1e-300)}
                    aug, names = augmented(base, eff, loc, scales)
                for mag in mags:
                    try:
                        starts.append(aug.vector({**start, **{names[c]: x for c, x in
                                                              shape.items() if c in names},
                                                  names[eff.magnitude]: mag}))
                    except (KeyError, ValueError):
                        continue
            if aug is None or not starts:
                continue
            try:
                costs = output_error(aug, np.stack(starts), list(recs), proc)
            except Exception:  # noqa: BLE001 - this kind cannot be simulated here
                continue
            if np.any(np.isfinite(costs)):
                jobs.append((float(np.nanmin(costs)), eff, loc, aug, names, starts))
        jobs.sort(key=lambda j: j[0])
        here = [j for j in jobs if j[2].between == m.loc.between]
        simpler = nested_effect(m.effect.kind)  # always fitted (``nested``)
        here = here[:settings.swap_kinds] + [
            j for j in here[settings.swap_kinds:] if simpler is not None
            and j[1].kind == simpler.kind]
        moved = [j for j in jobs if j[2].between != m.loc.between][:settings.swap_places]
        for cost0, eff, loc, aug, names, starts in here + moved:
            # what an element at loc sees (a known single's there) when m is moved
            amp_at = m.amplitudes if loc.between == m.loc.between else next(
                (c.amplitudes for c in known if c.loc.between == loc.between
                 and c.amplitudes is not None), None)
            fit = clock_of(settings).run(
                "swap", f"{m.label()} -> {new_label(eff, loc)}",
                lambda eff=eff, loc=loc, aug=aug, names=names, starts=starts, amp_at=amp_at:
                _swap_fit(chosen, k, m, others, eff, loc, aug, names, starts, recs, val,
                          proc, gap_before, before_blocks, settings, progress, amp_at))
            if fit is not None:
                out.append((k, fit))
    return out


def new_label(eff: Effect, loc: Location) -> str:
    """A swapped or moved member's label, before its candidate exists."""
    return f"{eff.kind} {'-'.join(loc.between)}"


def _swap_fit(chosen: SetFit, k: int, m: Candidate, others: list[Candidate], eff: Effect,
              loc: Location,
              aug: Structure, names: dict[str, str], starts: list[np.ndarray],
              recs: Sequence[Recording], val: Sequence[Recording], proc: Processing,
              gap_before: float, before_blocks: np.ndarray, settings: DiagnoseSettings,
              progress: Progress | None, amp: Amplitudes | None = None) -> SetFit | None:
    """One swap's joint refit (``set_fit._refit``, stopped early against the chosen set's
    train cost), judged as every set."""
    stop = set_stop(chosen.train_cost, settings)
    try:
        theta, cost, res = _refit(aug, starts, recs, proc, settings.fit_nfev, stop)
    except Exception as exc:  # noqa: BLE001 - a swap that cannot be fitted is none
        _say(progress, f"swap {m.label()} -> {new_label(eff, loc)}: fit failed ({exc})")
        return None
    vals = aug.as_dict(theta)
    moved = loc.between != m.loc.between
    new = Candidate(eff, loc, {c: vals[p] for c, p in names.items()
                                 if c != eff.magnitude}, fitted=True, structure=aug,
                    theta=np.asarray(theta, float), names=dict(names),
                    amplitudes=amp,
                    coefficients={c: vals[p] for c, p in names.items()},
                    note=(f"moved from {m.label()} in the set" if moved
                          else f"law swapped from {m.label()} in the set"))
    members = [new if j == k else o for j, o in enumerate(others)]
    out = SetFit(eff, loc, dict(new.shape), structure=aug, names=dict(names),
                 theta=np.asarray(theta, float), fitted=True, amplitudes=amp,
                 members=members, sensor=chosen.sensor)
    mark_stopped(out, bool(getattr(res, "stopped", False)), cost, chosen.train_cost,
                 settings)
    finish_set(out, cost, res, val, proc, gap_before, before_blocks, progress)
    return out


def swap_rivals(chosen: SetFit, swaps: Sequence[tuple[int, SetFit]], noise: float | None,
                settings: DiagnoseSettings,
                accept: Callable[[SetFit], bool] = lambda s: True
                ) -> tuple[SetFit | None, list[list[dict[str, Any]]]]:
    """The swap to name instead of ``chosen`` -- the lowest validation gap of the set and
    its swaps that ``accept`` passes, as the single verdict names the best of look-alike
    laws -- or None when ``chosen`` stays; and per member of the named set its look-alike
    rivals: the sets with another law for it (swaps, or the replaced law) whose gap is
    within the margin of the named set's (``swap_noise`` x the noise floor, or
    1 - ``separation`` of its gap without a floor): the data cannot separate them."""
    def margin(g: float) -> float:
        return settings.swap_noise * noise if noise is not None and noise > 0 \
            else (1.0 - settings.separation) * g

    ok = sorted(((k, s) for k, s in swaps if not s.stopped and np.isfinite(s.gap_after)
                 and s.gap_after < chosen.gap_after), key=lambda ks: ks[1].gap_after)
    best = next(((k, s) for k, s in ok if accept(s)), None)
    top = best[1] if best is not None else chosen
    rivals: list[list[dict[str, Any]]] = [[] for _ in top.members]
    options = [(k, s) for k, s in swaps if s is not top and not s.stopped
               and np.isfinite(s.gap_after)]
    if best is not None:
        options.append((best[0], chosen))
    named = member_coefficients(top)
    for k, s in options:
        if k < len(rivals) and s.gap_after - top.gap_after <= margin(top.gap_after):
            # a law that acts as the named one over the measured range is no rival (dev
            # seed 24525: a clearance m3-ground with its gap at 0.3 um is the spring)
            if k < len(named) and same_law(replace(top.members[k], coefficients=named[k]),
                                           replace(s.members[k], coefficients=
                                                   member_coefficients(s)[k])):
                continue
            rivals[k].append({"candidate": s.members[k].label(),
                              "closure": float(s.closure),
                              "in_set": s.label()})
    return (best[1] if best is not None else None), rivals


def _moved(s: SetFit, chosen: SetFit) -> bool:
    """Whether a member of ``s`` stands at a place none of ``chosen``'s members has (a
    sensor twin, ``sensor_swap``, at another channel: as much freedom, so all records too)."""
    return bool({m.loc.between for m in s.members}
                - {m.loc.between for m in chosen.members})


def all_records(s: SetFit, records: Sequence[Recording], proc: Processing) -> float:
    """``s``'s residual energy on ``records`` (train and validation) with its train fit;
    inf when it cannot be simulated.  The same law at two places has the same freedom, so
    the fit to all records compares them fairly (``ties``); the validation records alone
    can prefer a wrong place that extrapolates better by what the noise makes."""
    r = residual(s, records, proc)
    return float(r[0] @ r[0]) if r is not None else math.inf


def swap_members(chosen: SetFit, without: Sequence[float], structure: Structure,
                  train: Sequence[Recording], val: Sequence[Recording], proc: Processing,
                  gap_before: float, before_blocks: np.ndarray, noise: float | None,
                  settings: DiagnoseSettings, known: Sequence[Candidate],
                  rule: dict[str, object], progress: Progress | None = None
                  ) -> tuple[SetFit, list[list[dict[str, object]]]]:
    """The chosen set with each structural member's look-alike laws swapped in
    (``swap``): the swap with the lowest validation gap replaces it when it is
    consistent and every member still shows above the noise (``swap_rivals``); the sets
    within ``swap_noise`` x the floor of the named one give the members' rivals.  Each member's ``closure_added`` is what the set loses
    without it (the others' single gaps, as the set was judged)."""
    from .verdict import _consistent

    t0 = time.perf_counter()
    swaps = member_swaps(chosen, structure, train, val, proc, gap_before, before_blocks,
                         settings, known, progress)
    # the sensor member's twin fault too (``sensor_swap``: acc gain <-> force gain)
    swaps += sensor_swaps(chosen, train, val, proc, gap_before, before_blocks, settings,
                          progress)
    rule["swap_s"] = time.perf_counter() - t0  # CPU share of the swaps (must-show 3)
    _say(progress, f"swaps: {len(swaps)} fitted in {rule['swap_s']:.1f} s")
    if not swaps:
        return chosen, []
    tried: list[dict[str, Any]] = [{"set": s.label(), "closure": float(s.closure),
                                    "stopped": bool(s.stopped)} for _, s in swaps]
    rule["swaps"] = tried
    contrib: dict[int, list[float]] = {}
    records = [*train, *val]
    def accept_against(ref: SetFit) -> Callable[[SetFit], bool]:
        ref_all: list[float] = []  # the reference set on all records, simulated once
        return lambda s: accept(s, ref, ref_all)

    def accept(s: SetFit, ref: SetFit, ref_all: list[float]) -> bool:
        """As the set was judged: consistent, each one shows; a member at a place none
        of ``ref``'s has must fit all records better than ``ref``."""
        contrib[id(s)] = contributions(s, val, proc)
        low = not all(shown(s, contrib[id(s)], val, proc, noise, settings)[0])
        consistent = _consistent(s, settings.record_tolerance)
        entry = next((e for e in tried if e["set"] == s.label()), {})
        entry.update({"contributions": [float(x) for x in contrib[id(s)]],
                      "consistent": bool(consistent)})
        if low or not consistent:
            _say(progress, f"swap {s.label()}: refused ("
                           + ("a record worse" if not consistent else "contributions "
                              + ", ".join(f"{x:.3g}" for x in contrib[id(s)])
                              + f" against {settings.contribution_noise:g} x the floor "
                              f"{noise:.3g}") + ")")
            return False
        if _moved(s, ref):  # a member at another place must fit all records better
            if not ref_all:
                ref_all.append(all_records(ref, records, proc))
            mine, theirs = all_records(s, records, proc), ref_all[0]
            entry.update({"all_records": mine, "chosen_all_records": theirs})
            if not mine < theirs:
                _say(progress, f"swap {s.label()}: refused (all records {mine:.4g} against "
                               f"{ref.label()}'s {theirs:.4g})")
                return False
        return True

    win, rivals = swap_rivals(chosen, swaps, noise, settings, accept_against(chosen))
    ks = swapped_members(chosen, win) if win is not None else []
    moves = member_swaps(win, structure, train, val, proc, gap_before, before_blocks,
                         settings, known, progress, moves_only=ks) if ks else []
    if win is not None and moves:  # a law that won its swap, moved too (``swap_moves``)
        best, place = swap_rivals(win, moves, noise, settings, accept_against(win))
        win, rivals = merge_moved(win, best, moves, rivals, place, ks, tried, rule, progress)
    top = win if win is not None else chosen
    options = [s for _, s in swaps] + [chosen]
    if win is not None and any(nested_effect(m.effect.kind) for m in win.members):
        # the nested law fitted from the named set's own values (the chosen set, fitted
        # otherwise, is no fair comparison: 17549's greedy spring set)
        again = member_swaps(win, structure, train, val, proc, gap_before, before_blocks,
                             settings, known, progress, nested_only=True)
        options += [s for _, s in again]
    simpler = nested_swap(top, options, val, proc, settings, accept_against(chosen), rule,
                         progress)
    if simpler is not None:  # the richer law unproven: the nested one named, it a rival
        k, win = simpler
        while len(rivals) <= k:
            rivals.append([])
        rivals[k] = [r for r in rivals[k] if r["candidate"] != win.members[k].label()] + [
            {"candidate": top.members[k].label(), "closure": float(top.closure),
             "in_set": top.label()}]
    if win is not None:
        _say(progress, f"swap: {win.label()} closes {win.closure:.3f} against "
                       f"{chosen.label()}'s {chosen.closure:.3f}")
        rule["swapped"] = {"from": chosen.label(), "to": win.label()}
        for m, x, w in zip(win.members, contrib.get(id(win)) or contributions(win, val, proc),
                           without):
            m.contribution = float(x)
            m.closure_added = float((w - win.gap_after) / gap_before) \
                if gap_before > 0 else math.nan
        chosen = win
    return chosen, rivals
