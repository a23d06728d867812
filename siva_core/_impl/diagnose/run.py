"""The diagnosis driver: nominal fit, then stages of screening, magnitude scans and
candidate fits (structural and sensor), each stage adding the effect it finds while that
effect is significant on the validation records; then where and the signatures."""
from __future__ import annotations

import dataclasses
import math
import time
from typing import Any, Sequence

import numpy as np

from ..effects import EFFECTS
from ..recording import Recording
from ..structure import Structure
from .budget import Budget
from .grow import worth_pairing
from .elimination import without_first
from .bounded import bounded_nominal
from .fitting import bootstrap_intervals
from .identified import check_named
from .band import fit_nominal_in_band
from .nested import prefer_simpler
from .nominal import NominalFit, fit_nominal
from .outputs import Progress, _Outputs, _say
from .pulse_reading import one_dof_gain_note, reading_limit, shadowed_by_reading
from .residue import sensor_residue
from .results import Candidate, Diagnosis
from .scoring import validation_gap
from .set_members import fill_closures
from .set_test import one_value_separation
from .settings import DiagnoseSettings
from .signatures import amplitude_signatures
from .verdict import decide, simplest_same, stage_floor
from .sets import choose_set
from .without_member import KnownFits
from .ties import break_tie
from .tie_pairs import tie_pairs, tied_leads
from .weak_lead import tentative_lead
from .no_single import no_single_closes, train_lead
from .where import _explain, spectral_noise_floor, where_analysis

from .stage import Fraction, _stage
from .stage_outcome import explained, large_part, partial_lead, polish, refresh_coefficients


def diagnose(structure: Structure, train: Sequence[Recording], val: Sequence[Recording],
             processing: Any = "auto", *, settings: DiagnoseSettings | None = None,
             progress: Progress | None = None, fraction: Fraction | None = None
             ) -> Diagnosis:
    """Locate and explain the sim-to-real gap of ``structure`` (see the module doc)."""
    from ..siva import choose_processing

    settings = settings or DiagnoseSettings()
    if not train or not val:
        raise ValueError("diagnose needs at least one --train and one --val record")
    # the anytime budget (``budget``): a copy of the settings carries it to every step
    clock = Budget(settings.budget_s, settings.budget_cpu, say=progress)
    settings = dataclasses.replace(settings, clock=clock)
    t_all = time.perf_counter()
    timing: dict[str, float] = {}
    proc = choose_processing(processing, [*train, *val], structure.dofs)
    _say(progress, f"processing: {proc.describe() if hasattr(proc, 'describe') else proc}")

    t0 = time.perf_counter()
    if isinstance(processing, str) and processing == "auto":  # a band chosen from the data
        proc, nominal_fit = fit_nominal_in_band(structure, train, [*train, *val], proc,
                                                settings, progress)
    else:  # the caller's chain is kept as given
        nominal_fit = fit_nominal(structure, train, proc, settings, progress)
    # a nominal that escapes on the validation records has no gap there (bounded's doc)
    nominal_fit, val, escaped = bounded_nominal(structure, nominal_fit, train, val, proc,
                                                settings, progress)
    theta, train_cost, start = nominal_fit.theta, nominal_fit.train_cost, nominal_fit.start
    timing["nominal_fit"] = time.perf_counter() - t0
    val_prob = _Outputs(structure, val, proc, theta)
    res_before = val_prob.residuals(theta)[0]
    gap_before = float(res_before @ res_before)
    before_blocks = val_prob.blocks(res_before)
    try:  # the level a right model leaves: decides when look-alikes are fitted too
        noise = spectral_noise_floor(structure, val, proc, theta)
    except Exception:  # noqa: BLE001 - the closure criterion alone then
        noise = None
    _say(progress, f"nominal: train cost {train_cost:.4g}, validation gap {gap_before:.4g} "
                   f"({timing['nominal_fit']:.1f} s)")

    names = list(settings.effects) if settings.effects else list(EFFECTS)
    unknown = [n for n in names if n not in EFFECTS]
    if unknown:
        raise ValueError(f"unknown effect(s) {unknown} (known: {', '.join(EFFECTS)})")
    effects = [EFFECTS[n] for n in names]
    report = fraction or (lambda _x: None)
    report(0.2)
    n_stages = max(1, settings.max_effects)
    verdicts: list[Candidate] = []
    stages: list[dict[str, Any]] = []
    ranking: list[Candidate] = []
    cands: list[Candidate] = []
    later: list[Candidate] = []
    refused: list[Candidate] = []
    rule: dict[str, Any] = {}
    cur_struct, cur_fit, cur_train, cur_val = structure, nominal_fit, list(train), list(val)
    shadowed: dict[tuple[str, tuple[str, str]], bool] = {}
    cur_gap, cur_blocks = gap_before, before_blocks
    sensor_only = False
    stage_s, first_cut = 0.0, False
    tied_first: list[Candidate] = []
    for n in range(n_stages):
        tag = "" if n == 0 else f"stage{n + 1}_"
        # a further stage costs about what the last one did; not opened past the budget
        # (a tentative effect kept for it is then judged by the set rule as when the
        # stage names nothing)
        if n > 0 and not clock.allows("stage", f"{n + 1} of {n_stages}", stage_s):
            stages.append({"gap_before": cur_gap, "budget": clock.text()})
            _say(progress, f"stage {n + 1}: not opened ({clock.text()})")
            break
        t_stage, skipped = clock.now(), clock.n_skipped()
        lo, hi = 0.2 + 0.8 * n / n_stages, 0.2 + 0.8 * (n + 1) / n_stages
        # a stage opened for a sensor fault under an explaining verdict fits sensor faults
        # only (``residue``): before it, the search ended there
        rk, cs = _stage(cur_struct, cur_fit, cur_train, cur_val, proc,
                        [] if sensor_only else effects, settings,
                        cur_gap, cur_blocks, settings.sensors and not any(
                            v.category == "sensor" for v in verdicts),
                        progress, lambda x: report(lo + (hi - lo) * x), timing, tag,
                        noise)
        stage_s = clock.now() - t_stage
        clock.took("stage", stage_s)
        for c in rk:  # a gain's last shadow judgement: a set's copy of it inherits it
            if c.category == "sensor":
                shadowed[c.key] = shadowed_by_reading(c, rk) is not None
        if any(v.category == "sensor" for v in verdicts):  # paired with it at the end
            later += worth_pairing(rk, cur_fit.train_cost, settings)
        floor = stage_floor(cur_fit.train_cost, rk, noise, later=n > 0)
        v, r = decide(rk, cur_gap, floor, settings, later=bool(verdicts), spectral=noise,
                      separated=one_value_separation(cur_train, cur_val, proc,
                                                          settings.test_blocks))
        stages.append({"gap_before": cur_gap, "rule": r,
                       "ranking": [c.label() for c in rk],
                       "verdict": v.label() if v is not None else None})
        cut = clock.n_skipped() > skipped
        if cut:  # a fit of this stage was not opened: its lead is not checked, not named
            stages[-1]["budget_unchecked"] = v.label() if v is not None else (
                rk[0].label() if rk else None)
            _say(progress, f"stage {n + 1}: cut by the time budget; its lead "
                           f"{stages[-1]['budget_unchecked'] or '(none fitted)'} is not "
                           "named (its rivals, places or look-alikes were not all fitted)")
            v = None
        if n == 0:
            ranking, cands, rule = rk, cs, r
            first_cut = cut
        part = large_part(rk, cur_gap, noise, settings) if v is None and not verdicts \
            and not cut else None
        if v is None and not cut and (partial_lead(r, rk, settings) or part is not None) \
                and n + 1 < n_stages:
            # a significant part of a larger gap: keep it tentatively and look for the
            # rest; the set is named only if together they reach closure_min
            first = val_lead = tentative_lead(rk, noise, settings)  # val ties: train cost
            # no single closes much of a gap many times the noise: the train records rank
            # what a single explains (``no_single``); the validation leader is paired too
            by_train = train_lead(rk, first, cur_fit.train_cost, settings) \
                if n == 0 and no_single_closes(rk, cur_gap, noise, settings) else None
            if by_train is not None:
                stages[-1]["train_lead"] = f"{by_train.label()} for {first.label()}"
                _say(progress, f"stage 1: no single closes {settings.step_min:g} of the "
                               f"gap; {by_train.label()} lowers the train cost most "
                               f"({cur_fit.train_cost:.4g} -> {by_train.train_cost:.4g}): "
                               f"kept instead of {first.label()}")
                first = by_train
            v = simplest_same(first, [c for c in rk if c is not first
                                      and np.isfinite(c.closure) and not c.reading])
            stages[-1]["tentative"] = v.label()
            if n == 0:  # the leads it does not separate from: paired too (tie_pairs)
                tied_first = tied_leads(rk, v, noise, settings)
                if by_train is not None and all(c.key != val_lead.key for c in tied_first) \
                        and val_lead.key != v.key:
                    tied_first = [val_lead, *tied_first]
                stages[-1]["tied_leads"] = [c.label() for c in tied_first]
            if part is not None and not partial_lead(r, rk, settings):
                stages[-1]["tentative_large_part"] = part
                _say(progress, f"stage {n + 1}: {v.label()} closes {v.closure:.3f} of the "
                               f"gap, removing {part['removed_x_floor']:.1f} x the noise "
                               f"floor (>= {settings.faint_noise:g} x): a part of it, "
                               "looking for the rest")
            else:
                _say(progress, f"stage {n + 1}: {v.label()} closes {v.closure:.3f} of the "
                               "gap: a part of it, looking for a second effect")
        if v is None:
            _say(progress, f"stage {n + 1}: nothing named ({r.get('reason')})")
            if verdicts:  # its best fits are still paired with the effect before it
                refused = worth_pairing(rk, cur_fit.train_cost, settings)
            break
        _bootstrap(v, cur_train, proc, clock, progress)
        verdicts.append(v)
        _say(progress, f"stage {n + 1}: {v.label()} closes {v.closure:.3f} of the gap "
                       f"{cur_gap:.4g}")
        if n + 1 >= n_stages or sensor_only:
            break
        if explained(v, settings, noise):
            fault = sensor_residue(v, cur_train, proc, noise, settings) if settings.sensors \
                and not any(x.category == "sensor" for x in verdicts) else None
            if fault is None:
                break
            stages[-1]["sensor_residue"] = f"{fault.label()}: {fault.note}"
            sensor_only = True
            _say(progress, f"stage {n + 1}: {v.label()} leaves {v.gap_after:.3g} "
                           f"(> {settings.noise_factor:g} x the floor {noise:.3g}), and "
                           f"{fault.label()} lowers it ({fault.note}): a next stage of "
                           "sensor faults")
        # the next stage starts from this effect's model: converge it first, else the next
        # stage's candidates "close" what a longer fit of this one closes (issue 16: a force
        # gain fitted with the stage budget left half a gap that a coulomb with fc ~ 0, i.e.
        # the same model fitted longer, then closed)
        clock.run("polish", v.label(), lambda v=v, t=cur_train, va=cur_val, g=cur_gap,
                  b=cur_blocks: polish(v, t, va, proc, settings, g, b, progress))
        # the next stage starts from the model (or records) with this effect
        cur_train, cur_val = v.correct(cur_train), v.correct(cur_val)
        cur_struct = v.structure
        cur_fit = NominalFit(v.theta, v.train_cost, f"with {v.label()}")
        cur_gap, cur_blocks = validation_gap(cur_struct, v.theta, cur_val, proc)
    # the first stage's tied leads with what the later stages found (``tie_pairs``)
    tied = tie_pairs(tied_first, [*verdicts[1:], *refused], settings) \
        if verdicts and stages[0].get("tentative") else []
    if tied:
        stages[0]["tie_pairs"] = [f"{a.label()} + {b.label()}" for a, b in tied]
        _say(progress, "the first stage's tied leads paired with the later effects: "
                       + ", ".join(stages[0]["tie_pairs"]))
    if settings.backward:
        # skipped past the budget: the greedy set is then judged by the set rule, which
        # needs every member (``sets.choose_set``'s every_member_needed)
        alone = clock.run("backward step", "the second effect alone",
                          lambda: without_first(verdicts, structure, train, val, proc,
                                                gap_before, before_blocks, settings,
                                                progress)) \
            if len(verdicts) == 2 and all(v.category == "structure" for v in verdicts) \
            else None  # (``without_first`` applies to two structural effects only)
        if alone is not None:
            _bootstrap(alone, train, proc, clock, progress)
            verdicts = [alone]
            ranking = sorted([alone, *ranking], key=lambda c: -c.closure
                             if np.isfinite(c.closure) else math.inf)
            stages.append({"gap_before": gap_before, "backward": alone.note,
                           "verdict": alone.label()})
    refresh_coefficients(verdicts)
    report(0.97)

    t0 = time.perf_counter()
    best = ranking[0] if ranking else None
    where, plots = where_analysis(structure, theta, [*train, *val],
                                  ["train"] * len(train) + ["val"] * len(val), proc, best)
    # noise floor: the spectral estimate, capped by the best fit achieved on the train
    # records (a residual that small is reachable, so the noise cannot be larger)
    psd_floor = noise  # the spectral estimate, computed before the stages
    fits = [train_cost] + [c.train_cost for c in ranking if np.isfinite(c.train_cost)]
    where["noise_floor"] = float(min([psd_floor, *fits] if psd_floor is not None else fits))
    where["noise_floor_spectral"] = psd_floor
    verdict, rule0 = decide(ranking, gap_before, where["noise_floor"], settings,
                            separated=one_value_separation(train, val, proc,
                                                              settings.test_blocks))
    if first_cut:  # the first stage was cut by the budget: its ranking is incomplete
        verdict = None
        rule0["budget_unchecked"] = stages[0].get("budget_unchecked")
    rule = {**rule, **rule0}
    known = KnownFits(structure, theta, train, val, proc)  # the fits without a member
    verdict, verdicts, set_rule = choose_set(
        verdict, verdicts, ranking, structure, train, val, proc, gap_before, before_blocks,
        psd_floor, settings, progress, later, cands,
        frozenset(k for k, r in shadowed.items() if r), refused, known, tied, train_cost)
    rule.update(set_rule)
    if set_rule.get("reason"):
        rule["reason"] = set_rule["reason"]
    verdict, verdicts = break_tie(verdict, verdicts, ranking, train, val, proc, gap_before,
                                  where["noise_floor"], psd_floor, settings, rule, progress,
                                  known)
    # a law holding a simpler one (a clearance: a spring) named only when proven better
    verdict, verdicts = prefer_simpler(verdict, verdicts, ranking, structure, train, val,
                                       proc, gap_before, before_blocks,
                                       where["noise_floor"], psd_floor, settings, rule,
                                       known, progress)
    if escaped is not None:
        rule["nominal_escaped"] = escaped
        rule["reason"] = f"{rule.get('reason') or 'no reason given'}; {escaped['text']}"
    # a gap the nominal model's own unidentified coefficient explains names nothing
    verdict, verdicts = check_named(verdict, verdicts, structure, theta, train_cost,
                                    gap_before, train, val, proc, psd_floor, settings, rule,
                                    progress)
    fill_closures(verdicts, ranking)  # a swapped or moved member: never closure None
    rule["budget"] = clock.as_rule()
    if clock.reached:  # said plainly: the search was cut, the verdict is what was checked
        lead = rule.get("budget_unchecked")
        if first_cut and verdict is None:
            rule["reason"] = "the first stage was cut by the time budget: " + (
                f"its lead {lead} is not named (its rivals, places and look-alikes were "
                "not all fitted)" if lead else "no candidate was fitted")
        rule["reason"] = f"{rule.get('reason') or 'no reason given'}; {clock.text()}"
        _say(progress, clock.text())
    limit = reading_limit(structure, theta, [*train, *val])
    if limit is not None:  # what no verdict can say either way (pulse_reading's doc)
        rule["pulse_reading_limit"] = limit
        rule["reason"] = f"{rule.get('reason') or 'no reason given'}; {limit['text']}"
    same = one_dof_gain_note(structure, verdicts)
    if same is not None:  # an accelerometer gain a is a force gain 1/a on one DOF
        rule["one_dof_gain"] = same
        rule["reason"] = f"{rule.get('reason') or 'no reason given'}; {same}"
    if verdict is None:
        where["explanation"] = _explain(where, None) + (
            f" No candidate is named: {rule['reason']}."
            + (f" Best tried: {best.label()} (closure {best.closure:.2f})." if best else ""))
    timing["where"] = time.perf_counter() - t0
    timing["total"] = time.perf_counter() - t_all
    nominal = {"parameters": structure.as_dict(theta), "train_cost": train_cost,
               "gap": gap_before, "start": start,
               "gap_per_record": {rec.name: float(before_blocks[k].mean())
                                  for k, rec in enumerate(val)}}
    signatures = amplitude_signatures(structure, theta, val, proc, verdicts[0] if verdicts
                                      else best)
    report(1.0)
    return Diagnosis(verdict, ranking, verdicts, cands, where, nominal, rule, proc, timing,
                     structure, theta, list(train), list(val), plots, signatures, stages)


def _bootstrap(v: Candidate, train: Sequence[Recording], proc: Any, clock: Budget,
               progress: Progress | None) -> None:
    """The bootstrap interval of a named effect, within the budget (past it the
    Gauss-Newton interval of its fit stands, as when the bootstrap fails)."""
    def once() -> None:
        try:
            bootstrap_intervals(v, train, proc)
        except Exception as exc:  # noqa: BLE001 - the Gauss-Newton intervals stand
            _say(progress, f"{v.label()}: bootstrap interval failed ({exc})")
    clock.run("bootstrap", v.label(), once)
