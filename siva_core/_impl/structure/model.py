"""Structure: masses + elements from a model spec, assembled into M q'' = -sum f + G F(t).

The spec format is the one of CONTRACT.md (TOML file, same structure as JSON).  A
``Structure`` knows which parameters are identified (``free``), which are fixed, their
scale hints, and evaluates model accelerations for a whole batch of parameter sets at
once, with numpy or torch (so the same code serves training with autograd and simulation).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .modes import growth_rate, linear_modes
from .parts import Element, ParameterInfo, SpecError
from .spec import parse_spec, read_spec_file


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
        data = read_spec_file(path)
        try:
            return cls.from_dict(data)
        except SpecError as exc:
            raise SpecError(f"{path}: {exc}") from None

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "Structure":
        """Build and validate from the spec's dict form (the JSON body over HTTP)."""
        return cls(*parse_spec(data))

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
        return linear_modes(self.elements, values, self.masses)

    def linear_growth_rate(self, theta: Any) -> float:
        """Largest real part [1/s] of the linearised model's eigenvalues: > 0 diverges."""
        values = self.full_values(np.asarray(theta, dtype=float))
        return growth_rate(self.elements, values, self.masses)

    def describe(self) -> str:
        lines = [f"{self.name}: dofs {self.dofs}, masses {self.mass}"]
        for el in self.elements:
            lines.append(f"  {el.kind.name:16s} {el.between[0]}-{el.between[1]}: "
                         + ", ".join(f"{c}={p}" for c, p in zip(el.kind.coefficients, el.params)))
        return "\n".join(lines)
