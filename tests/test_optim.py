"""FastAdam: the same weights as torch.optim.Adam, bit for bit, and a state_dict that
round-trips (the service checkpoints the trainer's optimisers)."""
from __future__ import annotations

import copy

import torch
import torch.nn.functional as F

from siva_core._impl.networks import Discriminator, ParameterGenerator
from siva_core._impl.optim import FastAdam


def _train(gen: ParameterGenerator, disc: Discriminator, og: torch.optim.Optimizer,
           od: torch.optim.Optimizer, steps: int, seed: int) -> None:
    g = torch.Generator().manual_seed(seed)
    x = torch.randn(64, 3, generator=g)
    for _ in range(steps):
        th = gen(torch.randn(64, 16, generator=g))
        fake = torch.cat([x[:, :2], th.sum(-1, keepdim=True).float() * 1e-3], -1)
        rl, fl = disc(x), disc(fake.detach())
        ld = (F.binary_cross_entropy_with_logits(rl, torch.ones_like(rl))
              + F.binary_cross_entropy_with_logits(fl, torch.zeros_like(fl)))
        od.zero_grad(set_to_none=True)
        ld.backward()
        od.step()
        lg = F.binary_cross_entropy_with_logits(disc(fake), torch.ones_like(rl)) + (th ** 2).mean()
        og.zero_grad(set_to_none=True)
        lg.backward()
        og.step()


def _nets(cls: type) -> tuple:
    torch.manual_seed(0)
    gen, disc = ParameterGenerator(3), Discriminator(3)
    return gen, disc, cls(gen.parameters(), lr=1e-3, foreach=True), cls(disc.parameters(), lr=1e-3)


def _weights(*mods: torch.nn.Module) -> list[torch.Tensor]:
    return [p.detach().clone() for m in mods for p in m.parameters()]


def test_fast_adam_matches_torch_adam_bit_for_bit() -> None:
    a = _nets(torch.optim.Adam)
    b = _nets(FastAdam)
    for nets in (a, b):
        _train(*nets, steps=40, seed=1)
        for opt in nets[2:]:
            for group in opt.param_groups:
                group["lr"] = 1e-4  # the learning-rate switch at convergence
        _train(*nets, steps=40, seed=2)
    assert all(torch.equal(x, y) for x, y in zip(_weights(*a[:2]), _weights(*b[:2])))
    sa, sb = a[2].state_dict(), b[2].state_dict()
    assert all(torch.equal(sa["state"][k][n], sb["state"][k][n])
               for k in sa["state"] for n in ("step", "exp_avg", "exp_avg_sq"))


def test_fast_adam_state_dict_round_trip() -> None:
    ref = _nets(FastAdam)
    _train(*ref, steps=30, seed=1)
    snap = copy.deepcopy({"g": ref[0].state_dict(), "d": ref[1].state_dict(),
                          "og": ref[2].state_dict(), "od": ref[3].state_dict()})
    _train(*ref, steps=30, seed=2)
    new = _nets(FastAdam)
    new[0].load_state_dict(snap["g"])
    new[1].load_state_dict(snap["d"])
    new[2].load_state_dict(snap["og"])
    new[3].load_state_dict(snap["od"])
    _train(*new, steps=30, seed=2)
    assert all(torch.equal(x, y) for x, y in zip(_weights(*ref[:2]), _weights(*new[:2])))


def test_fast_adam_never_imports_the_compiler() -> None:
    """torch.optim.Optimizer's guards import torch._dynamo (~2 s of CPU) on first use;
    FastAdam's step, zero_grad and state_dict round trip must not."""
    import subprocess
    import sys

    code = ("import sys, torch\n"
            "from siva_core._impl.optim import FastAdam\n"
            "from siva_core._impl.networks import Discriminator\n"
            "d = Discriminator(3); opt = FastAdam(d.parameters(), lr=1e-3)\n"
            "for _ in range(3):\n"
            "    opt.zero_grad(set_to_none=True); d(torch.randn(8, 3)).sum().backward(); opt.step()\n"
            "opt.load_state_dict(opt.state_dict())\n"
            "assert 'torch._dynamo' not in sys.modules, 'torch._dynamo was imported'\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
