"""Where the trainers run: threads in the service process, or Ray actors (docs/fleet.md).

Why an executor: the front (HTTP routes, the store, the event log) is the same whatever
runs the trainers; only how a system's trainer is started, reached and stopped differs.
Both executors hand the service *trainer handles* with one surface (``TrainerHandle``):
the routes read published snapshots through it and never wait for training.

* ``threads`` (default, ``make run``): a :class:`~service.trainer.SystemWorker` per system,
  a thread in this process.
* ``ray`` (``SIVA_EXECUTOR=ray``): systems are grouped into detached, named Ray actors
  that restart from their checkpoints when their process or node dies
  (service/ray_executor.py); ``pip install '.[ray]'``.
"""
from __future__ import annotations

from typing import Any, Protocol

from siva_core import Structure

from ..settings import Settings
from ..trainer import DriftReport, Snapshot, SystemWorker, stop_workers


class TrainerHandle(Protocol):
    """What the service needs of one system's trainer, wherever it runs."""

    name: str
    structure: Structure

    def start(self) -> None: ...
    def notify(self) -> None: ...
    def request_stop(self) -> None: ...
    def stop(self, timeout: float = 60.0) -> None: ...
    def snapshot(self) -> Snapshot: ...
    def drift_report(self) -> DriftReport: ...
    def reset_drift(self) -> DriftReport: ...
    def problem(self) -> str | None: ...

    @property
    def alive(self) -> bool: ...
    @property
    def died(self) -> bool: ...
    @property
    def stopping(self) -> bool: ...
    @property
    def error(self) -> str | None: ...
    # also plain attributes: epoch (int), heartbeat (time.monotonic() of the last progress),
    # checkpoint_error (str | None)


class ThreadExecutor:
    """One trainer thread (and refiner thread) per system, in this process."""

    kind = "threads"

    def __init__(self, settings: Settings, store: Any, events: Any) -> None:
        self.settings = settings
        self.store = store
        self.events = events

    def trainer(self, name: str, structure: Structure) -> TrainerHandle:
        return SystemWorker(name, structure, self.store, self.settings, self.events)

    def await_starts(self, handles: list[TrainerHandle]) -> None:
        """Nothing to wait for: a trainer thread is started by ``start`` itself."""

    def removed(self, name: str) -> None:
        """The system was deleted (its trainer is stopped)."""

    def stop_all(self, handles: list[TrainerHandle], timeout: float) -> list[str]:
        """Stop every trainer (final checkpoints) within ``timeout`` in all; returns the
        names of those that did not stop in time."""
        return stop_workers(handles, timeout)

    def describe(self) -> dict[str, Any]:
        return {"kind": self.kind}


def make_executor(settings: Settings, store: Any, events: Any) -> Any:
    """The executor the settings ask for (``SIVA_EXECUTOR``)."""
    if settings.executor == "ray":
        from .ray_executor import RayExecutor

        return RayExecutor(settings, store, events)
    return ThreadExecutor(settings, store, events)


__all__ = ["TrainerHandle", "ThreadExecutor", "make_executor"]
