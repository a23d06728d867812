"""`siva diagnose`: where the sim-to-real gap lies, which unmodelled effect causes it, and
how far it shrinks once that effect is added.

Method (docs/diagnosis.md has the full rationale and the measured results):

1. **Nominal fit.**  The model as given is fitted to the ``--train`` records by output
   error (``refine``: simulate each record from its force, pass the simulation through the
   same processing chain as the measurement, compare), started from an equation-error
   least-squares guess.  ``gap_before`` = output-error cost of that fit on the ``--val``
   records, which are never used to fit anything.
2. **Candidates.**  Every registered effect (``effects.EFFECTS``) at every location (each
   DOF to ground, each DOF pair) that the model does not already have.
3. **Screening** (cheap, train records only): a score test.  Adding an element with a
   small magnitude ``c`` changes the force on the structure by ``c g(t)``, ``g`` the
   element's unit force along the nominal trajectory, so to first order its effect on the
   output is the response of the nominal model to ``g`` applied as an extra external force.
   That sensitivity column, with the nominal parameters' Jacobian projected out (the
   nominal model re-tunes itself when an element is added), gives the Gauss-Newton estimate
   of ``c`` and the share of the remaining train residual the candidate explains.  A
   dissipative candidate whose estimate comes out negative (an energy source) scores 0.
4. **Fit** of the best few screened candidates by output error on the train records
   (nominal parameters warm-started at the nominal fit, the new magnitude multi-started at
   a few multiples of the screening estimate, the best start then refined jointly).
   ``gap_after`` on the val records, ``closure = 1 - gap_after / gap_before``.
5. **Verdict** (a rule that guards against over-fitting, constants in ``DiagnoseSettings``):
   the best candidate by validation closure is named only if (a) the nominal gap is above
   the estimated noise floor, (b) its closure is at least ``closure_min``, (c) it leaves
   clearly less gap than the best candidate of a *different* kind (``separation``), and
   (d) no validation record gets worse with it (``record_tolerance``).  Otherwise null.
6. **Where**: the nominal model's validation residual split per DOF, per record (against
   amplitude), early/middle/late in each decay (by share of response energy) and by
   frequency band (around the nominal linear modes), with a one-paragraph explanation.
"""
from __future__ import annotations

import argparse
import base64
import copy
import io
import json
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np
from scipy import signal

from .effects import EFFECTS, Amplitudes, Effect
from .processing import Processing, States
from .recording import Recording
from .structure import GROUND, Structure

Progress = Callable[[str], None]


# ============================================================================ settings
@dataclass
class DiagnoseSettings:
    """Knobs of the diagnosis; the defaults are the documented method.

    top_k: candidates fitted by output error after screening (the rest are only screened).
    max_per_kind: at most this many locations of one kind among them, so that a rival of a
        different kind is always fitted (the verdict compares against it).
    nominal_nfev / fit_nfev: cost-evaluation budgets of the nominal and candidate fits.
    closure_min: least validation closure for a verdict (share of the gap removed).
    separation: the verdict's gap_after must be at most this fraction of the best
        other-kind candidate's gap_after.
    record_tolerance: no validation record may get worse by more than this fraction.
    noise_factor: the nominal validation gap must exceed this multiple of the estimated
        noise floor, else the nominal model already fits to the noise level (null).
    gap_min: ... and it must exceed this normalised output error (0.005 = 7 % RMS error):
        below it the nominal model fits as well as parameter extrapolation from the train
        amplitudes allows, and any flexible element "explains" that residue.
    ee_strong: a candidate explaining at least this share of the equation-error residual
        is fitted too, whatever its output-error score (strong effects such as a clearance
        can keep the nominal output-error fit so far off that its linearisation misleads).
    effects: names of the effects to try (default: all registered).
    nominal_start: initial values of the nominal parameters (skips the least-squares start).
    """

    top_k: int = 3
    max_per_kind: int = 2
    nominal_nfev: int = 40
    fit_nfev: int = 40
    closure_min: float = 0.5
    separation: float = 0.75
    record_tolerance: float = 0.05
    noise_factor: float = 2.0
    gap_min: float = 0.005
    ee_strong: float = 0.25
    effects: Sequence[str] | None = None
    nominal_start: Mapping[str, float] | None = None


# ============================================================================ results
@dataclass
class Location:
    """Where an element goes: DOF indices (j = -1 for ground) and names."""

    i: int
    j: int
    between: tuple[str, str]


@dataclass
class Candidate:
    """One effect at one location: its screening score and, if fitted, its gaps."""

    effect: Effect
    loc: Location
    shape: dict[str, float]
    score: float = 0.0            # share of the nominal train residual explained (linear)
    estimate: float = 0.0         # Gauss-Newton estimate of the magnitude
    admissible: bool = True       # estimate has the physical sign
    fitted: bool = False
    theta: np.ndarray | None = None
    structure: Structure | None = None
    coefficients: dict[str, float] = field(default_factory=dict)
    parameters: dict[str, float] = field(default_factory=dict)
    train_cost: float = math.nan
    gap_before: float = math.nan
    gap_after: float = math.nan
    closure: float = math.nan
    per_record: list[dict[str, Any]] = field(default_factory=list)
    fit_time_s: float = 0.0
    note: str = ""
    ee_score: float = 0.0         # share of the equation-error residual explained
    ee_start: tuple[dict[str, float], dict[str, float]] | None = None  # joint equation-
    # error solution (nominal parameters, new coefficients): a fit start
    ee_shape: dict[str, float] = field(default_factory=dict)

    @property
    def key(self) -> tuple[str, tuple[str, str]]:
        return (self.effect.kind, self.loc.between)

    def label(self) -> str:
        return f"{self.effect.kind} {self.loc.between[0]}-{self.loc.between[1]}"

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "kind": self.effect.kind, "between": list(self.loc.between),
            "gap_before": _num(self.gap_before), "gap_after": _num(self.gap_after),
            "closure": _num(self.closure), "effect": self.effect.name,
            "family": self.effect.family, "coefficients": _clean(self.coefficients),
            "parameters": _clean(self.parameters), "train_cost": _num(self.train_cost),
            "screen_score": _num(self.score), "per_record": self.per_record,
            "fit_time_s": round(self.fit_time_s, 3)}
        if self.note:
            out["note"] = self.note
        return out


@dataclass
class Diagnosis:
    """Everything a diagnosis produced; ``to_json`` gives the CONTRACT shape (extended)."""

    verdict: Candidate | None
    ranking: list[Candidate]
    screened: list[Candidate]
    where: dict[str, Any]
    nominal: dict[str, Any]
    rule: dict[str, Any]
    processing: Processing
    timing: dict[str, float]
    structure: Structure
    theta_nominal: np.ndarray
    train: list[Recording]
    val: list[Recording]
    plots: dict[str, Any] = field(default_factory=dict, repr=False)  # HTML report data

    def to_json(self) -> dict[str, Any]:
        v = None
        if self.verdict is not None:
            c = self.verdict
            v = {"kind": c.effect.kind, "between": list(c.loc.between), "effect": c.effect.name,
                 "family": c.effect.family, "closure": _num(c.closure),
                 "coefficients": _clean(c.coefficients),
                 "explanation": c.effect.describe(c.coefficients)}
        return {
            "verdict": v,
            "ranking": [c.to_json() for c in self.ranking],
            "where": self.where,
            "nominal": self.nominal,
            "rule": self.rule,
            "screening": [{"kind": c.effect.kind, "between": list(c.loc.between),
                           "shape": _clean(c.shape), "score": _num(c.score),
                           "estimate": _num(c.estimate), "admissible": c.admissible,
                           "ee_score": _num(c.ee_score),
                           "fitted": c.fitted} for c in self.screened],
            "processing": self.processing.describe() if hasattr(self.processing, "describe")
            else repr(self.processing),
            "records": {"train": [r.name for r in self.train], "val": [r.name for r in self.val]},
            "timing_s": {k: round(v, 3) for k, v in self.timing.items()},
        }


def _num(x: float) -> float | None:
    return None if x is None or not np.isfinite(x) else float(x)


def _clean(d: Mapping[str, float]) -> dict[str, float | None]:
    return {k: _num(v) for k, v in d.items()}


# ============================================================================ plumbing
class _Outputs:
    """Simulated outputs of one structure on a set of records, through the chain, in the
    normalisation of ``refine.output_error`` (each DOF of each record / its measured RMS).

    Wraps ``refine.OutputErrorProblem`` (same records, force gating, substeps, targets) so
    that costs here are exactly those ``refine`` minimises, and adds what the diagnosis
    needs beyond a cost: per-record/per-DOF blocks, the processed signals themselves, and
    simulation with an extra external force (the screening sensitivities).
    """

    def __init__(self, structure: Structure, records: Sequence[Recording], proc: Processing,
                 theta_ref: np.ndarray) -> None:
        from .refine import OutputErrorProblem

        self.structure = structure
        self.proc = proc
        self.prob = OutputErrorProblem.build(structure, list(records), proc,
                                             theta_ref=np.atleast_2d(theta_ref))
        self.n_groups = self.prob.n_groups

    @property
    def records(self) -> list[Any]:
        return self.prob.records

    def residuals(self, thetas: np.ndarray) -> np.ndarray:
        return self.prob.residuals(np.atleast_2d(thetas))

    def blocks(self, res: np.ndarray) -> np.ndarray:
        """(n_records, n_dof) NMSE per record and DOF from one residual vector."""
        out = np.empty((len(self.records), self.structure.n_dof))
        col = 0
        for k, r in enumerate(self.records):
            size = r.target.size
            blk = res[col:col + size].reshape(r.target.shape)
            out[k] = np.sum(blk ** 2, axis=0) * self.n_groups
            col += size
        return out

    def signals(self, theta: np.ndarray, k: int, force: np.ndarray | None = None
                ) -> tuple[States | None, Any]:
        """Record ``k`` simulated at one theta (optionally driven by another force) and
        processed the way ``refine`` does it (same interpolation, chain and substeps).
        Returns (processed states or None if diverged, the raw full-rate Simulation)."""
        from .simulate import simulate

        r = self.records[k]
        f = r.force if force is None else force
        sim = simulate(self.structure, np.asarray(theta, float), r.rec.time, r.q0, r.v0, f,
                       substeps=r.substeps, backend=self.prob.backend, interp=self.prob.interp)
        if not (np.all(np.isfinite(sim.q)) and np.all(np.isfinite(sim.v))
                and np.all(np.isfinite(sim.a))):
            return None, sim
        chain = self.prob.chain
        return chain.apply_simulated(r.rec, self.structure.dofs, sim.q, sim.v, sim.a), sim

    def output(self, st: States, k: int) -> np.ndarray:
        """Normalised compared quantities (T', n_dof) of processed simulated states."""
        r = self.records[k]
        sim = np.stack([getattr(st, _ATTR[q])[:, d] for d, q in enumerate(r.quantities)], -1)
        return sim * self.weight(k)

    def weight(self, k: int) -> np.ndarray:
        r = self.records[k]
        return 1.0 / (r.rms * math.sqrt(r.target.shape[0] * self.n_groups))


_ATTR = {"disp": "q", "vel": "v", "acc": "a"}


def _say(progress: Progress | None, msg: str) -> None:
    if progress is not None:
        progress(msg)


def _locations(structure: Structure) -> list[Location]:
    """Every DOF to ground, then every DOF pair (in DOF order)."""
    n = structure.n_dof
    out = [Location(i, -1, (structure.dofs[i], GROUND)) for i in range(n)]
    out += [Location(i, j, (structure.dofs[i], structure.dofs[j]))
            for i in range(n) for j in range(i + 1, n)]
    return out


def candidate_sites(structure: Structure, effects: Sequence[Effect]
                    ) -> list[tuple[Effect, Location]]:
    """Every effect at every location, minus the kinds the model already has there."""
    return [(eff, loc) for loc in _locations(structure) for eff in effects
            if not _has_element(structure, eff.kind, loc)]


def _has_element(structure: Structure, kind: str, loc: Location) -> bool:
    for el in structure.elements:
        if el.kind.name != kind:
            continue
        if {el.i, el.j} == {loc.i, loc.j}:
            return True
    return False


def _relative(q: np.ndarray, v: np.ndarray, loc: Location) -> tuple[np.ndarray, np.ndarray]:
    d = q[..., loc.i] - (q[..., loc.j] if loc.j >= 0 else 0.0)
    dv = v[..., loc.i] - (v[..., loc.j] if loc.j >= 0 else 0.0)
    return d, dv


def _gain_values(structure: Structure, theta: np.ndarray) -> np.ndarray:
    return structure.gains(theta)


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


# ============================================================================ nominal fit
def _plausible(structure: Structure, theta: np.ndarray, fs: float) -> bool:
    """A start worth simulating: finite, linear modes below 0.4 x the sampling rate and
    not unstable.  Least squares on badly derived states can return stiffnesses whose
    modes the records cannot even resolve; such a start would only force huge substeps."""
    if not np.all(np.isfinite(theta)):
        return False
    try:
        modes = structure.linear_modes(theta)
    except Exception:  # noqa: BLE001 - a start whose linearisation fails is not plausible
        return False
    return (all(f < 0.4 * fs for f in modes["frequency_hz"])
            and all(z > -1e-3 for z in modes["damping_ratio"]))


@dataclass
class NominalFit:
    """The nominal output-error fit and the equation-error fit it started from (kept for
    the equation-error screen: its states, chain and parameters)."""

    theta: np.ndarray
    train_cost: float
    start: str
    ls_theta: np.ndarray | None = None
    ls_chain: Processing | None = None


def fit_nominal(structure: Structure, train: Sequence[Recording], proc: Processing,
                settings: DiagnoseSettings, progress: Progress | None = None) -> NominalFit:
    """Output-error fit of the model as given on the train records.

    Start: the user's ``nominal_start``, else equation-error least squares on the train
    states of the chosen chain and, when different, of the data-driven ``Processing.auto``
    chain (least squares on states integrated without high-pass drifts is useless); each
    plausible start is costed alone (a batch would take the substeps of the stiffest) and
    the best is refined (``refine``, growing horizons).
    """
    from .baselines import least_squares
    from .refine import output_error, refine

    fs = min(r.fs for r in train)
    starts: list[tuple[str, np.ndarray, Processing | None]] = []
    if settings.nominal_start is not None:
        starts.append(("given", structure.vector(settings.nominal_start), None))
    chains: list[tuple[str, Processing]] = [("least squares", proc)]
    try:
        auto = Processing.auto(list(train), structure.dofs)
        if auto != proc:
            chains.append(("least squares (auto chain)", auto))
    except Exception:  # noqa: BLE001 - an optional second start
        pass
    for label, chain in chains:
        try:
            fit = least_squares(structure, [chain.apply(r, structure.dofs) for r in train])
            th = structure.vector(fit)
        except Exception as exc:  # noqa: BLE001 - try the next start
            _say(progress, f"nominal start {label} failed: {exc}")
            continue
        if _plausible(structure, th, fs):
            starts.append((label, th, chain))
        else:
            _say(progress, f"nominal start {label} rejected (implausible: "
                           f"{structure.as_dict(th)})")
    if not starts:
        raise ValueError("diagnose: no usable start for the nominal fit (least squares gave "
                         "nothing plausible); pass initial values")
    costs = []
    for _, th, _ in starts:
        try:
            costs.append(float(output_error(structure, th[None], list(train), proc)[0]))
        except Exception:  # noqa: BLE001 - a start that cannot be simulated is skipped
            costs.append(math.inf)
    best = int(np.argmin(costs))
    if not np.isfinite(costs[best]):
        raise ValueError("diagnose: the nominal model diverges from every start")
    label, th0, _ = starts[best]
    ls = [(c, th, ch) for c, (_, th, ch) in zip(costs, starts) if ch is not None]
    ls_cost, ls_theta, ls_chain = min(ls, key=lambda x: x[0]) if ls else (0, None, None)
    _say(progress, f"nominal start: {label} (train cost {costs[best]:.4g})")
    res = refine(structure, th0, list(train), proc, max_nfev=settings.nominal_nfev)
    c = float(output_error(structure, res.theta[None], list(train), proc)[0])
    if c <= costs[best]:
        return NominalFit(res.theta, c, label, ls_theta, ls_chain)
    return NominalFit(th0, costs[best], label, ls_theta, ls_chain)


# ============================================================================ screening
@dataclass
class _Nominal:
    """The nominal fit as the screening and the candidate fits see it: raw (full-rate)
    simulations of the train records, amplitudes per location, a force scale."""

    theta: np.ndarray
    outs: _Outputs
    raw: list[Any]
    amplitudes: dict[tuple[str, str], Amplitudes]
    force_scale: float


def _nominal_context(structure: Structure, theta: np.ndarray, train: Sequence[Recording],
                     proc: Processing) -> tuple[_Nominal, list[np.ndarray]]:
    outs = _Outputs(structure, train, proc, theta)
    raw, base = [], []
    for k in range(len(outs.records)):
        st, sim = outs.signals(theta, k)
        if st is None:
            raise ValueError("diagnose: the nominal fit diverges on a train record")
        raw.append(sim)
        base.append(outs.output(st, k))
    amps = {}
    for loc in _locations(structure):
        ds, vs = zip(*(_relative(s.q, s.v, loc) for s in raw))
        d, v = np.concatenate(ds), np.concatenate(vs)
        amps[loc.between] = Amplitudes(float(np.max(np.abs(d))), float(np.max(np.abs(v))),
                                       float(np.sqrt(np.mean(d ** 2))),
                                       float(np.sqrt(np.mean(v ** 2))))
    force_scale = float(max(np.sqrt(np.mean((structure.masses * s.a) ** 2)) for s in raw))
    return _Nominal(theta, outs, raw, amps, force_scale), base


def screen(structure: Structure, theta: np.ndarray, train: Sequence[Recording],
           proc: Processing, effects: Sequence[Effect],
           progress: Progress | None = None) -> tuple[list[Candidate], _Nominal]:
    """Score test of every candidate on the train records (see the module doc, step 3).

    Returns the candidates (admissible first, best score first; one per kind and location,
    its best shape) and the nominal context.
    """
    nom, base_out = _nominal_context(structure, theta, train, proc)
    outs, raw = nom.outs, nom.raw
    r = outs.residuals(theta)[0]
    cost0 = float(r @ r)
    # nominal Jacobian: projected out, since the nominal model re-tunes itself when an
    # element is added and only what it cannot absorb counts for the candidate
    n = theta.size
    step = 1e-5 * np.where(theta != 0, np.abs(theta), 1.0)
    thetas = np.repeat(theta[None], n + 1, axis=0)
    thetas[1:] += np.diag(step)
    R = outs.residuals(thetas)
    J = ((R[1:] - R[0]) / step[:, None]).T
    J[~np.isfinite(J)] = 0.0
    Jn = J / np.maximum(np.linalg.norm(J, axis=0), 1e-300)
    U, s, _ = np.linalg.svd(Jn, full_matrices=False)
    U = U[:, s > 1e-8 * s.max()] if s.size and s.max() > 0 else U[:, :0]
    r_perp = r - U @ (U.T @ r)
    gains = _gain_values(structure, theta)
    masses = structure.masses

    cands: list[Candidate] = []
    for eff, loc in candidate_sites(structure, effects):
        amp = nom.amplitudes[loc.between]
        for shape in eff.shape_grid(amp):
            c = Candidate(eff, loc, dict(shape))
            cands.append(c)
            twin = _representable(structure, theta, raw, eff, loc, shape)
            if twin:
                c.admissible = False
                c.note = f"the model's {twin} at this location already represents it"
                continue
            cols = []
            for k, rr in enumerate(outs.records):
                sim = raw[k]
                d, dv = _relative(sim.q, sim.v, loc)
                g = eff.unit_force(d, dv, shape)
                # a small force relative to what moves DOF i along the nominal run
                fref = float(np.sqrt(np.mean((masses[loc.i] * sim.a[:, loc.i]) ** 2)))
                grms = float(np.sqrt(np.mean(g ** 2)))
                if grms <= 0 or fref <= 0:
                    cols.append(np.zeros(rr.target.size))
                    continue
                eps = 1e-4 * fref / grms
                F = np.zeros((len(rr.rec), structure.n_dof)) if rr.force is None \
                    else np.array(rr.force, dtype=float)
                F[:, loc.i] -= eps * g / (gains[loc.i] if gains[loc.i] != 0 else 1.0)
                if loc.j >= 0:
                    F[:, loc.j] += eps * g / (gains[loc.j] if gains[loc.j] != 0 else 1.0)
                st, _ = outs.signals(theta, k, force=F)
                if st is None:
                    break
                cols.append(((outs.output(st, k) - base_out[k]) / eps).ravel())
            if len(cols) < len(outs.records):
                c.admissible, c.note = False, "sensitivity run diverged"
                continue
            j = np.concatenate(cols)
            j_perp = j - U @ (U.T @ j)
            jj = float(j_perp @ j_perp)
            if jj <= 0 or cost0 <= 0:
                c.admissible, c.note = False, "no effect on the output"
                continue
            jr = float(j_perp @ r_perp)
            c.estimate = -jr / jj
            c.score = (jr * jr / jj) / cost0
            if eff.magnitude in eff.positive and c.estimate < 0:
                c.admissible = False
                c.note = "the data ask for a negative (energy-supplying) coefficient"
    cands.sort(key=lambda c: (c.admissible, c.score), reverse=True)
    seen: set[tuple[str, tuple[str, str]]] = set()
    unique = []
    for c in cands:
        if c.key not in seen:
            seen.add(c.key)
            unique.append(c)
    _say(progress, "screening: " + ", ".join(f"{c.label()} {c.score:.3f}"
                                               for c in unique[:6] if c.admissible))
    return unique, nom


def ee_screen(structure: Structure, nominal: NominalFit, train: Sequence[Recording],
              cands: Sequence[Candidate]) -> None:
    """Equation-error score of every candidate (in place): the same projection as the
    output-error score test, on M a = -sum f + F over the processed train states, from the
    nominal least-squares fit.  No simulation, so it is cheap and immune to the phase drift
    that can trap an output-error fit when the effect is strong; but processed states are
    biased by the chain, so on its own it ranks chain artefacts too (it only adds strong
    candidates to the fitted set, see ``DiagnoseSettings.ee_strong``).
    The joint Gauss-Newton solution (nominal parameters + magnitude) is kept as a fit start.
    """
    if nominal.ls_theta is None or nominal.ls_chain is None:
        return
    states = [nominal.ls_chain.apply(r, structure.dofs) for r in train]
    q = np.concatenate([st.q for st in states])
    v = np.concatenate([st.v for st in states])
    a = np.concatenate([st.a for st in states])
    f = np.concatenate([st.f for st in states])
    th = np.asarray(nominal.ls_theta, float)
    w = 1.0 / np.maximum(np.sqrt(np.mean(a ** 2, axis=0)), 1e-300)  # each DOF counts alike
    acc0 = structure.accelerations(th, q, v, f)
    r = ((a - acc0) * w).ravel()
    n = th.size
    cols = []
    for p in range(n):
        h = 1e-6 * (abs(th[p]) if th[p] != 0 else 1.0)
        tp = th.copy()
        tp[p] += h
        cols.append(((structure.accelerations(tp, q, v, f) - acc0) * w).ravel() / h)
    J = np.stack(cols, axis=1)
    norms = np.maximum(np.linalg.norm(J, axis=0), 1e-300)
    U, sv, _ = np.linalg.svd(J / norms, full_matrices=False)
    U = U[:, sv > 1e-8 * sv.max()] if sv.size and sv.max() > 0 else U[:, :0]
    r_perp = r - U @ (U.T @ r)
    rr = float(r @ r)
    masses = structure.masses
    for c in cands:
        eff, loc = c.effect, c.loc
        d, dv = _relative(q, v, loc)
        amp = Amplitudes(float(np.max(np.abs(d))), float(np.max(np.abs(dv))),
                         float(np.sqrt(np.mean(d ** 2))), float(np.sqrt(np.mean(dv ** 2))))
        for shape in eff.shape_grid(amp):
            g = eff.unit_force(d, dv, shape)
            col = np.zeros_like(a)
            col[:, loc.i] -= g / masses[loc.i]
            if loc.j >= 0:
                col[:, loc.j] += g / masses[loc.j]
            j = (col * w).ravel()
            j_perp = j - U @ (U.T @ j)
            jj = float(j_perp @ j_perp)
            if jj <= 0 or rr <= 0:
                continue
            jr = float(j_perp @ r_perp)
            est = jr / jj
            if eff.magnitude in eff.positive and est < 0:
                continue
            score = jr * jr / jj / rr
            if score <= c.ee_score:
                continue
            A = np.column_stack([J / norms, j / np.linalg.norm(j)])
            sol, *_ = np.linalg.lstsq(A, r, rcond=None)
            delta = sol[:n] / norms
            mag = float(sol[n] / np.linalg.norm(j))
            if eff.magnitude in eff.positive and mag < 0:
                continue
            c.ee_score = score
            c.ee_shape = dict(shape)
            c.ee_start = (structure.as_dict(th + delta), {**shape, eff.magnitude: mag})


#: R^2 above which a candidate's force is "already in the model" (see _representable)
REDUNDANT_R2 = 0.99


def _representable(structure: Structure, theta: np.ndarray, raw: Sequence[Any], eff: Effect,
                   loc: Location, shape: Mapping[str, float]) -> str:
    """Names of the model's elements at ``loc`` whose coefficient sensitivities span the
    candidate's force along the nominal run (R^2 >= REDUNDANT_R2), else "".

    Skipping what the model already has must also skip near-equivalents: a power-law
    spring with beta ~ 2 *is* a cubic spring, and fitting one on top only wastes time (and
    its linearised score can look high, since beta enters nonlinearly)."""
    here = [el for el in structure.elements if {el.i, el.j} == {loc.i, loc.j}]
    if not here:
        return ""
    values = structure.full_values(np.asarray(theta, float))
    cols, g_all = [], []
    for sim in raw:
        d, dv = _relative(sim.q, sim.v, loc)
        sign = 1.0 if not here or here[0].i == loc.i else -1.0
        g_all.append(eff.unit_force(d, dv, dict(shape)))
        rec_cols = []
        for el in here:
            s_el = 1.0 if el.i == loc.i else -1.0  # element orientation vs the candidate's
            coeffs = {c: float(values[p]) for c, p in zip(el.kind.coefficients, el.params)}
            for cname, p in zip(el.kind.coefficients, el.params):
                if structure.parameters[p].fixed is not None:
                    continue
                h = 1e-6 * (abs(coeffs[cname]) or 1.0)
                up = dict(coeffs, **{cname: coeffs[cname] + h})
                f0 = np.asarray(el.kind.force(s_el * d, s_el * dv, **coeffs), float)
                f1 = np.asarray(el.kind.force(s_el * d, s_el * dv, **up), float)
                rec_cols.append(sign * s_el * (f1 - f0) / h)
        cols.append(rec_cols)
    if not cols or not cols[0]:
        return ""
    A = np.column_stack([np.concatenate([rc[k] for rc in cols]) for k in range(len(cols[0]))])
    g = np.concatenate(g_all)
    gg = float(g @ g)
    if gg <= 0:
        return ""
    A = A / np.maximum(np.linalg.norm(A, axis=0), 1e-300)
    sol, *_ = np.linalg.lstsq(A, g, rcond=None)
    r2 = 1.0 - float(np.sum((g - A @ sol) ** 2)) / gg
    return ", ".join(sorted({el.kind.name for el in here})) if r2 >= REDUNDANT_R2 else ""


def _pick(cands: Sequence[Candidate], settings: DiagnoseSettings) -> list[Candidate]:
    """The top_k admissible candidates, at most max_per_kind of a kind, and always at least
    one of a second kind (the verdict needs a rival to compare with)."""
    chosen: list[Candidate] = []
    per_kind: dict[str, int] = {}
    for c in cands:
        if not c.admissible or c.score <= 0:
            continue
        if len(chosen) >= settings.top_k:
            break
        if per_kind.get(c.effect.kind, 0) >= settings.max_per_kind:
            continue
        chosen.append(c)
        per_kind[c.effect.kind] = per_kind.get(c.effect.kind, 0) + 1
    if len(per_kind) == 1:
        for c in cands:
            if c.admissible and c.score > 0 and c.effect.kind not in per_kind:
                chosen.append(c)
                break
    strong = max(cands, key=lambda c: c.ee_score, default=None)
    if strong is not None and strong.ee_score >= settings.ee_strong and strong not in chosen:
        chosen.append(strong)
    return chosen


# ============================================================================ candidate fit
def fit_candidate(c: Candidate, structure: Structure, theta_nom: np.ndarray,
                  train: Sequence[Recording], proc: Processing, amp: Amplitudes,
                  settings: DiagnoseSettings, force_scale: float) -> None:
    """Fit nominal + candidate by output error on the train records (in place).

    Starts: the nominal fit with the new magnitude at a few multiples of the score test's
    estimate (its best shape), and the joint equation-error solution when there is one;
    each start is costed, the best is refined (growing horizons: a new element shifts the
    phase late in long records, where the landscape has local minima)."""
    from .refine import output_error, refine

    t0 = time.perf_counter()
    eff = c.effect
    floor = eff.typical_magnitude(amp, c.shape, force_scale)
    ref_mag = c.estimate if c.estimate != 0 else \
        (c.ee_start[1][eff.magnitude] if c.ee_start else floor)
    scales = {**{k: max(abs(v), 1e-12) for k, v in (c.shape or c.ee_shape).items()},
              eff.magnitude: max(abs(ref_mag), floor * 1e-3, 1e-300)}
    aug, names = augmented(structure, eff, c.loc, scales)
    groups: list[np.ndarray] = []
    if c.admissible and c.estimate != 0:
        nominal_values = structure.as_dict(theta_nom)
        batch = []
        for m in eff.starts(c.estimate, floor):
            vals = dict(nominal_values)
            vals.update({names[k]: v for k, v in c.shape.items()})
            vals[names[eff.magnitude]] = m
            batch.append(aug.vector(vals))
        groups.append(np.stack(batch))
    if c.ee_start is not None:
        nominal_ee, coeffs_ee = c.ee_start
        th_ee = aug.vector({**nominal_ee, **{names[k]: v for k, v in coeffs_ee.items()}})
        if _plausible(aug, th_ee, min(r.fs for r in train)):
            groups.append(th_ee[None])
    if not groups:
        raise ValueError("no admissible start (negative magnitude for a signed effect)")
    best_cost, th0 = math.inf, None
    for batch in groups:  # separately: a batch takes the substeps of its stiffest set
        try:
            costs = output_error(aug, batch, list(train), proc)
        except Exception:  # noqa: BLE001 - a start that cannot be simulated is skipped
            continue
        k = int(np.argmin(costs))
        if costs[k] < best_cost:
            best_cost, th0 = float(costs[k]), batch[k]
    if th0 is None:
        raise ValueError("every start diverges")
    res = refine(aug, th0, list(train), proc, max_nfev=settings.fit_nfev)
    c_ref = float(output_error(aug, res.theta[None], list(train), proc)[0])
    theta, cost = (res.theta, c_ref) if c_ref <= best_cost else (th0, best_cost)
    c.structure, c.theta = aug, theta
    vals = aug.as_dict(theta)
    c.coefficients = {k: vals[p] for k, p in names.items()}
    c.parameters = {p: vals[p] for p in structure.free}
    c.train_cost = cost
    c.fitted = True
    c.fit_time_s = time.perf_counter() - t0


# ============================================================================ where
def _energy_windows(y: np.ndarray) -> list[slice]:
    """Early / middle / late of a decay: where the measured response has delivered 50 %,
    then 90 %, of its energy (amplitude-based, so it means the same on every record)."""
    e = np.cumsum(np.sum(y ** 2, axis=1))
    if e[-1] <= 0:
        n = len(y)
        return [slice(0, n // 3), slice(n // 3, 2 * n // 3), slice(2 * n // 3, n)]
    i50 = int(np.searchsorted(e, 0.5 * e[-1])) + 1
    i90 = max(i50 + 1, int(np.searchsorted(e, 0.9 * e[-1])) + 1)
    return [slice(0, i50), slice(i50, i90), slice(i90, len(y))]


def _bands(freqs: Sequence[float], nyq: float) -> list[tuple[str, float, float]]:
    """Frequency bands around the nominal linear modes: below the first, one per mode
    (edges at geometric midpoints), and above the last (harmonics)."""
    fs_ = sorted(f for f in freqs if 0 < f < nyq)
    if not fs_:
        return [("all", 0.0, nyq)]
    edges = [fs_[0] / math.sqrt(2)]
    for a, b in zip(fs_[:-1], fs_[1:]):
        edges.append(math.sqrt(a * b))
    edges.append(min(nyq, fs_[-1] * math.sqrt(2)))
    out = [(f"below mode 1 (< {edges[0]:.3g} Hz)", 0.0, edges[0])]
    for m, f in enumerate(fs_):
        out.append((f"mode {m + 1} ({f:.3g} Hz: {edges[m]:.3g}-{edges[m + 1]:.3g} Hz)",
                    edges[m], edges[m + 1]))
    if edges[-1] < nyq:
        out.append((f"above (harmonics, > {edges[-1]:.3g} Hz)", edges[-1], nyq))
    return out


def where_analysis(structure: Structure, theta_nom: np.ndarray, records: Sequence[Recording],
                   roles: Sequence[str], proc: Processing,
                   best: Candidate | None) -> tuple[dict[str, Any], dict[str, Any]]:
    """Split the nominal output-error residual per DOF, record, decay phase and band.

    Returns (where-json, plot data for the HTML report).
    """
    outs = _Outputs(structure, records, proc, theta_nom)
    alt = _Outputs(best.structure, records, proc, best.theta) if best is not None and \
        best.structure is not None else None
    dofs = structure.dofs
    modes = structure.linear_modes(theta_nom)["frequency_hz"]
    per_record, plots = [], []
    dof_num = np.zeros(len(dofs))
    dof_den = np.zeros(len(dofs))
    win_err = np.zeros(3)
    win_sig = np.zeros(3)
    band_acc: dict[str, list[float]] = {}
    noise_nmse = []
    for k, (r, role) in enumerate(zip(outs.records, roles)):
        st, _ = outs.signals(theta_nom, k)
        y = r.target / r.rms  # per-DOF normalised measurement
        sim = None if st is None else np.stack(
            [getattr(st, _ATTR[q])[:, d] for d, q in enumerate(r.quantities)], -1) / r.rms
        aug = None
        if alt is not None:
            sa, _ = alt.signals(best.theta, k)
            if sa is not None:
                ra = alt.records[k]
                aug = np.stack([getattr(sa, _ATTR[q])[:, d]
                                for d, q in enumerate(ra.quantities)], -1) / ra.rms
        t = _kept_time(proc, r.rec, structure.dofs, len(y))
        fs = 1.0 / (t[1] - t[0]) if len(t) > 1 else 1.0
        noise_nmse.append(_noise_nmse(y, fs, _passband(proc, fs)))
        peak_force = float(np.max(np.abs(r.force))) if r.force is not None else 0.0
        entry: dict[str, Any] = {"record": r.rec.name, "role": role,
                                 "peak_force": peak_force,
                                 "response_rms": {d: float(x) for d, x in zip(dofs, r.rms)}}
        if sim is None:
            entry["gap"] = None
            per_record.append(entry)
            continue
        e = sim - y
        entry["gap"] = float(np.mean(np.mean(e ** 2, axis=0)))
        entry["gap_per_dof"] = {d: float(x) for d, x in zip(dofs, np.mean(e ** 2, axis=0))}
        if aug is not None:
            entry["gap_after"] = float(np.mean(np.mean((aug - y) ** 2, axis=0)))
        per_record.append(entry)
        plots.append({"record": r.rec.name, "role": role, "t": t, "y": y * r.rms,
                      "nominal": sim * r.rms, "augmented": None if aug is None else aug * r.rms,
                      "quantities": r.quantities, "fs": fs})
        if role != "val":
            continue
        dof_num += np.sum(e ** 2, axis=0) / len(e)
        dof_den += 1
        for w, sl in enumerate(_energy_windows(y)):
            win_err[w] += float(np.sum(e[sl] ** 2))
            win_sig[w] += float(np.sum(y[sl] ** 2))
        f, Pe = signal.welch(e, fs=fs, axis=0, nperseg=min(len(e), 1024))
        _, Py = signal.welch(y, fs=fs, axis=0, nperseg=min(len(y), 1024))
        for name, lo, hi in _bands(modes, fs / 2):
            m = (f >= lo) & (f < hi)
            acc = band_acc.setdefault(name, [0.0, 0.0])
            acc[0] += float(np.sum(Pe[m]))
            acc[1] += float(np.sum(Py[m]))
    val_entries = [e for e in per_record if e["role"] == "val" and e.get("gap") is not None]
    per_dof = {d: float(x) for d, x in zip(dofs, dof_num / np.maximum(dof_den, 1))}
    windows = {name: (float(win_err[w] / win_sig[w]) if win_sig[w] > 0 else None)
               for w, name in enumerate(("early", "middle", "late"))}
    total_e = sum(v[0] for v in band_acc.values()) or 1.0
    bands = {name: {"share_of_gap": float(v[0] / total_e),
                    "relative_error": float(v[0] / v[1]) if v[1] > 0 else None}
             for name, v in band_acc.items()}
    trend = _amplitude_trend(val_entries if len(val_entries) >= 2 else
                             [e for e in per_record if e.get("gap") is not None])
    val_noise = [n for n, (_, role) in zip(noise_nmse, zip(records, roles)) if role == "val"]
    where = {
        "per_dof": per_dof,
        "per_record": per_record,
        "amplitude_trend": trend,
        "decay": windows,
        "frequency_bands": bands,
        "noise_floor": float(np.mean(val_noise)) if val_noise else None,
        "modes_hz": [float(x) for x in modes],
    }
    where["explanation"] = _explain(where, best)
    return where, {"records": plots, "modes": modes}


def _passband(proc: Processing, fs: float) -> tuple[float, float] | None:
    """The band the chain lets through (band-pass, high-pass, anti-aliasing), if any."""
    lo = max([x for x in (proc.bandpass[0] if proc.bandpass else None, proc.highpass)
              if x is not None], default=0.0)
    hi = min([x for x in (proc.bandpass[1] if proc.bandpass else None, 0.4 * fs)
              if x is not None])
    return (lo, hi) if hi > lo else None


def _kept_time(proc: Processing, rec: Recording, dofs: Sequence[str], n: int) -> np.ndarray:
    i0 = proc.start_index(rec, dofs) + int(round(proc.trim * rec.fs))
    k = proc.decimation(rec.fs)
    t = rec.time[i0::k][:n]
    return t if len(t) == n else np.arange(n) * rec.dt * k + rec.time[0]


def _noise_nmse(y: np.ndarray, fs: float, band: tuple[float, float] | None) -> float:
    """White-noise floor of a normalised measured record as an NMSE: the median Welch PSD
    over the chain's passband (a decaying response occupies few bins, noise all of them)
    times the passband width, over the signal's variance.  Stationary lines (hum) are not
    counted; bins the chain filtered out would bias the median low, so they are excluded."""
    if len(y) < 32:
        return 0.0
    f, P = signal.welch(y, fs=fs, axis=0, nperseg=min(len(y), 1024))
    lo, hi = band if band is not None else (0.0, fs / 2)
    hi = min(hi, fs / 2)
    m = (f > lo) & (f < hi)
    if m.sum() < 4:
        m = f > 0
    var = np.mean(y ** 2, axis=0)
    floor = np.median(P[m], axis=0) * (hi - lo)
    return float(np.mean(floor / np.maximum(var, 1e-300)))


def _amplitude_trend(entries: Sequence[dict[str, Any]]) -> str:
    """Does the nominal gap grow or shrink with the excitation (peak force, else RMS)?"""
    if len(entries) < 2:
        return "one record only"
    amp = np.array([e["peak_force"] or np.mean(list(e["response_rms"].values()))
                    for e in entries])
    gap = np.array([e["gap"] for e in entries])
    order = np.argsort(amp)
    g = gap[order]
    if np.all(np.diff(g) > 0) and g[-1] > 1.5 * g[0]:
        return "grows with amplitude"
    if np.all(np.diff(g) < 0) and g[0] > 1.5 * g[-1]:
        return "shrinks with amplitude"
    if max(g) < 1.5 * min(g):
        return "about the same at every amplitude"
    return "varies with amplitude, not monotonically"


def _explain(where: Mapping[str, Any], best: Candidate | None) -> str:
    per_dof = where["per_dof"]
    parts = []
    if per_dof:
        worst = max(per_dof, key=lambda d: per_dof[d])
        tot = sum(per_dof.values()) or 1.0
        parts.append(f"The nominal model's validation gap is largest on {worst} "
                     f"({100 * per_dof[worst] / tot:.0f} % of it)")
    parts.append(f"it {where['amplitude_trend']}")
    win = {k: v for k, v in where["decay"].items() if v is not None}
    if win:
        w = max(win, key=lambda k: win[k])
        parts.append(f"relative to the response it is worst {w} in the decay "
                     f"(early {win.get('early', float('nan')):.3g}, late "
                     f"{win.get('late', float('nan')):.3g})")
    bands = where["frequency_bands"]
    if bands:
        b = max(bands, key=lambda k: bands[k]["share_of_gap"])
        parts.append(f"{100 * bands[b]['share_of_gap']:.0f} % of it lies in the band {b}")
    text = "; ".join(parts) + "."
    if best is not None:
        text += (f" Adding {best.effect.kind} {best.loc.between[0]}-{best.loc.between[1]} "
                 f"closes {100 * best.closure:.0f} % of it: {best.effect.describe(best.coefficients)}")
    return text


# ============================================================================ verdict
def decide(ranking: Sequence[Candidate], gap_before: float, noise_floor: float | None,
           settings: DiagnoseSettings) -> tuple[Candidate | None, dict[str, Any]]:
    """The documented verdict rule (module doc, step 5); returns (verdict, checks)."""
    rule: dict[str, Any] = {"closure_min": settings.closure_min,
                            "separation": settings.separation,
                            "record_tolerance": settings.record_tolerance,
                            "noise_factor": settings.noise_factor,
                            "gap_min": settings.gap_min}
    fitted = [c for c in ranking if c.fitted and np.isfinite(c.closure)]
    if not fitted:
        rule["reason"] = "no candidate could be fitted"
        return None, rule
    top = fitted[0]
    rival = next((c for c in fitted[1:] if c.effect.kind != top.effect.kind), None)
    checks = {
        "above_noise": bool(gap_before > settings.gap_min and (
            noise_floor is None or gap_before > settings.noise_factor * noise_floor)),
        "closure": bool(top.closure >= settings.closure_min),
        "separation": bool(rival is None or not np.isfinite(rival.gap_after)
                           or top.gap_after <= settings.separation * rival.gap_after),
        "consistent": bool(all(p["closure"] is not None and
                               p["closure"] >= -settings.record_tolerance
                               for p in top.per_record)),
    }
    rule.update({"candidate": top.label(), "rival": rival.label() if rival else None,
                 "checks": checks})
    if all(checks.values()):
        rule["reason"] = "all checks pass"
        return top, rule
    failed = [k for k, ok in checks.items() if not ok]
    reasons = {"above_noise": "the nominal model already fits the validation records to "
                              f"the noise level or within {settings.gap_min:g} NMSE",
               "closure": f"the best candidate closes less than {settings.closure_min:.0%} "
                          "of the validation gap",
               "separation": "a candidate of another kind explains the gap about as well",
               "consistent": "the best candidate makes a validation record worse"}
    rule["reason"] = "; ".join(reasons[k] for k in failed)
    return None, rule


# ============================================================================ driver
def diagnose(structure: Structure, train: Sequence[Recording], val: Sequence[Recording],
             processing: Any = "auto", *, settings: DiagnoseSettings | None = None,
             progress: Progress | None = None) -> Diagnosis:
    """Locate and explain the sim-to-real gap of ``structure`` (see the module doc)."""
    from .siva import choose_processing

    settings = settings or DiagnoseSettings()
    if not train or not val:
        raise ValueError("diagnose needs at least one --train and one --val record")
    t_all = time.perf_counter()
    timing: dict[str, float] = {}
    proc = choose_processing(processing, [*train, *val], structure.dofs)
    _say(progress, f"processing: {proc.describe() if hasattr(proc, 'describe') else proc}")

    t0 = time.perf_counter()
    nominal_fit = fit_nominal(structure, train, proc, settings, progress)
    theta, train_cost, start = nominal_fit.theta, nominal_fit.train_cost, nominal_fit.start
    timing["nominal_fit"] = time.perf_counter() - t0
    val_prob = _Outputs(structure, val, proc, theta)
    res_before = val_prob.residuals(theta)[0]
    gap_before = float(res_before @ res_before)
    before_blocks = val_prob.blocks(res_before)
    _say(progress, f"nominal: train cost {train_cost:.4g}, validation gap {gap_before:.4g} "
                   f"({timing['nominal_fit']:.1f} s)")

    names = list(settings.effects) if settings.effects else list(EFFECTS)
    unknown = [n for n in names if n not in EFFECTS]
    if unknown:
        raise ValueError(f"unknown effect(s) {unknown} (known: {', '.join(EFFECTS)})")
    t0 = time.perf_counter()
    cands, nom = screen(structure, theta, train, proc, [EFFECTS[n] for n in names], progress)
    ee_screen(structure, nominal_fit, train, cands)
    strong = sorted(cands, key=lambda c: -c.ee_score)[:3]
    _say(progress, "equation-error screening: " + ", ".join(
        f"{c.label()} {c.ee_score:.3f}" for c in strong))
    timing["screening"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    chosen = _pick(cands, settings)
    for c in chosen:
        try:
            fit_candidate(c, structure, theta, train, proc, nom.amplitudes[c.loc.between],
                          settings, nom.force_scale)
        except Exception as exc:  # noqa: BLE001 - one failed candidate must not sink the run
            c.note = f"fit failed: {exc}"
            _say(progress, f"{c.label()}: fit failed ({exc})")
            continue
        outs = _Outputs(c.structure, val, proc, c.theta)
        r_after = outs.residuals(c.theta)[0]
        c.gap_before = gap_before
        c.gap_after = float(r_after @ r_after) if np.all(np.isfinite(r_after)) else math.inf
        c.closure = 1.0 - c.gap_after / gap_before if gap_before > 0 else 0.0
        after_blocks = outs.blocks(r_after) if np.all(np.isfinite(r_after)) else \
            np.full_like(before_blocks, np.inf)
        c.per_record = []
        for k, rec in enumerate(val):
            gb, ga = float(before_blocks[k].mean()), float(after_blocks[k].mean())
            c.per_record.append({"record": rec.name, "gap_before": gb,
                                 "gap_after": _num(ga),
                                 "closure": _num(1 - ga / gb) if gb > 0 else None})
        _say(progress, f"{c.label()}: closure {c.closure:.3f} (val gap {gap_before:.4g} -> "
                       f"{c.gap_after:.4g}; {c.fit_time_s:.1f} s) "
                       + ", ".join(f"{k}={v:.4g}" for k, v in c.coefficients.items()))
    timing["candidate_fits"] = time.perf_counter() - t0
    ranking = sorted([c for c in chosen if c.fitted],
                     key=lambda c: -c.closure if np.isfinite(c.closure) else math.inf)

    t0 = time.perf_counter()
    best = ranking[0] if ranking else None
    where, plots = where_analysis(structure, theta, [*train, *val],
                                  ["train"] * len(train) + ["val"] * len(val), proc, best)
    # noise floor: the spectral estimate, capped by the best fit achieved on the train
    # records (a residual that small is reachable, so the noise cannot be larger)
    psd_floor = where.pop("noise_floor")
    fits = [train_cost] + [c.train_cost for c in ranking if np.isfinite(c.train_cost)]
    where["noise_floor"] = float(min([psd_floor, *fits] if psd_floor is not None else fits))
    where["noise_floor_spectral"] = psd_floor
    verdict, rule = decide(ranking, gap_before, where["noise_floor"], settings)
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
    return Diagnosis(verdict, ranking, cands, where, nominal, rule, proc, timing, structure,
                     theta, list(train), list(val), plots)


# ============================================================================ synthetic cases
def with_effect(structure: Structure, kind: str, between: Sequence[str],
                coefficients: Mapping[str, float]) -> Structure:
    """``structure`` plus one element with *known* coefficients (fixed parameters), so the
    free parameters stay those of ``structure``: the generator of a synthetic gap case."""
    spec = copy.deepcopy(structure.spec)
    spec["elements"].append({"kind": kind, "between": list(between),
                             "params": {c: float(v) for c, v in coefficients.items()}})
    return Structure.from_dict(spec)


def synthetic_impacts(structure: Structure, theta: Any, peaks: Sequence[float], *,
                      dof: str, fs: float = 2048.0, duration: float = 4.0,
                      pulse: float = 6.2e-3, t_hit: float = 0.1, acc_noise: float = 3e-3,
                      force_noise: float = 2e-3, seed: int = 0) -> list[Recording]:
    """Impact-hammer records of ``structure`` as instruments give them (acc per DOF and the
    force, no displacement): half-sine pulses of the given peaks on ``dof``, white noise of
    ``acc_noise`` x each acceleration's peak and ``force_noise`` x the force peak.

    Used by the tests and the benchmark to check the diagnosis on effects, magnitudes and
    seeds other than the shipped examples (``with_effect`` builds the generator)."""
    from .simulate import simulate

    rng = np.random.default_rng(seed)
    t = np.arange(int(round(duration * fs))) / fs
    k = structure.dofs.index(dof)
    out = []
    for peak in peaks:
        F = np.zeros((len(t), structure.n_dof))
        on = (t >= t_hit) & (t <= t_hit + pulse)
        F[on, k] = peak * np.sin(np.pi * (t[on] - t_hit) / pulse)
        sim = simulate(structure, np.asarray(theta, float), t, np.zeros(structure.n_dof),
                       np.zeros(structure.n_dof), F, substeps="auto")
        cols: dict[str, np.ndarray] = {"time": t}
        for d, name in enumerate(structure.dofs):
            a = sim.a[:, d]
            cols[f"acc_{name}"] = a + acc_noise * np.max(np.abs(a)) * rng.standard_normal(len(t))
        cols[f"force_{dof}"] = F[:, k] + force_noise * peak * rng.standard_normal(len(t))
        out.append(Recording.from_columns(cols, structure.dofs, name=f"impact_{peak:g}N"))
    return out


# ============================================================================ command
def diagnose_command(args: argparse.Namespace) -> int:
    """`siva diagnose MODEL --train CSV... --val CSV... [--out FILE] [--html FILE]`."""
    structure = Structure.from_file(args.model)
    train = [Recording.read(p, structure.dofs) for p in args.train]
    val = [Recording.read(p, structure.dofs) for p in args.val]
    progress = None if getattr(args, "quiet", False) else _stderr
    diag = diagnose(structure, train, val, getattr(args, "processing", "auto"),
                    progress=progress)
    text = json.dumps(diag.to_json(), indent=2)
    if getattr(args, "out", None):
        Path(args.out).write_text(text + "\n")
    else:
        sys.stdout.write(text + "\n")
    if getattr(args, "html", None):
        Path(args.html).write_text(html_report(diag))
        _say(progress, f"report: {args.html}")
    return 0


def _stderr(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


# ============================================================================ HTML report
def _png(fig: Any) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=96, bbox_inches="tight")
    import matplotlib.pyplot as plt

    plt.close(fig)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def html_report(diag: Diagnosis) -> str:
    """A self-contained HTML page: verdict, ranking, where, and three embedded figures."""
    import html as _html

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    data = diag.to_json()
    plots = diag.plots or {"records": []}
    recs = [p for p in plots["records"] if p["role"] == "val"] or plots["records"]
    figs: list[tuple[str, str]] = []
    if recs:
        gaps = {e["record"]: e.get("gap") or 0 for e in data["where"]["per_record"]}
        p = max(recs, key=lambda p: gaps.get(p["record"], 0))
        n = p["y"].shape[1]
        fig, axes = plt.subplots(n, 1, figsize=(10, 2.6 * n), sharex=True, squeeze=False)
        for d in range(n):
            ax = axes[d, 0]
            ax.plot(p["t"], p["y"][:, d], "k", lw=0.8, label="measured")
            ax.plot(p["t"], p["nominal"][:, d], "C3", lw=0.8, label="nominal model")
            if p["augmented"] is not None:
                ax.plot(p["t"], p["augmented"][:, d], "C0--", lw=0.8,
                        label="with " + (data["ranking"][0]["kind"] if data["ranking"] else ""))
            ax.set_ylabel(f"{p['quantities'][d]} {diag.structure.dofs[d]}")
            ax.legend(loc="upper right", fontsize=8)
        axes[-1, 0].set_xlabel("time [s]")
        fig.suptitle(f"validation record {p['record']} (processed)")
        figs.append(("Measured vs nominal vs augmented model", _png(fig)))

        fig, axes = plt.subplots(1, n, figsize=(5 * n, 3.2), squeeze=False)
        for d in range(n):
            ax = axes[0, d]
            for lab, x, sty in (("measured", p["y"][:, d], "k"),
                                ("nominal residual", p["nominal"][:, d] - p["y"][:, d], "C3"),
                                ("augmented residual", None if p["augmented"] is None else
                                 p["augmented"][:, d] - p["y"][:, d], "C0")):
                if x is None:
                    continue
                f, P = signal.welch(x, fs=p["fs"], nperseg=min(len(x), 1024))
                ax.semilogy(f, np.sqrt(P), sty, lw=0.9, label=lab)
            for m in plots.get("modes", []):
                ax.axvline(m, color="0.7", lw=0.6, ls=":")
            ax.set_xlabel("frequency [Hz]")
            ax.set_title(diag.structure.dofs[d])
            ax.legend(fontsize=8)
        fig.suptitle("residual spectra (Welch amplitude)")
        figs.append(("Residual spectra", _png(fig)))
    if data["ranking"]:
        fig, ax = plt.subplots(figsize=(8, 0.5 + 0.45 * len(data["ranking"])))
        labels = [f"{c['kind']} {c['between'][0]}-{c['between'][1]}" for c in data["ranking"]]
        vals = [c["closure"] or 0.0 for c in data["ranking"]]
        colors = ["C2" if data["verdict"] and i == 0 else "C7" for i in range(len(vals))]
        ax.barh(labels[::-1], vals[::-1], color=colors[::-1])
        ax.axvline(diag.rule.get("closure_min", 0.3), color="k", ls="--", lw=0.8)
        ax.set_xlabel("closure of the validation gap (1 - gap_after / gap_before)")
        figs.append(("Ranking", _png(fig)))

    esc = _html.escape
    v = data["verdict"]
    verdict = (f"<b>{esc(v['kind'])}</b> between <b>{esc(v['between'][0])}</b> and "
               f"<b>{esc(v['between'][1])}</b> &mdash; closure {v['closure']:.2f}<br>"
               f"{esc(v['explanation'])}" if v else
               f"<b>none</b> &mdash; {esc(str(diag.rule.get('reason', '')))}")
    rows = "".join(
        f"<tr><td>{esc(c['kind'])}</td><td>{esc(' - '.join(c['between']))}</td>"
        f"<td>{c['gap_before']:.4g}</td><td>{(c['gap_after'] or float('nan')):.4g}</td>"
        f"<td>{(c['closure'] or float('nan')):.3f}</td>"
        f"<td>{esc(', '.join(f'{k}={x:.4g}' for k, x in c['coefficients'].items() if x is not None))}</td></tr>"
        for c in data["ranking"])
    where = data["where"]
    w_rows = "".join(f"<tr><td>{esc(e['record'])}</td><td>{esc(e['role'])}</td>"
                     f"<td>{e['peak_force']:.4g}</td><td>{(e.get('gap') or float('nan')):.4g}</td>"
                     f"<td>{(e.get('gap_after') or float('nan')):.4g}</td></tr>"
                     for e in where["per_record"])
    imgs = "".join(f"<h3>{esc(t)}</h3><img src='{src}' style='max-width:100%'>" for t, src in figs)
    return f"""<!DOCTYPE html>
<html><head><meta charset="utf-8"><title>siva diagnose: {esc(diag.structure.name)}</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:auto;padding:1em}}
table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;padding:3px 8px;text-align:right}}
td:first-child{{text-align:left}}</style></head><body>
<h1>Sim-to-real gap of <code>{esc(diag.structure.name)}</code></h1>
<p>Verdict: {verdict}</p>
<p>{esc(where['explanation'])}</p>
<p>Nominal validation gap {data['nominal']['gap']:.4g} (normalised output error; estimated
noise floor {(where['noise_floor'] or float('nan')):.3g}); processing: {esc(data['processing'])}.</p>
<h2>Ranking (fitted candidates)</h2>
<table><tr><th>kind</th><th>between</th><th>gap before</th><th>gap after</th><th>closure</th>
<th>coefficients</th></tr>{rows}</table>
<h2>Where the gap lies</h2>
<table><tr><th>record</th><th>role</th><th>peak force</th><th>nominal gap</th>
<th>with best candidate</th></tr>{w_rows}</table>
<pre>{esc(json.dumps({k: where[k] for k in ('per_dof', 'amplitude_trend', 'decay', 'frequency_bands')}, indent=1))}</pre>
{imgs}
<h2>Full result</h2><pre>{esc(json.dumps(data, indent=1))}</pre>
</body></html>
"""


__all__ = ["diagnose", "diagnose_command", "Diagnosis", "DiagnoseSettings", "Candidate",
           "augmented", "decide", "html_report", "with_effect", "synthetic_impacts"]
