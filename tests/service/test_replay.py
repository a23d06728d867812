"""`siva replay`: a log re-run offline gives the live service's estimate.

The fixtures under tests/fixtures/ are real service logs (regenerate them with
``python tests/service/test_replay.py --regenerate`` after a change to training that
moves the numbers): ``duffing_run.mcap`` is a clean run whose data set changes mid-run;
``duffing_crash_1.mcap`` is the unfinished log of a ``siva serve`` killed with SIGKILL and
``duffing_crash_2.mcap`` the log of the next start, which resumed from the periodic
checkpoint (older than the moment of the kill); ``duffing_run_default_capability.mcap`` is
the clean run made with torch's portable kernels (``ATEN_CPU_CAPABILITY=default``), and
``duffing_run_no_fingerprint.mcap`` one logged on another machine before logs recorded
their platform.

Which verdict is right depends on where the tests run: a fixture whose platform
fingerprint is this one must replay bit-identically; any other (another CPU capability,
library build, or no fingerprint) must be ``reproduced`` within the stated tolerance - or
identical, when the arithmetic happens to agree.  `make test-platform` runs this file with
``ATEN_CPU_CAPABILITY=default`` so both cases are exercised on every CI run.
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

from service.storage.eventlog import (TOPIC_DATASET, TOPIC_SNAPSHOT, EventLog, is_finished,  # noqa: E402
                              read_events)
from service.replay.run import REPRODUCED_TOLERANCE_IN_STD, ReplayError, replay  # noqa: E402

SPEC_TOML = ROOT / "examples" / "models" / "duffing.toml"
#: the clean run made with torch's portable kernels (ATEN_CPU_CAPABILITY=default)
OTHER_CAPABILITY = FIX / "duffing_run_default_capability.mcap"
#: a clean run logged before logs carried a platform fingerprint (another machine)
NO_FINGERPRINT = FIX / "duffing_run_no_fingerprint.mcap"


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


def _assert_verdict(cmp: dict) -> None:
    """The verdict the platform calls for: identical on the log's own platform, else
    reproduced within the tolerance (or identical)."""
    plat = cmp["platform"]
    assert cmp["tolerance_in_std"] == REPRODUCED_TOLERANCE_IN_STD
    assert (cmp["verdict"] == "identical") == cmp["identical"]
    if plat["matches"]:
        assert plat["expected"] == "identical" and not plat["differences"]
        assert cmp["verdict"] == "identical", (
            f"not identical on the log's own platform ({cmp['max_diff_in_std']} std): if the "
            "trainer changed since the fixture was made, regenerate: "
            "python tests/service/test_replay.py --regenerate")
    else:
        assert plat["expected"] == "reproduced" and plat["differences"]
        assert cmp["verdict"] in ("identical", "reproduced"), cmp
        assert cmp["max_diff_in_std"] <= REPRODUCED_TOLERANCE_IN_STD, cmp


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
    """All fixtures but the pre-fingerprint one: three on this platform, one with torch's
    portable kernels (``ATEN_CPU_CAPABILITY=default``: another platform for the replay)."""
    FIX.mkdir(parents=True, exist_ok=True)
    shutil.copy(clean_run(tmp / "clean"), FIX / "duffing_run.mcap")
    crash_and_resume(tmp / "crash", FIX)
    env = {**os.environ, "ATEN_CPU_CAPABILITY": "default", "PYTHONPATH": str(ROOT)}
    subprocess.run([sys.executable, __file__, "--clean-run", str(tmp / "default"),
                    str(FIX / OTHER_CAPABILITY.name)], env=env, check=True)
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
    # with the trainer code the fixture was made with, the replay is exact on its platform
    cmp = out["replay"]["compared_to_log"]
    assert cmp["epoch"] == logged["epoch"]
    _assert_verdict(cmp)


def test_fixture_of_another_cpu_capability_is_reproduced_or_identical() -> None:
    """Must-show 2: a log made with torch's portable kernels, replayed here."""
    import torch

    out = replay(OTHER_CAPABILITY)
    cmp = out["replay"]["compared_to_log"]
    logged_fp = cmp["platform"]["logged"]
    assert logged_fp["torch_cpu_capability"] == "DEFAULT"
    assert cmp["platform"]["current"]["torch_cpu_capability"] == \
        torch.backends.cpu.get_cpu_capability()
    if torch.backends.cpu.get_cpu_capability() != "DEFAULT":
        assert "torch_cpu_capability" in cmp["platform"]["differences"]
        assert not cmp["platform"]["matches"]
    _assert_verdict(cmp)
    _assert_within_spread(out, _last_snapshot(OTHER_CAPABILITY).estimate_dict())


def test_log_without_a_fingerprint_counts_as_an_unknown_platform() -> None:
    out = replay(NO_FINGERPRINT)
    cmp = out["replay"]["compared_to_log"]
    assert cmp["platform"]["logged"] is None
    assert list(cmp["platform"]["differences"]) == ["platform"]
    assert cmp["platform"]["expected"] == "reproduced"
    _assert_verdict(cmp)


def _tampered_copy(src: Path, dst_dir: Path, shift_in_std: float) -> Path:
    """``src`` re-logged with its last snapshot's ``k`` mean moved by ``shift_in_std`` std."""
    events = read_events(src)
    last = max(i for i, e in enumerate(events) if e.topic == TOPIC_SNAPSHOT)
    with EventLog(dst_dir) as ev:
        for i, e in enumerate(events):
            x = e.event
            if e.topic == "/siva/spec":
                ev.log_spec(x.system, x.spec, settings=x.settings)
            elif e.topic == "/siva/recording":
                ev.log_recording(x.system, x.id, x.role, x.payload(), x.format, x.epoch, x.name)
            elif e.topic == TOPIC_DATASET:
                ev.log_dataset(x.system, x.epoch, x.train, x.validation, x.processing)
            elif e.topic == TOPIC_SNAPSHOT:
                est = x.estimate_dict()
                if i == last:
                    for key in ("parameters", "ensemble"):
                        if key in est and "k" in est[key]:
                            est[key]["k"]["mean"] += shift_in_std * est[key]["k"]["std"]
                ev.log_snapshot(x.system, est)
        return ev.path(events[0].event.system)


def test_a_replay_off_by_more_than_the_tolerance_differs_and_says_where(
        tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    from siva_cli import main

    log = _tampered_copy(FIX / "duffing_run.mcap", tmp_path, shift_in_std=0.5)
    out_json = tmp_path / "est.json"
    assert main(["replay", str(log), "--out", str(out_json)]) == 1
    cmp = json.loads(out_json.read_text())["replay"]["compared_to_log"]
    assert cmp["verdict"] == "differs" and not cmp["identical"]
    assert cmp["platform"]["matches"]  # the copy was logged here
    assert [w["parameter"] for w in cmp["where"]] == ["k"]
    assert cmp["where"][0]["diff_in_std"] == pytest.approx(0.5, abs=0.1)
    assert "note" in cmp  # a difference on the same platform: code change or nondeterminism
    assert "replay: differs" in capsys.readouterr().err
    # a wider tolerance accepts it (the CLI option)
    assert main(["replay", str(log), "--out", str(out_json), "--tolerance", "1"]) == 0
    assert json.loads(out_json.read_text())["replay"]["compared_to_log"]["verdict"] == \
        "reproduced"


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
    cmp = out["replay"]["compared_to_log"]
    assert len(cmp["platform"]["logged"]) > 5  # both logs carry a fingerprint
    _assert_verdict(cmp)
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
    assert cmp["platform"]["matches"], cmp["platform"]["differences"]
    assert cmp["identical"] and cmp["verdict"] == "identical", _THREADS_NOTE + f" ({cmp})"
    for p, s in logged["parameters"].items():
        assert out["parameters"][p]["mean"] == s["mean"] and out["parameters"][p]["std"] == s["std"]
    assert out["discriminator"]["loss_d"] == pytest.approx(logged["discriminator"]["loss_d"],
                                                           rel=1e-12)


def test_cli_writes_the_estimate(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    from siva_cli import main

    out = tmp_path / "est.json"
    assert main(["replay", str(OTHER_CAPABILITY), "--out", str(out)]) == 0
    body = json.loads(out.read_text())
    assert body["epoch"] == _last_snapshot(OTHER_CAPABILITY).epoch
    assert body["parameters"]["k"]["mean"] > 0
    cmp = body["replay"]["compared_to_log"]
    _assert_verdict(cmp)
    # the verdict and the measured difference, on stderr
    err = capsys.readouterr().err
    assert f"replay: {cmp['verdict']} at epoch {cmp['epoch']}" in err
    assert "tolerance 0.1 std" in err
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

    if sys.argv[1:2] == ["--clean-run"]:  # DATA_DIR OUT.mcap (regenerate's subprocess)
        shutil.copy(clean_run(Path(sys.argv[2])), sys.argv[3])
        sys.exit(0)
    if "--regenerate" not in sys.argv:
        sys.exit("usage: python tests/service/test_replay.py --regenerate")
    with tempfile.TemporaryDirectory() as tmp:
        regenerate(Path(tmp))
