"""What a worker checkpoint holds, whether a stored one can be resumed, and its file.

Why a version and the spec inside: a checkpoint written by another trainer version or for
another model must start training over, never load into the wrong networks.
"""
from __future__ import annotations

import io
import logging
import time
from pathlib import Path
from typing import Any, Mapping, Sequence

from .files import atomic_write

log = logging.getLogger("siva.service.store")

CHECKPOINT_VERSION = 1


def checkpoint_state(spec: Mapping[str, Any], trainer: Any, drift: Any,
                     train_ids: Sequence[str], val_ids: Sequence[str],
                     extra: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The dict ``Store.save_checkpoint`` writes (torch.save, atomically); ``extra``:
    more keys (the monitor's state, the first ``best``)."""
    return {**(extra or {}), "version": CHECKPOINT_VERSION, "spec": spec,
            "trainer": trainer.state_dict(),
            "drift": drift.state_dict(),
            "data": {"train": list(train_ids), "validation": list(val_ids)},
            "time": time.time()}


def matches(ckpt: Mapping[str, Any], spec: Mapping[str, Any]) -> bool:
    """True when ``ckpt`` was written by this checkpoint version for this very spec."""
    return ckpt.get("version") == CHECKPOINT_VERSION and ckpt.get("spec") == spec


def save_checkpoint(path: Path, state: dict[str, Any]) -> None:
    """torch.save into memory, then one atomic durable write (never a torn checkpoint)."""
    import torch

    buf = io.BytesIO()
    torch.save(state, buf)
    atomic_write(path, buf.getvalue())


def load_checkpoint(path: Path) -> dict[str, Any] | None:
    import torch

    if not path.exists():
        return None
    try:
        # our own file in our own data dir; it holds numpy arrays, hence weights_only=False
        return torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # noqa: BLE001 - a bad checkpoint means: start fresh
        log.error("%s: unreadable checkpoint (%s); training restarts from scratch", path, exc)
        return None
