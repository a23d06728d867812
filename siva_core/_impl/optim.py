"""Adam without the per-step overhead of ``torch.optim.Adam``, with the same numerics.

SIVA's networks are tiny (a few thousand weights) and take ~10^4 optimiser steps per fit;
``torch.optim.Adam.step`` spends most of its time in wrapper layers and in one small op
per tensor per update stage.  ``FastAdam`` keeps each parameter group's weights and Adam
moments in one contiguous buffer (the parameters and the per-parameter state are views
into it), so a step is nine elementwise ops on one vector.  Elementwise, these are the
operations of the ``foreach`` Adam in the same order (bit-identical weights, measured in
``tests/test_optim.py``), and ``state_dict``/``load_state_dict`` keep Adam's format.
Anything but the plain configuration SIVA uses (CPU float tensors; no weight decay,
amsgrad, maximize, capturable or fused) falls back to ``torch.optim.Adam.step``.

It also skips ``torch.optim.Optimizer``'s per-call layers, which cost as much as the
update itself here: the profiler wrapper around ``step`` (so step hooks registered on a
FastAdam are not called), the ``torch._disable_dynamo`` wrappers of ``add_param_group``,
``zero_grad``, ``state_dict`` and ``load_state_dict`` (the first call of any of them
imports ``torch._dynamo``: ~2 s of CPU per process, for a compiler SIVA never uses) and
``zero_grad``'s profiler context (``set_to_none=True`` just drops the gradients).
"""
from __future__ import annotations

from typing import Any

import torch


def _undecorated(fn: Any) -> Any:
    """The function under ``torch._disable_dynamo`` (itself when not wrapped)."""
    return getattr(fn, "__wrapped__", fn)


_ADD_PARAM_GROUP = _undecorated(torch.optim.Optimizer.add_param_group)
_ZERO_GRAD = _undecorated(torch.optim.Optimizer.zero_grad)
_STATE_DICT = _undecorated(torch.optim.Optimizer.state_dict)
_LOAD_STATE_DICT = _undecorated(torch.optim.Optimizer.load_state_dict)
_ONE = torch.tensor(1.0)  # the step counters' increment (read only)


class FastAdam(torch.optim.Adam):
    """``torch.optim.Adam`` with flat per-group buffers and a lean ``step``."""

    def __init__(self, params: Any, **kw: Any) -> None:
        super().__init__(params, **kw)
        self._flat: list[dict[str, Any] | None] = [self._flatten(g) for g in self.param_groups]

    # the Optimizer methods without their torch._dynamo guard (see the module docstring)
    def add_param_group(self, param_group: dict[str, Any]) -> None:
        _ADD_PARAM_GROUP(self, param_group)

    def zero_grad(self, set_to_none: bool = True) -> None:
        if not set_to_none:
            _ZERO_GRAD(self, set_to_none)
            return
        for group in self.param_groups:
            for p in group["params"]:
                p.grad = None

    def state_dict(self) -> dict[str, Any]:  # type: ignore[override]
        return _STATE_DICT(self)

    # ------------------------------------------------------------------ layout
    def _plain(self, group: dict[str, Any]) -> bool:
        return (not group["amsgrad"] and group["weight_decay"] == 0 and not group["maximize"]
                and not group["capturable"] and not group["differentiable"]
                and not group.get("fused") and not isinstance(group["lr"], torch.Tensor)
                and not isinstance(group["betas"][0], torch.Tensor))

    def _flatten(self, group: dict[str, Any]) -> dict[str, Any] | None:
        """Move the group's parameters into one buffer (values unchanged; the Parameter
        objects stay the same, their data become views)."""
        params = group["params"]
        if (not params or not self._plain(group)
                or any(p.is_sparse or p.is_complex() or not p.is_cpu for p in params)
                or len({p.dtype for p in params}) != 1):
            return None
        flat = torch.cat([p.detach().reshape(-1) for p in params])
        offsets, o = [], 0
        for p in params:
            k = p.numel()
            p.data = flat[o:o + k].view_as(p)
            offsets.append((o, k))
            o += k
        return {"params": flat, "offsets": offsets, "m": None, "v": None}

    def _bind_state(self, group: dict[str, Any], flat: dict[str, Any]) -> bool:
        """Point every parameter's Adam state at views of the flat moment buffers (copying
        the current values in); False when the state is not in the expected form."""
        states = [self.state.get(p) for p in group["params"]]
        if all(not s for s in states):
            m = torch.zeros_like(flat["params"])
            v = torch.zeros_like(flat["params"])
            dtype = torch.float64 if torch.get_default_dtype() == torch.float64 else torch.float32
            for p, (o, k) in zip(group["params"], flat["offsets"]):
                self.state[p] = {"step": torch.tensor(0.0, dtype=dtype),
                                 "exp_avg": m[o:o + k].view_as(p),
                                 "exp_avg_sq": v[o:o + k].view_as(p)}
        elif all(s and {"step", "exp_avg", "exp_avg_sq"} <= set(s) for s in states):
            m = torch.cat([s["exp_avg"].reshape(-1) for s in states])  # type: ignore[index]
            v = torch.cat([s["exp_avg_sq"].reshape(-1) for s in states])  # type: ignore[index]
            if m.dtype != flat["params"].dtype or m.numel() != flat["params"].numel():
                return False
            for p, s, (o, k) in zip(group["params"], states, flat["offsets"]):
                s["exp_avg"] = m[o:o + k].view_as(p)  # type: ignore[index]
                s["exp_avg_sq"] = v[o:o + k].view_as(p)  # type: ignore[index]
        else:
            return False
        flat["m"], flat["v"] = m, v
        flat["steps"] = [self.state[p]["step"] for p in group["params"]]
        return True

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:  # type: ignore[override]
        _LOAD_STATE_DICT(self, state_dict)
        for flat in self._flat:
            if flat is not None:
                flat["m"] = flat["v"] = None  # re-bound to the loaded state at the next step

    # ------------------------------------------------------------------ step
    @torch.no_grad()
    def step(self, closure: Any = None) -> Any:  # type: ignore[override]
        if closure is not None:
            return super().step(closure)
        while len(self._flat) < len(self.param_groups):  # groups added after construction
            self._flat.append(self._flatten(self.param_groups[len(self._flat)]))
        fallback = False
        for group, flat in zip(self.param_groups, self._flat):
            params = group["params"]
            if (flat is None or not self._plain(group) or any(p.grad is None for p in params)
                    or any(p.grad.is_sparse for p in params)):
                fallback = True
                continue
            if flat["m"] is None and not self._bind_state(group, flat):
                fallback = True
                continue
            beta1, beta2 = group["betas"]
            lr, eps = group["lr"], group["eps"]
            steps = flat["steps"]  # the state's step tensors (bound with m and v)
            g = torch.cat([p.grad.reshape(-1) for p in params])
            torch._foreach_add_(steps, _ONE, alpha=1.0)
            m, v, w = flat["m"], flat["v"], flat["params"]
            m.lerp_(g, 1 - beta1)
            v.mul_(beta2)
            v.addcmul_(g, g, value=1 - beta2)
            t = steps[0].item()
            step_size = (lr / (1 - beta1 ** t)) * -1
            denom = v.sqrt()
            denom.div_((1 - beta2 ** t) ** 0.5)
            denom.add_(eps)
            w.addcdiv_(m, denom, value=step_size)
        if fallback:
            # the parent's per-tensor update (its state tensors are views of our buffers, so
            # both stay in step); only groups not done above reach it
            done = [g for g, f in zip(self.param_groups, self._flat)
                    if f is not None and f["m"] is not None and self._plain(g)
                    and all(p.grad is not None for p in g["params"])]
            saved = [(p, p.grad) for g in done for p in g["params"]]
            for p, _ in saved:
                p.grad = None
            try:
                super().step()
            finally:
                for p, grad in saved:
                    p.grad = grad
        return None

    # marks ``step`` as already wrapped: Optimizer.__init__ then leaves it unwrapped
    step.hooked = True  # type: ignore[attr-defined]
