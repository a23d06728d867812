"""The knobs of a diagnosis (one dataclass, the documented defaults)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

#: refine's uncertainty for every fit inside a diagnosis: Gauss-Newton, no simulation.
#: refine's default bootstrap simulates ~70 force-noise replicates per record (measured:
#: 3 s of a 6.5 s refine on LO-NO), needed only for the named effects' intervals, which
#: ``fitting.bootstrap_intervals`` computes once at the end.
FAST = "gauss-newton"


@dataclass
class DiagnoseSettings:
    """Knobs of the diagnosis; the defaults are the documented method.

    top_k: candidates fitted by output error after screening (the rest are only screened).
    max_per_kind: at most this many locations of one kind among them, so that a rival of a
        different kind is always fitted (the verdict compares against it).
    nominal_nfev / fit_nfev: cost-evaluation budgets of the nominal and candidate fits.
    first_nfev: every chosen candidate is first fitted with this budget; only the
        ``finalists`` best by train cost (and any within ``finalist_ratio`` of the best)
        get the rest of ``fit_nfev`` on the full records (successive halving: the losers'
        half fits already show they lose, measured ~half of the fit time).
    closure_min: least validation closure for a verdict (share of the gap removed).
    separation: the verdict's gap_after must be at most this fraction of the best
        other-kind candidate's gap_after.
    record_tolerance: no validation record may get worse by more than this fraction of
        its own gap and of the mean record gap (records at the noise level may wobble).
    noise_factor: the nominal validation gap must exceed this multiple of the estimated
        noise floor, else the nominal model already fits to the noise level (null).
    gap_min: ... and it must exceed this normalised output error (0.005 = 7 % RMS error):
        below it the nominal model fits as well as parameter extrapolation from the train
        amplitudes allows, and any flexible element "explains" part of that residue
        (measured: 46 % of a 0.0009 null gap) ...
    faint_closure: ... unless the best candidate closes at least this share of it (a faint
        effect, well above the noise, that one law explains on the held-out records;
        measured: a small softening spring LO-ground, gap 0.0045, closure 0.96), or this
        share of its part above the noise floor, removing more than ``noise_factor`` x the
        floor (``verdict.closes_above_noise``: a right model leaves the noise; branch
        absorbed, the 3-DOF chain's small damper m1-m3: gap 0.000845 at 9.7 x the floor,
        the right damper closed 0.74 of it and 0.82 of the part above the floor).
    faint_noise: ... or the gap is at least this multiple of the spectral noise floor and
        the best candidate closes ``closure_min`` of it (a faint effect judged against the
        noise, not a fixed floor; issue 16: a quadratic damper 4-8 x the noise RMS closing
        0.75 of a 0.0021 gap was refused by the fixed floor).  Also: a first stage's
        best candidate removing at least this multiple of the floor is kept tentatively
        whatever its closure, and the next stage starts from it (``stage_outcome.large_part``;
        fresh seed 17335: 0.20 closed, 75 x the floor removed, the coulomb of the pair
        found only from its model).
    sensor_excess: a sensor fault (one value; the model otherwise as it was) passes the
        size checks above when it removes this share of the gap *above the noise floor*
        and the interval of its value excludes the fault-free sensor
        (``verdict.sensor_above_noise``): a right fault leaves the noise, which on a gap
        2-3 x the floor is only 0.4-0.6 of the whole gap.
    pairs: when no single effect explains the gap to the noise, the leading singles are
        paired and each pair re-fitted jointly (``pair_fit.fit_pair``); sets are compared by
        their validation gap (``set_rules.better``): more than one cause as the normal case.
    pair_members: how many structural singles (distinct places) are paired, plus the
        best sensor fault.
    pair_partners: the leading member is also paired with the best fit (by train cost)
        of this many kinds none of the members has (``sets.partners``): a pair's second
        effect, fitted alone, may close little of the validation gap.
    set_beam: sets of three (issue 16: two structural effects and a sensor fault) are
        looked for by growing this many of the best pairs (by validation gap) by one more
        member each, fitted jointly (``sets.grow_sets``); 0 = pairs only.
    contribution_noise: every named effect must change the simulated validation outputs
        by more than this multiple of the spectral noise floor (its own contribution,
        ``sets.contributions``): an element fitted to a residue moves them less than the
        noise (the issue's null named a 16 N/m clearance).
    ee_strong: a candidate explaining at least this share of the equation-error residual
        is fitted too, whatever its output-error score (strong effects such as a clearance
        can keep the nominal output-error fit so far off that its linearisation misleads).
    family_keep: a family goes to the scan and the local fit when its best screening score
        is at least this share of the leading family's (look-alikes are fitted side by side).
    runner_ups: the leading families whose second-best location is fitted too.
    stalled: a candidate fit whose train cost stays above this share of the nominal one
        is restarted from its magnitude scan.
    step_min: with several effects, each one added must close at least this share of the
        gap left before it (and pass the other checks); the set must reach closure_min.
    sensor_gain: the best sensor fault is fitted when correcting the records by its scanned
        value lowers the nominal train cost by at least this share.
    place_check: once a structural kind leads after the fits, fit it at every other place
        too (the place is decided by fits, not by the screen; False trades that for time).
    weak_places: a leader closing less than ``step_min`` of a gap at least ``faint_noise``
        x the noise floor, while removing more than ``noise_factor`` x the floor, has its
        kind fitted at this many other places, best screened first (``weak_lead``: two
        effects of one kind, none closing much alone).  0 = off.
    kind_check: when the leading structural effect closes less than this share of the gap,
        its look-alike kinds (restoring or dissipating, like it) are fitted at its place
        too (a law that leaves part of the gap may be a look-alike of the true one) ...
    kind_check_noise: ... or when it leaves more than this multiple of the spectral noise
        floor of the validation records (measured: a cubic damper NO-ground closing 0.989
        of the gap of a velocity-squared damper left 0.0018, 9 x the noise).
    backward: with two structural effects named in turn, re-fit the second alone and drop
        the first when it adds less than ``step_min`` of what is left (a greedy search
        can name a look-alike first that the true effect then makes redundant).
    tentative_closure: a first effect refused alone (size or separation) but kept
        tentatively is named with a second one only when together they close at least
        this share of the gap (measured: a wrong pair built that way closed 0.77, right
        pairs close 0.99+).
    nominal_poor: a nominal fit leaving more than this share of its train records' energy
        (train cost) is poor: it is restarted from other damping basins
        (``nominal._restarted``), and a band that keeps its modes replaces the first only
        when it is no poorer (``band.fit_nominal_in_band``).
    nominal_widest: a poor nominal fit is fitted again in the widest band (a band that
        cuts a mode leaves the nominal unable to follow its own records) when it leaves
        more than this share (the level at which ``nominal.FAILED`` calls a fit failed),
        or lacks a resolvable mode per DOF, or a mode is cut (``band.shows_its_modes``).
        A poor fit below this that shows every mode inside the band is what a strong
        missing effect leaves; its widest band was kept once in the LO-NO matrix and 100
        development seeds, by 2.5 % (docs/diagnosis.md, branch nomspeed), and costs a
        second nominal fit with its restarts.  ``nominal_poor``
        gives the rule before that branch.
    stop_ratio: early stop (speed): a candidate fit whose train cost on the full records
        is still above this multiple of the best train cost fitted so far in its stage,
        ``stop_after`` iterations into its full-record stage, ends there: it cannot win
        (the verdict's separation needs 1/``separation`` = 1.33 x), is no rival and gets no
        second round.  ``math.inf`` turns it off.
    stop_after: ... iterations of the full-record stage before that check (by then the
        growing horizons have brought the fit into its basin).
    max_effects: most effects named at once (added greedily while each one is significant
        on the validation records).
    sensors: also try sensor faults (accelerometer gain, channel delay, force gain).
    effects: names of the effects to try (default: all registered).
    nominal_start: initial values of the nominal parameters (skips the least-squares start).
    workers: threads for the independent scans, fits and judgements of a step
        (``parallel.run_each``); 0 = ``$SIVA_DIAGNOSE_WORKERS`` or every core.  The result
        does not depend on it.
    role_keep: the first fitted shortlist always holds the best candidate of each role
        (restoring, dissipative) that has any screening evidence, whatever the other
        role's lead (``screening.select_for_fit``): a damper hidden under restoring laws
        that rank first still gets a fit (issue 16, seventh round) ...
    role_floor: ... when its screening evidence is at least this share of the leading
        family's (a role far below it, e.g. a spring at 1 % of a damper, is no rival).
    role_places: when the leading fit leaves part of the gap, the best fit of the *other*
        role (by train cost) is also fitted at this many other places, strongest screened
        first (``stage``): its place is decided by fits, as the lead's is.  0 = off.
    lookalike_leads: the pair search also pairs up to this many look-alike laws fitted
        at the lead's place (``grow.second_leads``, best train cost first) with the lead's
        ``lookalike_mates`` best mates (the other members of its best pairs by validation
        gap), each started from the lead's force matched by the look-alike law
        (``grow.law_swap``): a wrong-law lead (a linear damper where a quadratic one is
        true) does not block the right pair.  0 = off.
    lookalike_mates: ... that many mates; and the best of them by train cost is also
        paired with that many of the later stage's best fits by train cost when that stage
        named nothing (``sets._later_mates``).
    lookalike_pairs: at most this many such extra pair fits (CPU: a LO-NO pair fit takes
        10-30 s), besides those ``lookalike_mates`` later-stage pairs.
    test_blocks: the held-out test of a set against a smaller one (``set_test``): the
        noise's share of their gain (the cross term of the larger set's residual with the
        change of the outputs) is summed over this many contiguous time blocks of each
        validation record, whose spread gives its standard error ...
    test_z: ... and a gain below ``set_rules.better``'s noise-floor margins still counts when
        it is at least this many standard errors (``set_test.gain_z``; 3: one-sided
        0.1 % for a normal cross term).  Measured: a faint coulomb removing 0.53 x the
        floor on the 2-DOF test records scores 24, a coulomb or cubic spring added where
        there is none scores < 0, one moving nothing ~1 (tests/test_diagnose_set_test);
        fresh seed 17241's 7 % accelerometer gain 12.8; invented members on the dev null
        24332 up to 2.33, 17266's spurious force gain 2.22 (thin below 3).
    member_test: a set member that looks like the rest of the set (a law of the same role
        as another structural member, or a sensor gain beside a structural law) is needed
        only when the held-out test shows it too (``test_z`` against the set without it)
        and, for a gain, its 95 % interval excludes 1 (``member_test``): the margins of
        ``set_rules.better`` compare with the spectral floor, which leaves out what every
        model leaves alike (hum in the band, the chain's misfit), and one more coefficient
        of any kind removes part of that (fresh seed 17790: five kinds each closed 0.45 of
        the true pair's leftover, and a third damper was named).
    member_separation: each member of a set must be separated (``separation``) from an
        effect of another role in its place: a fitted set of the same other members with
        a law of the other role or a sensor fault instead, whose gap the set does not beat
        by ``separation`` (``member_test.unseparated``; the single verdict's check (c) for
        each member).  Fresh seed 17790: with the true pair, a damper m3-ground left
        0.00236, a channel delay acc_m3 0.00252 -- a generic gain, no law's.
    swap_kinds: once a set is chosen, each structural member's law is swapped for its
        look-alike kinds at its place and the set re-fitted jointly from its own fit
        (``swap.member_swaps``); only this many kinds per member, the best by the train
        cost of their starts, are refined (CPU: one joint refine each; the fits' starts
        already rank the right law first or second).  0 = off.  A member found in a
        later stage never had its look-alikes compared with the other member present
        (fresh seed 17240: a cubic damper m1-m2 named beside a quadratic damper
        m2-ground for two quadratic dampers).
        The set with the lowest validation gap among the chosen one and its swaps (each
        consistent and every member above the noise, as the set was judged) is named, as
        the single verdict names the best of its look-alikes ...
    swap_places: ... and this many moves per member, the best by the train cost of
        their starts: its own kind at another place, started at the magnitudes whose
        force along the set's motion there matches the member's (1: each joint refit of
        a friction set costs 10-20 s on LO-NO; lono:two:0 took 163 CPU s with 2); a move
        is named only when it also fits all records (train and validation, with its train
        fit) better than the chosen set (fresh seed 17291: a cubic spring m1-ground named
        in a set for m1-m3).  0 = off.
    swap_noise: ... and the laws whose set's gap is within this multiple of the spectral
        noise floor of the named set's are listed as that member's rivals: the data cannot
        separate them (``swap.swap_rivals``).  The floor is the gap a right model leaves:
        a difference below it is within what the noise and the nominal parameters'
        extrapolation move (17240: the quadratic damper m1-m2's set 0.00864, the cubic's
        0.01018, floor 0.00518).
    tie_contenders: a single structural verdict and at most this many fitted singles
        with as many coefficients whose validation gap is within ``swap_noise`` x the
        noise floor of its gap, the lowest by train cost, are refitted on all records;
        the best fit there is named (``ties``: the same law at a neighbouring place, or a
        one-coefficient look-alike, has the same freedom, so all records compare them
        fairly).  0 = off.
    tie_leads: a first stage whose lead was kept tentatively while other structural
        singles tied with it (``tie_pairs``): at most this many of them are each paired
        with the later stages' effects, jointly refitted (``tie_pair_fits`` pair fits at
        most), and judged by the set rule.  0 = off.
    weak_pair_fits: when no single closes ``step_min`` of a gap at least ``faint_noise`` x
        the noise floor, at most this many more pairs of the singles that explain part of
        the *train* records (by train cost) with each other and the joining sensor faults
        (``no_single``).  0 = off.
    place_lookalikes: when the place check has run for the leading structural kind, at
        most this many look-alike kinds fitted at the leader's place whose validation gap
        is within ``swap_noise`` x the noise floor of its gap (the data cannot separate
        the laws there), the lowest by train cost, are fitted at every other place too
        (``ties.tied_look_alikes``; LO-NO matrix cubic damper LO-NO small: the linear
        damper NO-ground led and has no other place to fit, so the cubic damper LO-NO was
        never fitted).  0 = off.
    fit_wave: the candidate fits after the likely leader run in waves of this many; a
        wave's fits are stopped early (``stop_ratio``) against the best fit of the waves
        before it.  A schedule, not a worker count: the result depends on it (a larger
        wave stops fewer losers) but not on ``workers``.
    budget_s: seconds from the start of ``diagnose`` (``budget``): once the time spent
        plus what a unit of work of that kind has cost so far would pass it, no further
        stage, pair or set fit, swap, tie-break, polish or bootstrap is opened, and the
        verdict is chosen among what was fitted and checked (the report's
        ``rule["budget"]`` says where it stopped and what was not searched).  240 s: an
        answer within four minutes (issue 16: 12 of 60 fresh scenarios ran past 300 s);
        None = no budget.
    budget_cpu: measure ``budget_s`` in this process's CPU seconds instead of wall
        seconds (a benchmark whose limit is CPU time on a shared machine).
    clock: the running budget, set by ``diagnose`` (not a knob).
    """

    top_k: int = 4
    max_per_kind: int = 2
    nominal_nfev: int = 40
    fit_nfev: int = 40
    first_nfev: int = 20
    finalists: int = 3
    finalist_ratio: float = 3.0
    closure_min: float = 0.5
    separation: float = 0.75
    record_tolerance: float = 0.05
    noise_factor: float = 2.0
    gap_min: float = 0.005
    faint_closure: float = 0.8
    faint_noise: float = 10.0
    sensor_excess: float = 0.5
    pairs: bool = True
    pair_members: int = 3
    pair_partners: int = 2
    set_beam: int = 2
    contribution_noise: float = 2.0
    ee_strong: float = 0.25
    family_keep: float = 0.1
    runner_ups: int = 2
    stalled: float = 0.5
    step_min: float = 0.25
    sensor_gain: float = 0.2
    place_check: bool = True
    weak_places: int = 3
    kind_check: float = 0.95
    kind_check_noise: float = 3.0
    backward: bool = True
    tentative_closure: float = 0.8
    stop_ratio: float = 10.0
    stop_after: int = 2
    nominal_poor: float = 0.1
    nominal_widest: float = 0.5
    max_effects: int = 3
    sensors: bool = True
    effects: Sequence[str] | None = None
    nominal_start: Mapping[str, float] | None = None
    workers: int = 0
    fit_wave: int = 4
    role_keep: int = 1
    role_floor: float = 0.03
    role_places: int = 2
    lookalike_leads: int = 3
    lookalike_mates: int = 2
    lookalike_pairs: int = 6
    test_blocks: int = 8
    test_z: float = 3.0
    member_test: bool = True
    member_separation: bool = True
    swap_kinds: int = 2
    swap_places: int = 1
    swap_noise: float = 1.0
    tie_contenders: int = 3
    tie_leads: int = 2
    tie_pair_fits: int = 4
    weak_pair_fits: int = 8
    place_lookalikes: int = 2
    budget_s: float | None = 240.0
    budget_cpu: bool = False
    clock: Any = field(default=None, repr=False, compare=False)
