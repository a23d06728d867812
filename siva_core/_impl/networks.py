"""The paper's two networks (Sec. 2.3): parameter generator P and discriminator D."""
from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

SLOPE = 0.2  # LeakyReLU negative slope (paper)


def _run(layers: nn.Sequential, x: torch.Tensor) -> torch.Tensor:
    """``layers(x)`` for a stack of Linear and LeakyReLU, calling the functional ops
    directly: the same operations (bit-identical), without ``nn.Module.__call__``'s
    per-layer dispatch, which costs more than these tiny layers' arithmetic over the
    ~10^4 steps of a fit (module hooks on the inner layers are therefore not called)."""
    for layer in layers:
        if type(layer) is nn.Linear:
            x = F.linear(x, layer.weight, layer.bias)
        elif type(layer) is nn.LeakyReLU:
            x = F.leaky_relu(x, layer.negative_slope, layer.inplace)
        else:
            x = layer(x)
    return x


class ParameterGenerator(nn.Module):
    """Noise z -> physical parameters, 64 -> 32 -> 16 -> out, LeakyReLU 0.2, linear output.

    Scientific notation (paper Sec. 2.3): for each parameter the net outputs a mantissa
    correction ``a`` and an exponent correction ``b``; the parameter is
    ``(m0 + a) * 10 ** (e0 + b)``.  ``e0`` (and ``m0``) come from the scale hint or the
    order of magnitude of a least-squares first guess, so every output starts O(1) and one
    learning rate serves parameters that span ten orders of magnitude.  With
    ``scientific=False`` the output is ``m0 * 10**e0 * (1 + a)`` (plain relative scaling).
    """

    def __init__(self, n_params: int, latent_dim: int = 16, hidden: tuple[int, ...] = (64, 32, 16),
                 scientific: bool = True) -> None:
        super().__init__()
        self.n_params = n_params
        self.latent_dim = latent_dim
        self.scientific = scientific
        layers: list[nn.Module] = []
        width = latent_dim
        for h in hidden:
            layers += [nn.Linear(width, h), nn.LeakyReLU(SLOPE)]
            width = h
        self.body = nn.Sequential(*layers)
        self.head = nn.Linear(width, 2 * n_params if scientific else n_params)
        # start at the reference point: small output weights, zero bias
        with torch.no_grad():
            self.head.weight.mul_(0.1)
            self.head.bias.zero_()
        self.register_buffer("m0", torch.ones(n_params, dtype=torch.float64))
        self.register_buffer("e0", torch.zeros(n_params, dtype=torch.float64))
        # local coordinates (output-error phase, ``set_local``); empty = off
        self.register_buffer("anchor", torch.zeros(0, dtype=torch.float64))
        self.register_buffer("step", torch.zeros(0, dtype=torch.float64))
        self.register_buffer("log_mask", torch.zeros(0, dtype=torch.bool))

    def set_reference(self, values: torch.Tensor, exponents: torch.Tensor | None = None) -> None:
        """Centre the outputs on ``values`` (mantissa/exponent split unless given)."""
        values = values.to(torch.float64)
        if exponents is None:
            mag = values.abs().clamp_min(1e-300)
            exponents = torch.floor(torch.log10(mag))
        self.e0.copy_(exponents.to(torch.float64))
        self.m0.copy_(values / 10.0 ** self.e0)

    def set_local(self, anchor: torch.Tensor, step: torch.Tensor, is_log: torch.Tensor) -> None:
        """Switch to local coordinates around ``anchor``: x = step @ u with u the first n
        outputs, theta = anchor * exp(x) for log parameters, anchor + x otherwise.  ``step``
        is a Cholesky factor of the parameters' covariance (n, n), so one unit of output is
        one standard error along uncorrelated directions whatever the parameter's magnitude:
        the learning rate that moves alpha (sigma ~ 4e-3 relative) also resolves k1 (sigma
        ~ 4e-5), which the float32 mantissa outputs cannot, and the alpha-beta valley
        (correlation ~0.99) becomes round.  The head restarts at the anchor (small weights,
        zero bias); the body is kept."""
        self.anchor = anchor.to(torch.float64).clone()
        self.step = step.to(torch.float64).clone()
        self.log_mask = is_log.to(torch.bool).clone()
        with torch.no_grad():
            self.head.weight.mul_(0.1 / max(1e-12, float(self.head.weight.abs().max())))
            self.head.bias.zero_()

    @property
    def local(self) -> bool:
        return getattr(self, "anchor", None) is not None and self.anchor.numel() > 0

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        h = _run(self.body, z)
        out = F.linear(h, self.head.weight, self.head.bias).to(torch.float64)
        n = self.n_params
        if self.local:
            x = out[..., :n] @ self.step.T
            return torch.where(self.log_mask, self.anchor * torch.exp(x), self.anchor + x)
        if self.scientific:
            return (self.m0 + out[..., :n]) * torch.pow(10.0, self.e0 + out[..., n:])
        return self.m0 * 10.0 ** self.e0 * (1.0 + out[..., :n])


class Discriminator(nn.Module):
    """Features of a (state, acceleration) sample -> logit of "real", 64 -> 32 -> 1.

    The paper applies a sigmoid to the output; we return the logit and apply the sigmoid
    inside ``BCEWithLogits`` (the same loss, numerically stable).  ``prob`` gives D(x).
    """

    def __init__(self, in_dim: int, hidden: tuple[int, ...] = (64, 32)) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        width = in_dim
        for h in hidden:
            layers += [nn.Linear(width, h), nn.LeakyReLU(SLOPE)]
            width = h
        layers.append(nn.Linear(width, 1))
        self.net = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return _run(self.net, x).squeeze(-1)

    def prob(self, x: torch.Tensor) -> torch.Tensor:
        return torch.sigmoid(self.forward(x))


LN4 = math.log(4.0)
