"""`siva replay` of a log cut off by kill -9 stops at the last published snapshot: the
data-set changes logged after it describe training nobody saw (before: the replay trained
past the snapshot and differed from the live estimate by 13-45 standard deviations)."""
from __future__ import annotations

from service.storage.eventlog import EventLog
from service.replay.plan import log_files, plan_replay

SPEC = {"name": "s", "dofs": ["x"], "mass": {"x": 0.05}, "elements": [
    {"kind": "spring", "between": ["x", "ground"], "params": {"k": "k"}}]}


def _estimate(epoch: int) -> dict:
    return {"parameters": {}, "discriminator": {}, "epoch": epoch, "converged": False,
            "n_recordings": {"train": 1, "validation": 1}}


def _log(tmp_path, events) -> list:
    log = EventLog(tmp_path)
    log.log_spec("s", SPEC)
    log.log_recording("s", "r1", "train", b"a", "csv", 0)
    log.log_recording("s", "r2", "validation", b"b", "csv", 0)
    for kind, epoch, ids in events:
        if kind == "dataset":
            log.log_dataset("s", epoch, ids[:1], ids[1:])
        else:
            log.log_snapshot("s", _estimate(epoch))
    path = log.path("s")
    return [path]  # not closed: a process killed -9


def test_cut_off_log_ends_at_its_last_snapshot(tmp_path):
    files = _log(tmp_path, [("dataset", 0, ["r1", "r2"]), ("snapshot", 4, None),
                            ("dataset", 6, ["r2", "r1"])])
    plan = plan_replay(log_files(files))
    assert plan.final_epoch == 4
    assert [d.epoch for d in plan.datasets] == [0]
    assert plan.final_snapshot is not None and plan.final_snapshot.epoch == 4


def test_earlier_logs_keep_changes_after_their_last_snapshot(tmp_path):
    """In an earlier log a change after its last snapshot stays: a checkpoint taken after
    it carries its effect into the next log, which resumes at the checkpoint."""
    first = _log(tmp_path / "a", [("dataset", 0, ["r1", "r2"]), ("snapshot", 4, None),
                                  ("dataset", 5, ["r2", "r1"])])
    second = _log(tmp_path / "b", [("dataset", 8, ["r2", "r1"]), ("snapshot", 10, None)])
    plan = plan_replay([first[0], second[0]])
    assert [d.epoch for d in plan.datasets] == [0, 5, 8]
    assert plan.final_epoch == 10
