"""SIVA_EXECUTOR=ray: a system's first PUT does not wait for its trainer actor.

Starting a system on Ray (creating its host actor, ``add``, a first poll) took more than
60 s on a loaded cluster, on the request path, and a PUT timed out.  The PUT now answers
once the spec is stored; the executor's starter threads attach the trainer meanwhile.

These tests need no Ray: a stand-in ``ray`` module runs the real trainer host
(``TrainerHost``, real workers training in threads) in this process, with actors that are
created and called asynchronously as Ray's are; a gate holds the host's construction (a
cold actor start) or its ``add`` for as long as a test wants.  The real-cluster version of
the first test is in test_ray_executor.py (``make test-ray``).
"""
from __future__ import annotations

import sys
import threading
import time
from concurrent import futures
from pathlib import Path
from typing import Any, Iterator

import pytest
from fastapi.testclient import TestClient

from service.api.app import create_app
from service.fleet import ray_executor
from service.fleet.ray_host import TrainerHost
from service.settings import Settings
from service.systems import SivaService

GATE_S = 60.0  # a gate never opened fails the test rather than hanging it


# --------------------------------------------------------------------------- a stand-in Ray
class _Ref:
    def __init__(self, fut: futures.Future) -> None:
        self.fut = fut


class _Actor:
    """An actor: constructed on a pool thread; its calls run once it is constructed."""

    def __init__(self, ray: "FakeRay", cls: type, args: tuple[Any, ...]) -> None:
        self.ray = ray
        self.killed = False
        self.ready = ray.pool.submit(cls, *args)

    def instance(self) -> Any:
        return self.ready.result(timeout=GATE_S * 2)

    def __getattr__(self, method: str) -> Any:
        actor = self

        class Method:
            def remote(self, *args: Any, **kw: Any) -> _Ref:
                if actor.killed:
                    raise RuntimeError("actor killed")
                return _Ref(actor.ray.pool.submit(
                    lambda: getattr(actor.instance(), method)(*args, **kw)))
        return Method()


class _ActorClass:
    def __init__(self, ray: "FakeRay", cls: type) -> None:
        self.ray, self.cls, self.opts = ray, cls, {}

    def options(self, **opts: Any) -> "_ActorClass":
        self.opts = opts
        return self

    def remote(self, *args: Any) -> _Actor:
        name = self.opts["name"]
        with self.ray.lock:
            actor = self.ray.actors.get(name)
            if actor is None or actor.killed:
                actor = self.ray.actors[name] = _Actor(self.ray, self.cls, args)
                self.ray.created.append(actor)
            return actor


class FakeRay:
    """The part of the ``ray`` module the executor uses."""

    def __init__(self) -> None:
        self.pool = futures.ThreadPoolExecutor(max_workers=64)
        self.lock = threading.Lock()
        self.actors: dict[str, _Actor] = {}
        self.created: list[_Actor] = []

    def is_initialized(self) -> bool:
        return True

    def remote(self, cls: type) -> _ActorClass:
        return _ActorClass(self, cls)

    def get(self, ref: _Ref, timeout: float | None = None) -> Any:
        try:
            return ref.fut.result(timeout=timeout)
        except futures.TimeoutError:
            raise TimeoutError("GetTimeoutError") from None

    def wait(self, refs: list[_Ref], timeout: float | None = None) -> tuple[list, list]:
        done, _ = futures.wait([r.fut for r in refs], timeout=timeout,
                               return_when=futures.FIRST_COMPLETED)
        return [r for r in refs if r.fut in done], [r for r in refs if r.fut not in done]

    def kill(self, actor: _Actor, no_restart: bool = True) -> None:
        actor.killed = True


class GatedHost(TrainerHost):
    """The real trainer host; its construction and/or its ``add`` wait for a gate."""

    built = threading.Event()
    added = threading.Event()
    gate_init = True
    gate_init_end = False
    gate_add = False
    call_delay_s = 0.0
    adds: list[str] = []
    instances: list["GatedHost"] = []

    def __init__(self, *args: Any) -> None:
        self.constructed = False
        GatedHost.instances.append(self)
        if GatedHost.gate_init:
            assert GatedHost.built.wait(GATE_S), "the test never let the actor start"
        super().__init__(*args)  # adds the systems placed here (an actor restart's path)
        if GatedHost.gate_init_end:
            assert GatedHost.built.wait(GATE_S), "the test never let the actor finish"
        self.constructed = True

    def add(self, name: str) -> int:
        gen = super().add(name)
        if not self.constructed:
            return gen
        GatedHost.adds.append(name)  # the front's add
        time.sleep(GatedHost.call_delay_s)
        if GatedHost.gate_add:
            assert GatedHost.added.wait(GATE_S), "the test never let add answer"
        return gen

    def poll(self, *args: Any, **kw: Any) -> dict[str, Any]:
        if self.constructed:
            time.sleep(GatedHost.call_delay_s)
        return super().poll(*args, **kw)


@pytest.fixture
def fake_ray(monkeypatch: pytest.MonkeyPatch) -> Iterator[FakeRay]:
    ray = FakeRay()
    monkeypatch.setitem(sys.modules, "ray", ray)
    monkeypatch.setattr(ray_executor, "TrainerHost", GatedHost)
    for event in (GatedHost.built, GatedHost.added):
        event.clear()
    GatedHost.gate_init, GatedHost.gate_add, GatedHost.adds = True, False, []
    GatedHost.call_delay_s, GatedHost.gate_init_end, GatedHost.instances = 0.0, False, []
    yield ray
    GatedHost.built.set()
    GatedHost.added.set()
    ray.pool.shutdown(wait=True, cancel_futures=True)


def _settings(tmp_path: Path, **settings: Any) -> Settings:
    return Settings(data_dir=tmp_path / "data", executor="ray", refine_every_s=0,
                    torch_threads=1, **{"ray_poll_s": 0.1, **settings})


def _app(tmp_path: Path, **settings: Any) -> Any:
    return create_app(_settings(tmp_path, **settings))



def _workers(ray: FakeRay) -> dict[str, Any]:
    """Every trainer worker running in any (constructed, live) actor, by system."""
    out: dict[str, Any] = {}
    for actor in ray.created:
        if actor.ready.done() and not actor.killed:
            out.update(actor.instance().workers)
    return out


# --------------------------------------------------------------------------- the tests
def test_first_put_answers_while_the_actor_starts_then_the_system_trains(
        until, fake_ray, tmp_path, linear, oscillator) -> None:
    with TestClient(_app(tmp_path)) as c:
        t0 = time.monotonic()
        r = c.put("/v1/systems/osc", json=linear)
        put_s = time.monotonic() - t0
        assert r.status_code == 201, r.text
        assert put_s < 3.0, f"the PUT waited {put_s:.1f} s for the trainer actor"
        assert not GatedHost.built.is_set()  # the actor is still being created
        est = c.get("/v1/systems/osc/estimate").json()
        assert est["state"] == "starting" and est["epoch"] == 0
        # the contract's answers while starting: same spec 200, another 409
        again = c.put("/v1/systems/osc", json=linear)
        assert again.status_code == 200 and again.json()["created"] is False
        other = c.put("/v1/systems/osc", json=dict(linear, mass={"x": 0.06}))
        assert other.status_code == 409, other.text
        # uploads are stored (and read by the worker when it starts); reads answer
        for role, v0 in (("train", 1.0), ("validation", 0.6)):
            up = c.post(f"/v1/systems/osc/recordings?role={role}", content=oscillator(v0=v0),
                        headers={"content-type": "text/csv"})
            assert up.status_code == 202, up.text
        assert c.get("/v1/systems/osc/drift").status_code == 200
        assert c.get("/healthz").status_code == 200  # starting is not a failure
        assert c.get("/v1/systems/osc/estimate").json()["state"] == "starting"
        GatedHost.built.set()  # the actor comes up
        trained = until(lambda: (b := c.get("/v1/systems/osc/estimate").json())["epoch"] >= 3
                         and b, 120, "the system trained on Ray")
        assert trained["n_recordings"] == {"train": 1, "validation": 1}
        assert len(trained["data"]["train"]) == 1 and len(trained["data"]["validation"]) == 1
        assert list(_workers(fake_ray)) == ["osc"]
        assert len(fake_ray.created) == 1
    assert all(a.killed for a in fake_ray.created)  # a clean stop removes the actors


def test_delete_while_the_actor_starts_leaves_no_trainer(until, fake_ray, tmp_path, linear) -> None:
    with TestClient(_app(tmp_path)) as c:
        assert c.put("/v1/systems/gone", json=linear).status_code == 201
        t0 = time.monotonic()
        assert c.delete("/v1/systems/gone").status_code == 200
        assert time.monotonic() - t0 < 3.0
        assert c.get("/v1/systems/gone/estimate").status_code == 404
        GatedHost.built.set()
        # the actor finds it unplaced, the starter finds it deleted: nothing is added
        until(lambda: fake_ray.created and fake_ray.created[0].ready.done(), 30,
               "the actor constructed")
        time.sleep(1.0)
        assert _workers(fake_ray) == {} and GatedHost.adds == []
        assert not c.app.state.service.executor.starter.pending("gone")
        assert c.get("/healthz").status_code == 200


def test_delete_while_the_actor_finishes_starting_removes_its_worker(until, fake_ray, tmp_path,
                                                                     linear) -> None:
    """The actor's construction already started the system's worker (it was in the
    placement file) when the DELETE comes: the starter finds that worker and removes it."""
    GatedHost.gate_init, GatedHost.gate_init_end = False, True
    with TestClient(_app(tmp_path)) as c:
        assert c.put("/v1/systems/placed", json=linear).status_code == 201
        until(lambda: fake_ray.created, 30, "the actor is being created")
        inst = until(lambda: GatedHost.instances and getattr(GatedHost.instances[-1],
                                                              "workers", None), 30,
                      "the construction started the placed worker")
        assert list(inst) == ["placed"]
        assert c.delete("/v1/systems/placed").status_code == 200
        GatedHost.built.set()
        until(lambda: fake_ray.created[0].ready.done(), 30, "the actor constructed")
        until(lambda: _workers(fake_ray) == {}, 30, "the placed worker removed")
        until(lambda: not c.app.state.service.executor.starter.pending("placed"), 30,
               "the starter done")
        assert GatedHost.adds == []  # it found the system deleted: nothing added


def test_delete_while_add_answers_removes_what_it_started(until, fake_ray, tmp_path,
                                                          linear) -> None:
    """The host added the worker but its answer is not in when the DELETE comes (the
    poller, slowed here, has not seen it either): the attach removes that worker."""
    GatedHost.gate_init, GatedHost.gate_add = False, True
    with TestClient(_app(tmp_path, ray_poll_s=600.0)) as c:
        assert c.put("/v1/systems/late", json=linear).status_code == 201
        until(lambda: GatedHost.adds, 60, "the host added the worker")
        assert list(_workers(fake_ray)) == ["late"]
        t0 = time.monotonic()
        assert c.delete("/v1/systems/late").status_code == 200
        assert time.monotonic() - t0 < 3.0
        GatedHost.added.set()  # the add answers now
        until(lambda: _workers(fake_ray) == {}, 30, "the started worker removed")
        # registered again: started afresh
        assert c.put("/v1/systems/late", json=linear).status_code == 201
        until(lambda: list(_workers(fake_ray)) == ["late"], 60, "the new one started")
        assert c.get("/v1/systems/late/estimate").status_code == 200


def test_a_restarted_front_shows_the_running_epoch_at_once(until, fake_ray, tmp_path, linear,
                                                          oscillator) -> None:
    """The service's own start (not a PUT) waits for its systems' first attaches, in
    parallel: after the front was killed (its actors train on), the first read shows the
    epoch the actor reached, not ``starting``."""
    GatedHost.built.set()
    old = SivaService(_settings(tmp_path))
    old.start()
    old.put_system("osc", linear)
    for role, v0 in (("train", 1.0), ("validation", 0.6)):
        old.add_recording("osc", oscillator(v0=v0), role=role, fmt="csv", filename=f"{role}.csv")
    before = until(lambda: (s := old.worker("osc").snapshot()).epoch >= 5 and s, 120,
                    "trained a few epochs")
    # the front dies (kill -9): its threads stop with it; the actor trains on
    old.executor._stop.set()
    old.executor.starter.close(timeout=5.0)
    old.events.close()
    GatedHost.call_delay_s = 1.0  # the found actor answers each call in 1 s (loaded)
    with TestClient(create_app(_settings(tmp_path))) as c:
        first = c.get("/v1/systems/osc/estimate").json()
        assert first["state"] != "starting", first["state"]
        assert first["epoch"] >= before.epoch, (first["epoch"], before.epoch)
    assert len(fake_ray.created) == 1 and fake_ray.created[0].killed
