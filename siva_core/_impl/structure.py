"""Structure: masses + elements from a model spec, assembled into M q'' = -sum f + G F(t).

The spec format is the one of CONTRACT.md (TOML file, same structure as JSON).  A
``Structure`` knows which parameters are identified (``free``), which are fixed, their
scale hints, and evaluates model accelerations for a whole batch of parameter sets at
once, with numpy or torch (so the same code serves training with autograd and simulation).
"""
from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .elements import REGISTRY, ElementKind

GROUND = "ground"
_TOP_KEYS = frozenset({"name", "dofs", "mass", "elements", "parameters", "forces",
                       "channels", "description", "notes"})
_ELEMENT_KEYS = frozenset({"kind", "between", "params", "name", "description"})
_PARAM_RE = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


class SpecError(ValueError):
    """A model spec that cannot be used; the message names what and where."""


@dataclass(frozen=True)
class ParameterInfo:
    """Settings of one global parameter: its scale hint, or a fixed (known) value."""

    name: str
    scale: float | None = None
    fixed: float | None = None
    lower: float | None = None
    upper: float | None = None
    initial: float | None = None   # a nominal value (checks before training: the modes)


@dataclass(frozen=True)
class Element:
    """One element instance: a kind between DOF ``i`` and ``j`` (``j = -1`` is ground)."""

    kind: ElementKind
    between: tuple[str, str]
    i: int
    j: int
    params: tuple[str, ...]  # global parameter name per kind coefficient, in kind order


@dataclass
class Structure:
    """A lumped-mass model: DOFs, masses, elements, parameters and force inputs."""

    name: str
    dofs: list[str]
    mass: dict[str, float]
    elements: list[Element]
    parameters: dict[str, ParameterInfo]
    force_gains: dict[str, str | float] = field(default_factory=dict)
    spec: dict[str, Any] = field(default_factory=dict)
    #: ``[channels]``: how this system's files name and scale their channels
    channel_map: dict[str, str] = field(default_factory=dict)
    channel_units: dict[str, str] = field(default_factory=dict)

    # ---------------------------------------------------------------- construction
    @classmethod
    def from_file(cls, path: str | Path) -> "Structure":
        """Read a TOML or JSON spec file."""
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
        try:
            return cls.from_dict(data)
        except SpecError as exc:
            raise SpecError(f"{path}: {exc}") from None

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "Structure":
        """Build and validate from the spec's dict form (the JSON body over HTTP)."""
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

        mass_in = data.get("mass")
        if not isinstance(mass_in, Mapping):
            raise SpecError("'mass' must be a table {dof = kg}")
        mass: dict[str, float] = {}
        for d in dofs:
            if d not in mass_in:
                raise SpecError(f"mass.{d}: missing mass for DOF {d!r}")
            m = _number(mass_in[d], f"mass.{d}")
            if not m > 0:
                raise SpecError(f"mass.{d}: mass must be positive, got {m}")
            mass[d] = m
        for d in mass_in:
            if d not in index:
                raise SpecError(f"mass.{d}: {d!r} is not a DOF (dofs = {dofs})")

        param_in = data.get("parameters", {}) or {}
        if not isinstance(param_in, Mapping):
            raise SpecError("'parameters' must be a table of per-parameter settings")

        elements: list[Element] = []
        order: list[str] = []
        raw_elements = data.get("elements")
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
                    value = _number(pname, f"{where}.params.{c}")
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

        gains: dict[str, str | float] = {}
        forces_in = data.get("forces", {}) or {}
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
                gains[d] = _number(gain, f"forces.{d}.gain")

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
                scale=_opt_number(setting.get("scale"), f"{where}.scale"),
                fixed=_opt_number(setting.get("fixed"), f"{where}.fixed"),
                lower=_opt_number(setting.get("lower"), f"{where}.lower"),
                upper=_opt_number(setting.get("upper"), f"{where}.upper"),
                initial=_opt_number(setting.get("initial"), f"{where}.initial"),
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
        for pname in param_in:
            if pname not in parameters:
                raise SpecError(f"parameters.{pname}: not used by any element or force gain")
        try:
            spec = json.loads(json.dumps(dict(data)))
        except (TypeError, ValueError) as exc:
            raise SpecError(f"spec holds a value JSON cannot carry ({exc})") from None
        cmap, cunits = _channels(data.get("channels"), dofs)
        return cls(name, list(dofs), mass, elements, parameters, gains, spec, cmap, cunits)

    def read_options(self, channel_map: Mapping[str, str] | None = None,
                     units: Mapping[str, str] | None = None) -> dict[str, Any]:
        """Keyword arguments of :meth:`Recording.read` for this system's files: the spec's
        ``[channels]`` mapping and units, overridden by ``channel_map`` / ``units`` (the
        command line's ``--map``/``--unit``, an upload's query)."""
        return {"channel_map": {**self.channel_map, **(channel_map or {})} or None,
                "units": {**self.channel_units, **(units or {})} or None}

    # ---------------------------------------------------------------- parameters
    @property
    def free(self) -> list[str]:
        """Names of the identified parameters, in the order of the parameter vector."""
        return [p for p, info in self.parameters.items() if info.fixed is None]

    @property
    def n_dof(self) -> int:
        return len(self.dofs)

    @property
    def masses(self) -> np.ndarray:
        return np.array([self.mass[d] for d in self.dofs], dtype=float)

    def scales(self) -> dict[str, float | None]:
        return {p: self.parameters[p].scale for p in self.free}

    def full_values(self, theta: Any) -> dict[str, Any]:
        """Map a parameter vector (..., n_free) to {name: value}, adding fixed values."""
        out: dict[str, Any] = {}
        free = self.free
        for p, info in self.parameters.items():
            out[p] = info.fixed if info.fixed is not None else theta[..., free.index(p)]
        return out

    def as_dict(self, theta: Any) -> dict[str, float]:
        """A single parameter vector as {name: float} (free parameters only)."""
        theta = np.asarray(theta, dtype=float)
        return {p: float(theta[k]) for k, p in enumerate(self.free)}

    def vector(self, values: Mapping[str, float]) -> np.ndarray:
        """{name: value} -> parameter vector; every free parameter must be given."""
        missing = [p for p in self.free if p not in values]
        if missing:
            raise KeyError(f"missing values for parameters {missing}")
        return np.array([float(values[p]) for p in self.free])

    def parameter_units(self) -> dict[str, str]:
        """{parameter: SI unit} from the element kinds (a parameter shared by elements of
        different units lists each, joined by " or "; "" when no kind says)."""
        units: dict[str, list[str]] = {p: [] for p in self.parameters}
        for el in self.elements:
            for c, p in zip(el.kind.coefficients, el.params):
                u = el.kind.units.get(c, "") if hasattr(el.kind, "units") else ""
                if u and p in units and u not in units[p]:
                    units[p].append(u)
        return {p: " or ".join(u) for p, u in units.items() if not p.startswith("_fixed_")}

    def linear_parameters(self) -> list[str]:
        """Free parameters that enter the equations linearly wherever they appear."""
        lin = {p: True for p in self.free}
        for el in self.elements:
            for c, p in zip(el.kind.coefficients, el.params):
                if p in lin and c not in el.kind.linear:
                    lin[p] = False
        return [p for p, ok in lin.items() if ok]

    def physical_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper) per free parameter: the spec's ``lower``/``upper`` where given,
        else 0 below a coefficient a passive element needs non-negative (a damper's c, a
        spring's k: ``ElementKind.nonnegative``), else unbounded.  What SIVA may recommend."""
        nonneg = {p for el in self.elements
                  for c, p in zip(el.kind.coefficients, el.params)
                  if c in getattr(el.kind, "nonnegative", ())}
        lo, hi = [], []
        for p in self.free:
            info = self.parameters[p]
            lo.append(info.lower if info.lower is not None
                      else (0.0 if p in nonneg else -np.inf))
            hi.append(info.upper if info.upper is not None else np.inf)
        return np.array(lo, dtype=float), np.array(hi, dtype=float)

    # ---------------------------------------------------------------- force inputs
    def force_gain(self, dof: str) -> str | float:
        """Gain G of the measured force on ``dof`` (paper eq. 1: M a = -f + G F): a
        parameter name (identified, e.g. an unknown shaker calibration) or a number (1 when
        the spec says nothing).  The one place that knows the default."""
        return self.force_gains.get(dof, 1.0)

    def gain_values(self, values: Mapping[str, Any]) -> list[Any]:
        """Per DOF, the gain's value given ``full_values`` (arrays over the sets, torch or
        numpy, or plain numbers for fixed gains)."""
        out = []
        for d in self.dofs:
            g = self.force_gain(d)
            out.append(values[g] if isinstance(g, str) else g)
        return out

    def gains(self, theta: Any) -> np.ndarray:
        """(..., n_dof) numeric force gains for parameter sets ``theta`` (..., n_free)."""
        theta = np.asarray(theta, dtype=float)
        cols = self.gain_values(self.full_values(theta))
        return np.stack([np.broadcast_to(np.asarray(g, dtype=float), theta.shape[:-1])
                         for g in cols], axis=-1)

    # ---------------------------------------------------------------- physics
    def element_forces(self, theta: Any, q: Any, v: Any) -> list[Any]:
        """Force f of each element, broadcast over theta's and the states' leading axes."""
        values = self.full_values(theta)
        out = []
        for el in self.elements:
            d = q[..., el.i] if el.j < 0 else q[..., el.i] - q[..., el.j]
            dv = v[..., el.i] if el.j < 0 else v[..., el.i] - v[..., el.j]
            coeffs = {c: values[p] for c, p in zip(el.kind.coefficients, el.params)}
            out.append(el.kind.force(d, dv, **coeffs))
        return out

    def accelerations(self, theta: Any, q: Any, v: Any, f: Any | None = None) -> Any:
        """Model accelerations M^-1 (-sum f + G F) (paper eq. 1), batched.

        ``theta`` has shape (..., n_free) and ``q``, ``v``, ``f`` shape (..., n_dof); the
        leading axes broadcast, so one call evaluates many parameter sets on many samples.
        Works on numpy arrays and torch tensors alike.
        """
        values = self.full_values(theta)
        forces = self.element_forces(theta, q, v)
        cols: list[Any] = [0.0] * self.n_dof
        for el, fe in zip(self.elements, forces):
            cols[el.i] = cols[el.i] - fe
            if el.j >= 0:
                cols[el.j] = cols[el.j] + fe
        if f is not None:
            for k, g in enumerate(self.gain_values(values)):
                cols[k] = cols[k] + g * f[..., k]
        like = q[..., 0]
        stacked = []
        for k, d in enumerate(self.dofs):
            c = cols[k]
            stacked.append((c + like * 0) / self.mass[d])
        if type(q).__module__.startswith("torch"):
            import torch

            return torch.stack(torch.broadcast_tensors(*stacked), dim=-1)
        return np.stack(np.broadcast_arrays(*stacked), axis=-1)

    # ---------------------------------------------------------------- derived
    def linear_modes(self, theta: Any) -> dict[str, list[float]]:
        """Natural frequencies [Hz] and damping ratios of the linearised model about 0."""
        values = self.full_values(np.asarray(theta, dtype=float))
        n = self.n_dof
        K = np.zeros((n, n))
        C = np.zeros((n, n))
        eps = 1e-9
        for el in self.elements:
            coeffs = {c: float(values[p]) for c, p in zip(el.kind.coefficients, el.params)}
            kd = (el.kind.force(np.array(eps), np.array(0.0), **coeffs)
                  - el.kind.force(np.array(-eps), np.array(0.0), **coeffs)) / (2 * eps)
            cd = (el.kind.force(np.array(0.0), np.array(eps), **coeffs)
                  - el.kind.force(np.array(0.0), np.array(-eps), **coeffs)) / (2 * eps)
            for M, val in ((K, float(kd)), (C, float(cd))):
                M[el.i, el.i] += val
                if el.j >= 0:
                    M[el.j, el.j] += val
                    M[el.i, el.j] -= val
                    M[el.j, el.i] -= val
        Minv = np.diag(1.0 / self.masses)
        A = np.block([[np.zeros((n, n)), np.eye(n)], [-Minv @ K, -Minv @ C]])
        lam = np.linalg.eigvals(A)
        lam = lam[np.imag(lam) > 1e-12]
        lam = lam[np.argsort(np.abs(lam))]
        wn = np.abs(lam)
        return {"frequency_hz": [float(w / (2 * math.pi)) for w in wn],
                "damping_ratio": [float(-l.real / w) for l, w in zip(lam, wn)]}

    def describe(self) -> str:
        lines = [f"{self.name}: dofs {self.dofs}, masses {self.mass}"]
        for el in self.elements:
            lines.append(f"  {el.kind.name:16s} {el.between[0]}-{el.between[1]}: "
                         + ", ".join(f"{c}={p}" for c, p in zip(el.kind.coefficients, el.params)))
        return "\n".join(lines)


def _number(x: Any, where: str) -> float:
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        raise SpecError(f"{where}: must be a number, got {x!r}")
    x = float(x)
    if not math.isfinite(x):
        raise SpecError(f"{where}: must be finite, got {x}")
    return x


def _opt_number(x: Any, where: str) -> float | None:
    return None if x is None else _number(x, where)


def _channels(section: Any, dofs: list[str]) -> tuple[dict[str, str], dict[str, str]]:
    """The spec's ``[channels]`` table: ``map = {"Accel LO" = "acc_LO"}`` (stored channel
    name -> column name) and ``units = {acc_LO = "g"}`` (declared unit per column)."""
    from .formats import QUANTITIES, UNIT_FACTORS, split_unit, unit_factor

    if section is None:
        return {}, {}
    if not isinstance(section, Mapping):
        raise SpecError("'channels' must be a table with 'map' and/or 'units'")
    extra = [k for k in section if k not in ("map", "units")]
    if extra:
        raise SpecError(f"channels.{extra[0]}: unknown key (known: map, units)")
    cmap, units = section.get("map", {}) or {}, section.get("units", {}) or {}
    for key, table in (("map", cmap), ("units", units)):
        if not isinstance(table, Mapping) or not all(
                isinstance(k, str) and isinstance(v, str) for k, v in table.items()):
            raise SpecError(f"channels.{key}: must be a table of names to strings")

    def column_ok(col: str) -> bool:
        col = split_unit(col)[0]
        qty, _, dof = col.partition("_")
        return col == "time" or (qty in QUANTITIES and dof in dofs)

    for src, dst in cmap.items():
        if not column_ok(dst):
            raise SpecError(f"channels.map.{src}: {dst!r} is not a column of this model (time, "
                            f"or acc_/vel_/disp_/force_ + one of {dofs})")
    for col, unit in units.items():
        target = split_unit(cmap.get(col, col))[0]
        if not column_ok(target):
            raise SpecError(f"channels.units.{col}: not a column of this model")
        qty = "time" if target == "time" else target.partition("_")[0]
        if unit_factor(unit, qty) is None:
            raise SpecError(f"channels.units.{col}: {unit!r} is not a unit of {qty} (known: "
                            f"{', '.join(UNIT_FACTORS[qty])})")
    return dict(cmap), dict(units)
