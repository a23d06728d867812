"""One stage of the diagnosis: screen, scan and fit candidates (structural and sensor)
from the model so far, judge them on the validation records, and add the effect that is
significant (what a stage's outcome means for the next: ``stage_outcome``)."""
from __future__ import annotations

import dataclasses
import math
import time
from typing import Callable, Sequence

import numpy as np

from ..effects import Effect
from ..processing import Processing
from ..recording import Recording
from ..structure import Structure
from .budget import clock_of
from .early_stop import cannot_win, stop_limit
from .fitting import continue_fit, fit_candidate, scan_candidate
from .nominal import DISSIPATIVE, NominalFit
from .outputs import Progress, _say
from .parallel import run_each, waves, worker_count
from .results import Candidate
from .scoring import judge as _judge
from .screening import (_strength, ee_screen, other_kinds, other_places, screen,
                        select_for_fit)
from .pulse_reading import explained_by_reading, shadowed_by_reading
from .sensors import fit_sensor, scan_sensor, sensor_candidates, sensor_fits
from .settings import DiagnoseSettings
from .ties import tied_look_alikes, undecided_places
from .verdict import look_alike
from .weak_lead import weak_lead, weak_lead_places

Fraction = Callable[[float], None]
#: (leader's train cost, leader) a wave of fits is stopped against
Against = tuple[float, "Candidate | None"]


def finalists(chosen: Sequence[Candidate], settings: DiagnoseSettings) -> list[Candidate]:
    """The fitted candidates that get the second round: the ``finalists`` best by train
    cost, plus any within ``finalist_ratio`` of the best (a close rival must be fitted as
    well as the leader: the verdict's separation check compares their gaps), plus the
    best of the leading candidate's best rival kind."""
    fitted = sorted((c for c in chosen if c.fitted and np.isfinite(c.train_cost)),
                    key=lambda c: c.train_cost)
    if not fitted:
        return []
    # a fit cut short because it could not come near the leader gets no second round
    fitted = [c for c in fitted if not c.stopped] or fitted
    best = fitted[0].train_cost
    out = [c for k, c in enumerate(fitted)
           if k < settings.finalists or c.train_cost <= settings.finalist_ratio * best]
    rival = next((c for c in fitted if c.effect.kind != fitted[0].effect.kind), None)
    if rival is not None and rival not in out:
        out.append(rival)
    return out


def _lead(chosen: Sequence[Candidate]) -> Candidate | None:
    """The fitted candidate with the best validation closure, when it is structural."""
    best = max((c for c in chosen if c.fitted and np.isfinite(c.closure)),
               key=lambda c: c.closure, default=None)
    return best if best is not None and best.category == "structure" else None


def _stage(structure: Structure, fit: NominalFit, train: Sequence[Recording],
           val: Sequence[Recording], proc: Processing, effects: Sequence[Effect],
           settings: DiagnoseSettings, gap_before: float, before_blocks: np.ndarray,
           sensors: bool, progress: Progress | None, fraction: Callable[[float], None],
           timing: dict[str, float], tag: str, noise: float | None = None
           ) -> list[Candidate]:
    """One round: screen, scan every candidate's magnitude, fit the chosen ones, score
    them on the validation records.  Returns the fitted candidates, best closure first."""
    theta = fit.theta
    t0 = time.perf_counter()
    cands, nom = screen(structure, theta, train, proc, effects, progress)
    ee_screen(structure, fit, train, cands)
    timing[f"{tag}screening"] = time.perf_counter() - t0
    fraction(0.15)
    t0 = time.perf_counter()
    chosen = select_for_fit(cands, settings)
    workers = worker_count(settings)
    sens = sensor_candidates(structure, train) if sensors else []

    def scan(c: Candidate) -> None:  # independent of the other scans: on the cores
        try:
            if c.category == "sensor":
                scan_sensor(c, structure, theta, train, proc, nom.basis)
            else:
                scan_candidate(c, structure, theta, train, proc,
                               nom.amplitudes[c.loc.between], nom.force_scale,
                               nom.jacobian, nom.basis)
        except Exception as exc:  # noqa: BLE001 - one failed scan must not sink the run
            if c.category == "sensor":
                raise
            c.note = f"scan failed: {exc}"

    run_each(scan, [*chosen, *sens], workers)
    fraction(0.35)
    timing[f"{tag}scan"] = time.perf_counter() - t0
    scanned = sorted((c for c in [*chosen, *sens] if np.isfinite(c.scan_cost)),
                     key=lambda c: c.scan_cost)
    _say(progress, f"fitted next: {', '.join(c.label() for c in chosen)}; scans (train cost, "
                   f"nominal {fit.train_cost:.4g}): "
                   + ", ".join(f"{c.label()} {c.scan_cost:.4g}" for c in scanned[:8]))
    chosen += sensor_fits(sens, fit.train_cost, settings)
    t0 = time.perf_counter()
    first = dataclasses.replace(settings, fit_nfev=min(settings.first_nfev, settings.fit_nfev))
    # a later stage starts from an earlier effect's model: its fits are also stopped when
    # they remove too little of its train cost (``early_stop.gain_limit``)
    base = fit.train_cost if tag else math.nan

    def leader_cost() -> float:  # the best fit so far: a later one far above it stops
        return min((c.train_cost for c in chosen if c.fitted and not c.stopped
                    and np.isfinite(c.train_cost)), default=math.inf)

    def leader() -> Candidate | None:  # the best structural fit so far
        return min((c for c in chosen if c.fitted and not c.stopped
                    and c.category == "structure" and np.isfinite(c.train_cost)),
                   key=lambda c: c.train_cost, default=None)

    def fit_first(c: Candidate, stop: bool = True, against: Against | None = None) -> bool:
        lc, ld = against if against is not None else (leader_cost(), leader())
        try:
            if c.category == "sensor":
                # cut short after its first re-tune above the leader's limit, or when
                # the re-tune no longer lowers the stage's cost by the ``sensor_gain``
                # its scan was chosen on (``sensor_fits``): the scan's evidence is gone
                fit_sensor(c, structure, theta, train, proc, first, min(
                    stop_limit(lc, settings, base),
                    (1.0 - settings.sensor_gain) * fit.train_cost) if stop else math.inf)
            else:
                c.amplitudes = nom.amplitudes[c.loc.between]
                fit_candidate(c, structure, theta, train, proc, c.amplitudes, first,
                              nom.force_scale, fit.train_cost,
                              lc if stop else math.inf, ld if stop else None, base)
            return True
        except Exception as exc:  # noqa: BLE001 - one failed candidate must not sink the run
            c.note = f"fit failed: {exc}"
            _say(progress, f"{c.label()}: fit failed ({exc})")
            return False

    def fit_more(c: Candidate, stop: bool = True, lc: float | None = None) -> None:
        lc = leader_cost() if lc is None else lc
        try:
            continue_fit(c, train, proc, settings.fit_nfev - first.fit_nfev,
                         cannot_win(lc, settings, base_cost=base) if stop else None)
        except Exception as exc:  # noqa: BLE001 - the first fit stands
            _say(progress, f"{c.label()}: second round failed ({exc})")

    def judge(c: Candidate) -> None:
        _judge(c, val, proc, gap_before, before_blocks, progress)

    def rescue(c: Candidate, second: Callable[[Candidate], bool]) -> None:
        """A fit stopped on the train records that the validation records do not show
        losing -- within twice the separation margin of the best full fit's gap -- is
        fitted in full after all (and its second round when ``second`` says so):
        whatever can name or block a verdict is fitted as without the early stop."""
        best = min((x.gap_after for x in chosen if x.fitted and not x.stopped
                    and np.isfinite(x.gap_after)), default=math.inf)
        if not (c.stopped and np.isfinite(c.gap_after)
                and c.gap_after * settings.separation < 2.0 * best):
            return
        _say(progress, f"{c.label()}: its stopped fit closes {c.closure:.3f} on the "
                       "validation records: fitted in full")
        refit_in_full(c, second)

    def refit_in_full(c: Candidate, second: Callable[[Candidate], bool]) -> None:
        if not clock_of(settings).allows("full refit", c.label()):
            return
        t0 = clock_of(settings).now()
        _refit_in_full(c, second)
        clock_of(settings).took("full refit", clock_of(settings).now() - t0)

    def _refit_in_full(c: Candidate, second: Callable[[Candidate], bool]) -> None:
        c.stopped, c.note = False, ""
        if not fit_first(c, stop=False):
            return
        if second(c):
            fit_more(c, stop=False)
        judge(c)

    # the likely leader first (strongest screening evidence; sensor faults last): the
    # fits after it that cannot come near it stop early (``early_stop.cannot_win``).  Not
    # the scan cost: on the cubic damper LO-NO example every scan sits within 8 % of the
    # nominal cost and ranks the true law fourth; the screen ranks it first.  The others
    # in waves on the cores, each wave against the leader of the waves before it.
    order = sorted(chosen, key=lambda c: (c.category == "sensor", -_strength(c)))
    done = 0
    # every fit within the time budget (``budget``): a stage with a fit not opened is
    # cut, and ``run`` names nothing from it (its checks are incomplete)
    clock = clock_of(settings)
    for wave in waves(order, settings.fit_wave):
        against = (leader_cost(), leader())
        run_each(lambda c: clock.run("candidate fit", c.label(),
                                     lambda: fit_first(c, against=against)), wave, workers)
        done += len(wave)
        fraction(0.4 + 0.4 * done / max(len(chosen), 1))
    lc = leader_cost()  # the second round's stop: the leader after the first round
    run_each(lambda c: clock.run("second round", c.label(), lambda: fit_more(c, lc=lc)),
             finalists(chosen, settings), workers)
    fraction(0.9)
    run_each(judge, [c for c in chosen if c.fitted], workers)
    for c in [c for c in chosen if c.stopped]:
        rescue(c, lambda x: x in finalists(chosen, settings))

    def unsure(c: Candidate) -> bool:  # leaves part of the gap, or more than the noise
        return c.closure < settings.kind_check or (
            noise is not None and c.gap_after > settings.kind_check_noise * noise)

    def fit_extra(extra: Sequence[Candidate], lead: Candidate) -> None:
        """Scan, fit and judge ``extra`` beside ``lead``: in waves on the cores, then
        each one taken into the stage (and rescued) in order."""
        def one(c: Candidate, against: Against) -> None:
            try:
                scan_candidate(c, structure, theta, train, proc,
                               nom.amplitudes[c.loc.between], nom.force_scale,
                               nom.jacobian, nom.basis)
            except Exception as exc:  # noqa: BLE001 - the fit starts without the scan
                c.note = f"scan failed: {exc}"
            if not fit_first(c, against=against):
                return
            if c.train_cost <= settings.finalist_ratio * lead.train_cost:
                fit_more(c, lc=against[0])
            judge(c)

        for wave in waves(extra, settings.fit_wave, first_alone=False):
            against = (leader_cost(), leader())
            run_each(lambda c: clock.run("check fit", c.label(), lambda: one(c, against)),
                     wave, workers)
            for c in wave:
                chosen.append(c)
                if c.fitted:
                    rescue(c, lambda x: x.train_cost
                           <= settings.finalist_ratio * lead.train_cost)

    # the place and the law of the leading structural effect are decided by fits: its
    # look-alike kinds at its place (when it leaves part of the gap), then its kind at
    # every other place, then look-alikes again if the place moved
    lead = _lead(chosen)
    if settings.place_check and lead is not None and lead.closure >= settings.step_min:
        # a look-alike law at the leader's place whose fit was stopped early against it
        # is fitted in full: it is the leader's rival, not a loser (the full matrix's
        # quadratic damper NO-ground, large: its stopped fit closed 0.25, the cubic
        # damper 0.99 was named; fitted in full the quadratic one closes 0.999)
        for c in [c for c in chosen if c.stopped and c.loc.between == lead.loc.between
                  and look_alike(lead.effect.kind, c.effect.kind)]:
            _say(progress, f"{c.label()}: a look-alike of the leader stopped early: "
                           "fitted in full")
            refit_in_full(c, lambda x: True)
        lead = _lead(chosen) or lead
        # look-alike laws are always fitted beside the leader (issue 16: a cubic damper
        # NO-ground closing 0.992 was named where a quadratic one was true); every kind
        # of its role when it leaves part of the gap
        for c in other_kinds(cands, lead, chosen):
            if unsure(lead) or look_alike(lead.effect.kind, c.effect.kind):
                fit_extra([c], lead)
            lead = _lead(chosen) or lead
        place = lead.loc.between
        fit_extra(other_places(cands, lead.effect.kind, chosen), lead)
        # look-alike laws the validation records cannot separate from the leader at its
        # place are placed by fits too (the leader's own kind may have no other place)
        for kind in tied_look_alikes(chosen, lead, noise, settings):
            every = other_places(cands, kind, chosen)
            more = undecided_places(every, chosen, lead, noise, settings)
            if len(more) < len(every):
                _say(progress, f"{kind}: not fitted at {len(every) - len(more)} place(s) "
                               f"where {lead.effect.kind} was separated from the leader")
            if more:
                _say(progress, f"{kind} {'-'.join(place)}: a look-alike within the noise "
                               "of the leader, also fitted at "
                               + ", ".join("-".join(c.loc.between) for c in more))
                fit_extra(more, lead)
        lead = _lead(chosen) or lead
        if lead.loc.between != place and unsure(lead):
            for c in other_kinds(cands, lead, chosen):
                fit_extra([c], lead)
    elif settings.place_check and not tag and weak_lead(lead, gap_before, noise, settings):
        # a lead closing little of a gap many times the noise: its kind at other places
        # too (``weak_lead``: two effects of one kind, none closing much alone); in the
        # first stage only, where nothing explains part of the gap yet: later stages' gaps
        # are many times the noise whenever the nominal fits poorly (fresh seed 17474:
        # six more fits of 4-50 s each in stage 2, naming nothing)
        more = weak_lead_places(cands, lead, chosen, settings)
        if more:
            _say(progress, f"{lead.label()}: a weak lead (closure {lead.closure:.3f}), "
                           "its kind also fitted at "
                           + ", ".join("-".join(c.loc.between) for c in more))
            fit_extra(more, lead)
    # the other role's best fit, at its other places too, when the leader leaves part of
    # a gap above the noise (``noise_factor``, as the pair search): a second effect of
    # the other role (a damper beside a spring) has its place decided by fits as the
    # leader's is (issue 16: a cubic damper fitted at LO-ground only, where LO-NO was
    # true; the leader, a cubic spring, closed 0.24)
    lead = _lead(chosen)
    if settings.role_places > 0 and lead is not None and unsure(lead) and (
            noise is None or gap_before > settings.noise_factor * noise):
        role = lead.effect.kind in DISSIPATIVE
        other = min((c for c in chosen if c.fitted and not c.stopped
                     and c.category == "structure" and np.isfinite(c.train_cost)
                     and (c.effect.kind in DISSIPATIVE) != role),
                    key=lambda c: c.train_cost, default=None)
        if other is not None:
            more = other_places(cands, other.effect.kind, chosen)[:settings.role_places]
            if more:
                at = ", ".join("-".join(c.loc.between) for c in more)
                _say(progress, f"{other.label()}: the best fit of the other role, also "
                               f"fitted at {at}")
                fit_extra(more, lead)
    timing[f"{tag}candidate_fits"] = time.perf_counter() - t0
    fitted = [c for c in chosen if c.fitted]
    for c in fitted:  # a force gain the few-sample pulse's reading explains: not a fault
        if explained_by_reading(c, train):
            c.reading = True
            c.note = ("within what the hammer pulse's reading between its samples "
                      "explains: not named")
            _say(progress, f"{c.label()}: gain {c.coefficients.get('gain', math.nan):.4g} "
                           "is within the pulse-reading band: not a fault")
    for c in fitted:  # ... and one channel's gain that the common (force) gain out-fits
        shadow = shadowed_by_reading(c, fitted)
        if shadow is not None and not c.reading:
            c.reading = True
            c.note = (f"{shadow.label()}, within the pulse-reading band, fits at least as "
                      "well: a share of the reading error, not named")
            _say(progress, f"{c.label()}: {shadow.label()} (pulse reading) fits the train "
                           f"records at least as well ({shadow.train_cost:.4g} <= "
                           f"{c.train_cost:.4g}): not a fault")
    stage_cands = cands + sens
    # best closure first; a gain the pulse reading explains after the others (never a
    # verdict, nor the tentative first effect)
    ranking = sorted(fitted, key=lambda c: (c.reading, -c.closure if np.isfinite(c.closure)
                                            else math.inf))
    return ranking, stage_cands
