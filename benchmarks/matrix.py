"""The confusion-matrix cases of `bench_diagnose.py --matrix`: withheld effects at every
place, two sizes, sensor faults, nulls and two-effect cases, on two structures.

Why sizes are derived, not listed: the benchmark must say something about structures and
places it was not tuned on.  Each effect's size is set from the nominal truth's own
response (one simulation at the largest train amplitude): at the place, the relative
displacement ``d`` and velocity ``v`` peaks give the effect's *equivalent* linear
coefficient, ``F(d, v) / v`` for dissipative laws and ``F(d, v) / d`` for stiffness laws,
and the magnitude is chosen so that this equals a share of the structure's own scale:

* dissipative (damper, quadratic/cubic damper, coulomb): ``DAMPING`` x the critical
  damping ``2 m w1`` (lightest mass, first linear mode): an extra damping ratio;
* stiffness (spring, quadratic/cubic spring): ``STIFFNESS`` x ``m w1^2``; the cubic
  spring's small size is *softening* (negative), its large one hardening;
* clearance: contact stiffness ``CONTACT`` x ``m w1^2``, gap at 40 % of ``d``.

Structures: ``lono`` (examples/models/lono.toml, the truth of the shipped lono/ records,
hammer on NO; train 150 + 450 N, validate 50 + 800 N) and ``chain3`` (benchmarks/cases.py's
3-DOF chain with its cubic spring m2-m3, hammer on the middle mass m2; train 100 + 250 N,
validate 40 + 400 N).  Records: ``synthetic_impacts`` (acc per DOF + force, 0.3 % / 0.2 %
noise, 4 s at 2048 Hz), train seed 11, validation seed 12.
"""
from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from siva_core import EFFECTS, Recording, Structure, synthetic_impacts, with_effect

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("SIVA_SHARED_DATA") or ROOT.parent / "shared" / "data")

#: extra damping ratio of the two sizes (dissipative laws)
DAMPING = {"faint": 0.001, "small": 0.003, "large": 0.01}
#: equivalent stiffness as a share of m w1^2 (the cubic spring's small size is softening)
STIFFNESS = {"faint": 0.015, "small": 0.04, "large": 0.12}
#: clearance contact stiffness as a share of m w1^2
CONTACT = {"faint": 0.2, "small": 0.5, "large": 1.5}
DISSIPATIVE = {"damper", "quadratic_damper", "cubic_damper", "coulomb"}
KINDS = ("coulomb", "damper", "quadratic_damper", "cubic_damper", "spring", "cubic_spring",
         "quadratic_spring", "clearance")
SENSORS = {"accelerometer_gain": 0.85, "channel_delay": 2.0, "force_gain": 1.15}


@dataclass(frozen=True)
class Rig:
    name: str
    force_dof: str
    train_peaks: tuple[float, float]
    val_peaks: tuple[float, float]
    #: two-effect cases: ((kind, place, size), (kind, place, size))
    pairs: tuple[tuple[tuple[str, str, str], tuple[str, str, str]], ...]

    def nominal(self) -> Structure:
        if self.name == "lono":
            return Structure.from_file(ROOT / "examples" / "models" / "lono.toml")
        from cases import CHAIN3
        return CHAIN3.structure()

    def truth(self) -> dict[str, float]:
        if self.name == "lono":
            return json.loads((DATA / "lono" / "truth.json").read_text())["truth"]
        from cases import CHAIN3
        return dict(CHAIN3.truth)


STRUCTURES = {
    "lono": Rig("lono", "NO", (150.0, 450.0), (50.0, 800.0),
                ((("coulomb", "NO-ground", "large"), ("quadratic_damper", "LO-ground", "large")),
                 (("cubic_damper", "LO-NO", "large"), ("spring", "NO-ground", "small")))),
    "chain3": Rig("chain3", "m2", (100.0, 250.0), (40.0, 400.0),
                  ((("coulomb", "m1-ground", "large"), ("quadratic_damper", "m3-ground", "large")),
                   (("cubic_damper", "m1-m2", "large"), ("spring", "m3-ground", "small")))),
}


def places(structure: Structure) -> list[str]:
    """Every DOF to ground, then every DOF pair ('LO-ground', 'LO-NO')."""
    d = structure.dofs
    return [f"{a}-ground" for a in d] + [f"{a}-{b}" for i, a in enumerate(d) for b in d[i + 1:]]


def _between(place: str) -> tuple[str, str]:
    a, b = place.split("-")
    return a, b


def _has(structure: Structure, kind: str, place: str) -> bool:
    """The model already has this kind there (not an unmodelled effect); the power spring
    with beta ~ 2 of LO-NO counts as a cubic spring (its law already holds it)."""
    a, b = _between(place)
    pair = {a, b}
    for el in structure.spec["elements"]:
        if set(el["between"]) == pair and (el["kind"] == kind or (
                kind == "cubic_spring" and el["kind"] == "power_spring")):
            return True
    return False


@lru_cache(maxsize=None)
def _peaks(rig_name: str) -> dict[str, tuple[float, float]]:
    """Peak |relative displacement| and |relative velocity| per place, nominal truth at the
    largest train amplitude, and the structure's scales (lightest mass, first mode)."""
    from siva_core import simulate

    rig = STRUCTURES[rig_name]
    st = rig.nominal()
    th = st.vector(rig.truth())
    fs, n = 2048.0, 4 * 2048
    t = np.arange(n) / fs
    F = np.zeros((n, st.n_dof))
    k = st.dofs.index(rig.force_dof)
    on = (t >= 0.1) & (t <= 0.1 + 6.2e-3)
    F[on, k] = rig.train_peaks[1] * np.sin(np.pi * (t[on] - 0.1) / 6.2e-3)
    sim = simulate(st, th, t, np.zeros(st.n_dof), np.zeros(st.n_dof), F, substeps="auto")
    q, v = np.asarray(sim.q), np.asarray(sim.v)
    out = {}
    for place in places(st):
        a, b = _between(place)
        i = st.dofs.index(a)
        j = st.dofs.index(b) if b != "ground" else -1
        d = q[:, i] - (q[:, j] if j >= 0 else 0.0)
        dv = v[:, i] - (v[:, j] if j >= 0 else 0.0)
        out[place] = (float(np.max(np.abs(d))), float(np.max(np.abs(dv))))
    m = min(float(x) for x in st.spec["mass"].values())
    w1 = 2 * np.pi * min(st.linear_modes(th)["frequency_hz"])
    out["_scale"] = (m, float(w1))
    return out


def coefficients(rig_name: str, kind: str, place: str, size: str) -> dict[str, float]:
    """The effect's coefficients for this size (see the module doc)."""
    peaks = _peaks(rig_name)
    d, v = peaks[place]
    m, w1 = peaks["_scale"]
    eff = EFFECTS[kind]
    if kind == "clearance":
        gap = 0.4 * d
        return {"k": CONTACT[size] * m * w1 ** 2, "gap": gap}
    unit = abs(float(eff.unit_force(np.array(d), np.array(v), {})))
    if kind in DISSIPATIVE:
        mag = DAMPING[size] * 2 * m * w1 * v / unit
    else:
        mag = STIFFNESS[size] * m * w1 ** 2 * d / unit
        if kind == "cubic_spring" and size in ("small", "faint"):
            mag = -mag
    return {eff.magnitude: float(f"{mag:.3g}")}


@dataclass(frozen=True)
class MatrixCase:
    """``rig:kind:place:size``, ``rig:null``, ``rig:sensor:fault:channel``,
    ``rig:two:i`` (the i-th pair of ``Rig.pairs``), ``rig:pair:kind:place:size:kind:place:
    size`` (any two structural effects) or ``rig:mixed:kind:place:size:fault:channel`` (a
    structural effect and a sensor fault at once, issue 16)."""

    rig: str
    what: str
    args: tuple[str, ...]

    @property
    def name(self) -> str:
        return ":".join((self.rig, self.what, *self.args))

    def nominal(self) -> Structure:
        return STRUCTURES[self.rig].nominal()

    def _elements(self) -> list[tuple[str, str, str]]:
        if self.what == "two":
            return list(STRUCTURES[self.rig].pairs[int(self.args[0])])
        if self.what == "pair":
            return [tuple(self.args[:3]), tuple(self.args[3:6])]  # type: ignore[list-item]
        if self.what in EFFECTS:
            return [(self.what, self.args[0], self.args[1])]
        if self.what == "mixed":
            return [(self.args[0], self.args[1], self.args[2])]
        return []

    def _fault(self) -> tuple[str, str] | None:
        if self.what == "sensor":
            return self.args[0], self.args[1]
        if self.what == "mixed":
            return self.args[3], self.args[4]
        return None

    def records(self) -> tuple[list[Recording], list[Recording]]:
        rig = STRUCTURES[self.rig]
        gen = rig.nominal()
        for kind, place, size in self._elements():
            gen = with_effect(gen, kind, _between(place),
                              coefficients(self.rig, kind, place, size))
        theta = gen.vector(rig.truth())
        train = synthetic_impacts(gen, theta, list(rig.train_peaks), dof=rig.force_dof, seed=11)
        val = synthetic_impacts(gen, theta, list(rig.val_peaks), dof=rig.force_dof, seed=12)
        if self._fault() is not None:
            fault, channel = self._fault()
            value = SENSORS[fault]
            out = []
            for r in [*train, *val]:
                x = np.asarray(r.channels[channel], float)
                if fault == "channel_delay":  # measured(t) = true(t - delay)
                    x = np.interp(r.time - value / r.fs, r.time, x)
                else:
                    x = x * value
                out.append(dataclasses.replace(r, channels={**r.channels, channel: x}))
            train, val = out[:2], out[2:]
        return train, val

    def expected(self) -> list[tuple[str, tuple[str, ...]]]:
        out = [(k, _between(p)) for k, p, _ in self._elements()]
        if self._fault() is not None:
            out.append((self._fault()[0], (self._fault()[1],)))
        return out

    def truths(self) -> list[dict[str, float]]:
        out = [coefficients(self.rig, k, p, s) for k, p, s in self._elements()]
        if self._fault() is not None:
            fault = self._fault()[0]
            v = SENSORS[fault]
            out.append({"delay": v / 2048.0} if fault == "channel_delay" else {"gain": v})
        return out


def parse(name: str) -> MatrixCase:
    rig, what, *args = name.split(":")
    if rig not in STRUCTURES:
        raise ValueError(f"unknown structure {rig!r} in {name!r} (known: {', '.join(STRUCTURES)})")
    return MatrixCase(rig, what, tuple(args))


def _sensor_cases(rig: Rig, rotate: int = 0) -> list[MatrixCase]:
    st = rig.nominal()
    d = st.dofs
    return [MatrixCase(rig.name, "sensor", ("accelerometer_gain", f"acc_{d[rotate % len(d)]}")),
            MatrixCase(rig.name, "sensor", ("channel_delay", f"acc_{d[(-1 - rotate) % len(d)]}")),
            MatrixCase(rig.name, "sensor", ("force_gain", f"force_{rig.force_dof}"))]


def cases(scope: str, rigs: list[str], rotate: int = 0) -> list[MatrixCase]:
    """``full``: every kind x every place it is missing x both sizes, the null, the sensor
    faults, every pair.  ``reduced``: every kind once per structure (place and size
    rotating through the list, so a reduced run still visits ground and coupling places
    and both sizes), the null, the sensor faults and the first pair.  ``rotate`` = r > 0
    shifts the reduced run's places, sizes and sensor channels by r (the null, the force
    gain and the pair, the same as for r = 0, are left out): reduced runs with r = 0, 1,
    ... visit the full matrix piece by piece."""
    out: list[MatrixCase] = []
    for name in rigs:
        rig = STRUCTURES[name]
        st = rig.nominal()
        if scope == "full" or rotate == 0:
            out.append(MatrixCase(name, "null", ()))
        for n, kind in enumerate(KINDS):
            where = [p for p in places(st) if not _has(st, kind, p)]
            if scope == "full":
                out += [MatrixCase(name, kind, (p, s)) for p in where for s in ("small", "large")]
            elif where:
                out.append(MatrixCase(name, kind, (where[(n + rotate) % len(where)],
                                                   ("small", "large")[(n + rotate) % 2])))
        sensors = _sensor_cases(rig, 0 if scope == "full" else rotate)
        out += sensors if scope == "full" or rotate == 0 else sensors[:2]
        if scope == "full" or rotate == 0:
            pairs = rig.pairs if scope == "full" else rig.pairs[:1]
            out += [MatrixCase(name, "two", (str(i),)) for i in range(len(pairs))]
    return out


#: look-alike laws (issue 16): every one of a group at every place, sized "small"
LOOK_ALIKE_GROUPS = (("damper", "quadratic_damper", "cubic_damper", "coulomb"),
                     ("spring", "cubic_spring", "clearance"))


def issue16_cases(rigs: list[str]) -> list[MatrixCase]:
    """The rows issue 16 adds: both two-effect pairs, a structural effect with a sensor
    fault, each look-alike law at every place it is missing (small), faint sizes of the
    look-alike laws (first place) and the null."""
    out: list[MatrixCase] = []
    for name in rigs:
        rig = STRUCTURES[name]
        st = rig.nominal()
        out.append(MatrixCase(name, "null", ()))
        out += [MatrixCase(name, "two", (str(i),)) for i in range(len(rig.pairs))]
        kind, place, size = rig.pairs[0][0]
        out.append(MatrixCase(name, "mixed", (kind, place, size, "accelerometer_gain",
                                              f"acc_{st.dofs[-1]}")))
        for group in LOOK_ALIKE_GROUPS:
            for kind in group:
                where = [p for p in places(st) if not _has(st, kind, p)]
                out += [MatrixCase(name, kind, (p, "small")) for p in where]
                if where:
                    out.append(MatrixCase(name, kind, (where[0], "faint")))
    return out


def pairs_cases(rigs: list[str]) -> list[MatrixCase]:
    """Two effects at once by a fixed rule (issue 16, rows written before they were run):
    each kind ``KINDS[i]`` with ``KINDS[(i + 3) % 8]`` (every law once first and once
    second; dissipative with stiffness mostly), the first at place ``i``, the second half
    the place list further on (another place), sizes large + large for even ``i`` and
    large + small for odd ``i``; then each sensor fault beside a structural law (every
    other kind, its place rotating, large) on a channel rotating over the DOFs.  A place
    where the model already holds the kind moves to the next place."""
    out: list[MatrixCase] = []
    for name in rigs:
        rig = STRUCTURES[name]
        st = rig.nominal()
        ps = places(st)

        def at(kind: str, k: int) -> str:
            for j in range(len(ps)):
                p = ps[(k + j) % len(ps)]
                if not _has(st, kind, p):
                    return p
            raise ValueError(f"{kind} is already everywhere in {name}")

        for i, first in enumerate(KINDS):
            second = KINDS[(i + 3) % len(KINDS)]
            pa = at(first, i)
            pb = at(second, ps.index(pa) + max(1, len(ps) // 2))
            if pb == pa:
                pb = at(second, ps.index(pa) + 1)
            size_b = "large" if i % 2 == 0 else "small"
            out.append(MatrixCase(name, "pair", (first, pa, "large", second, pb, size_b)))
        faults = [("accelerometer_gain", "acc"), ("channel_delay", "acc"), ("force_gain", "force")]
        for j, (fault, prefix) in enumerate(faults + faults[:1]):
            kind = KINDS[(2 * j + 1) % len(KINDS)]
            dof = rig.force_dof if prefix == "force" else st.dofs[(j + 1) % len(st.dofs)]
            out.append(MatrixCase(name, "mixed", (kind, at(kind, j + 1), "large", fault,
                                                  f"{prefix}_{dof}")))
    return out


def case_names(scope: str, rigs: list[str], rotate: int = 0) -> list[str]:
    if scope == "issue16":
        return [c.name for c in issue16_cases(rigs)]
    if scope == "pairs":
        return [c.name for c in pairs_cases(rigs)]
    return [c.name for c in cases(scope, rigs, rotate)]
