"""Screening (step 3): score tests of every candidate, output-error and equation-error,
and the choice of which candidates the fit stage gets."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from ..effects import Amplitudes, Effect
from ..processing import Processing
from ..recording import Recording
from ..structure import Structure
from .nominal import DISSIPATIVE, NominalFit
from .outputs import (Progress, _gain_values, _locations, _Outputs, _relative, _say,
                      candidate_sites)
from .results import Candidate, Location
from .settings import DiagnoseSettings


@dataclass
class _Nominal:
    """The nominal fit as the screening and the candidate fits see it: raw (full-rate)
    simulations of the train records, amplitudes per location, a force scale."""

    theta: np.ndarray
    outs: _Outputs
    raw: list[Any]
    amplitudes: dict[tuple[str, str], Amplitudes]
    force_scale: float
    jacobian: np.ndarray | None = None   # d residual / d nominal theta (train records)
    basis: np.ndarray | None = None      # orthonormal basis of its column space


def jacobian_basis(outs: _Outputs, theta: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The residual at ``theta``, the Jacobian by forward differences and an orthonormal
    basis of its (normalised) columns: what the model's own parameters can re-tune, to
    be projected out of a residual (screening, ``residue``)."""
    r = outs.residuals(theta)[0]
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
    return r, J, U


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
    # nominal Jacobian: projected out, since the nominal model re-tunes itself when an
    # element is added and only what it cannot absorb counts for the candidate
    r, J, U = jacobian_basis(outs, theta)
    cost0 = float(r @ r)
    r_perp = r - U @ (U.T @ r)
    nom.jacobian, nom.basis = J, U
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


def select_for_fit(cands: Sequence[Candidate], settings: DiagnoseSettings
                   ) -> list[Candidate]:
    """Which screened candidates the magnitude scan and the local fit get.

    The best location of every family (by output- or equation-error score) whose score is
    at least ``settings.family_keep`` of the leading family's: a look-alike law that could
    still win after the joint fit is never dropped at screening; at most ``settings.top_k``
    families, plus the runner-up location of the two leading families (the place can be
    confused too) and the strongest equation-error candidate."""
    def strength(c: Candidate) -> float:
        return max(c.score if c.admissible else 0.0, c.ee_score)

    ranked = sorted((c for c in scan_targets(cands) if strength(c) > 0), key=strength,
                    reverse=True)
    if not ranked:
        return []
    top = strength(ranked[0])
    chosen: list[Candidate] = []
    kinds: list[str] = []
    for c in ranked:
        if c.effect.kind in kinds or strength(c) < settings.family_keep * top:
            continue
        kinds.append(c.effect.kind)
        chosen.append(c)
    chosen = chosen[:settings.top_k]
    for kind in [c.effect.kind for c in chosen[:settings.runner_ups]]:
        second = [c for c in ranked if c.effect.kind == kind and c not in chosen]
        if second and strength(second[0]) >= settings.family_keep * top:
            chosen.append(second[0])
    strong = max(cands, key=lambda c: c.ee_score, default=None)
    if strong is not None and strong.ee_score >= settings.ee_strong and strong not in chosen:
        chosen.append(strong)
    # each role (restoring, dissipative) gets its best candidates whatever the other
    # role's lead: a dissipative effect hidden under restoring laws that rank first (or
    # the reverse) is still fitted (issue 16: a cubic damper LO-NO beside a spring
    # NO-ground, the screen's first six all restoring but one); not a role far below
    # (``role_floor`` of the leading family's evidence)
    for role in (False, True):
        have = sum(1 for c in chosen if (c.effect.kind in DISSIPATIVE) == role)
        extra = [c for c in ranked if (c.effect.kind in DISSIPATIVE) == role
                 and c not in chosen and strength(c) >= settings.role_floor * top]
        chosen += extra[:max(0, settings.role_keep - have)]
    return chosen


def other_places(cands: Sequence[Candidate], kind: str, fitted: Sequence[Candidate]
                 ) -> list[Candidate]:
    """The best-scoring candidate (shape) of ``kind`` at every location not fitted yet,
    strongest first: once a kind leads after the fits, its place is decided by fits at
    every place, not by the screen (measured: a velocity-squared damper LO-NO screened
    third of its kind behind LO-ground and NO-ground, and NO-ground was named)."""
    done = {c.loc.between for c in fitted if c.effect.kind == kind}
    best: dict[tuple[str, str], Candidate] = {}
    for c in scan_targets(cands):
        if c.effect.kind != kind or c.loc.between in done:
            continue
        b = best.get(c.loc.between)
        if b is None or _strength(c) > _strength(b):
            best[c.loc.between] = c
    return sorted(best.values(), key=lambda c: -_strength(c))


def other_kinds(cands: Sequence[Candidate], lead: Candidate, fitted: Sequence[Candidate]
                ) -> list[Candidate]:
    """The best-scoring candidate of every other kind *at the lead's place* that acts
    alike (restoring or dissipating, like the lead), not fitted yet, strongest first:
    look-alike laws at one place are told apart by fits, not by the screen (measured: a
    clearance m2-ground on a 3-DOF chain, gap 1.17, screened behind clearances elsewhere;
    a cubic spring m2-ground led with closure 0.76 and the clearance was never fitted)."""
    role = lead.effect.kind in DISSIPATIVE
    done = {c.effect.kind for c in fitted if c.loc.between == lead.loc.between}
    best: dict[str, Candidate] = {}
    for c in scan_targets(cands):
        if c.loc.between != lead.loc.between or c.effect.kind in done \
                or (c.effect.kind in DISSIPATIVE) != role:
            continue
        b = best.get(c.effect.kind)
        if b is None or _strength(c) > _strength(b):
            best[c.effect.kind] = c
    return sorted(best.values(), key=lambda c: -_strength(c))


def _strength(c: Candidate) -> float:
    """A candidate's screening evidence: the better of its output-error score (when its
    sign is admissible) and its equation-error score."""
    return max(c.score if c.admissible else 0.0, c.ee_score)


def scan_targets(cands: Sequence[Candidate]) -> list[Candidate]:
    """Every candidate the coarse magnitude scan visits: all but those the model already
    represents or whose sensitivity run diverged (an inadmissible screening sign does not
    exclude a candidate: the linearisation at zero magnitude can get the sign wrong when
    the effect is strong)."""
    return [c for c in cands if "already represents" not in c.note
            and "diverged" not in c.note]
