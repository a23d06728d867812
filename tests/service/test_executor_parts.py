"""The Ray executor's parts that need no Ray: placement, the event queue, the trainer's
view of a shared data dir (what trainer actors on other nodes read), and the executor
setting's validation."""
from __future__ import annotations

from pathlib import Path

import pytest

from service.fleet.ray_host import MAX_QUEUED_EVENTS, EventQueue
from service.fleet.ray_placement import Placement, read_placement
from service.settings import Settings
from service.errors import UnknownSystem
from service.storage.recordings import UploadFacts
from service.storage.store import Store
from service.storage.trainer_view import TrainerStoreView


def test_placement_packs_systems_and_survives_a_restart(tmp_path: Path) -> None:
    p = Placement(tmp_path, per_actor=2)
    hosts = [p.assign(n) for n in ("a", "b", "c", "d", "e")]
    assert hosts == ["h0", "h0", "h1", "h1", "h2"]
    assert p.assign("c") == "h1"  # idempotent
    p.remove("b")
    assert p.assign("f") == "h0"  # the freed place is reused before a new host is made
    # what a restarted actor reads: the file, not its creation arguments
    assert read_placement(tmp_path) == {"h0": ["a", "f"], "h1": ["c", "d"], "h2": ["e"]}
    assert Placement(tmp_path, per_actor=2).host_of("e") == "h2"
    assert read_placement(tmp_path / "nowhere") == {}


def test_event_queue_keeps_order_until_acknowledged() -> None:
    q = EventQueue()
    q.log_dataset("s", 0, ["r1"], ["r2"], processing=None)
    for k in range(3):
        q.log_snapshot("s", {"epoch": k})
    pending = q.pending(0)
    assert [(seq, m) for seq, m, _, _ in pending] == [
        (1, "log_dataset"), (2, "log_snapshot"), (3, "log_snapshot"), (4, "log_snapshot")]
    assert pending[0][3] == {"processing": None}
    assert [seq for seq, *_ in q.pending(2)] == [3, 4]  # a lost poll: resent, never lost
    assert q.pending(4) == []


def test_event_queue_is_bounded_and_keeps_dataset_events() -> None:
    q = EventQueue()
    q.log_dataset("s", 0, ["r1"], ["r2"])
    for k in range(MAX_QUEUED_EVENTS + 10):
        q.log_snapshot("s", {"epoch": k})
    items = q.pending(0)
    assert len(items) == MAX_QUEUED_EVENTS
    assert items[0][1] == "log_dataset"  # snapshots went first


def _upload(store: Store, name: str, raw: bytes, role: str) -> str:
    meta, _ = store.add_recording(name, raw, role=role, fmt="csv", filename="x.csv",
                                  info=UploadFacts(n_samples=3, fs=100.0))
    return meta.id


def test_trainer_view_reads_what_the_front_commits(tmp_path: Path) -> None:
    front = Store(tmp_path)
    spec = {"name": "s", "dofs": ["x"]}
    front.put_spec("s", spec)
    view = TrainerStoreView(tmp_path)
    assert view.spec("s") == spec and view.recordings("s") == []
    r1 = _upload(front, "s", b"time,acc_x\n0,1\n", "train")
    r2 = _upload(front, "s", b"time,acc_x\n0,2\n", "validation")
    assert [m.id for m in view.recordings("s")] == [r1, r2]
    assert view.counts("s") == {"train": 1, "validation": 1}
    assert view.read_raw("s", view.recording("s", r2)) == b"time,acc_x\n0,2\n"
    # an upload in flight (bytes written, meta not yet committed) is invisible, and the
    # view never removes it (only the front cleans up, at its start)
    orphan = tmp_path / "systems" / "s" / "recordings" / "r000003-abc.data.csv"
    orphan.write_bytes(b"partial")
    assert len(view.recordings("s")) == 2 and orphan.exists()
    view.save_checkpoint("s", {"epoch": 7})
    assert front.load_checkpoint("s") == {"epoch": 7}
    front.delete_system("s")
    with pytest.raises(UnknownSystem):
        view.recordings("s")
    with pytest.raises(UnknownSystem):
        view.spec("../s")


def test_executor_settings_are_checked() -> None:
    s = Settings.from_env({"SIVA_EXECUTOR": "ray", "SIVA_RAY_ADDRESS": "127.0.0.1:6390",
                           "SIVA_RAY_SYSTEMS_PER_ACTOR": "4", "SIVA_RAY_CPUS_PER_ACTOR": "0.5"})
    assert (s.executor, s.ray_address, s.ray_systems_per_actor, s.ray_cpus_per_actor) == (
        "ray", "127.0.0.1:6390", 4, 0.5)
    with pytest.raises(ValueError, match="executor"):
        Settings(executor="processes")
    with pytest.raises(ValueError, match="ray_systems_per_actor"):
        Settings(ray_systems_per_actor=0)
    assert Settings(ray_address="").ray_address is None
    assert Settings().executor == "threads"  # `make run` unchanged


def test_an_unreachable_trainer_actor_is_a_domain_error_answered_503() -> None:
    """The Ray handle raises a domain error (``Unavailable``), not an HTTP one; the API's
    one mapping (``http_errors``) answers it 503 with Retry-After."""
    from fastapi import FastAPI
    from fastapi.testclient import TestClient

    from service.api import http_errors
    from service.errors import Unavailable
    from service.fleet.ray_trainer import RayTrainer

    class Call:
        def remote(self, *args: object) -> object:
            return object()

    class Host:
        reset_drift = Call()

    class Ray:
        def get(self, ref: object, timeout: float | None = None) -> object:
            raise TimeoutError("the actor is restarting")

    class Executor:
        ray = Ray()

        def known_host(self, host_id: str) -> Host:
            return Host()

    handle = RayTrainer(Executor(), "s", None, "h0")  # type: ignore[arg-type]
    with pytest.raises(Unavailable, match="is starting on Ray") as starting:
        handle.reset_drift()  # not attached to its host yet
    assert starting.value.retry_after_s == 5
    handle.generation = 1  # attached
    with pytest.raises(Unavailable, match="trainer actor is unavailable") as caught:
        handle.reset_drift()
    assert http_errors.status_of(caught.value) == 503

    app = FastAPI()
    http_errors.install(app)

    @app.post("/reset")
    def reset() -> None:
        handle.reset_drift()

    res = TestClient(app).post("/reset")
    assert res.status_code == 503 and res.headers["retry-after"] == "60"
    assert "trainer actor is unavailable" in res.json()["detail"]
