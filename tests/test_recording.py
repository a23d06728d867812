"""Recording formats and validation: every malformed record is refused with a message that
names the file, the column and the row; unknown columns only warn."""
from __future__ import annotations

import io
import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from siva_core import (Recording, RecordingError, mcap_bytes, read_mcap_recording,
                       write_mcap_recording)
from siva_core._impl.mcap_recording import TOPIC  # the format's private constant

DOFS = ["x"]


def csv_text(cols: dict) -> str:
    """Same layout as the conftest helper: header, then repr() floats."""
    names = list(cols)
    return ",".join(names) + "\n" + "".join(
        ",".join(repr(float(x)) for x in row) + "\n" for row in zip(*(cols[n] for n in names)))


def _lines(cols: dict) -> list[str]:
    return csv_text(cols).splitlines()


def _refused(text: str | bytes, *parts: str, dofs=DOFS, name: str = "bad.csv",
             fmt: str = "csv") -> str:
    raw = text.encode() if isinstance(text, str) else text
    with pytest.raises(RecordingError) as exc:
        Recording.read(raw, dofs, name=name, fmt=fmt)
    msg = str(exc.value)
    assert name in msg, msg
    for p in parts:
        assert p in msg, f"{p!r} not in {msg!r}"
    return msg


# ------------------------------------------------------------------------- valid input
def test_valid_csv_roundtrip(small_columns):
    rec = Recording.read(csv_text(small_columns).encode(), DOFS, name="ok.csv")
    assert len(rec) == 40 and rec.fs == pytest.approx(100.0)
    assert set(rec.channels) == {"disp_x", "acc_x", "force_x"}
    again = Recording.read(rec.to_csv().encode(), DOFS)
    np.testing.assert_allclose(again.time, rec.time, rtol=1e-9, atol=1e-15)
    for k in rec.channels:
        np.testing.assert_allclose(again.channels[k], rec.channels[k], rtol=1e-9, atol=1e-15)


def test_units_in_header_are_accepted_when_si(small_columns):
    cols = {"time [s]": small_columns["time"], "disp_x [m]": small_columns["disp_x"],
            "acc_x (m/s^2)": small_columns["acc_x"], "force_x [N]": small_columns["force_x"]}
    rec = Recording.read(csv_text(cols).encode(), DOFS)
    assert set(rec.channels) == {"disp_x", "acc_x", "force_x"}


def test_reference_file_reads(shared_data):
    rec = Recording.read(shared_data / "lono" / "impact_530N.csv", ["LO", "NO"])
    assert rec.fs == pytest.approx(2048.0)
    assert set(rec.channels) == {"acc_LO", "acc_NO", "force_NO"}
    assert rec.name == "impact_530N.csv"


def test_unknown_columns_warn_not_fail(small_columns):
    cols = {**small_columns, "temperature": np.ones(40), "acc_y": np.zeros(40)}
    with pytest.warns(UserWarning, match="temperature") as rec_w:
        rec = Recording.read(csv_text(cols).encode(), DOFS, name="extra.csv")
    assert "extra.csv" in str(rec_w[0].message) and "acc_y" in str(rec_w[0].message)
    assert "temperature" not in rec.channels and "acc_y" not in rec.channels
    assert rec.meta["ignored_columns"] == ["temperature", "acc_y"]


def test_trailing_separators_and_blank_end_lines(small_columns):
    text = "\n".join(line + "," for line in _lines(small_columns)) + "\n\n\n"
    rec = Recording.read(text.encode(), DOFS)
    assert len(rec) == 40


# ------------------------------------------------------------------------- refused
@pytest.mark.parametrize("line, col, value, expect", [
    (5, 2, "nan", ("'acc_x'", "row 6", "not finite")),  # acc_x, data row 4 = file row 6
    (10, 1, "-inf", ("'disp_x'", "row 11", "not finite")),
    (3, 3, "", ("'force_x'", "row 4", "not a number")),
    (7, 1, "12;5", ("'disp_x'", "row 8", "'12;5' is not a number")),
], ids=["nan", "inf", "empty", "non-numeric"])
def test_bad_cell_names_column_and_row(small_columns, line, col, value, expect):
    lines = _lines(small_columns)
    cells = lines[line].split(",")
    cells[col] = value
    lines[line] = ",".join(cells)
    _refused("\n".join(lines), *expect)


def test_ragged_short_row(small_columns):
    lines = _lines(small_columns)
    lines[4] = ",".join(lines[4].split(",")[:2])
    _refused("\n".join(lines), "row 5", "2 values", "header has 4", "'acc_x'")


def test_ragged_long_row(small_columns):
    lines = _lines(small_columns)
    lines[9] = lines[9] + ",7.0"
    _refused("\n".join(lines), "row 10", "5 values", "header has 4")


def test_blank_line_inside_data(small_columns):
    lines = _lines(small_columns)
    lines.insert(6, "")
    _refused("\n".join(lines), "row 7", "0 values")


def test_non_uniform_time(small_columns):
    cols = dict(small_columns)
    t = cols["time"].copy()
    t[20:] += 0.003
    cols["time"] = t
    _refused(csv_text(cols), "'time'", "row 22", "non-uniform")  # index 20 = file row 22


def test_decreasing_time(small_columns):
    cols = dict(small_columns)
    t = cols["time"].copy()
    t[12], t[13] = t[13], t[12]
    cols["time"] = t
    _refused(csv_text(cols), "'time'", "row 15", "does not increase")  # index 13


def test_repeated_time(small_columns):
    cols = dict(small_columns)
    t = cols["time"].copy()
    t[30] = t[29]
    cols["time"] = t
    _refused(csv_text(cols), "'time'", "row 32", "does not increase")  # index 30


def test_missing_dof(small_columns):
    _refused(csv_text(small_columns), "DOF 'y'", "acc_y", dofs=["x", "y"])


def test_force_alone_is_not_a_dof(small_columns):
    cols = {"time": small_columns["time"], "force_x": small_columns["force_x"]}
    _refused(csv_text(cols), "DOF 'x'")


def test_missing_time_column(small_columns):
    cols = {k: v for k, v in small_columns.items() if k != "time"}
    _refused(csv_text(cols), "no 'time' column")


def test_too_few_samples(small_columns):
    cols = {k: v[:5] for k, v in small_columns.items()}
    _refused(csv_text(cols), "5 samples", "at least")


def test_header_only(small_columns):
    _refused("time,acc_x\n", "0 samples")


@pytest.mark.parametrize("text", ["", "\n\n", "   \r\n"])
def test_empty_file(text):
    _refused(text, "empty file")


def test_binary_garbage_with_nul():
    rng = np.random.default_rng(1)
    _refused(bytes(rng.integers(0, 256, 4000, dtype=np.uint8)) + b"\x00", "binary")


def test_binary_garbage_not_utf8():
    _refused(b"\xff\xfe\xfa" * 300, "not UTF-8")


@pytest.mark.parametrize("header,unit", [("acc_x [g]", "[g]"), ("acc_x (g)", "[g]"),
                                         ("disp_x [mm]", "[mm]"), ("time [ms]", "[ms]"),
                                         ("force_x [kN]", "[kN]"), ("vel_x [in/s]", "[in/s]")])
def test_wrong_unit_hint(small_columns, header, unit):
    cols = dict(small_columns)
    qty = header.split()[0]
    cols[header] = cols.pop(qty) if qty in cols else cols["acc_x"]
    msg = _refused(csv_text(cols), repr(header), unit, "SI")
    assert "column" in msg


def test_duplicate_column(small_columns):
    text = csv_text(small_columns).replace("force_x", "acc_x", 1)
    _refused(text, "row 1", "'acc_x'", "twice")


def test_semicolon_separated(small_columns):
    text = csv_text(small_columns).replace(",", ";")
    _refused(text, "row 1", "separated by ','")


def test_error_names_the_path(tmp_path: Path, small_columns):
    lines = _lines(small_columns)
    lines[3] = lines[3].replace(lines[3].split(",")[2], "x")
    path = tmp_path / "rig_run_7.csv"
    path.write_text("\n".join(lines))
    with pytest.raises(RecordingError, match=r"rig_run_7\.csv: column 'acc_x', row 4"):
        Recording.read(path, DOFS)


def test_missing_file(tmp_path: Path):
    with pytest.raises(RecordingError, match="nope.csv"):
        Recording.read(tmp_path / "nope.csv", DOFS)


def test_unknown_format(small_columns):
    with pytest.raises(RecordingError, match="unknown recording format 'xlsx'"):
        Recording.read(csv_text(small_columns).encode(), DOFS, name="a", fmt="xlsx")


# ------------------------------------------------------------------------- JSON / NPZ / MCAP
def _rec(small_columns) -> Recording:
    return Recording.from_columns(small_columns, DOFS, name="r")


def test_json_roundtrip(small_columns):
    rec = _rec(small_columns)
    back = Recording.read(rec.to_json().encode(), DOFS, name="r.json", fmt="json")
    np.testing.assert_array_equal(back.time, rec.time)
    for k, v in rec.channels.items():
        np.testing.assert_array_equal(back.channels[k], v)
    wrapped = json.dumps({"columns": rec.to_columns()}).encode()
    assert len(Recording.read(wrapped, DOFS)) == 40  # sniffed as JSON


def test_npz_roundtrip(small_columns, tmp_path: Path):
    rec = _rec(small_columns)
    back = Recording.read(rec.to_npz(), DOFS)  # sniffed as NPZ
    np.testing.assert_array_equal(back.time, rec.time)
    rec.write(tmp_path / "r.npz")
    back = Recording.read(tmp_path / "r.npz", DOFS)
    for k, v in rec.channels.items():
        np.testing.assert_array_equal(back.channels[k], v)


@pytest.mark.parametrize("rows", [None, 7])
def test_mcap_roundtrip(small_columns, tmp_path: Path, rows):
    rec = _rec(small_columns)
    path = tmp_path / "r.mcap"
    write_mcap_recording(rec, path, rows_per_message=rows)
    back = Recording.read(path, DOFS)
    np.testing.assert_array_equal(back.time, rec.time)
    for k, v in rec.channels.items():
        np.testing.assert_array_equal(back.channels[k], v)
    assert len(Recording.read(path.read_bytes(), DOFS)) == 40  # sniffed as MCAP


def test_mcap_is_standard(small_columns):
    """Opened with the mcap library itself: one channel, JSON, with a JSON schema."""
    from mcap.reader import make_reader

    reader = make_reader(io.BytesIO(mcap_bytes(_rec(small_columns))))
    msgs = list(reader.iter_messages())
    assert len(msgs) == 1
    schema, channel, message = msgs[0]
    assert channel.topic == TOPIC and channel.message_encoding == "json"
    assert schema.encoding == "jsonschema" and json.loads(schema.data)["type"] == "object"
    assert set(json.loads(message.data)) == {"time", "disp_x", "acc_x", "force_x"}


def test_mcap_validation_reaches_rows(small_columns):
    cols = dict(small_columns)
    t = cols["time"].copy()
    t[25] = t[24]
    cols["time"] = t
    rec = Recording(t, {k: v for k, v in cols.items() if k != "time"}, "r")
    with pytest.raises(RecordingError, match=r"bad\.mcap: column 'time', row 25"):
        read_mcap_recording(mcap_bytes(rec, rows_per_message=10), DOFS, name="bad.mcap")


def test_mcap_garbage_and_wrong_topic(small_columns):
    good = mcap_bytes(_rec(small_columns))
    _refused(good[:8] + b"\x00garbage" * 20, "unreadable MCAP", name="g.mcap", fmt="mcap")
    _refused(good[: len(good) // 2], name="cut.mcap", fmt="mcap")
    _refused(b"not an mcap", "not an MCAP file", name="n.mcap", fmt="mcap")
    from mcap.writer import Writer

    buf = io.BytesIO()
    w = Writer(buf)
    w.start()
    sid = w.register_schema("x", "jsonschema", b"{}")
    cid = w.register_channel("/other", "json", sid)
    w.add_message(cid, log_time=0, data=b"{}", publish_time=0)
    w.finish()
    _refused(buf.getvalue(), "no message on topic /recording", "/other", name="t.mcap",
             fmt="mcap")


@pytest.mark.parametrize("body,parts", [
    ("[1, 2, 3]", ["object of columns"]),
    ('{"time": 3}', ["'time'", "list"]),
    ('{"time": [0, 1, 2], "acc_x": [1, "a", 2]}', ["'acc_x'", "row 1", "not a number"]),
    ('{"time": [0, 1, 2], "acc_x": [1, true, 2]}', ["'acc_x'", "row 1"]),
    ('{"time": [0, 1', ["invalid JSON"]),
    ("{}", ["no columns"]),
])
def test_json_refused(body, parts):
    _refused(body.encode(), *parts, name="b.json", fmt="json")


def test_json_null_is_refused_as_not_finite(small_columns):
    cols = {k: v.tolist() for k, v in small_columns.items()}
    cols["acc_x"][17] = None
    _refused(json.dumps(cols).encode(), "'acc_x'", "row 17", "not finite", name="n.json",
             fmt="json")


def test_npz_refused(small_columns):
    _refused(b"PK\x03\x04broken zip", "NPZ", name="b.npz", fmt="npz")
    buf = io.BytesIO()
    np.savez(buf, time=small_columns["time"], acc_x=np.ones((40, 2)))
    _refused(buf.getvalue(), "'acc_x'", "shape", name="s.npz", fmt="npz")
    buf = io.BytesIO()
    np.savez(buf, time=small_columns["time"], acc_x=np.array(["a"] * 40))
    _refused(buf.getvalue(), "'acc_x'", name="d.npz", fmt="npz")


def test_no_warning_for_clean_record(small_columns):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        Recording.read(csv_text(small_columns).encode(), DOFS)
