"""Reading a model spec (CONTRACT.md: a TOML file, or the same structure as JSON) into the
parts of a ``Structure``, checking everything; a ``SpecError`` names what and where."""
from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any, Mapping, NamedTuple

from ..elements import REGISTRY
from .channels import channels_table
from .parts import GROUND, Element, ParameterInfo, SpecError

_TOP_KEYS = frozenset({"name", "dofs", "mass", "elements", "parameters", "forces",
                       "channels", "description", "notes"})
_ELEMENT_KEYS = frozenset({"kind", "between", "params", "name", "description"})
_PARAM_RE = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


class SpecParts(NamedTuple):
    """A checked spec: the arguments of ``Structure``, in its field order."""

    name: str
    dofs: list[str]
    mass: dict[str, float]
    elements: list[Element]
    parameters: dict[str, ParameterInfo]
    force_gains: dict[str, str | float]
    spec: dict[str, Any]
    channel_map: dict[str, str]
    channel_units: dict[str, str]


def read_spec_file(path: Path) -> Any:
    """The spec file's content (TOML, or JSON by its suffix), not yet checked."""
    path = Path(path)
    try:
        text = path.read_bytes().decode("utf-8-sig")
    except OSError as exc:
        raise SpecError(f"{path}: cannot read model spec ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise SpecError(f"{path}: not UTF-8 text (byte {exc.start})") from None
    if path.suffix.lower() == ".json":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise SpecError(f"{path}: invalid JSON at line {exc.lineno}: {exc.msg}") from None
    else:
        import tomllib

        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise SpecError(f"{path}: invalid TOML: {exc}") from None
    return data


def parse_spec(data: Mapping[str, Any]) -> SpecParts:
    """Check the spec's dict form (the JSON body over HTTP) section by section."""
    if not isinstance(data, Mapping):
        raise SpecError("model spec must be an object/table")
    unknown_top = [k for k in data if k not in _TOP_KEYS]
    if unknown_top:
        raise SpecError(f"{unknown_top[0]}: unknown top-level key (known: "
                        f"{', '.join(sorted(_TOP_KEYS))})")
    name = data.get("name", "model")
    if not isinstance(name, str) or not name:
        raise SpecError("'name' must be a non-empty string")
    dofs = data.get("dofs")
    if (not isinstance(dofs, list) or not dofs
            or not all(isinstance(d, str) and d for d in dofs)):
        raise SpecError("'dofs' must be a non-empty list of DOF names")
    if len(set(dofs)) != len(dofs):
        raise SpecError(f"'dofs' has duplicate names: {dofs}")
    if GROUND in dofs:
        raise SpecError("'dofs': 'ground' is reserved and cannot be a DOF name")
    for d in dofs:
        if not d.replace("_", "").isalnum():
            raise SpecError(f"'dofs': name {d!r} must be letters, digits and '_'")
    index = {d: k for k, d in enumerate(dofs)}
    mass = _masses(data.get("mass"), dofs, index)
    param_in = data.get("parameters", {}) or {}
    if not isinstance(param_in, Mapping):
        raise SpecError("'parameters' must be a table of per-parameter settings")
    elements, order, param_in = _elements(data.get("elements"), dofs, index, param_in)
    gains = _force_gains(data.get("forces", {}) or {}, dofs, index, order)
    parameters = _parameters(param_in, order)
    for pname in param_in:
        if pname not in parameters:
            raise SpecError(f"parameters.{pname}: not used by any element or force gain")
    try:
        spec = json.loads(json.dumps(dict(data)))
    except (TypeError, ValueError) as exc:
        raise SpecError(f"spec holds a value JSON cannot carry ({exc})") from None
    cmap, cunits = channels_table(data.get("channels"), dofs)
    return SpecParts(name, list(dofs), mass, elements, parameters, gains, spec, cmap, cunits)


def _masses(mass_in: Any, dofs: list[str], index: dict[str, int]) -> dict[str, float]:
    """``mass = {dof = kg}``: positive, one per DOF and no other."""
    if not isinstance(mass_in, Mapping):
        raise SpecError("'mass' must be a table {dof = kg}")
    mass: dict[str, float] = {}
    for d in dofs:
        if d not in mass_in:
            raise SpecError(f"mass.{d}: missing mass for DOF {d!r}")
        m = number(mass_in[d], f"mass.{d}")
        if not m > 0:
            raise SpecError(f"mass.{d}: mass must be positive, got {m}")
        mass[d] = m
    for d in mass_in:
        if d not in index:
            raise SpecError(f"mass.{d}: {d!r} is not a DOF (dofs = {dofs})")
    return mass


def _elements(raw_elements: Any, dofs: list[str], index: dict[str, int],
              param_in: Mapping[str, Any]) -> tuple[list[Element], list[str], Mapping[str, Any]]:
    """``[[elements]]``: each a known kind between a DOF and a DOF or ground, with a
    parameter name (or a literal number: an anonymous fixed parameter) per coefficient.
    Returns the elements, the parameter names in order of appearance and the parameter
    settings with the literals' added."""
    elements: list[Element] = []
    order: list[str] = []
    if not isinstance(raw_elements, list) or not raw_elements:
        raise SpecError("'elements' must be a non-empty list")
    for n, el in enumerate(raw_elements):
        where = f"elements[{n}]"
        if not isinstance(el, Mapping):
            raise SpecError(f"{where}: must be a table")
        extra = [k for k in el if k not in _ELEMENT_KEYS]
        if extra:
            raise SpecError(f"{where}.{extra[0]}: unknown key (known: "
                            f"{', '.join(sorted(_ELEMENT_KEYS))})")
        kind_name = el.get("kind")
        if not isinstance(kind_name, str) or kind_name not in REGISTRY:
            raise SpecError(f"{where}.kind: unknown element kind {kind_name!r} "
                            f"(known: {', '.join(sorted(REGISTRY))})")
        kind = REGISTRY[kind_name]
        between = el.get("between")
        if (not isinstance(between, (list, tuple)) or len(between) != 2
                or not all(isinstance(b, str) for b in between)):
            raise SpecError(f"{where}.between: must be two names [dof, dof or 'ground']")
        a, b = between
        if a == GROUND and b in index:
            raise SpecError(f"{where}.between: put the DOF first: [{b!r}, 'ground'] "
                            "(d = q_i - q_j is measured from the first name)")
        if a not in index:
            raise SpecError(f"{where}.between: {a!r} is not a DOF (dofs = {dofs})")
        if b != GROUND and b not in index:
            raise SpecError(f"{where}.between: {b!r} is not a DOF or 'ground' (dofs = {dofs})")
        if a == b:
            raise SpecError(f"{where}.between: an element cannot connect {a!r} to itself")
        params = el.get("params", {})
        if not isinstance(params, Mapping):
            raise SpecError(f"{where}.params: must be a table coefficient -> parameter name")
        names = []
        for c in kind.coefficients:
            if c not in params:
                raise SpecError(f"{where}.params: kind {kind.name!r} needs coefficient {c!r} "
                                f"(coefficients: {', '.join(kind.coefficients)})")
            pname = params[c]
            if isinstance(pname, (int, float)) and not isinstance(pname, bool):
                # a literal number: an anonymous fixed parameter
                value = number(pname, f"{where}.params.{c}")
                pname = f"_fixed_{n}_{c}"
                param_in = {**param_in, pname: {"fixed": value}}
            if not isinstance(pname, str) or not _PARAM_RE.fullmatch(pname):
                raise SpecError(f"{where}.params.{c}: must be a parameter name (letters, "
                                f"digits, '_'), got {pname!r}")
            names.append(pname)
            if pname not in order:
                order.append(pname)
        for c in params:
            if c not in kind.coefficients:
                raise SpecError(f"{where}.params.{c}: kind {kind.name!r} has no coefficient "
                                f"{c!r} (coefficients: {', '.join(kind.coefficients)})")
        elements.append(Element(kind, (a, b), index[a], -1 if b == GROUND else index[b],
                                tuple(names)))
    return elements, order, param_in


def _force_gains(forces_in: Any, dofs: list[str], index: dict[str, int],
                 order: list[str]) -> dict[str, str | float]:
    """``[forces]``: the gain G of each measured force, a number or a parameter name
    (appended to ``order``)."""
    gains: dict[str, str | float] = {}
    if not isinstance(forces_in, Mapping):
        raise SpecError("'forces' must be a table {dof = {gain = ...}}")
    for d, setting in forces_in.items():
        if d not in index:
            raise SpecError(f"forces.{d}: {d!r} is not a DOF (dofs = {dofs})")
        if isinstance(setting, Mapping):
            extra = [k for k in setting if k != "gain"]
            if extra:
                raise SpecError(f"forces.{d}.{extra[0]}: unknown key (known: gain)")
        gain = setting.get("gain", 1.0) if isinstance(setting, Mapping) else setting
        if isinstance(gain, str):
            if not _PARAM_RE.fullmatch(gain):
                raise SpecError(f"forces.{d}.gain: must be a number or a parameter name, "
                                f"got {gain!r}")
            if gain not in order:
                order.append(gain)
            gains[d] = gain
        else:
            gains[d] = number(gain, f"forces.{d}.gain")
    return gains


def _parameters(param_in: Mapping[str, Any], order: list[str]) -> dict[str, ParameterInfo]:
    """``[parameters]``: the settings of each parameter named by an element or a gain."""
    parameters: dict[str, ParameterInfo] = {}
    for pname in order:
        setting = param_in.get(pname, {}) or {}
        where = f"parameters.{pname}"
        if not isinstance(setting, Mapping):
            raise SpecError(f"{where}: must be a table (scale, fixed, lower, upper)")
        unknown = set(setting) - {"scale", "fixed", "lower", "upper", "initial"}
        if unknown:
            raise SpecError(f"{where}: unknown setting(s) {sorted(unknown)} "
                            "(known: scale, fixed, lower, upper, initial)")
        info = ParameterInfo(
            pname,
            scale=opt_number(setting.get("scale"), f"{where}.scale"),
            fixed=opt_number(setting.get("fixed"), f"{where}.fixed"),
            lower=opt_number(setting.get("lower"), f"{where}.lower"),
            upper=opt_number(setting.get("upper"), f"{where}.upper"),
            initial=opt_number(setting.get("initial"), f"{where}.initial"),
        )
        if info.scale is not None and not info.scale > 0:
            raise SpecError(f"{where}.scale: must be positive, got {info.scale}")
        if info.lower is not None and info.upper is not None and not info.lower < info.upper:
            raise SpecError(f"{where}: lower ({info.lower}) must be below upper "
                            f"({info.upper})")
        if info.fixed is not None and (
                (info.lower is not None and info.fixed < info.lower)
                or (info.upper is not None and info.fixed > info.upper)):
            raise SpecError(f"{where}.fixed: {info.fixed} is outside [lower, upper]")
        parameters[pname] = info
    return parameters


def number(x: Any, where: str) -> float:
    """A finite number (not a bool), else a SpecError naming ``where``."""
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        raise SpecError(f"{where}: must be a number, got {x!r}")
    x = float(x)
    if not math.isfinite(x):
        raise SpecError(f"{where}: must be finite, got {x}")
    return x


def opt_number(x: Any, where: str) -> float | None:
    """``number``, or None when absent."""
    return None if x is None else number(x, where)
