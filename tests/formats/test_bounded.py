"""Bounded parsing: small uploads that would decompress or nest into a lot of memory are
refused before allocating (RecordingTooLarge -> HTTP 413), and odd numbers are refused."""
from __future__ import annotations

import io
import json
import subprocess
import sys
import textwrap
import zipfile

import numpy as np
import pytest

from siva_core import Recording, RecordingError
from siva_core import ReadLimits, RecordingTooLarge

DOFS = ["x"]


def npz_bomb(n_values: int = 64_000_000) -> bytes:
    """~0.5 MB of deflated zeros that declares ``n_values`` float64 values (512 MB)."""
    header = {"descr": "<f8", "fortran_order": False, "shape": (n_values,)}
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED, compresslevel=9) as z:
        with z.open("acc_x.npy", "w", force_zip64=True) as fh:
            np.lib.format.write_array_header_1_0(fh, header)
            block = bytes(1 << 20)
            left = n_values * 8
            while left:
                fh.write(block[:min(left, len(block))])
                left -= min(left, len(block))
        z.writestr("time.npy", _npy(np.arange(16) * 0.01))
    return buf.getvalue()


def _npy(arr: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, arr)
    return buf.getvalue()


def mcap_zstd_bomb(n_values: int = 200_000_000) -> bytes:
    """A zstd-compressed chunk holding one JSON message of ``n_values`` zeros (~400 MB)."""
    from mcap.writer import CompressionType, Writer

    body = b'{"time": [' + b"0," * (n_values - 1) + b'0], "acc_x": [0]}'
    buf = io.BytesIO()
    w = Writer(buf, compression=CompressionType.ZSTD, chunk_size=len(body) + 1024)
    w.start()
    sid = w.register_schema(name="siva.Recording", encoding="jsonschema", data=b"{}")
    cid = w.register_channel(topic="/recording", message_encoding="json", schema_id=sid)
    w.add_message(cid, log_time=0, publish_time=0, data=body)
    w.finish()
    return buf.getvalue()


def _peak_rss_growth_mb(code: str) -> str:
    """A program that runs ``code`` and prints its peak-RSS growth (MB) after the imports."""
    # VmHWM, not ru_maxrss: Linux carries ru_maxrss over from the forking parent (pytest,
    # which just built the bombs), which hides the child's own growth.
    prog = textwrap.dedent("""
        import re, sys
        def hwm_mb():
            return int(re.search(r"VmHWM:\\s*(\\d+)", open('/proc/self/status').read())[1]) / 1024
        from siva_core import Recording, RecordingError
        import mcap.stream_reader, zstandard
        import siva_core; siva_core.RECORDING_FORMATS  # the readers, loaded before measuring
        raw = open(sys.argv[1], 'rb').read()
        base = hwm_mb()
        """) + textwrap.dedent(code) + textwrap.dedent("""
        print('GROWTH_MB', hwm_mb() - base)
        """)
    return prog


@pytest.fixture(scope="module")
def bombs(tmp_path_factory) -> dict[str, object]:
    d = tmp_path_factory.mktemp("bombs")
    out = {}
    for name, make in (("npz", npz_bomb), ("mcap", mcap_zstd_bomb)):
        raw = make()
        (d / f"bomb.{name}").write_bytes(raw)
        out[name] = d / f"bomb.{name}"
    return out


@pytest.mark.parametrize("fmt", ["npz", "mcap"])
def test_bomb_refused_with_bounded_memory(bombs, fmt):
    path = bombs[fmt]
    size_mb = path.stat().st_size / 2**20
    assert size_mb < 0.6
    prog = _peak_rss_growth_mb(f"""
        try:
            Recording.read(raw, ['x'], fmt={fmt!r}, name='bomb')
            print('ACCEPTED')
        except RecordingError as exc:
            print('REFUSED', type(exc).__name__, exc)
        """)
    run = subprocess.run([sys.executable, "-c", prog, str(path)], capture_output=True,
                         text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    assert "REFUSED RecordingTooLarge" in run.stdout, run.stdout
    growth = float(run.stdout.split("GROWTH_MB")[1])
    print(f"{fmt} bomb {size_mb:.2f} MB: peak RSS growth {growth:.1f} MB; {run.stdout}")
    assert growth < 200


@pytest.mark.slow  # ~10 s and ~1 GB for a moment: the control, not the guard
def test_the_memory_measurement_sees_an_unguarded_read(bombs):
    """Control: with the limit lifted the same NPZ bomb is decompressed (> 400 MB growth), so
    the measurement above can fail."""
    prog = _peak_rss_growth_mb("""
        from siva_core import ReadLimits
        try:
            Recording.read(raw, ['x'], fmt='npz', limits=ReadLimits(max_decompressed_bytes=2**40))
        except RecordingError as exc:
            print('REFUSED', exc)
        """)
    run = subprocess.run([sys.executable, "-c", prog, str(bombs["npz"])], capture_output=True,
                         text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    assert float(run.stdout.split("GROWTH_MB")[1]) > 400, run.stdout


def test_npz_reads_only_the_model_columns():
    """A huge member the model does not use is never opened (and is listed as ignored)."""
    buf = io.BytesIO()
    t = np.arange(64) * 0.01
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("time.npy", _npy(t))
        z.writestr("acc_x.npy", _npy(np.sin(t)))
        z.writestr("acc_y.npy", b"not even an npy member")
    with pytest.warns(UserWarning, match="acc_y"):
        rec = Recording.read(buf.getvalue(), DOFS, fmt="npz")
    assert list(rec.channels) == ["acc_x"] and rec.meta["ignored_columns"] == ["acc_y"]


def test_npz_member_count_and_declared_size_checked_first():
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        for k in range(300):
            z.writestr(f"junk{k}.npy", b"")
    with pytest.raises(RecordingTooLarge, match="300 archive members, at most 256"):
        Recording.read(buf.getvalue(), DOFS, fmt="npz")
    t = np.arange(64) * 0.01
    raw = io.BytesIO()
    np.savez(raw, time=t, acc_x=t)
    with pytest.raises(RecordingTooLarge, match="above the limit"):
        Recording.read(raw.getvalue(), DOFS, fmt="npz",
                       limits=ReadLimits(max_decompressed_bytes=1000))


def test_npz_lying_header_refused():
    """A .npy header claiming more values than the member holds: refused, not allocated."""
    member = io.BytesIO()
    np.lib.format.write_array_header_1_0(member, {"descr": "<f8", "fortran_order": False,
                                                  "shape": (10**9,)})
    member.write(bytes(800))
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        z.writestr("time.npy", _npy(np.arange(100) * 0.01))
        z.writestr("acc_x.npy", member.getvalue())
    with pytest.raises(RecordingError, match="declares 1000000000 values"):
        Recording.read(buf.getvalue(), DOFS, fmt="npz")


def test_complex_npz_refused():
    raw = io.BytesIO()
    t = np.arange(64) * 0.01
    np.savez(raw, time=t, acc_x=np.exp(1j * t))
    with pytest.raises(RecordingError, match="'acc_x' is complex"):
        Recording.read(raw.getvalue(), DOFS, fmt="npz")


@pytest.mark.parametrize("cell", ["1_0", "1_000.5", "_1"])
def test_csv_underscore_number_refused(cell):
    rows = "\n".join(f"{i * 0.01},{cell if i == 5 else 0.5}" for i in range(20))
    with pytest.raises(RecordingError, match=rf"'acc_x', row 7: '{cell}' is not a number"):
        Recording.read(f"time,acc_x\n{rows}\n".encode(), DOFS, fmt="csv")


def test_json_depth_and_number_limits():
    deep = b'{"time": ' + b"[" * 5000 + b"]" * 5000 + b"}"
    with pytest.raises(RecordingError, match="nested 5001 levels deep, at most 16"):
        Recording.read(deep, DOFS, fmt="json")
    big = json.dumps({"time": [0.0] * 20, "acc_x": [0.0] * 19}).replace("]}", ", " + "9" * 400
                                                                        + "]}")
    with pytest.raises(RecordingError, match="number with 400 characters"):
        Recording.read(big.encode(), DOFS, fmt="json")
    # brackets inside strings do not count
    ok = {"time": list(np.arange(20) * 0.1), "acc_x": [1.0] * 20, "note [[[[": []}
    with pytest.warns(UserWarning):
        assert len(Recording.read(json.dumps(ok).encode(), DOFS, fmt="json")) == 20
