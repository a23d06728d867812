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
from dataclasses import asdict, dataclass, field
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
    effects: names of the effects to try (default: all registered).
    nominal_start: initial values of the nominal parameters (skips the least-squares start).
    """

    top_k: int = 3
    max_per_kind: int = 2
    nominal_nfev: int = 40
    fit_nfev: int = 25
    closure_min: float = 0.3
    separation: float = 0.75
    record_tolerance: float = 0.05
    noise_factor: float = 2.0
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

    def cost(self, thetas: np.ndarray) -> np.ndarray:
        return self.prob.cost(np.atleast_2d(thetas))

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

    def signals(self, theta: np.ndarray, k: int, force: np.ndarray | None = None,
                raw: bool = False) -> tuple[States | None, Any]:
        """Record ``k`` simulated at one theta (optionally with another force), processed.
        Returns (processed states or None if diverged, raw Simulation)."""
        from .simulate import simulate, simulated_recording

        r = self.records[k]
        f = r.force if force is None else force
        sim = simulate(self.structure, np.asarray(theta, float), r.rec.time, r.q0, r.v0, f,
                       substeps=r.substeps, backend=self.prob.backend)
        if not (np.all(np.isfinite(sim.q)) and np.all(np.isfinite(sim.v))):
            return None, sim
        srec = simulated_recording(r.rec, self.structure, sim.q, sim.v, sim.a)
        return self.proc.apply(srec, self.structure.dofs), sim

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
    values = structure.full_values(np.asarray(theta, float))
    g = np.ones(structure.n_dof)
    for k, d in enumerate(structure.dofs):
        gain = structure.force_gains.get(d, 1.0)
        g[k] = float(values[gain]) if isinstance(gain, str) else float(gain)
    return g


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
def fit_nominal(structure: Structure, train: Sequence[Recording], proc: Processing,
                settings: DiagnoseSettings, progress: Progress | None = None
                ) -> tuple[np.ndarray, float, str]:
    """Output-error fit of the model as given on the train records.

    Start: the user's ``nominal_start``, else equation-error least squares on the train
    states of the chosen chain and, when that chain does not make integration safe, of the
    data-driven ``Processing.auto`` chain (least squares on drifting integrals is useless);
    the start with the lowest output error is refined (``refine``, growing horizons).
    Returns (theta, train cost, how it started).
    """
    from .baselines import least_squares
    from .refine import output_error, refine

    starts: list[tuple[str, np.ndarray]] = []
    if settings.nominal_start is not None:
        starts.append(("given", structure.vector(settings.nominal_start)))
    else:
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
            if np.all(np.isfinite(th)):
                starts.append((label, th))
    if not starts:
        raise ValueError("diagnose: no usable start for the nominal fit (least squares "
                         "failed); pass initial values")
    costs = output_error(structure, np.stack([s for _, s in starts]), list(train), proc)
    order = np.argsort(costs)
    best = int(order[0])
    if not np.isfinite(costs[best]):
        raise ValueError("diagnose: the nominal model diverges from every start")
    label, th0 = starts[best]
    _say(progress, f"nominal start: {label} (train cost {costs[best]:.4g})")
    res = refine(structure, th0, list(train), proc, max_nfev=settings.nominal_nfev)
    c = output_error(structure, np.stack([th0, res.theta]), list(train), proc)
    theta = res.theta if c[1] <= c[0] else th0
    return theta, float(min(c)), label


# ============================================================================ screening
def _amplitudes(outs: _Outputs, theta: np.ndarray, loc: Location) -> tuple[Amplitudes, list]:
    """Relative displacement/velocity at ``loc`` along the nominal simulation of each train
    record (full rate, the signals the element would see)."""
    dmax = vmax = 0.0
    d2 = v2 = 0.0
    n = 0
    for k in range(len(outs.records)):
        sim = outs._raw_cache[k]
        d, dv = _relative(sim.q, sim.v, loc)
        dmax, vmax = max(dmax, float(np.max(np.abs(d)))), max(vmax, float(np.max(np.abs(dv))))
        d2 += float(np.sum(d ** 2))
        v2 += float(np.sum(dv ** 2))
        n += d.size
    return Amplitudes(dmax, vmax, math.sqrt(d2 / max(n, 1)), math.sqrt(v2 / max(n, 1))), []


def screen(structure: Structure, theta: np.ndarray, train: Sequence[Recording],
           proc: Processing, effects: Sequence[Effect],
           progress: Progress | None = None) -> tuple[list[Candidate], float]:
    """Score test of every candidate on the train records (see the module doc, step 3).

    Returns the candidates (best first) and the nominal train cost.
    """
    outs = _Outputs(structure, train, proc, theta)
    r = outs.residuals(theta)[0]
    cost0 = float(r @ r)
    # nominal Jacobian (the nominal model re-tunes itself when an element is added)
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

    # nominal simulation (raw, full rate) and processed outputs of each train record
    base_out, raw = [], []
    for k in range(len(outs.records)):
        st, sim = outs.signals(theta, k)
        if st is None:
            raise ValueError("diagnose: the nominal fit diverges on a train record")
        raw.append(sim)
        base_out.append(outs.output(st, k))
    outs._raw_cache = raw  # type: ignore[attr-defined]
    gains = _gain_values(structure, theta)
    masses = structure.masses

    cands: list[Candidate] = []
    for loc in _locations(structure):
        amp, _ = _amplitudes(outs, theta, loc)
        for eff in effects:
            if _has_element(structure, eff.kind, loc):
                continue
            for shape in eff.shape_grid(amp):
                cols = []
                ok = True
                for k, rr in enumerate(outs.records):
                    sim = raw[k]
                    d, dv = _relative(sim.q, sim.v, loc)
                    g = eff.unit_force(d, dv, shape)
                    # reference force: mass x acceleration of DOF i along the nominal run
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
                        ok = False
                        break
                    cols.append(((outs.output(st, k) - base_out[k]) / eps).ravel())
                c = Candidate(eff, loc, dict(shape))
                if not ok:
                    c.admissible, c.note = False, "sensitivity run diverged"
                    cands.append(c)
                    continue
                j = np.concatenate(cols)
                j_perp = j - U @ (U.T @ j)
                jj = float(j_perp @ j_perp)
                if jj <= 0 or cost0 <= 0:
                    c.admissible = False
                    cands.append(c)
                    continue
                jr = float(j_perp @ r_perp)
                c.estimate = -jr / jj
                c.score = (jr * jr / jj) / cost0
                if eff.magnitude in eff.positive and c.estimate < 0:
                    c.admissible = False
                    c.note = "the data ask for a negative (energy-supplying) coefficient"
                cands.append(c)
    cands.sort(key=lambda c: (c.admissible, c.score), reverse=True)
    # one entry per (kind, location): the best shape
    seen: set[tuple[str, tuple[str, str]]] = set()
    unique = []
    for c in cands:
        if c.key in seen:
            continue
        seen.add(c.key)
        unique.append(c)
    _say(progress, "screening: " + ", ".join(f"{c.label()} {c.score:.3f}"
                                               for c in unique[:6] if c.admissible))
    outs._amp = {tuple(l.between): _amplitudes(outs, theta, l)[0]  # type: ignore[attr-defined]
                 for l in _locations(structure)}
    return unique, cost0


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
    return chosen


# ============================================================================ candidate fit
def fit_candidate(c: Candidate, structure: Structure, theta_nom: np.ndarray,
                  train: Sequence[Recording], proc: Processing, amp: Amplitudes,
                  settings: DiagnoseSettings, force_scale: float) -> None:
    """Fit nominal + candidate by output error on the train records (in place)."""
    from .refine import output_error, refine

    t0 = time.perf_counter()
    eff = c.effect
    floor = eff.typical_magnitude(amp, c.shape, force_scale)
    mags = eff.starts(c.estimate, floor)
    scales = {**{k: max(abs(v), 1e-12) for k, v in c.shape.items()},
              eff.magnitude: max(abs(c.estimate), floor * 1e-3, 1e-300)}
    aug, names = augmented(structure, eff, c.loc, scales)
    nominal_values = structure.as_dict(theta_nom)
    starts = []
    for m in mags:
        vals = dict(nominal_values)
        vals.update({names[k]: v for k, v in c.shape.items()})
        vals[names[eff.magnitude]] = m
        starts.append(aug.vector(vals))
    starts = np.stack(starts)
    costs = output_error(aug, starts, list(train), proc)
    th0 = starts[int(np.argmin(costs))]
    res = refine(aug, th0, list(train), proc, max_nfev=settings.fit_nfev, horizons=None)
    both = output_error(aug, np.stack([th0, res.theta]), list(train), proc)
    theta = res.theta if both[1] <= both[0] else th0
    c.structure, c.theta = aug, theta
    vals = aug.as_dict(theta)
    c.coefficients = {k: vals[p] for k, p in names.items()}
    c.parameters = {p: vals[p] for p in structure.free}
    c.train_cost = float(min(both))
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
        noise_nmse.append(_noise_nmse(y, fs))
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


def _kept_time(proc: Processing, rec: Recording, dofs: Sequence[str], n: int) -> np.ndarray:
    i0 = proc.start_index(rec, dofs) + int(round(proc.trim * rec.fs))
    k = proc.decimation(rec.fs)
    t = rec.time[i0::k][:n]
    return t if len(t) == n else np.arange(n) * rec.dt * k + rec.time[0]


def _noise_nmse(y: np.ndarray, fs: float) -> float:
    """White-noise floor of a normalised measured record as an NMSE: the median Welch PSD
    over the band (a decaying response occupies few bins, noise all of them) times the
    bandwidth, over the signal's variance.  Stationary lines (hum) are not counted."""
    if len(y) < 32:
        return 0.0
    f, P = signal.welch(y, fs=fs, axis=0, nperseg=min(len(y), 1024))
    var = np.mean(y ** 2, axis=0)
    floor = np.median(P[1:], axis=0) * (f[-1] - f[0])
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
                            "noise_factor": settings.noise_factor}
    fitted = [c for c in ranking if c.fitted and np.isfinite(c.closure)]
    if not fitted:
        rule["reason"] = "no candidate could be fitted"
        return None, rule
    top = fitted[0]
    rival = next((c for c in fitted[1:] if c.effect.kind != top.effect.kind), None)
    checks = {
        "above_noise": bool(noise_floor is None or gap_before > settings.noise_factor * noise_floor),
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
    reasons = {"above_noise": "the nominal model already fits to the noise level",
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
    from .refine import OutputErrorProblem
    from .siva import choose_processing

    settings = settings or DiagnoseSettings()
    if not train or not val:
        raise ValueError("diagnose needs at least one --train and one --val record")
    t_all = time.perf_counter()
    timing: dict[str, float] = {}
    proc = choose_processing(processing, [*train, *val], structure.dofs)
    _say(progress, f"processing: {proc.describe() if hasattr(proc, 'describe') else proc}")

    t0 = time.perf_counter()
    theta, train_cost, start = fit_nominal(structure, train, proc, settings, progress)
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
    cands, _ = screen(structure, theta, train, proc, [EFFECTS[n] for n in names], progress)
    timing["screening"] = time.perf_counter() - t0

    # amplitudes per location and a force scale for magnitude floors
    tr_outs = _Outputs(structure, train, proc, theta)
    raws = [tr_outs.signals(theta, k)[1] for k in range(len(tr_outs.records))]
    tr_outs._raw_cache = raws  # type: ignore[attr-defined]
    force_scale = float(np.max([np.sqrt(np.mean((structure.masses * s.a) ** 2)) for s in raws]))

    t0 = time.perf_counter()
    chosen = _pick(cands, settings)
    for c in chosen:
        amp, _ = _amplitudes(tr_outs, theta, c.loc)
        try:
            fit_candidate(c, structure, theta, train, proc, amp, settings, force_scale)
        except Exception as exc:  # noqa: BLE001 - one failed candidate must not sink the run
            c.note = f"fit failed: {exc}"
            _say(progress, f"{c.label()}: fit failed ({exc})")
            continue
        prob = OutputErrorProblem.build(c.structure, list(val), proc,
                                        theta_ref=c.theta[None])
        outs = _Outputs.__new__(_Outputs)
        outs.structure, outs.proc, outs.prob, outs.n_groups = c.structure, proc, prob, \
            prob.n_groups
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
    diag = Diagnosis(verdict, ranking, cands, where, nominal, rule, proc, timing, structure,
                     theta, list(train), list(val))
    diag._plots = plots  # type: ignore[attr-defined]
    return diag


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
    plots = getattr(diag, "_plots", {"records": []})
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
           "augmented", "decide", "html_report"]
