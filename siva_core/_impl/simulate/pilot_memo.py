"""The substeps a pilot chose, remembered for the same model, sets and record (speed).

``pilot_substeps`` simulates the sets it is given (the first and the extremes of each
parameter) to find the amplitudes reached, and from them the substeps.  A diagnosis asks
for the substeps of the very same single set on the very same record again and again: a
fit's cost at its result (``output_error``), then the second round's ``refine`` from that
result, the early stop's leader heads, a polish or a bootstrap from it.  ``refine`` then
runs at 1.25 x those substeps, so its pilot's simulation is thrown away; here the choice
is remembered instead and the pilot is not run again (issue 16, branch speed34).

Why it changes nothing: the substeps are a deterministic function of the inputs kept in
the key (the structure object, the sets bit for bit, the step, the initial states, the
force bit for bit, the options); a caller that gets no pilot arrays simulates the sets
itself, at those substeps, and a set's run does not depend on the run that chose them.
"""
from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from typing import Any

import numpy as np

#: entries kept (least recently used dropped); each holds a key of a few hundred bytes
#: and a strong reference to its structure (so that its ``id`` is not reused)
MEMO_SIZE = 512

_MEMO: "OrderedDict[tuple[Any, ...], tuple[Any, int]]" = OrderedDict()
_LOCK = threading.Lock()


def _digest(a: Any) -> bytes:
    if a is None:
        return b"none"
    arr = np.ascontiguousarray(np.asarray(a, dtype=float))
    return hashlib.blake2b(arr.tobytes(), digest_size=16,
                           person=str(arr.shape).encode()[:16]).digest()


def memo_key(structure: Any, th: np.ndarray, dt: float, q0: Any, v0: Any,
             force: np.ndarray | None, n_samples: int | None, omega_h: float, backend: str,
             max_substeps: int, interp: str, real_h: float | None) -> tuple[Any, ...]:
    """What the pilot's choice depends on (the model by identity and its fixed values)."""
    fixed = tuple((p, info.fixed) for p, info in structure.parameters.items())
    masses = tuple(float(x) for x in np.ravel(structure.masses))
    return (id(structure), fixed, masses, _digest(th), float(dt), _digest(q0), _digest(v0),
            _digest(force), n_samples, float(omega_h), backend, int(max_substeps), interp,
            None if real_h is None else float(real_h))


def recall(key: tuple[Any, ...], structure: Any) -> int | None:
    """The substeps chosen before for ``key`` (None when not seen)."""
    with _LOCK:
        hit = _MEMO.get(key)
        if hit is None or hit[0] is not structure:
            return None
        _MEMO.move_to_end(key)
        return hit[1]


def remember(key: tuple[Any, ...], structure: Any, m: int) -> None:
    with _LOCK:
        _MEMO[key] = (structure, int(m))
        _MEMO.move_to_end(key)
        while len(_MEMO) > MEMO_SIZE:
            _MEMO.popitem(last=False)


def clear() -> None:
    """Forget every choice (tests)."""
    with _LOCK:
        _MEMO.clear()
