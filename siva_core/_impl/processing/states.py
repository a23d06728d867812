"""What the chain produces (``States``) and what it is fed for simulations.

``simulated_recording`` turns simulated states into a Recording with the channels of the
measured one, so that the chain processes simulation and measurement alike.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Sequence

import numpy as np

from ..recording import Recording


@dataclass
class States:
    """Processed states of one record, arrays of shape (T, n_dof).

    Arrays may carry extra leading axes (e.g. (B, T, n_dof) for a batch of simulations
    processed by :meth:`Processing.apply_simulated`); ``t`` is always (T,).
    """

    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    a: np.ndarray
    f: np.ndarray
    name: str = "record"
    has_force: bool = False
    start_index: int = 0  # index into the raw recording of the first kept sample
    decimation: int = 1

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0])

    @property
    def fs(self) -> float:
        return 1.0 / self.dt

    def __len__(self) -> int:
        return len(self.t)



def copy_states(st: States) -> States:
    """A States whose arrays the caller may modify (the memo's stay as computed)."""
    cp = lambda x: x.copy() if isinstance(x, np.ndarray) else x
    return replace(st, t=cp(st.t), q=cp(st.q), v=cp(st.v), a=cp(st.a), f=cp(st.f))


def simulated_recording(measured: Recording, dofs: Sequence[str] | Any, q: np.ndarray,
                        v: np.ndarray, a: np.ndarray, *, name: str | None = None) -> Recording:
    """A Recording of simulated (T, n_dof) states with the channels ``measured`` has.

    ``dofs``: the DOF names, or anything with a ``dofs`` attribute (a Structure).

    The force channels are copied from ``measured`` (the simulation was driven by them), so
    ``proc.apply(simulated_recording(...))`` gives states processed exactly like
    ``proc.apply(measured)``: same derivations, filters, start and decimation.
    """
    dofs = list(getattr(dofs, "dofs", dofs))
    sim = {"disp": np.asarray(q, float), "vel": np.asarray(v, float),
           "acc": np.asarray(a, float)}
    for key, x in sim.items():
        if x.shape != (len(measured), len(dofs)):
            raise ValueError(f"simulated {key} has shape {x.shape}, expected "
                             f"({len(measured)}, {len(dofs)})")
    channels: dict[str, np.ndarray] = {}
    for key, x in measured.channels.items():
        qty, _, d = key.partition("_")
        if qty == "force":
            channels[key] = x.copy()
        elif qty in sim and d in dofs:
            channels[key] = sim[qty][:, dofs.index(d)].copy()
    return Recording(measured.time.copy(), channels, name or f"{measured.name} (simulated)",
                     {"simulated": True})
