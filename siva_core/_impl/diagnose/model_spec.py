"""The augmented model as a spec file (TOML like examples/models/*.toml): what the user
adds to the model next, with the identified values, their 95 % intervals and units.

Spec parameters carry ``scale``/``lower``/``upper``/``fixed`` (no initial value), so the
identified value goes into ``scale`` (the magnitude identification starts from) and, with
its interval and unit, into a comment next to it."""
from __future__ import annotations

import json
import math
from typing import Any, Mapping, Sequence

from .results import Candidate, Diagnosis
from .units import unit


def _value(x: Any) -> str:
    if isinstance(x, bool):
        return "true" if x else "false"
    if isinstance(x, (int, float)):
        if isinstance(x, float) and not math.isfinite(x):
            raise ValueError(f"cannot write {x} to a spec file")
        return repr(float(x)) if isinstance(x, float) else str(x)
    if isinstance(x, str):
        return json.dumps(x)
    if isinstance(x, Mapping):
        return "{ " + ", ".join(f"{_key(k)} = {_value(v)}" for k, v in x.items()) + " }"
    if isinstance(x, (list, tuple)):
        return "[" + ", ".join(_value(v) for v in x) + "]"
    raise TypeError(f"cannot write {type(x).__name__} to a spec file")


def _key(k: str) -> str:
    return k if k.replace("_", "").replace("-", "").isalnum() else json.dumps(k)


def element_block(c: Candidate) -> str:
    """The ``[[elements]]`` block (and its ``[parameters.*]``) the candidate adds."""
    if c.category == "sensor":
        v = c.coefficients.get(c.effect.magnitude)
        lo, hi = c.intervals.get(c.effect.magnitude, (math.nan, math.nan))
        return (f"# sensor fault, not a model element: {c.effect.kind} on {c.loc.between[0]} "
                f"= {v:.5g} (95 % {lo:.5g} .. {hi:.5g}) {unit(c.effect.kind, c.effect.magnitude)}"
                "\n# correct the channel (divide a gain out, shift a delay back) and "
                "re-identify the nominal model\n")
    names = c.names or {k: k for k in c.coefficients}
    lines = ["[[elements]]", f"kind = {_value(c.effect.kind)}",
             f"between = {_value(list(c.loc.between))}",
             f"params = {_value({k: names[k] for k in c.effect.coefficients if k in names})}",
             ""]
    for k in c.effect.coefficients:
        if k not in c.coefficients or k not in names:
            continue
        v = c.coefficients[k]
        setting: dict[str, float] = {"scale": float(abs(v)) if v else 1.0}
        if k in c.effect.positive:
            setting["lower"] = 0.0
        lo, hi = c.intervals.get(k, (math.nan, math.nan))
        interval = f", 95 % {lo:.5g} .. {hi:.5g}" if math.isfinite(lo) else ""
        lines.append(f"[parameters.{_key(names[k])}]  # identified {v:.5g}{interval} "
                     f"{unit(c.effect.kind, k)}")
        lines += [f"{_key(a)} = {_value(b)}" for a, b in setting.items()]
        lines.append("")
    return "\n".join(lines)


def spec_toml(spec: Mapping[str, Any], header: Sequence[str] = ()) -> str:
    """A model spec dict as TOML (the subset the spec format uses)."""
    out = [f"# {h}" for h in header]
    tables, arrays = {}, {}
    for k, v in spec.items():
        if isinstance(v, Mapping):
            tables[k] = v
        elif isinstance(v, list) and v and all(isinstance(e, Mapping) for e in v):
            arrays[k] = v
        else:
            out.append(f"{_key(k)} = {_value(v)}")
    for k, v in tables.items():
        simple = {a: b for a, b in v.items() if not isinstance(b, Mapping)}
        nested = {a: b for a, b in v.items() if isinstance(b, Mapping)}
        if simple or not nested:
            out += ["", f"[{_key(k)}]"] + [f"{_key(a)} = {_value(b)}" for a, b in simple.items()]
        for a, b in nested.items():
            out += ["", f"[{_key(k)}.{_key(a)}]"] + [f"{_key(x)} = {_value(y)}"
                                                     for x, y in b.items()]
    for k, rows in arrays.items():
        for row in rows:
            out += ["", f"[[{_key(k)}]]"] + [f"{_key(a)} = {_value(b)}" for a, b in row.items()]
    return "\n".join(out) + "\n"


def augmented_spec(diag: Diagnosis) -> dict[str, Any]:
    """The model with every named structural effect, parameter scales at the identified
    values (the nominal ones at the last stage's fit)."""
    structural = [c for c in diag.verdicts if c.category == "structure"]
    if not structural:
        raise ValueError("no structural effect was named: there is no element to add "
                         f"({diag.rule.get('reason', 'no verdict')})")
    last = structural[-1]
    spec = json.loads(json.dumps(last.structure.spec))
    values = last.structure.as_dict(last.theta)
    params = spec.setdefault("parameters", {})
    for p, v in values.items():
        setting = dict(params.get(p) or {})
        if "fixed" in setting:
            continue
        setting["scale"] = float(abs(v)) if v else setting.get("scale", 1.0)
        params[p] = setting
    return spec


def write_model(diag: Diagnosis) -> str:
    """The TOML text of ``augmented_spec`` with a header naming what was added."""
    spec = augmented_spec(diag)
    head = [f"{diag.structure.name} + " + " + ".join(c.label() for c in diag.verdicts
                                                     if c.category == "structure"),
            "written by `siva diagnose --write-model`; parameter scales = identified values"]
    for c in diag.verdicts:
        for k, v in c.coefficients.items():
            lo, hi = c.intervals.get(k, (math.nan, math.nan))
            head.append(f"{c.label()}: {k} = {v:.5g} {unit(c.effect.kind, k)}"
                        + (f" (95 % {lo:.5g} .. {hi:.5g})" if math.isfinite(lo) else ""))
    return spec_toml(spec, head)
