"""Supervision of trainer threads, in process: a thread that dies is reported by /healthz
(503 with the reason) and restarted from its checkpoint after a back-off; a stuck one is
reported; DELETE and shutdown never wait longer than SIVA_STOP_TIMEOUT_S for a trainer."""
from __future__ import annotations

import threading
import time

import pytest

from service.fleet import executor as executor_mod
from service.systems import SivaService
from service.settings import Settings

SPEC = {"name": "a", "dofs": ["x"], "mass": {"x": 0.05}, "elements": [
    {"kind": "spring", "between": ["x", "ground"], "params": {"k": "k"}}]}


def _until(pred, timeout: float = 20.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if pred():
            return
        time.sleep(0.05)
    raise AssertionError("condition not reached in time")


@pytest.fixture
def service_with(tmp_path, monkeypatch):
    made: list[SivaService] = []

    def make(worker_run, **settings):
        class Worker(executor_mod.SystemWorker):
            def _run(self):
                worker_run(self, super()._run)

        monkeypatch.setattr(executor_mod, "SystemWorker", Worker)
        svc = SivaService(Settings(data_dir=tmp_path / "data", refine_every_s=0, **settings))
        svc.start()
        made.append(svc)
        return svc

    yield make
    for svc in made:
        svc.stop()


@pytest.mark.filterwarnings("ignore::pytest.PytestUnhandledThreadExceptionWarning")
def test_a_dead_trainer_is_reported_then_restarted(service_with):
    runs: list[int] = []

    def run(worker, original):
        runs.append(1)
        if len(runs) == 1:
            raise RuntimeError("injected crash of the trainer thread")
        original()

    svc = service_with(run)
    svc.put_system("a", SPEC)
    _until(lambda: any("dead" in p for p in svc.health_problems()))
    _until(lambda: len(runs) == 2 and svc.workers["a"].alive)  # back-off 2 s, then restart
    _until(lambda: svc.health_problems() == [])


def test_a_stuck_trainer_is_reported(service_with):
    release = threading.Event()

    def run(worker, original):
        release.wait(30)  # never beats

    svc = service_with(run, stuck_after_s=0.3)
    svc.put_system("a", SPEC)
    _until(lambda: any("stuck" in p for p in svc.health_problems()))
    release.set()


def test_delete_and_stop_do_not_wait_for_a_slow_epoch(service_with):
    release = threading.Event()

    def run(worker, original):
        release.wait(60)  # an epoch that ignores the stop request

    svc = service_with(run, stop_timeout_s=1.0)
    svc.put_system("a", SPEC)
    t0 = time.monotonic()
    svc.delete_system("a")
    assert time.monotonic() - t0 < 5.0
    assert svc.store.systems() == []
    svc.put_system("a", SPEC)
    t0 = time.monotonic()
    svc.stop()
    assert time.monotonic() - t0 < 5.0
    release.set()
