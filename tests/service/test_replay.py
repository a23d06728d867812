"""`siva replay`: a log re-run offline gives the live service's estimate.

The fixtures under tests/fixtures/ are real service logs (regenerate them with
``python tests/service/test_replay.py --regenerate`` after a change to training that
moves the numbers): ``duffing_run.mcap`` is a clean run whose data set changes mid-run;
``duffing_crash_1.mcap`` is the unfinished log of a ``siva serve`` killed with SIGKILL and
``duffing_crash_2.mcap`` the log of the next start, which resumed from the periodic
checkpoint (older than the moment of the kill).
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
FIX = ROOT / "tests" / "fixtures"
DATA = Path(os.environ.get("SIVA_SHARED_DATA") or ROOT.parent / "shared" / "data") / "duffing"
sys.path.insert(0, str(ROOT))

from service.mcap_log import (TOPIC_DATASET, TOPIC_SNAPSHOT, EventLog, is_finished,  # noqa: E402
                              read_events)
from service.replay import ReplayError, replay  # noqa: E402

SPEC_TOML = ROOT / "examples" / "models" / "duffing.toml"


def decimated(name: str, offset: int = 0, k: int = 10) -> bytes:
    """A 1 kHz version of a reference record (small, so epochs take milliseconds)."""
    lines = (DATA / name).read_text().splitlines()
    return ("\n".join([lines[0]] + lines[1 + offset::k]) + "\n").encode()


def _last_snapshot(*paths: Path):
    snaps = [e.event for p in paths for e in read_events(p) if e.topic == TOPIC_SNAPSHOT]
    return snaps[-1]


def _assert_within_spread(out: dict, logged: dict, k: float = 1.0) -> None:
    for p, s in logged["parameters"].items():
        got = out["parameters"][p]["mean"]
        assert abs(got - s["mean"]) <= k * s["std"] + 1e-12 * abs(s["mean"]), (p, got, s)


_THREADS_NOTE = ("not bit-identical: the live trainer ran with another torch thread count "
                 "than the replay (torch.set_num_threads is per thread under OpenMP; the "
                 "worker must set it in its training thread)")


def _wait_epoch(client, name: str, epoch: int, timeout: float = 300.0) -> dict:
    deadline = time.monotonic() + timeout
    while True:
        est = client.estimate(name)
        if est["epoch"] >= epoch:
            return est
        assert time.monotonic() < deadline, f"epoch {epoch} not reached: {est['epoch']}"
        time.sleep(0.05)


# ------------------------------------------------------------------ real runs (fixtures, live)
def clean_run(data_dir: Path, epochs: int = 60, change_at: int = 20) -> Path:
    """A real service: train + validation records, a second validation record mid-run."""
    from clients import SivaClient
    from service.demo import ServerThread
    from service.settings import Settings

    # from_env: `make test-ray` runs this live part with SIVA_EXECUTOR=ray
    st = Settings.from_env(data_dir=data_dir, snapshot_every=5, checkpoint_every_s=3600)
    with ServerThread(st) as url, SivaClient(url) as c:
        c.register("duffing", SPEC_TOML)
        c.upload("duffing", decimated("train_v5.csv"), role="train")
        c.upload("duffing", decimated("val_v3.csv"), role="validation")
        _wait_epoch(c, "duffing", change_at)
        c.upload("duffing", decimated("val_v8.csv"), role="validation")
        _wait_epoch(c, "duffing", epochs)
    (log,) = sorted((data_dir / "logs" / "duffing").glob("*.mcap"))
    return log


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def crash_and_resume(data_dir: Path, out: Path) -> tuple[Path, Path]:
    """``siva serve`` killed with SIGKILL after a checkpoint, then a new start resumes."""
    from clients import SivaClient
    from service.demo import ServerThread
    from service.settings import Settings

    port = _free_port()
    env = {**os.environ, "SIVA_SNAPSHOT_EVERY": "5", "SIVA_CHECKPOINT_EVERY_S": "1",
           "SIVA_LOG_LEVEL": "WARNING", "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-m", "siva_cli", "serve", "--port", str(port),
                             "--data-dir", str(data_dir)], env=env, cwd=ROOT,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        with SivaClient(f"http://127.0.0.1:{port}") as c:
            deadline = time.monotonic() + 120
            while not c.health():
                assert time.monotonic() < deadline and proc.poll() is None, "server did not start"
                time.sleep(0.2)
            c.register("duffing", SPEC_TOML)
            c.upload("duffing", decimated("train_v5.csv"), role="train")
            c.upload("duffing", decimated("val_v3.csv"), role="validation")
            _wait_epoch(c, "duffing", 25)
            while (c.estimate("duffing").get("checkpoint_epoch") or 0) < 10:
                time.sleep(0.1)
            _wait_epoch(c, "duffing", c.estimate("duffing")["epoch"] + 3)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(30)
    (first,) = sorted((data_dir / "logs" / "duffing").glob("*.mcap"))
    assert not is_finished(first)
    crash_1 = out / "duffing_crash_1.mcap"
    shutil.copy(first, crash_1)  # as the kill left it (the next start finishes it in place)
    st = Settings(data_dir=data_dir, snapshot_every=5, checkpoint_every_s=3600)
    with ServerThread(st) as url, SivaClient(url) as c:
        start = c.estimate("duffing")["epoch"]
        c.upload("duffing", decimated("train_v5.csv", offset=5), role="train")
        _wait_epoch(c, "duffing", start + 25)
    second = [p for p in sorted((data_dir / "logs" / "duffing").glob("*.mcap")) if p != first]
    crash_2 = out / "duffing_crash_2.mcap"
    shutil.copy(second[-1], crash_2)
    return crash_1, crash_2


def regenerate(tmp: Path) -> None:
    FIX.mkdir(parents=True, exist_ok=True)
    shutil.copy(clean_run(tmp / "clean"), FIX / "duffing_run.mcap")
    crash_and_resume(tmp / "crash", FIX)
    for f in sorted(FIX.glob("*.mcap")):
        print(f, f.stat().st_size, "bytes")


# ------------------------------------------------------------------ tests
def test_fixture_replays_to_the_logged_estimate() -> None:
    fx = FIX / "duffing_run.mcap"
    out = replay(fx)
    logged = _last_snapshot(fx).estimate_dict()
    assert out["epoch"] == logged["epoch"] > 50
    assert out["n_recordings"] == logged["n_recordings"] == {"train": 1, "validation": 2}
    assert set(out) >= {"parameters", "discriminator", "epoch", "converged", "n_recordings"}
    for p in ("b", "b_nl", "k", "k_nl"):
        s = out["parameters"][p]
        assert set(s) >= {"mean", "std"}
        if out["ensemble_state"] == "final":
            assert s["ci95"][0] <= s["mean"] <= s["ci95"][1]
        else:  # provisional (this short run never left the equation-error phase)
            assert s.get("ci95") is None
    # the data set changed mid-run, later than the recording arrived: replay follows the
    # worker's dataset events, not the arrival epochs
    sets = [e.event.epoch for e in read_events(fx) if e.topic == TOPIC_DATASET]
    assert len(sets) == 2 and sets[0] == 0
    assert out["replay"]["data_changes"] == 2 and out["replay"]["exact"] is True
    _assert_within_spread(out, logged)
    # with the trainer code the fixture was made with, the replay is exact
    cmp = out["replay"]["compared_to_log"]
    assert cmp["epoch"] == logged["epoch"]
    assert cmp["identical"], ("not identical: if the trainer changed since the fixture was made, "
                              "regenerate: python tests/service/test_replay.py --regenerate")


def test_crash_then_resume_replays_across_both_logs() -> None:
    c1, c2 = FIX / "duffing_crash_1.mcap", FIX / "duffing_crash_2.mcap"
    assert not is_finished(c1) and is_finished(c2)
    first_set = [e.event for e in read_events(c2) if e.topic == TOPIC_DATASET][0]
    killed_at = _last_snapshot(c1).epoch
    assert 0 < first_set.epoch < killed_at, "the resume started from an older checkpoint"
    out = replay([c1, c2])
    logged = _last_snapshot(c2).estimate_dict()
    assert out["epoch"] == logged["epoch"]
    assert out["n_recordings"] == logged["n_recordings"] == {"train": 2, "validation": 1}
    _assert_within_spread(out, logged)
    assert out["replay"]["compared_to_log"]["identical"], _THREADS_NOTE
    # the killed run alone (an unfinished file) replays to its own last snapshot
    alone = replay(c1)
    assert alone["epoch"] == killed_at
    _assert_within_spread(alone, _last_snapshot(c1).estimate_dict())


def test_later_log_alone_says_which_logs_are_missing() -> None:
    with pytest.raises(ReplayError, match="earlier logs"):
        replay(FIX / "duffing_crash_2.mcap")


def test_directory_of_logs(tmp_path: Path) -> None:
    d = tmp_path / "logs"
    d.mkdir()
    for f in ("duffing_crash_1.mcap", "duffing_crash_2.mcap"):
        shutil.copy(FIX / f, d / f)
    assert replay(d)["epoch"] == _last_snapshot(FIX / "duffing_crash_2.mcap").epoch
    with pytest.raises(ReplayError, match="no .mcap"):
        replay(tmp_path / "logs" / "..")


def test_live_service_run_replays_exactly(tmp_path: Path) -> None:
    log = clean_run(tmp_path, epochs=30, change_at=10)
    out = replay(log)
    logged = _last_snapshot(log).estimate_dict()
    assert out["epoch"] == logged["epoch"] >= 30
    _assert_within_spread(out, logged)  # the requirement
    cmp = out["replay"]["compared_to_log"]
    assert cmp["identical"], _THREADS_NOTE + f" ({cmp})"
    for p, s in logged["parameters"].items():
        assert out["parameters"][p]["mean"] == s["mean"] and out["parameters"][p]["std"] == s["std"]
    assert out["discriminator"]["loss_d"] == pytest.approx(logged["discriminator"]["loss_d"],
                                                           rel=1e-12)


def test_cli_writes_the_estimate(tmp_path: Path) -> None:
    from siva_cli import main

    out = tmp_path / "est.json"
    assert main(["replay", str(FIX / "duffing_run.mcap"), "--out", str(out)]) == 0
    body = json.loads(out.read_text())
    assert body["epoch"] == _last_snapshot(FIX / "duffing_run.mcap").epoch
    assert body["parameters"]["k"]["mean"] > 0
    assert main(["replay", str(tmp_path / "missing.mcap")]) == 2


def test_log_without_dataset_events_uses_arrival_epochs(tmp_path: Path) -> None:
    with EventLog(tmp_path) as ev:
        ev.log_spec("d", {**__import__("tomllib").loads(SPEC_TOML.read_text())},
                    settings={"seed": 3})
        ev.log_recording("d", "a", "train", decimated("train_v5.csv"), "csv", 0)
        ev.log_recording("d", "b", "validation", decimated("val_v3.csv"), "csv", 0)
        ev.log_snapshot("d", {"parameters": {}, "discriminator": {}, "epoch": 6,
                              "converged": False, "n_recordings": {"train": 1, "validation": 1}})
        path = ev.path("d")
    out = replay(path)
    assert out["epoch"] == 6 and out["replay"]["exact"] is False
    assert out["replay"]["settings"] == {"seed": 3}
    assert set(out["parameters"]) == {"b", "b_nl", "k", "k_nl"}


def test_unreplayable_logs_are_refused_with_a_reason(tmp_path: Path) -> None:
    with EventLog(tmp_path) as ev:
        ev.log_recording("x", "a", "train", decimated("train_v5.csv"), "csv", 0)
        no_spec = ev.path("x")
    with pytest.raises(ReplayError, match="no /siva/spec"):
        replay(no_spec)
    with EventLog(tmp_path) as ev:
        ev.log_spec("y", {"name": "y", "dofs": ["x"], "mass": {"x": 1.0},
                          "elements": [{"kind": "spring", "between": ["x", "ground"],
                                        "params": {"k": "k"}}]})
        untrained = ev.path("y")
    with pytest.raises(ReplayError, match="no training"):
        replay(untrained)
    with pytest.raises(ReplayError, match="several systems"):
        replay([no_spec, untrained])
    with pytest.raises(ReplayError, match="no such"):
        replay(tmp_path / "nope.mcap")


if __name__ == "__main__":
    import tempfile

    if "--regenerate" not in sys.argv:
        sys.exit("usage: python tests/service/test_replay.py --regenerate")
    with tempfile.TemporaryDirectory() as tmp:
        regenerate(Path(tmp))
