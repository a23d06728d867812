"""MCAP event logs: standard-readable, typed, crash-safe, recoverable."""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import warnings
from pathlib import Path

import pytest
from mcap.reader import NonSeekingReader, make_reader

from service.storage.eventlog.fingerprint import platform_fingerprint
from service.storage.eventlog import (TOPIC_DATASET, TOPIC_RECORDING, TOPIC_SNAPSHOT, TOPIC_SPEC,
                                      EventLog, RecordingEvent, SnapshotEvent, is_finished,
                                      read_events, recover)

ROOT = Path(__file__).resolve().parents[2]
SPEC = {"name": "duffing", "dofs": ["x"], "mass": {"x": 0.05},
        "elements": [{"kind": "spring", "between": ["x", "ground"], "params": {"k": "k"}}]}
CSV = b"time,acc_x\n" + b"".join(f"{i / 100:.2f},{(i % 7) - 3}\n".encode() for i in range(200))


def _snapshot(epoch: int) -> dict:
    return {"parameters": {"k": {"mean": 300.0 + epoch, "std": 1.0, "ci95": [298.0, 302.0]}},
            "discriminator": {"loss_d": 1.38}, "epoch": epoch, "converged": epoch > 5,
            "n_recordings": {"train": 1, "validation": 1}, "state": "training"}


def _fill(ev: EventLog, system: str = "duffing", n_snap: int = 3) -> None:
    ev.log_spec(system, SPEC)
    ev.log_recording(system, "r1", "train", CSV, "csv", 0, name="a.csv")
    ev.log_recording(system, "r2", "validation", CSV + b"\n", "csv", 0)
    ev.log_dataset(system, 0, ["r1"], ["r2"])
    for e in range(n_snap):
        ev.log_snapshot(system, _snapshot(5 * (e + 1)))


def test_the_logged_estimate_is_the_api_estimate_without_importing_it() -> None:
    """The log keeps its own estimate model (it does not import the HTTP schemas); its
    typed keys are the API's contract keys, with the same types, so the two cannot drift."""
    from service.api.schemas import Estimate
    from service.storage.eventlog import LoggedEstimate

    logged = LoggedEstimate.model_fields
    api = Estimate.model_fields
    assert set(logged) <= set(api)
    for key, field in logged.items():
        assert field.is_required() and api[key].is_required(), key
    body = {"parameters": {"k": {"mean": 1.0}}, "discriminator": {}, "epoch": 3,
            "converged": False, "n_recordings": {"train": 1}, "state": "training"}
    assert LoggedEstimate.model_validate(body).model_dump(mode="json") == body


def test_standard_reader_sees_schemas_channels_and_summary(tmp_path: Path) -> None:
    ev = EventLog(tmp_path, settings={"seed": 7, "preset": "fast"})
    _fill(ev)
    path = ev.path("duffing")
    assert path is not None and path.parent == tmp_path / "logs" / "duffing"
    ev.close()
    assert is_finished(path)
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert summary.statistics.message_count == 7
        topics = {c.topic: c for c in summary.channels.values()}
        assert set(topics) == {TOPIC_SPEC, TOPIC_RECORDING, TOPIC_DATASET, TOPIC_SNAPSHOT}
        for ch in topics.values():
            assert ch.message_encoding == "json"
            schema = summary.schemas[ch.schema_id]
            assert schema.encoding == "jsonschema"
            js = json.loads(schema.data)
            assert js["type"] == "object" and "properties" in js
        # the snapshot schema types the estimate's contract keys (the log's own model)
        snap_schema = json.loads(summary.schemas[topics[TOPIC_SNAPSHOT].schema_id].data)
        est = snap_schema["$defs"]["LoggedEstimate"]
        assert {"parameters", "discriminator", "epoch", "converged",
                "n_recordings"} <= set(est["required"])
        msgs = [(c.topic, json.loads(m.data)) for _s, c, m in reader.iter_messages()]
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
    assert [t for t, _ in msgs] == [TOPIC_SPEC, TOPIC_RECORDING, TOPIC_RECORDING, TOPIC_DATASET,
                                    TOPIC_SNAPSHOT, TOPIC_SNAPSHOT, TOPIC_SNAPSHOT]
    assert msgs[0][1]["spec"] == SPEC and msgs[0][1]["settings"] == {"seed": 7, "preset": "fast"}
    assert meta["siva"]["system"] == "duffing" and meta["siva"]["settings.seed"] == "7"
    # the platform a bit-identical replay needs (service/fingerprint.py)
    assert meta["siva.platform"] == platform_fingerprint()
    assert {"python", "torch", "numpy", "scipy", "numba", "torch_cpu_capability",
            "torch_blas", "numpy_blas", "cpu_simd"} <= set(meta["siva.platform"])
    # the non-seeking (streaming) reader of the mcap library reads the same
    with open(path, "rb") as fh:
        n = sum(1 for _ in NonSeekingReader(fh).iter_messages(log_time_order=False))
    assert n == 7


def test_recording_bytes_round_trip_and_are_checked(tmp_path: Path) -> None:
    with EventLog(tmp_path) as ev:
        _fill(ev)
        path = ev.path("duffing")
    events = read_events(path)
    recs = [e.event for e in events if e.topic == TOPIC_RECORDING]
    assert [r.id for r in recs] == ["r1", "r2"] and recs[0].role == "train"
    assert recs[0].payload() == CSV and recs[1].payload() == CSV + b"\n"
    assert recs[0].name == "a.csv" and recs[0].size == len(CSV)
    bad = RecordingEvent(**{**recs[0].model_dump(), "data": recs[1].data})
    with pytest.raises(ValueError, match="sha256"):
        bad.payload()
    snaps = [e.event for e in events if e.topic == TOPIC_SNAPSHOT]
    assert isinstance(snaps[-1], SnapshotEvent) and snaps[-1].epoch == 15
    assert snaps[-1].estimate_dict()["state"] == "training"  # extra keys survive
    times = [e.log_time for e in events]
    assert times == sorted(times) and len(set(times)) == len(times)


def test_each_message_is_durable_before_close_and_recover_finishes_it(tmp_path: Path) -> None:
    ev = EventLog(tmp_path)
    _fill(ev)
    live = ev.path("duffing")
    crashed = tmp_path / "crashed.mcap"
    shutil.copy(live, crashed)  # what is on disk right now, as if the process died here
    ev.close()
    assert not is_finished(crashed)
    assert len(read_events(crashed)) == 7
    out = recover(crashed)
    assert out == crashed and is_finished(out)
    assert (tmp_path / "crashed.mcap.partial").exists()
    with open(out, "rb") as fh:
        reader = make_reader(fh)
        assert reader.get_summary().statistics.message_count == 7
        assert [json.loads(m.data) for _s, _c, m in reader.iter_messages()] == \
            [json.loads(m.data) for _s, _c, m in make_reader(open(live, "rb")).iter_messages()]
    assert recover(out) == out  # already finished: unchanged


def test_truncation_anywhere_keeps_a_readable_prefix(tmp_path: Path) -> None:
    ev = EventLog(tmp_path)
    _fill(ev, n_snap=2)
    raw = ev.path("duffing").read_bytes()
    ev.close()
    full = 6  # spec, 2 recordings, dataset, 2 snapshots
    counts = []
    cut_file = tmp_path / "cut.mcap"
    # every cut point in the tail (the last two messages) and a spread over the rest
    cuts = sorted(set(range(max(0, len(raw) - 1200), len(raw) + 1)) | set(range(0, len(raw), 97)))
    for cut in cuts:
        cut_file.write_bytes(raw[:cut])
        if cut < 8:  # a crash while writing the magic: an empty log, not an error
            assert read_events(cut_file) == []
            continue
        counts.append(len(read_events(cut_file)))
    cut_file.write_bytes(b"NOTMCAP!" + raw[8:])
    with pytest.raises(Exception):
        read_events(cut_file)
    assert counts == sorted(counts), "a longer prefix never yields fewer events"
    assert counts[-1] == full and min(counts) == 0
    # a torn chunk in the middle of the file ends the good data there, and recover keeps it
    cut_file.write_bytes(raw[: len(raw) - 600])
    kept = len(read_events(cut_file))
    assert 0 < kept < full
    recovered = recover(cut_file)
    with open(recovered, "rb") as fh:
        assert make_reader(fh).get_summary().statistics.message_count == kept


def test_garbage_tail_is_cut(tmp_path: Path) -> None:
    ev = EventLog(tmp_path)
    _fill(ev, n_snap=1)
    raw = ev.path("duffing").read_bytes()
    ev.close()
    f = tmp_path / "zeros.mcap"
    f.write_bytes(raw + b"\x00" * 4096)  # what a crash can leave in pre-allocated blocks
    assert len(read_events(f)) == 5
    flipped = bytearray(raw)
    flipped[-40] ^= 0xFF  # corrupt the last chunk's compressed bytes: its CRC fails
    f.write_bytes(bytes(flipped))
    assert len(read_events(f)) == 4
    assert is_finished(recover(f))


_KILL_SCRIPT = r"""
import os, signal, sys
sys.path.insert(0, {root!r})
from service.storage.eventlog import EventLog
ev = EventLog({data!r})
ev.log_spec("sys1", {{"name": "m", "dofs": ["x"]}})
ev.log_recording("sys1", "r1", "train", b"time,acc_x\n0,1\n", "csv", 0)
ev.log_snapshot("sys1", {{"parameters": {{}}, "discriminator": {{}}, "epoch": 3,
                          "converged": False, "n_recordings": {{"train": 1, "validation": 0}}}})
print(ev.path("sys1"), flush=True)
os.kill(os.getpid(), signal.SIGKILL)
"""


def test_sigkill_mid_run_then_next_start_recovers(tmp_path: Path) -> None:
    data = tmp_path / "data"
    proc = subprocess.run([sys.executable, "-c", _KILL_SCRIPT.format(root=str(ROOT), data=str(data))],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    path = Path(proc.stdout.strip())
    assert path.exists() and not is_finished(path)
    assert [e.topic for e in read_events(path)] == [TOPIC_SPEC, TOPIC_RECORDING, TOPIC_SNAPSHOT]
    ev = EventLog(data)  # a new service process: finishes what the dead one left
    assert ev.recovered == [path]
    # the service keeps no .partial copy; the recovery is noted in the finished file
    assert is_finished(path) and not path.with_name(path.name + ".partial").exists()
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        assert reader.get_summary().statistics.message_count == 3
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
    assert int(meta["siva.recovery"]["bytes_kept"]) <= int(meta["siva.recovery"]["bytes_total"])
    ev.close()


def test_files_per_system_and_per_process_start(tmp_path: Path) -> None:
    a = EventLog(tmp_path)
    a.log_spec("one", SPEC)
    a.log_spec("two", SPEC)
    assert a.path("one") != a.path("two") and a.path("three") is None
    a.close()
    b = EventLog(tmp_path)
    b.log_spec("one", SPEC)
    b.close()
    files = sorted((tmp_path / "logs" / "one").glob("*.mcap"))
    assert len(files) == 2 and all(is_finished(f) for f in files)


def test_recreated_system_starts_a_new_file(tmp_path: Path) -> None:
    ev = EventLog(tmp_path)
    ev.log_spec("s", SPEC)
    ev.log_recording("s", "r1", "train", CSV, "csv", 0)
    first = ev.path("s")
    ev.log_spec("s", {**SPEC, "mass": {"x": 0.1}})  # DELETE + PUT in the same process
    second = ev.path("s")
    ev.log_recording("s", "r1", "train", CSV + b"\n", "csv", 0)
    ev.close()
    assert first != second and is_finished(first) and is_finished(second)
    assert [e.topic for e in read_events(first)] == [TOPIC_SPEC, TOPIC_RECORDING]
    assert read_events(second)[0].event.spec["mass"] == {"x": 0.1}


def test_closed_log_drops_events_instead_of_raising(tmp_path: Path) -> None:
    ev = EventLog(tmp_path)
    ev.log_spec("s", SPEC)
    ev.close()
    ev.close()  # idempotent
    import logging

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        logging.disable(logging.CRITICAL)
        try:
            ev.log_snapshot("s", _snapshot(1))
        finally:
            logging.disable(logging.NOTSET)
    assert len(read_events(next((tmp_path / "logs" / "s").glob("*.mcap")))) == 1


def test_concurrent_writers_lose_nothing(tmp_path: Path) -> None:
    ev = EventLog(tmp_path)
    ev.log_spec("s", SPEC)

    def work(k: int) -> None:
        for i in range(20):
            ev.log_recording("s", f"t{k}-{i}", "train", CSV + str(i).encode(), "csv", i)

    threads = [threading.Thread(target=work, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    path = ev.path("s")
    ev.close()
    with open(path, "rb") as fh:
        msgs = [(c.topic, m.sequence) for _s, c, m in make_reader(fh).iter_messages()]
    recs = [seq for topic, seq in msgs if topic == TOPIC_RECORDING]
    assert sorted(recs) == list(range(1, 81)) and recs == sorted(recs)


def test_role_and_format_are_validated(tmp_path: Path) -> None:
    with EventLog(tmp_path) as ev:
        ev.log_recording("s", "r1", "val", CSV, "csv", 0)
        with pytest.raises(ValueError):
            ev.log_recording("s", "r2", "test", CSV, "csv", 0)
        with pytest.raises(ValueError):
            ev.log_recording("s", "r3", "train", CSV, "csv", -1)
        path = ev.path("s")
    (rec,) = [e.event for e in read_events(path)]
    assert rec.role == "validation"


@pytest.mark.skipif(shutil.which("node") is None or not os.environ.get("SIVA_MCAP_NODE_MODULES"),
                    reason="cross-check with the TypeScript @mcap/core reader: set "
                           "SIVA_MCAP_NODE_MODULES to a node_modules with @mcap/core, @mcap/support")
def test_typescript_reader_reads_the_log(tmp_path: Path) -> None:
    with EventLog(tmp_path) as ev:
        _fill(ev)
        path = ev.path("duffing")
    script = tmp_path / "read.cjs"
    script.write_text(
        "const fs=require('fs');const {McapIndexedReader}=require('@mcap/core');"
        "const {loadDecompressHandlers}=require('@mcap/support');"
        "(async()=>{const buf=fs.readFileSync(process.argv[2]);"
        "const readable={size:async()=>BigInt(buf.length),read:async(o,l)=>"
        "buf.subarray(Number(o),Number(o+l))};"
        "const r=await McapIndexedReader.Initialize({readable,"
        "decompressHandlers:await loadDecompressHandlers()});let n=0;"
        "for await (const m of r.readMessages()){JSON.parse(Buffer.from(m.data));n++;}"
        "console.log(n);})();")
    env = {**os.environ, "NODE_PATH": os.environ["SIVA_MCAP_NODE_MODULES"]}
    out = subprocess.run(["node", str(script), str(path)], capture_output=True, text=True,
                         env=env, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "7"
