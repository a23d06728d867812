"""Making and stopping trainers; the snapshot every system has before any estimate."""
from __future__ import annotations

import time
from typing import Any

from siva_core import Structure

from ..settings import Settings
from .published import Snapshot


def stop_workers(workers: list[Any], timeout: float) -> list[str]:
    """Ask every worker to stop, then wait at most ``timeout`` in all."""
    for w in workers:
        w.request_stop()
    deadline = time.monotonic() + timeout
    for w in workers:
        w.stop(timeout=max(0.0, deadline - time.monotonic()))
    return [w.name for w in workers if w.alive]


def base_snapshot(name: str, state: str, epoch: int = 0,
                  error: str | None = None) -> Snapshot:
    """The snapshot every system has before any estimate exists."""
    return Snapshot(system=name, state=state, epoch=epoch, error=error)


def default_trainer(structure: Structure, settings: Settings) -> Any:
    """SivaTrainer with the preset and seed of the settings."""
    from siva_core import SivaSettings, SivaTrainer

    preset = getattr(SivaSettings, settings.preset, None)
    if preset is None:
        raise ValueError(f"unknown SIVA preset {settings.preset!r} (fast, paper)")
    return SivaTrainer(structure, preset(seed=settings.seed))
