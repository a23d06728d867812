"""What a worker checkpoint holds, and whether a stored one can be resumed.

Why a version and the spec inside: a checkpoint written by another trainer version or for
another model must start training over, never load into the wrong networks.
"""
from __future__ import annotations

import time
from typing import Any, Mapping, Sequence

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
