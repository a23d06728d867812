"""Sets of effects (issue 16): more than one cause as the normal case.

The greedy stages add one effect at a time; a right first effect that leaves a record
worse because a second is missing, or two effects of which neither closes half the gap
alone, are lost that way.  Here the leading single candidates are paired and each pair
is re-fitted *jointly* (structural + structural: both elements in one model; sensor +
structural: the structural candidate fitted on the sensor-corrected records), and sets
are compared by their validation gap: a larger set replaces a smaller one only when the
effect it adds removes a real part of what the smaller one leaves (``step_min`` of it and
more than the noise) and every member is needed (without it the set's gap grows by
``step_min``).  Every named member must also *show above the noise*: its own
contribution to the simulated validation outputs (the output change from the best fit
known without it, ``without_member``) must exceed ``contribution_noise`` x the floor: a
spurious element fitted to a residue (the issue's null: k = 16 N/m) moves them less.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ..processing import Processing
from ..recording import Recording
from ..structure import Structure
from .grow import grow_sets, joiners, partners, refit_from_lead, second_leads
from .no_single import no_single_closes, weak_pairs
from .outputs import Progress, _say
from .pair_fit import best_known, fit_pair
from .parallel import run_each, worker_count
from .pulse_reading import (nuisance_reading, outside_range, reading_range,
                            within_range)
from .results import Candidate
from .scoring import judge
from .set_fit import SetFit, refit_stopped
from .pruned import without_members
from .set_rules import better, can_pair, pair_members, relevant
from .set_members import (contributions, member_coefficients, shown, shown_pinned,
                          with_embedded)
from .set_test import BlockTest, without_fits
from .member_test import held_out_shows, look_alike_member, unseparated
from .swap import swap_members
from .settings import DiagnoseSettings
from .verdict import closes_above_noise
from .without_member import KnownFits


def _greedy_set(verdicts: Sequence[Candidate], val: Sequence[Recording], proc: Processing,
                gap_before: float, before_blocks: np.ndarray,
                progress: Progress | None) -> SetFit | None:
    """The effects the greedy stages added, as one set judged on the original records
    (the last stage's model holds them all; a sensor member corrects the records)."""
    last = verdicts[-1]
    if last.structure is None or last.theta is None:
        return None
    sensor = next((v for v in verdicts if v.category == "sensor"), None)
    g = SetFit(last.effect, last.loc, dict(last.shape), structure=last.structure,
               names=dict(last.names), theta=last.theta, fitted=True,
               amplitudes=last.amplitudes, members=list(verdicts), sensor=sensor)
    g.train_cost = last.train_cost
    g.coefficients = dict(last.coefficients)
    if sensor is last:  # a sensor found after a structural effect: its model is the last's
        g = SetFit(verdicts[0].effect, verdicts[0].loc, dict(verdicts[0].shape),
                   structure=last.structure, names=dict(verdicts[0].names), theta=last.theta,
                   fitted=True, amplitudes=verdicts[0].amplitudes, members=list(verdicts),
                   sensor=sensor)
    judge(g, val, proc, gap_before, before_blocks, progress)
    return g


def choose_set(verdict: Candidate | None, verdicts: Sequence[Candidate],
               ranking: Sequence[Candidate], structure: Structure,
               train: Sequence[Recording], val: Sequence[Recording], proc: Processing,
               gap_before: float, before_blocks: np.ndarray, noise: float | None,
               settings: DiagnoseSettings, progress: Progress | None = None,
               later: Sequence[Candidate] = (), scanned: Sequence[Candidate] = (),
               shadowed_keys: frozenset[tuple[str, tuple[str, str]]] = frozenset(),
               refused: Sequence[Candidate] = (), known: KnownFits | None = None,
               tied: Sequence[tuple[Candidate, Candidate]] = (),
               nominal_cost: float = math.nan
               ) -> tuple[Candidate | None, list[Candidate], dict[str, object]]:
    """Compare the single verdict, the greedy stages' set and the joint pair fits by their
    validation gaps (module doc); returns (verdict, named effects, rule entries).
    ``later``: structural candidates of the stages after a named sensor fault, each
    paired with that fault (its value re-fitted with them: ``joint_sensor``).
    ``scanned``: the first stage's screened and scanned candidates (``joiners``).
    ``shadowed_keys``: accelerometer gains whose last stage found them shadowed by a force
    gain within the pulse-reading band (``pulse_reading.shadowed_by_reading``): a set with
    a re-fitted copy of one is refused too.  A force gain within the band is not among
    them: in a set it is the records' nuisance (``nuisance_reading``).
    ``refused``: the best fits of a later stage that named nothing, each paired with the
    one structural effect named before it.  ``known``: the fits without a member
    (``without_member``), for the contributions.  ``tied``: more pairs (``tie_pairs``).
    ``nominal_cost``: the nominal train cost (``no_single.weak_pairs``)."""
    from itertools import combinations

    from .verdict import _consistent

    rule: dict[str, object] = {}
    options: list[SetFit] = []
    if len(verdicts) > 1:
        g = _greedy_set(verdicts, val, proc, gap_before, before_blocks, progress)
        if g is not None:
            options.append(g)
    explained = verdict is not None and verdict.closure >= settings.kind_check and (
        noise is None or verdict.gap_after <= settings.kind_check_noise * noise)
    if settings.pairs and not explained and (noise is None
                                             or gap_before > settings.noise_factor * noise):
        members = pair_members(ranking, settings, settings.pair_members)
        # look-alike laws at the lead's place, fitted again from the lead's force in their
        # law: second leads of the pairs (``grow.second_leads``)
        lead0 = partners(ranking, members, settings)[0]
        seconds = [] if any(o.closure >= settings.kind_check and noise is not None
                            and o.gap_after <= settings.kind_check_noise * noise
                            for o in options) else second_leads(ranking, lead0, settings)
        swap_starts: dict[tuple[str, tuple[str, str]], list[np.ndarray]] = {}
        if seconds:
            seconds = seconds[:settings.lookalike_leads]
            for c in seconds:
                swap_starts[c.key] = refit_from_lead(c, lead0, structure, train, val, proc,
                                                     gap_before, before_blocks, settings,
                                                     progress)
            ranking = sorted(ranking, key=lambda c: (
                c.reading, -c.closure if np.isfinite(c.closure) else math.inf))
            members = pair_members(ranking, settings, settings.pair_members)
        # a greedy set that explains the gap to the noise (as ``explained`` for a single)
        # is not searched around: only the pairs of the members, as before issue 16's
        # fifth round (CPU: a LO-NO pair fit takes 10-30 s)
        settled = any(o.closure >= settings.kind_check and noise is not None
                      and o.gap_after <= settings.kind_check_noise * noise for o in options)
        # a greedy set with a sensor fault is fitted again as a pair: the fault's value
        # re-fitted with the structural model, as every other sensor + structural pair
        done = {frozenset(m.key for m in o.members) for o in options
                if o.sensor is None or settled}
        sensor = next((v for v in verdicts if v.category == "sensor"), None)
        extra = [(c, sensor) for c in later if sensor is not None]
        # a later stage that named nothing: its best fits, each with the one effect named
        # before it (fresh seed 17278: the damper m2-ground of stage 2, refused alone as
        # below the faint floor, was never paired with the quadratic damper m1-m2)
        if len(verdicts) == 1 and verdicts[0].category == "structure":
            extra += [(verdicts[0], c) for c in refused]
        extra += list(tied)  # the tied first leads with the later effects (tie_pairs)
        joining = joiners(ranking, verdicts, scanned)
        # ranked by train cost, unless the greedy stages' set already closes enough
        if no_single_closes(ranking, gap_before, noise, settings) and not any(
                o.closure >= settings.tentative_closure for o in options):
            weak = weak_pairs(ranking, joining, nominal_cost, settings)
            rule["no_single_pairs"] = said = [f"{a.label()} + {b.label()}" for a, b in weak]
            _say(progress, "no single closes much: pairs by train cost "
                 + (", ".join(said) or "none (no single lowers the train cost enough)"))
            extra += weak
        lead, mates = partners(ranking, members, settings)
        faults = [] if settled else joining
        if settled:
            lead, mates = None, []
        if lead is not None:
            extra += [(lead, c) for c in [*mates, *faults]]
            mates = [lead, *mates]
        # settled: not the members' pairs either (the first member with each candidate was
        # fitted jointly by stage 2, which chose the second; a pair without the first must
        # beat a set at the noise floor); ``extra`` still (lonomax2: 21 s of lono:two:0)
        combos = [] if settled else list(combinations(members, 2))
        pairs = []
        for a, b in [*combos, *extra]:
            if frozenset((a.key, b.key)) not in done:
                done.add(frozenset((a.key, b.key)))
                pairs.append((a, b))
        # independent joint fits: on the cores (``parallel.run_each``), kept in order;
        # each stopped early against the best set or single known before them
        against = best_known(options, ranking)

        def pair(ab: tuple[Candidate, Candidate], ref: float) -> SetFit | None:
            return fit_pair(ab[0], ab[1], structure, train, val, proc, gap_before,
                            before_blocks, settings, progress, ref,
                            swap_starts.get(ab[0].key, ()))

        def fit_all(abs_: list[tuple[Candidate, Candidate]]) -> list[SetFit]:
            fits = run_each(lambda ab: pair(ab, against), abs_, worker_count(settings))
            origin = {id(f): ab for f, ab in zip(fits, abs_) if f is not None}
            fitted = [p for p in fits if p is not None]
            return with_embedded(fitted + refit_stopped(
                fitted, lambda o: pair(origin[id(o)], math.inf), settings), verdicts)

        options += fit_all(pairs)
        # the look-alike second leads, each with the lead's best mates: the members at
        # another place (or the sensor fault) of the lead's best pairs by validation gap
        # (fresh seed 17219: a quadratic damper + force gain led, the cubic damper with
        # the same gain, never paired before, closes 0.96 against 0.88)
        swaps = []
        if lead is not None and seconds:
            best = sorted((o for o in options if len(o.members) == 2
                           and np.isfinite(o.gap_after)
                           and any(m.key == lead.key for m in o.members)),
                          key=lambda o: o.gap_after)
            with_lead = [m for o in best for m in o.members
                         if m.key != lead.key and m.loc.between != lead.loc.between]
            with_lead = [m for k, m in enumerate(with_lead)
                         if all(m.key != o.key for o in with_lead[:k])]
            swaps = [(x, m) for m in with_lead[:settings.lookalike_mates] for x in seconds
                     if x.key != lead.key and frozenset((x.key, m.key)) not in done]
            swaps = swaps[:settings.lookalike_pairs]
            done.update(frozenset((x.key, m.key)) for x, m in swaps)
            swaps += _later_mates(seconds, refused, lead, done, settings)
        if swaps:
            against = best_known(options, ranking)
            options += fit_all(swaps)
        # three effects: the best pairs grown by one more member (``grow``)
        options += grow_sets(options, [*members, *mates, *faults],
                             structure, train, val, proc, gap_before, before_blocks, noise,
                             settings, progress, best_known(options, ranking))
    singles = {c.key: c for c in ranking if np.isfinite(c.gap_after)}
    single_gap = {k: c.gap_after for k, c in singles.items()}
    # every set fitted, by its members: a set of three without one member is the pair of
    # the other two when that pair was fitted
    fitted_sets = {frozenset(m.key for m in o.members): o for o in options
                   if np.isfinite(o.gap_after)}
    set_gap = {k: o.gap_after for k, o in fitted_sets.items()}
    cur_gap = verdict.gap_after if verdict is not None else gap_before
    tester = BlockTest(val, proc, settings.test_blocks)
    chosen: SetFit | None = None
    chosen_without: list[float] = []
    chosen_own: list[str] = []
    chosen_nuisance: list[Candidate] = []
    tried = []
    queue = sorted(options, key=_gap)
    while queue:
        s = queue.pop(0)
        alone = [single_gap.get(m.key, gap_before) for m in s.members]
        # without a member, the set is (about) the other member alone
        without = [min(alone[:k] + alone[k + 1:], default=gap_before)
                   for k in range(len(alone))]
        keys = [m.key for m in s.members]
        if len(keys) > 2:
            without = [set_gap.get(frozenset(keys[:k] + keys[k + 1:]), w)
                       for k, w in enumerate(without)]
        need = settings.closure_min if verdict is not None else settings.tentative_closure
        # a sensor member re-fitted with the set may land within the pulse-reading band:
        # then it is a nuisance of the records, not a fault (``nuisance_reading``)
        # ... unless the set's own fit pins it outside that band, value and interval
        # (``outside_reading``): then it is a fault, whatever its single fit said
        ranges = [reading_range(m, train, s.structure, s.theta) for m in s.members]
        pinned = [m.category == "sensor" and outside_range(m, r)
                  for m, r in zip(s.members, ranges)]
        reading = [m.category == "sensor" and not p and (m.reading or within_range(m, r))
                   for m, r, p in zip(s.members, ranges, pinned)]
        # an accelerometer gain its stage found shadowed by the force gain's reading
        # (``pulse_reading.shadowed_by_reading``) refuses the set: not a nuisance either
        shadowed = any(m.key in shadowed_keys for m in s.members)
        nuisance = nuisance_reading(s, reading, single_gap, gap_before)
        # the size: of the gap (of what the nuisance gain alone leaves), or of its part
        # above the noise floor
        ref = nuisance if nuisance is not None else gap_before
        # the members judged as needed: all but a nuisance gain
        # each "without" as a fitted set too: the held-out test of ``better``
        wo = without_fits(s.members, singles, fitted_sets)
        # a pinned gain's step is judged on the gap above the floor (``set_rules.better``)
        judged = [(w, lambda f=f, s=s: tester.z(f, s), p) for w, f, r, p
                  in zip(without, wo, reading, pinned) if not (r and nuisance is not None)]
        # each member separated from an effect of another role in its place (``member_test``)
        unsep = [(k, o) for k, o in (unseparated(s.members, s.gap_after, fitted_sets,
                                                 settings.separation)
                                     if settings.member_separation and len(s.members) > 1
                                     else []) if not (reading[k] and nuisance is not None)]
        # a member that looks like the rest of the set needs the held-out test as well
        # (``member_test``): the margins alone let a generic coefficient in
        alike = [k for k, (f, r, p) in enumerate(zip(wo, reading, pinned))
                 if settings.member_test and not p and not (r and nuisance is not None)
                 and look_alike_member(s.members, k)]
        alike_ok = all(held_out_shows(s.members, k, tester.z(wo[k], s) if wo[k] is not None
                                      else math.nan, settings.test_z) for k in alike)
        vs_single = (lambda s=s: tester.z(verdict, s)) if verdict is not None else None
        adds_pinned = verdict is not None and any(m.key == verdict.key for m in s.members) \
            and all(p for m, p in zip(s.members, pinned) if m.key != verdict.key)
        checks = {"relevant": relevant(ref, 1.0 - s.gap_after / ref, noise, settings),
                  "not_pulse_reading": not shadowed and (not any(reading)
                                                          or nuisance is not None),
                  "closure": bool(1.0 - s.gap_after / ref >= need or closes_above_noise(
                      ref, s.gap_after, noise, need, settings)),
                  "consistent": _consistent(s, settings.record_tolerance),
                  "every_member_needed": all(better(s, w, noise, settings, t, p)
                                             for w, t, p in judged) and alike_ok,
                  "every_member_separated": not unsep,
                  "better_than_single": better(s, cur_gap, noise, settings, vs_single,
                                               adds_pinned)}
        # the margins alone (the rule before the held-out test): which sets the test let in
        by_test = bool(tester.known(s)) and not (
            all(better(s, w, noise, settings, above_floor=p) for w, _, p in judged)
            and better(s, cur_gap, noise, settings, above_floor=adds_pinned))
        tried.append({"set": s.label(), "closure": float(s.closure), "checks": checks,
                      "held_out_z": tester.known(s), "by_held_out_test": by_test})
        if unsep:
            tried[-1]["unseparated"] = {s.members[k].label(): o.label() for k, o in unsep}
            _say(progress, "  not separated: " + ", ".join(
                f"{s.members[k].label()} from {o.label()} ({o.gap_after:.4g})"
                for k, o in unsep))
        if alike:
            tried[-1]["look_alike_members"] = [s.members[k].label() for k in alike]
        if any(pinned):
            tried[-1]["pinned_gain"] = [m.label() for m, p in zip(s.members, pinned) if p]
        _say(progress, f"set {s.label()}: closure {s.closure:.3f}, failed "
                       f"{[k for k, ok in checks.items() if not ok] or 'none'} (noise "
                       f"{noise if noise is not None else math.nan:.3g}, without each "
                       + ", ".join(f"{w:.4g}" for w in without) + (
                           f"; held-out z {tester.known(s)}" if tester.known(s) else "")
                       + (" [passes by the held-out test]" if by_test and all(checks.values())
                          else "") + (" [a gain pinned outside the pulse reading]"
                                      if any(pinned) else "") + ")")
        if all(checks.values()):
            contrib = contributions(s, val, proc, known, wo)
            shows, own = shown(s, contrib, val, proc, noise, settings)
            shows, own = shown_pinned(s, shows, own, [r if p else None for r, p in
                                                      zip(ranges, pinned)], wo, tester, settings)
            low = [m.label() for m, ok, r in zip(s.members, shows, reading)
                   if not ok and not (r and nuisance is not None)]
            tried[-1]["contributions"] = [float(x) for x in contrib]
            if own:
                tried[-1]["own_channel"] = own
            if low:
                tried[-1]["checks"]["above_noise_each"] = False
                # the set without the members that do not show, judged in its turn
                less = without_members(s, [k for k, m in enumerate(s.members)
                                           if m.label() in low], structure, train, val,
                                       proc, gap_before, before_blocks, settings, progress)
                if less is not None and np.isfinite(less.gap_after) and frozenset(
                        m.key for m in less.members) not in fitted_sets:
                    fitted_sets[frozenset(m.key for m in less.members)] = less
                    queue = sorted([*queue, less], key=_gap)
                continue
            chosen, chosen_without, chosen_own = s, without, own
            if nuisance is not None:
                chosen_nuisance = [m for m, r in zip(s.members, reading) if r]
            for m, x, w in zip(s.members, contrib, without):
                m.contribution = float(x)
                m.closure_added = float((w - s.gap_after) / gap_before) if gap_before > 0 \
                    else math.nan
            break
    rule["sets"] = tried
    member_rivals: list[list[dict[str, object]]] = []
    if chosen is not None and len(chosen.members) > 1:
        chosen, member_rivals = swap_members(
            chosen, chosen_without, structure, train, val, proc, gap_before, before_blocks,
            noise, settings, [*ranking, *scanned], rule, progress)
    if chosen is not None:
        named = list(chosen.members)
        for m, rv in zip(named, member_rivals):
            known = {r["candidate"] for r in m.rivals}
            m.rivals = [*m.rivals, *(r for r in rv if r["candidate"] not in known)]
        for k, (m, coeffs) in enumerate(zip(named, member_coefficients(chosen))):
            if m.category == "structure" and coeffs:
                m.coefficients = coeffs
                if k < len(chosen.member_intervals):
                    m.intervals = dict(chosen.member_intervals[k])
        if chosen_nuisance:  # fitted with the set, never named
            named = [m for m in named if m not in chosen_nuisance]
            rule["nuisance"] = [m.label() for m in chosen_nuisance]
            for m in named:
                m.nuisances = list(chosen_nuisance)
                m.note = (m.note + "; " if m.note else "") + (
                    "fitted with " + ", ".join(x.label() for x in chosen_nuisance)
                    + " as a nuisance (within the pulse-reading band: not a fault)")
        rule["combined_closure"] = float(chosen.closure)
        rule["reason"] = (f"{len(named)} effects, fitted jointly, together close "
                          f"{chosen.closure:.3f} of the gap; each one is needed and shows "
                          "above the noise")
        if chosen_nuisance:
            rule["reason"] = (f"{', '.join(m.label() for m in named)} with "
                              f"{', '.join(m.label() for m in chosen_nuisance)} (the "
                              "hammer pulse's reading, a nuisance, not named) closes "
                              f"{chosen.closure:.3f} of the gap; each effect is needed "
                              "and shows above the noise")
        cannot = [f"{m.label()} from {', '.join(r['candidate'] for r in rv)}"
                  for m, rv in zip(chosen.members, member_rivals) if rv]
        if cannot:
            rule["reason"] = f"{rule['reason']}; the data cannot separate {'; '.join(cannot)}"
        if chosen_own:
            rule["reason"] = f"{rule['reason']}; {'; '.join(chosen_own)}"
        _say(progress, f"set: {chosen.label()} closes {chosen.closure:.3f}")
        return named[0], named, rule
    if verdict is not None:
        contrib = contributions(verdict, val, proc, known)
        x = contrib[0] if contrib else math.inf
        verdict.contribution = float(x)
        shows, own = shown(verdict, [x], val, proc, noise, settings)
        if not shows[0]:
            rule["reason"] = (f"{verdict.label()} changes the validation outputs by less "
                              f"than {settings.contribution_noise:g} x the noise floor")
            return None, [], rule
        verdict.closure_added = float(verdict.closure)
        rule["combined_closure"] = float(verdict.closure)
        if own:
            rule["own_channel"] = own
        return verdict, [verdict], rule
    return None, [], rule


def _later_mates(seconds: Sequence[Candidate], refused: Sequence[Candidate],
                 lead: Candidate, done: set[frozenset], settings: DiagnoseSettings
                 ) -> list[tuple[Candidate, Candidate]]:
    """The best look-alike second lead (by train cost, after its refit from the lead's
    force) with the later stage's best fits by train cost (``refused``, fitted on the
    lead's model), when that stage named nothing; added to the look-alike pairs.  The
    lead's best pairs by *validation* gap choose its mates otherwise, and a wrong-law lead
    makes the right mate's pair look poor there: pair row lono quadratic damper LO-NO +
    cubic spring LO-ground led by a cubic damper LO-NO, the cubic spring second of the
    later stage by train cost but third of the lead's pairs by validation gap (after a
    channel delay and a clearance), never paired with the quadratic damper.  The later
    stage's own fit of the look-alike itself, or of a law of its role at its place, is no
    mate.  ``done`` is updated."""
    fits = [x for x in seconds if x.key != lead.key and np.isfinite(x.train_cost)]
    if not fits:
        return []
    x = min(fits, key=lambda c: c.train_cost)
    mates = [m for m in refused if m.key != x.key and can_pair(x, m)]
    out = []
    for m in mates[:settings.lookalike_mates]:
        if frozenset((x.key, m.key)) not in done:
            done.add(frozenset((x.key, m.key)))
            out.append((x, m))
    return out


def _gap(s: Candidate) -> float:
    return s.gap_after if np.isfinite(s.gap_after) else math.inf
