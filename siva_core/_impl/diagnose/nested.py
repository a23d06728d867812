"""Nested laws (issue 16, branch lookalike3): a law that holds a simpler registered law as
a special case is named only when the held-out records show it is better.

A clearance whose gap is small, or a gap the measured motion always exceeds, *is* a
linear spring over these records (the clearance's force k (d - gap sign d) differs from
k d by a constant step the fit absorbs into k).  The richer law has one more coefficient,
so it always fits the train records at least as well, and the verdict, which names the
lowest validation gap, named the clearance for a missing spring (fresh seed 17578:
spring m1-m4 named clearance m1-m4; 17549: spring m2-ground named clearance m2-ground
in a three-set).  ``verdict.same_law`` catches the gap at ~0 (R^2 >= 0.999) only.

The rule: when the named law has a simpler law nested in it (``simpler_law``: found in
the effect registry by setting a shape coefficient to 0 and comparing the forces, so a
new law with such a limit is covered without a list), the simpler law at the same place
is fitted too (a single verdict: its own single fit, or one refine from the richer
fit's values; a set member: always among the swapped kinds, ``swap.member_swaps``), and
the richer law is kept only when its gain over the simpler one on the validation records
is at least ``test_z`` standard errors of the noise (``set_test.BlockTest``, the statistic
the set search compares sets with).  Otherwise the simpler law is named when it passes
the checks every verdict passes, and the richer one is listed as its rival with its
closure (the data cannot separate them); when the simpler one does not pass them the
richer one stays, with the simpler one as its rival.
"""
from __future__ import annotations

import math
from functools import lru_cache
from typing import Any, Sequence

import numpy as np

from ..effects import EFFECTS, Effect
from ..processing import Processing
from ..recording import Recording
from ..structure import Structure
from .model_edit import augmented
from .outputs import Progress, _say
from .results import Candidate
from .scoring import judge
from .set_members import below_noise, contributions, floor_for
from .set_test import BlockTest
from .settings import FAST, DiagnoseSettings
from .verdict import decide

#: values of a shape coefficient tried as the limit that leaves a simpler law
LIMITS = (0.0,)


def _grid() -> tuple[np.ndarray, np.ndarray]:
    phi = np.linspace(0.0, 2 * np.pi, 97)
    return np.concatenate([s * np.sin(phi) for s in (0.1, 0.5, 1.0, 3.0)]), \
        np.concatenate([s * np.cos(phi) for s in (0.1, 0.5, 1.0, 3.0)])


@lru_cache(maxsize=None)
def simpler_law(name: str) -> tuple[str, tuple[tuple[str, float], ...]] | None:
    """(the registered structural effect nested in effect ``name``, the shape values that
    turn ``name``'s law into it), or None: a shape coefficient at a value of ``LIMITS``
    leaves a law whose force, with the same magnitude, equals another effect's with no
    shape coefficient (clearance, gap 0 -> spring)."""
    eff = EFFECTS.get(name)
    if eff is None or eff.family == "sensor":
        return None
    shape = [c for c in eff.coefficients if c != eff.magnitude]
    if not shape:
        return None
    d, v = _grid()
    for s in shape:
        for lim in LIMITS:
            vals = {c: (lim if c == s else 1.0) for c in shape}
            try:
                f = eff.unit_force(d, v, vals)
            except Exception:  # noqa: BLE001 - a law not defined at this limit
                continue
            if not np.all(np.isfinite(f)) or not np.any(f):
                continue
            for other in EFFECTS.values():
                if other.name == name or other.family == "sensor" \
                        or len(other.coefficients) != len(eff.coefficients) - len(shape):
                    continue
                try:
                    g = other.unit_force(d, v, {})
                except Exception:  # noqa: BLE001 - not comparable
                    continue
                if np.allclose(f, g, rtol=1e-9, atol=1e-12 * float(np.abs(g).max())):
                    return other.name, tuple((c, vals[c]) for c in shape if c == s)
    return None


def nested_effect(kind: str) -> Effect | None:
    """The simpler registered effect nested in ``kind``'s law, or None."""
    got = simpler_law(kind)
    return EFFECTS[got[0]] if got is not None else None


def _fit_simple(rich: Candidate, eff: Effect, structure: Structure,
                train: Sequence[Recording], val: Sequence[Recording], proc: Processing,
                gap_before: float, before_blocks: np.ndarray, settings: DiagnoseSettings,
                progress: Progress | None) -> Candidate | None:
    """``eff`` at ``rich``'s place fitted on the train records from ``rich``'s nominal
    parameters and magnitude (the richer law at its limit), judged on ``val``."""
    from ..refine import output_error, refine

    mag = rich.coefficients.get(eff.magnitude, rich.coefficients.get(rich.effect.magnitude))
    if mag is None or not all(p in rich.parameters for p in structure.free):
        return None
    aug, names = augmented(structure, eff, rich.loc, {eff.magnitude: max(abs(mag), 1e-12)})
    try:
        th0 = aug.vector({**rich.parameters, names[eff.magnitude]: float(mag)})
        res = refine(aug, th0, list(train), proc, max_nfev=settings.fit_nfev,
                     uncertainty=FAST)
        cost = float(output_error(aug, res.theta[None], list(train), proc)[0])
    except Exception as exc:  # noqa: BLE001 - no simpler fit: the richer law stands
        _say(progress, f"nested: {eff.kind} at {'-'.join(rich.loc.between)} not fitted "
                       f"({exc})")
        return None
    vals = aug.as_dict(res.theta)
    c = Candidate(eff, rich.loc, {}, fitted=True, structure=aug,
                  theta=np.asarray(res.theta, float), names=dict(names),
                  amplitudes=rich.amplitudes, train_cost=cost,
                  coefficients={k: vals[p] for k, p in names.items()},
                  parameters={p: vals[p] for p in structure.free},
                  note=f"fitted as the law nested in {rich.label()}")
    judge(c, val, proc, gap_before, before_blocks, progress)
    return c


def prefer_simpler(verdict: Candidate | None, verdicts: list[Candidate],
                   ranking: Sequence[Candidate], structure: Structure,
                   train: Sequence[Recording], val: Sequence[Recording], proc: Processing,
                   gap_before: float, before_blocks: np.ndarray, noise_floor: float | None,
                   noise: float | None, settings: DiagnoseSettings, rule: dict[str, Any],
                   known: Any = None, progress: Progress | None = None
                   ) -> tuple[Candidate | None, list[Candidate]]:
    """A single structural verdict whose law nests a simpler one: the simpler law at its
    place named instead unless the verdict beats it by ``test_z`` on the validation
    records (module doc); ``rule["nested"]`` says what was compared."""
    if verdict is None or len(verdicts) != 1 or verdicts[0] is not verdict \
            or verdict.category != "structure" or verdict.structure is None:
        return verdict, verdicts
    eff = nested_effect(verdict.effect.kind)
    if eff is None:
        return verdict, verdicts
    simple = next((c for c in ranking if c.fitted and not c.stopped
                   and c.effect.kind == eff.kind and c.loc.between == verdict.loc.between
                   and c.structure is not None and c.theta is not None
                   and np.isfinite(c.gap_after)), None)
    if simple is None:
        simple = _fit_simple(verdict, eff, structure, train, val, proc, gap_before,
                             before_blocks, settings, progress)
    if simple is None or not np.isfinite(simple.gap_after):
        return verdict, verdicts
    z = BlockTest(val, proc, settings.test_blocks).z(simple, verdict)
    entry: dict[str, Any] = {"richer": verdict.label(), "simpler": simple.label(),
                             "gaps": [float(verdict.gap_after), float(simple.gap_after)],
                             "z": round(float(z), 2) if np.isfinite(z) else None,
                             "test_z": settings.test_z}
    rule["nested"] = entry
    if z >= settings.test_z:
        entry["named"] = verdict.label()
        _say(progress, f"nested: {verdict.label()} beats {simple.label()} by {z:.1f} "
                       "standard errors on the validation records: kept")
        return verdict, verdicts
    ok, _ = decide([simple], gap_before, noise_floor, settings)
    contrib = contributions(simple, val, proc, known)
    x = contrib[0] if contrib else math.inf
    rival = {"candidate": verdict.label(), "closure": float(verdict.closure)}
    if ok is None or below_noise(x, floor_for(simple, noise), settings):
        entry["named"] = verdict.label()
        entry["refused"] = simple.label()
        verdict.rivals = [*verdict.rivals, {"candidate": simple.label(),
                                            "closure": float(simple.closure)}]
        rule["reason"] = (f"{rule.get('reason') or 'all checks pass'}; the data cannot "
                          f"separate {verdict.label()} from the simpler law "
                          f"{simple.label()} (z {z:.1f} < {settings.test_z:g}), which "
                          "fails a check alone")
        return verdict, verdicts
    simple.rivals = [r for r in verdict.rivals if r["candidate"] != simple.label()
                     and r["candidate"] != verdict.label()] + [rival]
    simple.closure_added = float(simple.closure)
    simple.contribution = float(x)
    entry["named"] = simple.label()
    rule["combined_closure"] = float(simple.closure)
    rule["reason"] = (f"{simple.label()} is named: {verdict.label()} holds it as a special "
                      f"case and does not beat it on the validation records ({z:.1f} "
                      f"standard errors of the noise, {settings.test_z:g} needed; gaps "
                      f"{verdict.gap_after:.4g} and {simple.gap_after:.4g}): the data "
                      f"cannot separate them")
    _say(progress, f"nested: {simple.label()} named for {verdict.label()} (z {z:.1f})")
    return simple, [simple]


def nested_swap(top: Any, options: Sequence[Any], val: Sequence[Recording],
                proc: Processing, settings: DiagnoseSettings, accept: Any,
                rule: dict[str, Any], progress: Progress | None = None
                ) -> tuple[int, Any] | None:
    """(member index, the set of ``options`` to name instead of the set ``top``): the one
    with the law nested in a member's law at its place, the other members as in ``top``,
    when ``top`` does not beat it by ``test_z`` on the validation records and it passes
    ``accept`` (the set's checks); None when ``top`` stays.  ``rule["nested"]`` lists the
    comparisons."""
    labels = [m.label() for m in top.members]
    compared = []
    test = BlockTest(val, proc, settings.test_blocks)  # ``top`` simulated once
    for k, m in enumerate(top.members):
        eff = nested_effect(m.effect.kind) if m.category == "structure" else None
        if eff is None:
            continue
        same = [s for s in options if s is not top and not s.stopped
                and np.isfinite(s.gap_after) and len(s.members) == len(labels)
                and s.members[k].effect.kind == eff.kind
                and s.members[k].loc.between == m.loc.between
                and [x.label() for i, x in enumerate(s.members) if i != k]
                == [x for i, x in enumerate(labels) if i != k]]
        for s in sorted(same, key=lambda s: s.gap_after):
            z = test.z(s, top)
            entry = {"richer": top.label(), "simpler": s.label(),
                     "gaps": [float(top.gap_after), float(s.gap_after)],
                     "z": round(float(z), 2) if np.isfinite(z) else None,
                     "test_z": settings.test_z}
            compared.append(entry)
            if z >= settings.test_z:
                _say(progress, f"nested: {top.label()} beats {s.label()} by {z:.1f} "
                               "standard errors on the validation records: kept")
                continue
            if not accept(s):
                entry["refused"] = True
                continue
            rule["nested"] = compared
            _say(progress, f"nested: {s.label()} named for {top.label()} (z {z:.1f})")
            return k, s
    if compared:
        rule["nested"] = compared
    return None
