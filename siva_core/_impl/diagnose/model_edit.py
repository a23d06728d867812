"""Models with one more element: the augmented candidate model (free new coefficients)
and the synthetic-case generator (known, fixed coefficients)."""
from __future__ import annotations

import copy
from typing import Mapping, Sequence

from ..effects import Effect
from ..structure import Structure
from .results import Location


def _param_name(structure: Structure, coef: str, loc: Location, taken: set[str]) -> str:
    base = f"{coef}_{loc.between[0]}_{loc.between[1]}"
    name, n = base, 2
    while name in structure.parameters or name in taken:
        name, n = f"{base}_{n}", n + 1
    return name


def augmented(structure: Structure, effect: Effect, loc: Location,
              scales: Mapping[str, float]) -> tuple[Structure, dict[str, str]]:
    """The model plus one element of ``effect`` at ``loc``; returns it and the map
    coefficient -> new parameter name.  New coefficients get a scale hint and, when the
    effect says they are signed, a lower bound of 0 (an energy source is not an effect)."""
    spec = copy.deepcopy(structure.spec)
    names: dict[str, str] = {}
    taken: set[str] = set()
    for c in effect.coefficients:
        names[c] = _param_name(structure, c, loc, taken)
        taken.add(names[c])
    spec.setdefault("elements", []).append(
        {"kind": effect.kind, "between": list(loc.between), "params": dict(names)})
    params = dict(spec.get("parameters") or {})
    for c, p in names.items():
        setting: dict[str, float] = {"scale": float(max(abs(scales.get(c, 1.0)), 1e-300))}
        if c in effect.positive:
            setting["lower"] = 0.0
        params[p] = setting
    spec["parameters"] = params
    return Structure.from_dict(spec), names


def with_effect(structure: Structure, kind: str, between: Sequence[str],
                coefficients: Mapping[str, float]) -> Structure:
    """``structure`` plus one element with *known* coefficients (fixed parameters), so the
    free parameters stay those of ``structure``: the generator of a synthetic gap case."""
    spec = copy.deepcopy(structure.spec)
    spec["elements"].append({"kind": kind, "between": list(between),
                             "params": {c: float(v) for c, v in coefficients.items()}})
    return Structure.from_dict(spec)
