"""Start-up reconciliation (issue 19): after each of four damages to a system's event log,
a restart brings the log in line with the store, and `siva replay` of the log folder
exits 0, bit-identical to what the service published after the restart.

Before: the server started healthy, wrote nothing back, and the replay exited 2
("recording ... was used for training but is not in the log(s)", or "resumed from a
checkpoint ... pass the earlier logs") for good; crash recovery left a `.mcap.partial`.

The base data dir has two process starts (two log files): train + validation records,
a stop; a second train record, a stop (its final checkpoint is what the restart resumes).
"""
from __future__ import annotations

import io
import json
import os
import shutil
from pathlib import Path

import pytest

from service.storage.eventlog import TOPIC_RECORDING, TOPIC_REPAIR, is_finished, read_events
from service.storage.eventlog.reader import _good_records

ROOT = Path(__file__).resolve().parents[2]
DATA = Path(os.environ.get("SIVA_SHARED_DATA") or ROOT.parent / "shared" / "data") / "duffing"
SPEC_TOML = ROOT / "examples" / "models" / "duffing.toml"


def _decimated(name: str, offset: int = 0, k: int = 10) -> bytes:
    lines = (DATA / name).read_text().splitlines()
    return ("\n".join([lines[0]] + lines[1 + offset::k]) + "\n").encode()


def _settings(data_dir: Path):
    from service.settings import Settings

    return Settings(data_dir=data_dir, snapshot_every=2, checkpoint_every_s=3600)


def _wait_epoch(c, epoch: int, timeout: float = 120.0) -> dict:
    import time

    deadline = time.monotonic() + timeout
    while True:
        est = c.estimate("duffing")
        if est["epoch"] >= epoch:
            return est
        assert time.monotonic() < deadline, f"epoch {epoch} not reached: {est['epoch']}"
        time.sleep(0.05)


def _run(data_dir: Path, uploads: list[tuple[bytes, str]], epochs: int) -> None:
    """One process start: register (idempotent), upload, train ``epochs`` more, stop."""
    from clients import SivaClient
    from service.demo import ServerThread

    with ServerThread(_settings(data_dir)) as url, SivaClient(url) as c:
        c.register("duffing", SPEC_TOML)
        start = c.estimate("duffing")["epoch"]
        for body, role in uploads:
            c.upload("duffing", body, role=role)
        _wait_epoch(c, start + epochs)


@pytest.fixture(scope="module")
def base(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("base")
    _run(d, [(_decimated("train_v5.csv"), "train"), (_decimated("val_v3.csv"), "validation")], 6)
    _run(d, [(_decimated("train_v5.csv", offset=5), "train")], 6)
    assert len(list((d / "logs" / "duffing").glob("*.mcap"))) == 2
    return d


def _logs(d: Path) -> list[Path]:
    return sorted((d / "logs" / "duffing").glob("*.mcap"))


def _stored_ids(d: Path) -> set[str]:
    return {p.name[:-len(".json")] for p in (d / "systems" / "duffing" / "recordings").glob("*.json")}


def _drop_last_recording_chunk(path: Path) -> None:
    """Cut the chunk that holds the newest log's last recording out of the file."""
    from mcap.exceptions import EndOfFile
    from mcap.records import Message
    from mcap.stream_reader import StreamReader

    raw = path.read_bytes()
    last = None
    for a, b in _good_records(raw):
        try:
            for rec in StreamReader(io.BytesIO(raw[a:b]), skip_magic=True).records:
                if isinstance(rec, Message) and b'"sha256"' in rec.data:
                    last = (a, b)
        except EndOfFile:
            pass
    assert last is not None
    path.write_bytes(raw[:last[0]] + raw[last[1]:])


def _damage(d: Path, kind: str) -> None:
    newest = _logs(d)[-1]
    if kind == "last recording chunk dropped":
        _drop_last_recording_chunk(newest)
    elif kind == "newest log truncated mid-chunk":
        raw = newest.read_bytes()
        a, b = next((a, b) for a, b in _good_records(raw) if b > len(raw) // 2)
        newest.write_bytes(raw[:(a + b) // 2])  # mid-way through a chunk
        # what an earlier version's crash recovery left behind: cleaned up too
        shutil.copy(_logs(d)[0], _logs(d)[0].with_name(_logs(d)[0].name + ".partial"))
    elif kind == "newest log deleted":
        newest.unlink()
    elif kind == "log folder deleted":
        shutil.rmtree(d / "logs")
    elif kind != "none":
        raise AssertionError(kind)


DAMAGES = ["last recording chunk dropped", "newest log truncated mid-chunk",
           "newest log deleted", "log folder deleted"]


@pytest.mark.parametrize("damage", DAMAGES + ["none"])
def test_restart_after_log_damage_replays(base: Path, tmp_path: Path, damage: str,
                                          capsys: pytest.CaptureFixture) -> None:
    from siva_cli import main

    d = tmp_path / "data"
    shutil.copytree(base, d)
    before = {p.name for p in _logs(d)}
    _damage(d, damage)
    if damage in ("last recording chunk dropped", "log folder deleted"):
        # what the issue found: no replay (exit 2) - and a restart used to change nothing
        assert main(["replay", str(d / "logs" / "duffing"), "--out", str(tmp_path / "o.json")]) == 2

    _run(d, [], 4)  # restart: reconcile, resume from the checkpoint, train on, stop

    new = [p for p in _logs(d) if p.name not in before]
    assert len(new) == 1, [p.name for p in _logs(d)]
    repairs = [e.event for e in read_events(new[0]) if e.topic == TOPIC_REPAIR]
    if damage == "none":
        assert repairs == [], "an intact log needs no repair"
    else:
        (repair,) = repairs  # the repair itself is logged
        assert repair.reasons
    # the log holds every stored recording (the store is the truth), with the same bytes
    logged = {e.event.id: e.event for p in _logs(d) for e in read_events(p)
              if e.topic == TOPIC_RECORDING}
    assert set(logged) == _stored_ids(d) and len(logged) == 3
    for rid, ev in logged.items():
        meta = json.loads((d / "systems" / "duffing" / "recordings" / f"{rid}.json").read_text())
        assert ev.sha256 == meta["sha256"]
    assert not list((d / "logs").rglob("*.partial")), "no .partial copies left"
    assert all(is_finished(p) for p in _logs(d))

    out = tmp_path / "replay.json"
    capsys.readouterr()
    assert main(["replay", str(d / "logs" / "duffing"), "--out", str(out)]) == 0
    body = json.loads(out.read_text())
    cmp = body["replay"]["compared_to_log"]
    assert body["n_recordings"] == {"train": 2, "validation": 1}
    # the log was made here: the replay is bit-identical to the last published estimate
    assert cmp["platform"]["matches"] and cmp["verdict"] == "identical", cmp


def test_a_baseline_supersedes_earlier_files_even_of_another_spec(tmp_path: Path) -> None:
    """A system deleted and created again (another spec) whose log was then repaired: the
    replay starts at the repair's baseline and does not trip over the older incarnation."""
    from service.storage.eventlog import EventLog
    from service.replay.plan import log_files, plan_replay
    from service.replay.run import explains

    def spec(k: str) -> dict:
        return {"name": "s", "dofs": ["x"], "mass": {"x": 0.05}, "elements": [
            {"kind": "spring", "between": ["x", "ground"], "params": {"k": k}}]}

    est = {"parameters": {}, "discriminator": {}, "converged": False,
           "n_recordings": {"train": 1, "validation": 1}}
    with EventLog(tmp_path) as old:
        old.log_spec("s", spec("k_old"))
        old.log_recording("s", "r1", "train", b"a", "csv", 0)
        old.log_recording("s", "r2", "validation", b"b", "csv", 0)
        old.log_dataset("s", 0, ["r1"], ["r2"])
        old.log_snapshot("s", {**est, "epoch": 4})
    files = log_files(tmp_path / "logs" / "s")
    assert explains(files, 4, ["r1"], ["r2"]) is None
    with EventLog(tmp_path) as new:
        new.log_spec("s", spec("k"))
        new.log_repair("s", ["the log cannot reproduce the checkpoint"], [],
                       {"epoch": 10, "state": b"state", "train": ["r1"], "validation": ["r2"]})
        new.log_dataset("s", 10, ["r1"], ["r2"])
        new.log_snapshot("s", {**est, "epoch": 12})
    files = log_files(tmp_path / "logs" / "s")
    assert len(files) == 2
    plan = plan_replay(files)
    assert plan.spec.spec == spec("k") and set(plan.recordings) == {"r1", "r2"}
    assert [d.epoch for d in plan.datasets] == [10] and plan.final_epoch == 12
    assert plan.baselines[0].baseline_epoch == 10 and plan.baselines[0].state_bytes() == b"state"
    assert explains(files, 12, ["r1"], ["r2"]) is None
    assert "not the one" in explains(files, 12, ["r2"], ["r1"])
