"""SIVA training: the adversarial loop of paper Sec. 2.4, one epoch at a time.

``SivaTrainer`` is the stateful engine behind both ``Siva.fit`` (train until converged,
then harvest Approach II) and the service (train forever as records arrive).  Choices
where the paper is vague, each measured in ``benchmarks/bench_siva_choices.py``:

* Discriminator input: a *(state, acceleration)* sample of a validation record,
  ``[q/sq, v/sv, a/sa]`` per DOF.  Real: the measured acceleration; fake: the model's
  acceleration at the same measured state.  A discriminator on accelerations alone
  compares only their histograms, which a wrong model can match; conditioned on the state
  it judges the equation of motion itself.  (``disc_input="acc"`` gives the other choice.)
* MSE on accelerations normalised per DOF by the training RMS, so gamma means the same
  for any units; gamma = 10 by default (the MSE term drives identification, the
  adversarial term validates and regularises).
* One epoch = ceil(N_train / batch) steps; each step draws ``batch`` training samples,
  ``batch`` validation samples and ``batch`` noise vectors (one parameter set per sample).
* The per-epoch sample for Approach II is the mean generator output over the epoch's
  last batch.
* Learning rate: the paper's 1e-4 throughout (``paper()``), or 1e-3 until convergence
  and 1e-4 for the Approach II harvest (``fast()``): 10x fewer epochs to converge, the
  same small per-epoch jitter afterwards; the harvest starts ``ensemble_burn_in`` epochs
  after the switch, once the optimiser has settled at the smaller step.
* Initialisation: the exponent e0 of each parameter from its scale hint, else from the
  order of magnitude of an equation-error least-squares guess; mantissa starts at 1
  (``init="magnitude"``).  ``init="ls"`` starts at the least-squares value itself.
"""
from __future__ import annotations

import contextlib
import copy
import math
from dataclasses import asdict, dataclass, field
from typing import Any, Iterator, Sequence

import numpy as np
import torch
import torch.nn.functional as F

from .convergence import ConvergenceMonitor
from .ensemble import Ensemble
from .linearized import Linearization
from .networks import LN4, Discriminator, ParameterGenerator
from .optim import FastAdam
from .processing import States
from .structure import Structure


@dataclass
class SivaSettings:
    """Hyper-parameters; ``paper()`` gives the paper's defaults."""

    batch_size: int = 300
    lr: float = 1e-4
    lr_d: float | None = None  # discriminator learning rate (None: same as lr)
    lr_converged: float | None = None  # learning rate once converged (None: unchanged)
    gamma: float = 10.0
    latent_dim: int = 16
    seed: int = 42
    disc_input: str = "state_acc"  # or "acc"
    scientific: bool = True
    init: str = "magnitude"  # or "ls" or "scale"
    max_epochs: int = 1000
    ensemble_epochs: int = 200  # Approach II samples harvested after convergence
    ensemble_burn_in: int = 0  # epochs skipped after convergence before harvesting
    ensemble_maxlen: int | None = 400  # running-ensemble bound for the service
    conv_window: int = 20
    conv_rel_tol: float = 2e-3
    conv_min_epochs: int = 40
    steps_per_epoch: int | None = None  # None: ceil(N_train / batch_size)
    threads: int = 1
    # output-error phase (``use_output_error``): see linearized.py and docs/method.md
    fit_target: str = "output"  # "output": equation error, then the output-error phase;
    #                             "equation": the paper's equation error only
    oe_lr: float = 0.05          # generator/discriminator step in the output-error phase
    oe_steps: int = 25           # steps per epoch in that phase
    oe_batch: int = 64           # parameter sets (and validation samples) per step
    oe_min_epochs: int = 20      # epochs before its convergence is judged
    oe_conv_window: int = 10     # its convergence window: the generator starts at the
    #                              anchor, already near the optimum (docs/perf.md)
    oe_noise: int = 64           # parametric-bootstrap replicates drawn from per epoch
    oe_burn_in: int = 5          # output-error epochs skipped after its convergence (its
    #                              step does not change at convergence, unlike phase 1's)
    oe_ensemble_epochs: int = 100  # Approach II samples harvested in that phase (``Siva``)
    # with the output-error phase to follow (``Siva.fit``), the equation-error phase only
    # has to reach the basin and supply Approach III's candidates (the anchor; the
    # reported Approach II is the later phase's): it is judged converged at a looser
    # tolerance, keeps its step and harvests a few epochs (docs/perf.md)
    handover_epochs: int = 30
    handover_rel_tol: float = 2e-2
    handover_steps: int = 16     # at most this many steps per epoch in that phase

    @classmethod
    def paper(cls, **kw: Any) -> "SivaSettings":
        """The paper: Adam 1e-4, batch 300, seed 42, 1000 epochs, Approach II from epoch 400."""
        base = dict(batch_size=300, lr=1e-4, seed=42, max_epochs=1000, ensemble_epochs=600,
                    conv_min_epochs=400, fit_target="equation")
        base.update(kw)
        return cls(**base)

    @classmethod
    def fast(cls, **kw: Any) -> "SivaSettings":
        """Defaults of this project: the paper's networks and optimiser, a larger learning
        rate, automatic convergence and a shorter Approach II harvest."""
        base = dict(lr=1e-3, lr_converged=1e-4, max_epochs=600, ensemble_epochs=150,
                    ensemble_burn_in=25)
        base.update(kw)
        return cls(**base)


@dataclass
class EpochLog:
    epoch: int
    loss_d: float
    loss_adv: float
    loss_mse: float
    theta: np.ndarray
    converged: bool


@dataclass
class _Pool:
    """Samples of several records stacked as torch tensors, with per-record offsets.

    For a model linear in every free parameter the acceleration is ``a0 + phi @ theta``
    per sample; ``phi`` and ``a0`` are precomputed once so a training step costs one
    small product instead of a walk over the elements (3-4x faster per step).
    """

    q: torch.Tensor
    v: torch.Tensor
    a: torch.Tensor
    f: torch.Tensor
    names: list[str]
    bounds: list[tuple[int, int]] = field(default_factory=list)
    phi: torch.Tensor | None = None  # (N, n_dof, n_free)
    a0: torch.Tensor | None = None  # (N, n_dof)

    @classmethod
    def of(cls, states: Sequence[States], structure: Structure) -> "_Pool":
        cat = lambda attr: torch.from_numpy(np.concatenate([getattr(s, attr) for s in states]))
        bounds, start = [], 0
        for s in states:
            bounds.append((start, start + len(s)))
            start += len(s)
        pool = cls(cat("q"), cat("v"), cat("a"), cat("f"), [s.name for s in states], bounds)
        free = structure.free
        if set(structure.linear_parameters()) == set(free):
            zero = torch.zeros(len(free), dtype=torch.float64)
            pool.a0 = structure.accelerations(zero, pool.q, pool.v, pool.f)
            cols = []
            for k in range(len(free)):
                unit = zero.clone()
                unit[k] = 1.0
                cols.append(structure.accelerations(unit, pool.q, pool.v, pool.f) - pool.a0)
            pool.phi = torch.stack(cols, dim=-1)
        return pool

    def __len__(self) -> int:
        return self.q.shape[0]

    def draw(self, n: int, rng: torch.Generator) -> "_Batch":
        idx = torch.randint(0, len(self), (n,), generator=rng)
        return _Batch(self.q[idx], self.v[idx], self.a[idx], self.f[idx],
                      None if self.phi is None else self.phi[idx],
                      None if self.a0 is None else self.a0[idx], idx)


@dataclass
class _Batch:
    q: torch.Tensor
    v: torch.Tensor
    a: torch.Tensor
    f: torch.Tensor
    phi: torch.Tensor | None
    a0: torch.Tensor | None
    idx: torch.Tensor | None = None  # the samples' rows in their pool

    def model_acc(self, structure: Structure, theta: torch.Tensor) -> torch.Tensor:
        """Model accelerations at this batch's states, one parameter set per sample."""
        if self.phi is not None:
            return self.a0 + (self.phi * theta[:, None, :]).sum(-1)
        return structure.accelerations(theta, self.q, self.v, self.f)


class _ValidationSurrogate:
    """D's view of the validation records in the output-error phase: real = the processed
    measured quantities, fake = the linearised processed simulation at the generator's x,
    both next to the measured processed state (as in the equation-error phase)."""

    def __init__(self, lin: Linearization) -> None:
        ys, r0s, js, qs, vs = [], [], [], [], []
        n = lin.J.shape[1]
        for k, ser in enumerate(lin.series):
            sl = slice(ser.start, ser.start + ser.T * ser.width)
            w = lin.weight[k]
            ys.append(lin.targets[k])
            r0s.append(lin.r[sl].reshape(ser.T, ser.width) / w)
            js.append(lin.J[sl].reshape(ser.T, ser.width, n) / w[None, :, None])
            qs.append(lin.states[k].q)
            vs.append(lin.states[k].v)
        cat = lambda xs: torch.from_numpy(np.ascontiguousarray(np.concatenate(xs)))
        self.y, self.r0, self.J, self.q, self.v = (cat(x) for x in (ys, r0s, js, qs, vs))
        rms = lambda x: x.pow(2).mean(0).sqrt().clamp_min(1e-12)
        self.sy, self.sq, self.sv = rms(self.y), rms(self.q), rms(self.v)
        self.n = self.y.shape[0]
        self.names = [r.name for r in lin.records]
        # the real features of every sample (elementwise, so indexing them is bit-identical
        # to computing them for the drawn rows)
        self.real = torch.cat([self.q / self.sq, self.v / self.sv, self.y / self.sy], -1).float()
        edges = np.cumsum([0] + [ser.T for ser in lin.series])
        self.bounds = list(zip(edges[:-1].tolist(), edges[1:].tolist()))

    def features(self, idx: torch.Tensor, x: torch.Tensor | None) -> torch.Tensor:
        if x is None:
            return self.real[idx]
        y = self.y[idx]
        if x is not None:
            y = y + self.r0[idx] + (self.J[idx] * x[:, None, :]).sum(-1)
        return torch.cat([self.q[idx] / self.sq, self.v[idx] / self.sv, y / self.sy], -1).float()


@dataclass
class _OutputErrorPhase:
    lin: Linearization
    A: torch.Tensor          # J^T J
    Jt: torch.Tensor         # J^T
    g0: torch.Tensor         # J^T r
    s2: float                # residual variance per row at the anchor (chi^2 scale)
    noise: torch.Tensor | None
    val: _ValidationSurrogate | None
    start_epoch: int
    is_log: torch.Tensor
    theta: torch.Tensor
    scale: torch.Tensor

    @classmethod
    def of(cls, train: Linearization, val: Linearization | None, epoch: int) -> "_OutputErrorPhase":
        J = torch.from_numpy(train.J)
        r = torch.from_numpy(train.r)
        dof = max(1, train.r.size - train.J.shape[1])
        noise = torch.from_numpy(train.noise) if train.noise.size else None
        return cls(train, J.T @ J, J.T.contiguous(), J.T @ r, max(train.cost / dof, 1e-300),
                   noise, _ValidationSurrogate(val) if val is not None else None, epoch,
                   torch.from_numpy(train.is_log), torch.from_numpy(train.theta),
                   torch.from_numpy(train.scale))

    def to_x(self, theta: torch.Tensor) -> torch.Tensor:
        ratio = (theta / self.theta).clamp_min(1e-12)
        return torch.where(self.is_log, torch.log(ratio), (theta - self.theta) / self.scale)


class SivaTrainer:
    """The SIVA adversarial loop, resumable and warm-startable (``set_data`` any time)."""

    def __init__(self, structure: Structure, settings: SivaSettings | None = None) -> None:
        self.structure = structure
        self.settings = settings or SivaSettings.fast()
        s = self.settings
        n = len(structure.free)
        if n == 0:
            raise ValueError("the model has no free parameters to identify")
        torch.set_num_threads(max(1, s.threads))
        with torch.random.fork_rng():
            torch.manual_seed(s.seed)
            self.generator = ParameterGenerator(n, s.latent_dim, scientific=s.scientific)
            n_in = structure.n_dof * (3 if s.disc_input == "state_acc" else 1)
            self.discriminator = Discriminator(n_in)
        self.opt_g = FastAdam(self.generator.parameters(), lr=s.lr, foreach=True)
        self.opt_d = FastAdam(self.discriminator.parameters(), lr=s.lr_d or s.lr,
                                      foreach=True)
        self.rng = torch.Generator().manual_seed(s.seed)
        self.epoch = 0
        self.initialised = False
        self.history: dict[str, list] = {"loss_d": [], "loss_adv": [], "loss_mse": [], "theta": []}
        self.monitor = ConvergenceMonitor(window=s.conv_window, rel_tol=s.conv_rel_tol,
                                          min_epochs=s.conv_min_epochs)
        self.ensemble = Ensemble(maxlen=s.ensemble_maxlen)
        self.train: _Pool | None = None
        self.val: _Pool | None = None
        self._scale: dict[str, torch.Tensor] = {}
        self.oe: _OutputErrorPhase | None = None

    # ------------------------------------------------------------------ data
    def set_data(self, train: Sequence[States], val: Sequence[States]) -> None:
        """Use these records from now on; networks and optimiser state are kept."""
        if not train:
            raise ValueError("SIVA needs at least one training record")
        self.train = _Pool.of(train, self.structure)
        self.val = _Pool.of(val, self.structure) if val else None
        ref = self.train
        rms = lambda x: x.pow(2).mean(0).sqrt().clamp_min(1e-12)
        self._scale = {"q": rms(ref.q), "v": rms(ref.v), "a": rms(ref.a)}
        # D's "real" input for every sample of the pool it is drawn from, computed once
        # (elementwise: each row is what _features gives for a drawn batch, bit for bit)
        pool = self.val if self.val is not None else self.train
        self._real_features = self._features(pool.q, pool.v, pool.a)
        if not self.initialised:
            self._initialise(train)

    def _initialise(self, train: Sequence[States]) -> None:
        s = self.structure
        guess = least_squares_guess(s, train)
        hints = s.scales()
        values = torch.ones(len(s.free), dtype=torch.float64)
        exps = torch.zeros(len(s.free), dtype=torch.float64)
        for k, p in enumerate(s.free):
            g = guess.get(p)
            mag = hints[p] if hints[p] is not None else (abs(g) if g and math.isfinite(g) else 1.0)
            exps[k] = math.floor(math.log10(mag))
            if self.settings.init == "ls" and g is not None and math.isfinite(g):
                values[k] = g
            else:
                values[k] = 10.0 ** exps[k]
        self.generator.set_reference(values, exps)
        self.initial_guess_ = guess
        self.initialised = True

    # ------------------------------------------------------------------ features
    def _features(self, q: torch.Tensor, v: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
        sa = a / self._scale["a"]
        if self.settings.disc_input == "acc":
            return sa.float()
        return torch.cat([q / self._scale["q"], v / self._scale["v"], sa], dim=-1).float()

    def _noise(self, n: int) -> torch.Tensor:
        return torch.randn(n, self.settings.latent_dim, generator=self.rng)

    # ------------------------------------------------------------------ training
    def run_epoch(self) -> EpochLog:
        """One epoch of alternating D and P updates (paper eqs. 2 and 4)."""
        # numba's OpenMP layer (the batched simulation) resets the OpenMP thread count of
        # the calling thread; tiny torch ops then wait on a second spinning thread (a
        # 64-sample BCE took 5 ms instead of 7 us): restore ours before every epoch
        want = max(1, self.settings.threads)
        if torch.get_num_threads() != want:
            torch.set_num_threads(want)
        if self.oe is not None:
            return self._run_epoch_output_error()
        if self.train is None:
            raise RuntimeError("set_data() first")
        s = self.settings
        B = s.batch_size
        steps = s.steps_per_epoch or max(1, math.ceil(len(self.train) / B))
        val = self.val if self.val is not None else self.train
        sa = self._scale["a"]
        st = self.structure
        sums = np.zeros(3)
        theta = None
        for _ in range(steps):
            bt = self.train.draw(B, self.rng)
            bv = val.draw(B, self.rng)
            theta = self.generator(self._noise(B))
            # discriminator step: real validation accelerations vs the model's at the same states
            fake_val = bv.model_acc(st, theta)
            real_logit = self.discriminator(self._real_features[bv.idx])
            fake_logit = self.discriminator(self._features(bv.q, bv.v, fake_val.detach()))
            bce = F.binary_cross_entropy_with_logits
            loss_d = (bce(real_logit, self._label(real_logit, 1.0))
                      + bce(fake_logit, self._label(fake_logit, 0.0)))
            self.opt_d.zero_grad(set_to_none=True)
            loss_d.backward()
            self.opt_d.step()
            # generator step: fool the updated D on validation, match training accelerations (eq. 4)
            with self._d_frozen():
                logit = self.discriminator(self._features(bv.q, bv.v, fake_val))
            loss_adv = F.binary_cross_entropy_with_logits(logit, self._label(logit, 1.0))
            loss_mse = ((bt.model_acc(st, theta) - bt.a) / sa).pow(2).mean()
            loss_p = loss_adv + s.gamma * loss_mse
            self.opt_g.zero_grad(set_to_none=True)
            loss_p.backward()
            self.opt_g.step()
            sums += (loss_d.item(), loss_adv.item(), loss_mse.item())
        sums /= steps
        theta_epoch = theta.detach().mean(0).numpy()
        e, conv, harvested = self._end_epoch(sums, theta_epoch)
        if conv and not harvested and s.lr_converged is not None:
            self._set_lr(s.lr_converged)
        return EpochLog(e, float(sums[0]), float(sums[1]), float(sums[2]), theta_epoch, conv)

    def _end_epoch(self, sums: np.ndarray, theta_epoch: np.ndarray) -> tuple[int, bool, bool]:
        """Log the epoch and update convergence and the Approach II harvest; returns
        (epoch index, converged, whether this epoch's sample was harvested)."""
        e = self.epoch
        self.epoch += 1
        h = self.history
        for key, value in zip(("loss_d", "loss_adv", "loss_mse"), sums):
            h[key].append(float(value))
        h["theta"].append(theta_epoch)
        was = self.monitor.converged
        conv = self.monitor.update(e, theta_epoch)
        s = self.settings
        burn_in = s.oe_burn_in if self.oe is not None else s.ensemble_burn_in
        harvested = bool(conv and was and e > self.monitor.converged_at + burn_in)
        if harvested:
            self.ensemble.add(theta_epoch, e)
        return e, conv, harvested

    # ------------------------------------------------------------------ output-error phase
    def use_output_error(self, train: Linearization, val: Linearization | None = None, *,
                         resume: bool = False) -> None:
        """Judge the generator from now on by the output error linearised at ``train.theta``
        (chain-consistent: see linearized.py).  The generator switches to local coordinates
        around the anchor (one unit = one standard error), the convergence monitor and the
        Approach II ensemble restart (equation-error samples are biased), and each epoch
        fits the anchor's residuals plus one parametric-bootstrap noise replicate.

        ``resume=True``: a trainer restored by ``load_state_dict`` from a checkpoint taken in
        this phase gets the same linearisation back and nothing else changes (networks,
        optimisers, monitor and ensemble are the checkpoint's): training continues exactly."""
        if resume:
            self.oe = _OutputErrorPhase.of(train, val, self.epoch)
            if not hasattr(self, "oe_targets_"):
                self.oe_targets_ = []
            return
        s = self.settings
        step = train.step_matrix()
        self.generator.set_local(torch.from_numpy(train.theta), torch.from_numpy(step),
                                 torch.from_numpy(train.is_log))
        self.opt_g = FastAdam(self.generator.parameters(), lr=s.oe_lr, foreach=True)
        self.opt_d = FastAdam(self.discriminator.parameters(), lr=s.oe_lr, foreach=True)
        self.oe = _OutputErrorPhase.of(train, val, self.epoch)
        self.monitor = ConvergenceMonitor(window=s.oe_conv_window, rel_tol=s.conv_rel_tol,
                                          min_epochs=self.epoch + s.oe_min_epochs)
        self.ensemble.reset()
        self.oe_targets_: list[np.ndarray] = []

    def _run_epoch_output_error(self) -> EpochLog:
        s = self.settings
        ph = self.oe
        assert ph is not None
        B = s.oe_batch
        harvesting = self.monitor.converged
        e = None
        if harvesting and ph.noise is not None and len(ph.noise):
            e = ph.noise[int(torch.randint(0, len(ph.noise), (1,), generator=self.rng))]
        g = ph.g0 if e is None else ph.g0 + ph.Jt @ e
        sums = np.zeros(3)
        theta = None
        for _ in range(s.oe_steps):
            theta = self.generator(self._noise(B))
            x = ph.to_x(theta)
            # chi^2-scaled: one standard error away from the epoch's optimum costs ~1
            loss_fit = (((x @ ph.A) * x).sum(-1) + 2 * (x @ g)).mean() / ph.s2
            loss_d = torch.zeros(())
            loss_adv = torch.zeros(())
            if ph.val is not None:
                idx = torch.randint(0, ph.val.n, (B,), generator=self.rng)
                real = ph.val.features(idx, None)
                fake = ph.val.features(idx, x)
                real_logit = self.discriminator(real)
                fake_logit = self.discriminator(fake.detach())
                bce = F.binary_cross_entropy_with_logits
                loss_d = (bce(real_logit, self._label(real_logit, 1.0))
                          + bce(fake_logit, self._label(fake_logit, 0.0)))
                self.opt_d.zero_grad(set_to_none=True)
                loss_d.backward()
                self.opt_d.step()
                with self._d_frozen():
                    logit = self.discriminator(fake)
                loss_adv = F.binary_cross_entropy_with_logits(logit, self._label(logit, 1.0))
            loss_p = loss_adv + s.gamma * loss_fit
            self.opt_g.zero_grad(set_to_none=True)
            loss_p.backward()
            self.opt_g.step()
            sums += (loss_d.item(), loss_adv.item(), loss_fit.item())
        sums /= s.oe_steps
        theta_epoch = theta.detach().mean(0).numpy()
        # the epoch's own optimum (closed form), to measure how well the generator tracks it
        target = -np.linalg.solve(ph.A.numpy(), g.numpy())
        e, conv, harvested = self._end_epoch(sums, theta_epoch)
        if harvested:
            self.oe_targets_.append(ph.lin.to_theta(target))
        return EpochLog(e, float(sums[0]), float(sums[1]), float(sums[2]), theta_epoch, conv)

    def _label(self, logit: torch.Tensor, value: float) -> torch.Tensor:
        """A constant BCE target like ``logit`` (reused: the same few shapes every step;
        nothing writes to it)."""
        key = (tuple(logit.shape), logit.dtype, value)
        labels = self.__dict__.setdefault("_labels", {})
        t = labels.get(key)
        if t is None:
            t = labels[key] = torch.full_like(logit, value)
        return t

    @contextlib.contextmanager
    def _d_frozen(self) -> Iterator[None]:
        """D's weights as constants while building the generator's loss: its backward pass
        then computes only the gradient the generator needs (the weights' gradients were
        discarded by D's next ``zero_grad`` anyway; the generator's are bit-identical)."""
        d = self.discriminator
        cached = self.__dict__.get("_d_params")
        if cached is None or cached[0] is not d:  # parameters() walks the modules: ~50 us
            cached = self._d_params = (d, list(d.parameters()))
        params = [p for p in cached[1] if p.requires_grad]
        for p in params:
            p.requires_grad_(False)
        try:
            yield
        finally:
            for p in params:
                p.requires_grad_(True)

    def _set_lr(self, lr: float) -> None:
        for opt in (self.opt_g, self.opt_d):
            for group in opt.param_groups:
                group["lr"] = lr

    @property
    def converged(self) -> bool:
        return self.monitor.converged

    # ------------------------------------------------------------------ read-outs
    @torch.no_grad()
    def sample(self, n: int = 1000, seed: int | None = None) -> np.ndarray:
        """Approach I: n parameter sets from the trained generator, (n, n_free)."""
        g = torch.Generator().manual_seed(self.settings.seed if seed is None else seed)
        z = torch.randn(n, self.settings.latent_dim, generator=g)
        return self.generator(z).numpy()

    @torch.no_grad()
    def discriminator_scores(self, n_eval: int = 2000) -> dict[str, Any]:
        """D on each validation record: mean D(real), D(fake) and the BCE loss vs ln 4
        (plus, in the output-error phase, D's AUC separating real from simulated)."""
        if self.oe is not None:
            return self._discriminator_scores_output_error(n_eval)
        pool = self.val if self.val is not None else self.train
        if pool is None:
            return {}
        # the generator's central estimate: mean over a fixed noise batch
        theta = torch.from_numpy(self.sample(256, seed=self.settings.seed + 1).mean(0))
        records: dict[str, dict[str, float]] = {}
        tot_real, tot_fake, count = 0.0, 0.0, 0
        for name, (i0, i1) in zip(pool.names, pool.bounds):
            step = max(1, (i1 - i0) // n_eval)
            sl = slice(i0, i1, step)
            q, v, a, f = pool.q[sl], pool.v[sl], pool.a[sl], pool.f[sl]
            fake = self.structure.accelerations(theta, q, v, f)
            pr = self.discriminator.prob(self._features(q, v, a)).clamp(1e-7, 1 - 1e-7)
            pf = self.discriminator.prob(self._features(q, v, fake)).clamp(1e-7, 1 - 1e-7)
            lr_, lf_ = -pr.log().mean().item(), -(1 - pf).log().mean().item()
            records[name] = {"d_real": pr.mean().item(), "d_fake": pf.mean().item(),
                             "loss_d": lr_ + lf_}
            tot_real += lr_ * len(pr)
            tot_fake += lf_ * len(pf)
            count += len(pr)
        loss_d = (tot_real + tot_fake) / max(count, 1)
        return {"loss_d": loss_d, "ln4": LN4, "ln4_distance": abs(loss_d - LN4), "records": records}

    # ------------------------------------------------------------------ checkpoint
    def state_dict(self) -> dict[str, Any]:
        """An independent snapshot (deep copy: live tensors would change under it)."""
        return copy.deepcopy({"settings": asdict(self.settings), "epoch": self.epoch, "initialised": self.initialised,
                "generator": self.generator.state_dict(), "discriminator": self.discriminator.state_dict(),
                "opt_g": self.opt_g.state_dict(), "opt_d": self.opt_d.state_dict(),
                "rng": self.rng.get_state(), "monitor": self.monitor.state_dict(),
                "ensemble": self.ensemble.state_dict(),
                "history": {k: [np.asarray(x).tolist() for x in v] for k, v in self.history.items()},
                "initial_guess": getattr(self, "initial_guess_", {})})

    @torch.no_grad()
    def _discriminator_scores_output_error(self, n_eval: int) -> dict[str, Any]:
        ph = self.oe
        assert ph is not None
        if ph.val is None:
            return {}
        theta = torch.from_numpy(self.sample(256, seed=self.settings.seed + 1).mean(0))
        x = ph.to_x(theta[None])
        records: dict[str, dict[str, float]] = {}
        prs, pfs = [], []
        for name, (i0, i1) in zip(ph.val.names, ph.val.bounds):
            idx = torch.arange(i0, i1, max(1, (i1 - i0) // n_eval))
            pr = self.discriminator.prob(ph.val.features(idx, None)).clamp(1e-7, 1 - 1e-7)
            pf = self.discriminator.prob(ph.val.features(idx, x.expand(len(idx), -1))
                                         ).clamp(1e-7, 1 - 1e-7)
            records[name] = {"d_real": float(pr.mean()), "d_fake": float(pf.mean()),
                             "loss_d": float(-pr.log().mean() - (1 - pf).log().mean())}
            prs.append(pr)
            pfs.append(pf)
        pr, pf = torch.cat(prs), torch.cat(pfs)
        loss_d = float(-pr.log().mean() - (1 - pf).log().mean())
        # AUC = P(D(real) > D(fake)) (Mann-Whitney): 0.5 = indistinguishable
        both = torch.cat([pr, pf]).numpy()
        ranks = np.argsort(np.argsort(both)) + 1.0
        n1 = len(pr)
        auc = float((ranks[:n1].sum() - n1 * (n1 + 1) / 2) / (n1 * len(pf)))
        return {"loss_d": loss_d, "ln4": LN4, "ln4_distance": abs(loss_d - LN4),
                "d_real": float(pr.mean()), "d_fake": float(pf.mean()), "auc": auc,
                "target": "output", "records": records}

    def load_state_dict(self, d: dict[str, Any]) -> None:
        self.epoch = d["epoch"]
        self.initialised = d["initialised"]
        gen = d["generator"]
        if gen.get("anchor") is not None and gen["anchor"].numel() > 0:
            # saved in local coordinates: size the buffers before loading them
            n = self.generator.n_params
            self.generator.set_local(torch.zeros(n), torch.eye(n), torch.zeros(n, dtype=torch.bool))
        self.generator.load_state_dict(gen)
        self.discriminator.load_state_dict(d["discriminator"])
        self.opt_g.load_state_dict(d["opt_g"])
        self.opt_d.load_state_dict(d["opt_d"])
        self.rng.set_state(d["rng"])
        self.monitor.load_state_dict(d["monitor"])
        self.ensemble.load_state_dict(d["ensemble"])
        self.history = {k: list(v) for k, v in d["history"].items()}
        self.history["theta"] = [np.asarray(t) for t in self.history["theta"]]
        self.initial_guess_ = d.get("initial_guess", {})


def least_squares_guess(structure: Structure, states: Sequence[States]) -> dict[str, float]:
    """Equation-error least squares for the linear parameters (nonlinear ones at their
    scale hint or 1): a first guess for orders of magnitude, not an estimate."""
    free = structure.free
    lin = structure.linear_parameters()
    base = np.array([structure.parameters[p].scale or 1.0 for p in free])
    rows, rhs = [], []
    for st in states:
        step = max(1, len(st) // 5000)
        q, v, a, f = st.q[::step], st.v[::step], st.a[::step], st.f[::step]
        th0 = base.copy()
        th0[[free.index(p) for p in lin]] = 0.0
        a0 = structure.accelerations(th0, q, v, f)
        cols = []
        for p in lin:
            th = th0.copy()
            th[free.index(p)] = 1.0
            cols.append((structure.accelerations(th, q, v, f) - a0).reshape(-1))
        if not cols:
            return {}
        w = 1.0 / np.maximum(np.sqrt((a ** 2).mean(0)), 1e-12)
        rows.append(np.stack(cols, axis=1) * np.tile(w, len(q))[:, None])
        rhs.append(((a - a0) * w).reshape(-1))
    A, b = np.concatenate(rows), np.concatenate(rhs)
    norm = np.maximum(np.linalg.norm(A, axis=0), 1e-300)
    sol = np.linalg.lstsq(A / norm, b, rcond=None)[0] / norm
    out = {p: float(base[free.index(p)]) for p in free if p not in lin}
    out.update({p: float(x) for p, x in zip(lin, sol)})
    return out
