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
from dataclasses import asdict
from typing import Any, Iterator, Sequence

import numpy as np
import torch
import torch.nn.functional as F

from ..convergence import ConvergenceMonitor
from ..ensemble import Ensemble
from ..linearized import Linearization
from ..networks import Discriminator, ParameterGenerator
from ..optim import FastAdam
from ..processing import States
from ..structure import Structure
from .initial_guess import least_squares_guess, reference
from .output_error_phase import OutputErrorPhase
from .pools import Pool
from .scores import equation_error_scores, output_error_scores
from .settings import EpochLog, SivaSettings


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
        self.train: Pool | None = None
        self.val: Pool | None = None
        self._scale: dict[str, torch.Tensor] = {}
        self.oe: OutputErrorPhase | None = None

    # ------------------------------------------------------------------ data
    def set_data(self, train: Sequence[States], val: Sequence[States]) -> None:
        """Use these records from now on; networks and optimiser state are kept."""
        if not train:
            raise ValueError("SIVA needs at least one training record")
        self.train = Pool.of(train, self.structure)
        self.val = Pool.of(val, self.structure) if val else None
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
        values, exps = reference(s, guess, self.settings.init)
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
            # D: real validation accelerations vs the model's at the same states; the
            # generator: fool the updated D on validation, match training accelerations (eq. 4)
            fake_val = bv.model_acc(st, theta)
            loss_d, loss_adv = self._adversarial_step(self._real_features[bv.idx],
                                                      self._features(bv.q, bv.v, fake_val))
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
            self.oe = OutputErrorPhase.of(train, val, self.epoch)
            if not hasattr(self, "oe_targets_"):
                self.oe_targets_ = []
            return
        s = self.settings
        step = train.step_matrix()
        self.generator.set_local(torch.from_numpy(train.theta), torch.from_numpy(step),
                                 torch.from_numpy(train.is_log))
        self.opt_g = FastAdam(self.generator.parameters(), lr=s.oe_lr, foreach=True)
        self.opt_d = FastAdam(self.discriminator.parameters(), lr=s.oe_lr, foreach=True)
        self.oe = OutputErrorPhase.of(train, val, self.epoch)
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
                loss_d, loss_adv = self._adversarial_step(ph.val.features(idx, None),
                                                          ph.val.features(idx, x))
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

    def _adversarial_step(self, real: torch.Tensor, fake: torch.Tensor
                          ) -> tuple[torch.Tensor, torch.Tensor]:
        """D's step on ``real`` vs ``fake`` features (paper eq. 2), then the generator's
        adversarial loss on ``fake`` against the updated D, its weights frozen (eq. 4):
        (loss_d, loss_adv)."""
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
        return loss_d, bce(logit, self._label(logit, 1.0))

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
        return equation_error_scores(self.discriminator, self.structure, pool, theta,
                                     self._features, n_eval)

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
        return output_error_scores(self.discriminator, ph, theta, n_eval)

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
