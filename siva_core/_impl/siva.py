"""The SIVA estimator: records in, identified parameters with uncertainty out.

``Siva(structure).fit(train, val)`` follows the paper and adds one step it suggests
(Sec. 3.1, "initial guesses for optimization routines"): the recommended ``best`` value
is an output-error refinement started from Approach III, simulating the model with the
measured force and passing simulation and measurement through the same processing chain,
so the final estimate does not inherit the chain's bias.
"""
from __future__ import annotations

import dataclasses

import json
import math
import sys
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

from .ensemble import normal_summary
from .refine import NUMERICAL_REL_STD
from .processing import Processing
from .progress import Eta
from .recording import Recording
from .structure import Structure
from .training import SivaSettings, SivaTrainer

Progress = Callable[[str], None]


def _stderr(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def choose_processing(processing: str | dict | Processing | None, recordings: Sequence[Recording],
                      dofs: Sequence[str]) -> Processing:
    """'auto' (chosen from the data), 'none', 'paper', a dict of settings, or an instance."""
    if isinstance(processing, Processing):
        return processing
    if processing is None or processing == "none":
        return Processing()
    if processing == "paper":
        return Processing.paper()
    if processing == "auto":
        return Processing.auto(recordings, dofs)
    if isinstance(processing, str):
        processing = json.loads(processing)
    if isinstance(processing, dict):
        kw = dict(processing)
        if "bandpass" in kw and kw["bandpass"] is not None:
            kw["bandpass"] = tuple(kw["bandpass"])
        return Processing(**kw)
    raise ValueError(f"processing: cannot use {processing!r}")


@dataclass
class Identification:
    """Everything one SIVA run produced (``to_json`` gives the CONTRACT shape)."""

    structure: Structure
    approach_I: dict[str, dict]
    approach_II: dict[str, dict]
    approach_III: np.ndarray
    best: np.ndarray
    best_std: np.ndarray | None
    samples_I: np.ndarray
    samples_II: np.ndarray
    history: dict[str, list]
    converged_epoch: int | None
    epochs: int
    discriminator: dict[str, Any]
    metrics: dict[str, Any]
    timing_s: dict[str, float]
    baselines: dict[str, dict[str, float]] = field(default_factory=dict)
    processing: Processing | None = None
    notes: list[str] = field(default_factory=list)
    approach_II_equation_error: dict[str, dict] = field(default_factory=dict)
    best_cov: np.ndarray | None = None

    @property
    def names(self) -> list[str]:
        return self.structure.free

    def estimates(self) -> dict[str, np.ndarray]:
        """Each approach's point estimate as a parameter vector."""
        n = self.names
        return {"approach_I": np.array([self.approach_I[p]["mean"] for p in n]),
                "approach_II": np.array([self.approach_II[p]["mean"] for p in n]),
                "approach_III": self.approach_III, "best": self.best}

    def to_json(self) -> dict[str, Any]:
        params: dict[str, Any] = {}
        for k, p in enumerate(self.names):
            entry: dict[str, Any] = {
                "approach_I": _stats(self.approach_I[p]),
                "approach_II": {**_stats(self.approach_II[p]), "ess": self.approach_II[p].get("ess")},
                **({"approach_II_equation_error": _stats(self.approach_II_equation_error[p])}
                   if p in self.approach_II_equation_error else {}),
                "approach_III": float(self.approach_III[k]),
                "best": float(self.best[k]),
            }
            if self.best_std is not None:
                s = float(self.best_std[k])
                entry["best_std"] = s
                entry["best_ci95"] = [float(self.best[k] - 1.96 * s), float(self.best[k] + 1.96 * s)]
            params[p] = entry
        corr: dict[str, Any] = {}
        if len(self.samples_II) > 2:
            corr["approach_II"] = np.corrcoef(self.samples_II, rowvar=False).tolist()
        if self.best_cov is not None:
            s = np.sqrt(np.clip(np.diag(self.best_cov), 1e-300, None))
            corr["best"] = (self.best_cov / np.outer(s, s)).tolist()
        return {"parameters": params, "correlation": {"names": self.names, **corr},
                "validation": self.metrics.get("validation_test", {}),
                "metrics": self.metrics, "discriminator": self.discriminator,
                "timing_s": self.timing_s, "baselines": self.baselines,
                "training": {"epochs": self.epochs, "converged_epoch": self.converged_epoch,
                             "n_ensemble": int(len(self.samples_II))},
                "processing": _processing_json(self.processing), "notes": self.notes,
                "assessment": self.assessment().to_json()}

    def assessment(self, **commands: str) -> Any:
        """The verdict (accepted / rejected, unphysical or undetermined values, what to try
        next): :func:`siva_core._impl.assessment.assess`."""
        from .assessment import assess

        return assess(self, **commands)


def _stats(d: dict) -> dict:
    return {"mean": d["mean"], "std": d["std"], "ci95": d["ci95"]}


def _processing_json(p: Processing | None) -> dict | None:
    if p is None:
        return None
    from dataclasses import asdict

    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(p).items()}


@dataclass
class Recommendation:
    """What ``recommend_best`` found: the recommended ``theta`` (and its ``std``, None when
    the refinement was not run or not accepted), Approach III's winner, the output error of
    ``theta`` on the records (None without refinement) and a note for the user."""

    theta: np.ndarray
    std: np.ndarray | None
    note: str | None
    theta_III: np.ndarray
    output_error: float | None
    refined: bool
    refine_result: Any = None
    timing_s: dict[str, float] = field(default_factory=dict)

    def __iter__(self):  # ``theta, std, note = recommend_best(...)``
        return iter((self.theta, self.std, self.note))


def recommend_best(structure: Structure, candidates: Any, train: Sequence[Recording],
                   processing: Processing, *, refine: bool = True) -> Recommendation:
    """SIVA's recommended value from ensemble candidates (``Siva.fit`` and the service).

    Approach III: every candidate (rows of ``candidates``) is simulated on the raw training
    records in one batch and the one with the smallest displacement MSE wins.  Then
    ``best``: the output-error refinement (``refine.refine``) from that winner, through the
    same processing chain, kept only when it succeeded and does not raise the output error;
    otherwise ``best`` is the Approach III winner and ``std`` is None.

    Pure: reads its arguments, touches no trainer state or random generator.
    """
    from .refine import displacement_mse, force_profiled_output_error, output_error
    from .refine import refine as _refine
    from .output_error import default_force_spread

    st = structure
    names = st.free
    train = list(train)
    cand = np.atleast_2d(np.asarray(candidates, dtype=float))
    if cand.size == 0 or not train:
        raise ValueError("recommend_best needs at least one candidate and one training record")
    timing: dict[str, float] = {}
    t0 = time.perf_counter()
    lo, hi = st.physical_bounds()
    moved = physical_candidates(cand, lo, hi, names)
    cand = moved.candidates
    mse = displacement_mse(st, cand, train, processing)
    theta_III = cand[int(np.nanargmin(mse))].copy() if np.isfinite(mse).any() else cand[-1].copy()
    timing["approach_III"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    best, best_std, note, oe, refined, res = theta_III.copy(), None, None, None, False, None
    if refine and not np.isfinite(mse).any():
        # nothing to refine from (e.g. Approach II's mean of a softening spring that runs
        # away): best stays the candidate, without interval, and says why
        note = "every candidate's simulation diverges on the training records: not refined"
    elif refine:
        # An impact's response scales with its impulse: with a force sensor and no
        # identified gain, one force multiplier per record is fitted as a nuisance
        # parameter so that sensor error is not absorbed by the structure's parameters.
        gains = [g for g in st.force_gains.values() if isinstance(g, str) and g in names]
        forced = all(r.has_force(st.dofs) for r in train)
        fit_scale = forced and not gains
        fit_spread = fit_scale and default_force_spread(st, theta_III, train)
        # The pulse's spread too when enabled (``output_error.FIT_FORCE_SPREAD_BY_DEFAULT``,
        # off: it fixed one structure and broke two, docs/perf.md 6.4) and identifiable.
        res = _refine(st, theta_III, train, processing, fit_force_scale=fit_scale,
                      fit_force_spread=fit_spread, bounds=(lo, hi))
        # judged by the cost the refinement minimised: with fitted force scales, start and
        # result each with their own (``force_profiled_output_error``)
        if fit_scale:
            c_ref = force_profiled_output_error(st, np.stack([theta_III, res.theta]), train,
                                                processing, fit_spread=fit_spread)
        else:
            c_ref = output_error(st, np.stack([theta_III, res.theta]), train, processing)
        if res.success and np.all(np.isfinite(res.theta)) and c_ref[1] <= c_ref[0]:
            # Gauss-Newton std, inflated for the correlation of filtered residuals
            best, best_std = res.theta, res.std  # block-bootstrap (sandwich) std
            oe, refined = float(c_ref[1]), True
            if res.force_scale is not None:
                note = ("best: fitted force scale per training record "
                        + ", ".join(f"{r.name}={f:.4f}"
                                    for r, f in zip(train, np.ravel(res.force_scale))))
        else:
            oe = float(c_ref[0])
            note = f"refinement did not improve on Approach III ({res.message})"
    timing["refine"] = time.perf_counter() - t0
    outside = [n for n, v, a, b in zip(names, best, lo, hi) if not a <= v <= b]
    if outside:  # cannot happen through the bounded refinement; a last guard all the same
        best = np.clip(best, lo, hi)
        note = ((note + "; ") if note else "") + (
            f"best: {', '.join(outside)} clipped to the physical bounds")
    if moved.names:
        note = ((note + "; ") if note else "") + (
            f"Approach III candidates with {', '.join(moved.names)} outside the physical "
            f"bounds (e.g. negative damping) were moved inside before choosing")
    return Recommendation(np.asarray(best, dtype=float), best_std, note, theta_III, oe, refined,
                          res, timing)


@dataclass
class _Moved:
    candidates: np.ndarray
    names: list[str]


def physical_candidates(cand: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                        names: Sequence[str] | None = None) -> _Moved:
    """Candidates with every value strictly inside the physical bounds
    (:meth:`Structure.physical_bounds`): a value below ``lo`` is reflected above it (a
    damping of -0.9 becomes 0.9: same magnitude, physical sign), one on the bound is moved
    1e-3 of the parameter's typical size inside (the refinement's log scale cannot start at
    0).  Returns the moved candidates and the indices (or ``names``) of the parameters that
    had to move."""
    cand = np.array(cand, dtype=float, copy=True)
    typical = np.nanmedian(np.abs(cand), axis=0)
    typical = np.where(np.isfinite(typical) & (typical > 0), typical, 1.0)
    moved: list[int] = []
    for k in range(cand.shape[1]):
        col = cand[:, k]
        bad = ~((col > lo[k]) & (col < hi[k])) & np.isfinite(col)
        if not bad.any():
            continue
        moved.append(k)
        gap = 1e-3 * typical[k]
        below = col <= lo[k]
        col[below] = lo[k] + np.maximum(lo[k] - col[below], gap)
        above = col >= hi[k]
        col[above] = hi[k] - np.maximum(col[above] - hi[k], gap)
        if np.isfinite(lo[k]) and np.isfinite(hi[k]):
            out = ~((col > lo[k]) & (col < hi[k]))
            col[out] = 0.5 * (lo[k] + hi[k])
    labels = [names[k] for k in moved] if names is not None else [str(k) for k in moved]
    return _Moved(cand, labels)


class Siva:
    """SIVA estimator (scikit-learn style: settings in ``__init__``, ``fit`` returns self).

    Parameters
    ----------
    structure: the model (known masses, element kinds; parameters to identify).
    processing: the chain for measured records ('auto', 'none', 'paper', dict, Processing).
    settings: training hyper-parameters (``SivaSettings.fast()`` by default;
        ``preset="paper"`` gives the paper's).
    n_samples: Approach I sample count (paper: 1000).
    n_candidates: at most this many Approach II samples are simulated for Approach III.
    refine: run the output-error refinement that gives ``best``.
    fit_target: "output" (default of the fast preset): after the paper's equation-error
        training, SIVA continues on the output error through the processing chain
        (unbiased on measured data; Approach II from that phase); "equation": the paper's
        equation error only (the paper preset's default).
    baselines: also fit plain least squares and SINDy (pysindy) on the same states.
    """

    def __init__(self, structure: Structure, *, processing: Any = "auto",
                 settings: SivaSettings | None = None, preset: str = "fast", seed: int = 42,
                 max_epochs: int | None = None, n_samples: int = 1000, n_candidates: int = 600,
                 refine: bool = True, baselines: bool = True, progress: Progress | None = _stderr,
                 progress_every: int = 25, fit_target: str | None = None) -> None:
        self.structure = structure
        self.processing = processing
        self.settings = settings
        self.preset = preset
        self.seed = seed
        self.max_epochs = max_epochs
        self.n_samples = n_samples
        self.n_candidates = n_candidates
        self.refine = refine
        self.baselines = baselines
        self.progress = progress
        self.progress_every = progress_every
        self.fit_target = fit_target

    def _say(self, msg: str) -> None:
        if self.progress:
            self.progress(msg)

    def _settings(self) -> SivaSettings:
        if self.settings is not None:
            return self.settings
        make = SivaSettings.paper if self.preset == "paper" else SivaSettings.fast
        kw: dict[str, Any] = {"seed": self.seed}
        if self.max_epochs is not None:
            kw["max_epochs"] = self.max_epochs
        if self.fit_target is not None:
            if self.fit_target not in ("output", "equation"):
                raise ValueError(f"fit_target must be 'output' or 'equation', got {self.fit_target!r}")
            kw["fit_target"] = self.fit_target
        return make(**kw)

    def fit(self, train: Sequence[Recording], val: Sequence[Recording]) -> "Siva":
        t_all = time.perf_counter()
        st = self.structure
        names = st.free
        timing: dict[str, float] = {}
        proc = choose_processing(self.processing, [*train, *val], st.dofs)
        self.processing_ = proc
        self.train_recordings_, self.val_recordings_ = list(train), list(val)
        t0 = time.perf_counter()
        self.train_states_ = [proc.apply(r, st.dofs) for r in train]
        self.val_states_ = [proc.apply(r, st.dofs) for r in val]
        timing["processing"] = time.perf_counter() - t0

        # --- SIVA training (until converged, then the Approach II harvest)
        settings = self._settings()
        # with the output-error phase to follow, this phase only has to find the basin and
        # supply Approach III's candidates: converged at a looser tolerance, no step change,
        # a short harvest (docs/perf.md); the output-error phase gets ``settings`` back
        handover = settings.fit_target == "output"
        phase1 = (dataclasses.replace(settings, conv_rel_tol=settings.handover_rel_tol,
                                      lr_converged=None, ensemble_burn_in=0)
                  if handover else settings)
        trainer = SivaTrainer(st, phase1)
        trainer.set_data(self.train_states_, self.val_states_)
        if handover and trainer.train is not None:
            full = max(1, math.ceil(len(trainer.train) / settings.batch_size))
            trainer.settings.steps_per_epoch = min(settings.steps_per_epoch or full,
                                                   settings.handover_steps)
        t0 = time.perf_counter()
        eta = Eta(settings.max_epochs)  # an upper bound: training stops once converged
        harvest = (min(settings.handover_epochs, settings.ensemble_epochs) if handover
                   else settings.ensemble_epochs)
        while trainer.epoch < settings.max_epochs:
            log = trainer.run_epoch()
            if self.progress and (log.epoch % self.progress_every == 0):
                rel = ", ".join(f"{p}={v:.5g}" for p, v in zip(names, log.theta))
                self._say(f"{eta.text(log.epoch + 1)}  D={log.loss_d:.4f} (ln4=1.3863)  "
                          f"adv={log.loss_adv:.4f}  mse={log.loss_mse:.3e}  "
                          f"{'converged ' if log.converged else ''}{rel}")
            if trainer.converged and len(trainer.ensemble) >= harvest:
                break
        timing["training"] = time.perf_counter() - t0
        self.trainer_ = trainer
        notes: list[str] = []
        if not trainer.converged:
            notes.append(f"not converged after {trainer.epoch} epochs: Approach II uses the "
                         f"last {harvest} epochs")
        self._say(f"training: {trainer.epoch} epochs in {timing['training']:.1f} s, "
                  f"converged at epoch {trainer.monitor.converged_at}")

        # --- Approach II of the equation-error phase, then Approach III over it (one
        # batched simulation of the candidates) and ``best``: the output-error refinement
        # from it (shared with the service: ``recommend_best``)
        samples_ee = (trainer.ensemble.samples if len(trainer.ensemble)
                      else np.array(trainer.history["theta"][-harvest:]))
        rec = recommend_best(st, samples_ee[-self.n_candidates:], train, proc, refine=self.refine)
        theta_III, best, best_std = rec.theta_III, rec.theta, rec.std
        self.refine_ = rec.refine_result
        if rec.note:
            notes.append(rec.note)
        timing["approach_III"] = rec.timing_s["approach_III"]
        timing["refine"] = rec.timing_s["refine"]
        summ_ee = normal_summary(samples_ee, names)

        # --- the output-error phase: SIVA judged on what was measured, through the chain
        if settings.fit_target == "output":
            t0 = time.perf_counter()
            trainer.settings = settings
            self._output_error_phase(trainer, settings, best, train, val, proc, notes)
            timing["training_output_error"] = time.perf_counter() - t0

        # --- Approach I and II
        t0 = time.perf_counter()
        samples_I = trainer.sample(self.n_samples)
        if len(trainer.ensemble):
            samples_II = trainer.ensemble.samples
        else:
            n_ii = (settings.oe_ensemble_epochs if settings.fit_target == "output"
                    else settings.ensemble_epochs)
            samples_II = np.array(trainer.history["theta"][-n_ii:])
        summ_I = normal_summary(samples_I, names, ess=False)
        summ_II = normal_summary(samples_II, names, floor_rel=NUMERICAL_REL_STD)
        timing["approach_I_II"] = time.perf_counter() - t0
        if settings.fit_target == "output" and self.refine and len(samples_II):
            # the output-error phase takes the Gauss-Newton step of the linearised problem;
            # when the refinement stopped in a worse basin (measured: 2 of 20 LO-NO runs,
            # validation statistic 64 and 1723) that step finds the better one: refine again
            # from Approach II's mean and keep whichever simulates the records better
            # (skipped when Approach II's mean lies within 3 of best's standard errors and
            # within 0.5 % of it: the same basin, where a second refinement returns the
            # same optimum and is not kept; a wrong basin with a validation statistic of
            # 64+ is assumed to sit farther away -- an assumption, not re-measured)
            t0 = time.perf_counter()
            mean_II = samples_II.mean(0)
            gap = np.abs(mean_II - best)
            same_basin = (best_std is not None and np.all(np.isfinite(best_std))
                          and np.all(gap <= 3.0 * np.asarray(best_std))
                          and np.all(gap <= 5e-3 * np.abs(best)))
            better = None if same_basin else self._rerefine(best, mean_II, train, val, proc)
            if better is not None:
                rec, best, best_std = better, better.theta, better.std
                self.refine_ = better.refine_result
                notes.append("best: refined again from Approach II's mean (lower output error "
                             "than the first refinement)")
            timing["refine"] += time.perf_counter() - t0
        if settings.fit_target == "output":
            # Approach III over the output-error ensemble (the paper's rule, its candidates)
            from .refine import displacement_mse

            t0 = time.perf_counter()
            cand = samples_II[-self.n_candidates:]
            mse = displacement_mse(st, cand, train, proc)
            if np.isfinite(mse).any():
                theta_III = cand[int(np.nanargmin(mse))].copy()
            timing["approach_III"] += time.perf_counter() - t0

        # --- metrics on training and (held-out) validation records
        t0 = time.perf_counter()
        ests = {"approach_I": samples_I.mean(0), "approach_II": samples_II.mean(0),
                "approach_III": theta_III, "best": best}
        baselines: dict[str, dict[str, float]] = {}
        if self.baselines:
            baselines = self._baselines(timing)
            for bname, vals in baselines.items():
                try:
                    ests[bname] = st.vector(vals)
                except KeyError:
                    pass
        metrics = self._metrics(ests, train, val, proc)
        if val:
            from .validation import validation_score

            metrics["validation_test"] = {}
            for key in ("approach_II", "best"):
                try:
                    metrics["validation_test"][key] = validation_score(st, ests[key], val, proc)
                except ValueError as exc:
                    metrics["validation_test"][key] = {"error": str(exc)}
        timing["metrics"] = time.perf_counter() - t0
        timing["total"] = time.perf_counter() - t_all
        self.result_ = Identification(
            st, summ_I, summ_II, theta_III, best, best_std, samples_I, samples_II,
            trainer.history, trainer.monitor.converged_at, trainer.epoch,
            trainer.discriminator_scores(), metrics, timing, baselines, proc, notes, summ_ee,
            None if rec.std is None or rec.refine_result is None else rec.refine_result.cov)
        return self

    def _output_error_phase(self, trainer: SivaTrainer, settings: SivaSettings,
                            anchor: np.ndarray, train: Sequence[Recording],
                            val: Sequence[Recording], proc: Processing, notes: list[str]) -> None:
        """Continue training on the output error linearised at ``anchor`` until converged,
        then harvest the Approach II ensemble (see linearized.py)."""
        from .linearized import linearize

        st = self.structure
        try:
            lin_tr = linearize(st, anchor, train, proc, n_noise=settings.oe_noise,
                               seed=settings.seed)
            lin_va = linearize(st, anchor, val, proc) if val else None
        except ValueError as exc:
            notes.append(f"output-error phase skipped ({exc}); Approach II is equation error")
            return
        trainer.use_output_error(lin_tr, lin_va)
        start = trainer.epoch
        limit = start + max(settings.oe_min_epochs + 4 * settings.oe_conv_window,
                            settings.max_epochs // 2) + settings.oe_ensemble_epochs
        eta = Eta(limit, start=start)  # an upper bound again
        import copy

        good = copy.deepcopy(trainer.generator.state_dict())
        while trainer.epoch < limit:
            log = trainer.run_epoch()
            if not (np.all(np.isfinite(log.theta)) and np.isfinite(log.loss_mse)):
                # the linearised output error is flat along a direction the records do not
                # determine; the generator ran off along it.  Keep the last finite state.
                trainer.generator.load_state_dict(good)
                trainer.ensemble.drop_nonfinite()
                notes.append(f"output-error phase stopped at epoch {log.epoch}: the generator "
                             "left the finite range (the records do not determine every "
                             "parameter); Approach I/II are from the last finite epoch")
                break
            good = copy.deepcopy(trainer.generator.state_dict())
            if self.progress and (log.epoch % self.progress_every == 0):
                rel = ", ".join(f"{p}={v:.5g}" for p, v in zip(st.free, log.theta))
                self._say(f"{eta.text(log.epoch + 1)}  [output error]  D={log.loss_d:.4f}  "
                          f"fit={log.loss_mse:.3e}  {'converged ' if log.converged else ''}{rel}")
            if trainer.converged and len(trainer.ensemble) >= settings.oe_ensemble_epochs:
                break
        if not trainer.converged:
            notes.append("output-error phase not converged: Approach II uses its last epochs")

    def _rerefine(self, best: np.ndarray, mean_II: np.ndarray, train: Sequence[Recording],
                  val: Sequence[Recording], proc: Processing) -> "Recommendation | None":
        """``recommend_best`` (fitted on the training records) from Approach II's mean, kept
        when it simulates training *and* validation records better than ``best``: the
        paper's Approach III selects "using identification data, validation data, or
        both": one training record can hold a wrong basin that the validation records
        expose (None otherwise)."""
        from .refine import force_profiled_output_error, output_error

        # (Approach II's mean itself is not compared: its force scales were profiled out)
        recs = [*train, *val]
        if not np.all(np.isfinite(mean_II)):
            return None
        rec = recommend_best(self.structure, mean_II[None], train, proc)
        if not rec.refined:
            return None
        # with fitted force scales, each candidate is judged with its own per record (the
        # refinement's cost); plain output error would favour a basin that absorbs the
        # force's error
        scaled = rec.refine_result is not None and rec.refine_result.force_scale is not None
        judge = force_profiled_output_error if scaled else output_error
        kw = ({"fit_spread": rec.refine_result.force_spread is not None} if scaled else {})
        cost = judge(self.structure, np.stack([best, rec.theta]), recs, proc, **kw)
        return rec if np.isfinite(cost[1]) and cost[1] < 0.999 * cost[0] else None

    def _baselines(self, timing: dict[str, float]) -> dict[str, dict[str, float]]:
        from . import baselines as bl

        out: dict[str, dict[str, float]] = {}
        for name in ("least_squares", "sindy"):
            t0 = time.perf_counter()
            try:
                out[name] = getattr(bl, name)(self.structure, self.train_states_)
            except Exception as exc:  # noqa: BLE001 - a failed baseline must not sink the run
                self._say(f"baseline {name} failed: {exc}")
                continue
            timing[f"baseline_{name}"] = time.perf_counter() - t0
        return out

    def _metrics(self, ests: dict[str, np.ndarray], train: Sequence[Recording],
                 val: Sequence[Recording], proc: Processing) -> dict[str, Any]:
        from .refine import displacement_mse, output_error

        names = list(ests)
        thetas = np.stack([ests[n] for n in names])
        out: dict[str, Any] = {"units": {"disp_mse_mm2": "mm^2", "output_error": "normalised MSE"}}
        for split, recs in (("train", train), ("validation", val)):
            if not recs:
                continue
            mse = displacement_mse(self.structure, thetas, recs, proc)
            oe = output_error(self.structure, thetas, recs, proc)
            out[split] = {n: {"disp_mse_mm2": float(m * 1e6), "output_error": float(o)}
                          for n, m, o in zip(names, mse, oe)}
        return out
