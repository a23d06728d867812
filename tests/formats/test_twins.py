"""Each new format, written by its own library's writer, reads back to its CSV twin's numbers."""
from __future__ import annotations

import io

import numpy as np
import pytest

from siva_core import Recording, RecordingError
from siva_core import RECORDING_FORMATS as REGISTRY
from siva_core import resolve_format, sniff_format

NEW_FORMATS = ("lvm", "uff58", "tdms", "mat")


@pytest.fixture(scope="module")
def csv_twin(shared_data) -> Recording:
    """The LO-NO 530 N impact (acc, force on two DOFs), 1 s of it: the CSV twin."""
    rec = Recording.read(shared_data / "lono" / "impact_530N.csv", ["LO", "NO"])
    return rec.slice(0, 2048)


def _same_numbers(a: Recording, b: Recording) -> None:
    assert list(a.channels) == list(b.channels)
    scale = float(np.abs(a.time).max())
    np.testing.assert_allclose(b.time, a.time, rtol=0, atol=1e-12 * scale)
    for k in a.channels:
        np.testing.assert_allclose(b.channels[k], a.channels[k], rtol=1e-12, atol=0)


def _write_with_library(rec: Recording, fmt: str, path) -> None:
    """The file written by the format's own library (pyuff, npTDMS, scipy.io) or, for
    LabVIEW's text format that has no Python writer, ours."""
    path.write_bytes(rec.to_bytes(fmt))


@pytest.mark.parametrize("fmt", NEW_FORMATS)
def test_new_format_reads_to_the_csv_twin(csv_twin, fmt, tmp_path):
    path = tmp_path / f"impact{REGISTRY[fmt].suffixes[0]}"
    _write_with_library(csv_twin, fmt, path)
    back = Recording.read(path, ["LO", "NO"])
    _same_numbers(csv_twin, back)
    assert sniff_format(path.read_bytes()) == fmt
    assert len(Recording.read(path.read_bytes(), ["LO", "NO"])) == len(csv_twin)  # sniffed


def test_tdms_written_by_nptdms_directly(csv_twin, tmp_path):
    """A TDMS file as a LabVIEW user has it: waveform channels in a group, no time channel."""
    from nptdms import ChannelObject, TdmsWriter

    path = tmp_path / "rig.tdms"
    with TdmsWriter(path) as w:
        w.write_segment([ChannelObject("Untitled", k, v, properties={
            "wf_increment": csv_twin.dt, "wf_start_offset": float(csv_twin.time[0])})
            for k, v in csv_twin.channels.items()])
    _same_numbers(csv_twin, Recording.read(path, ["LO", "NO"]))


def test_mat_written_by_scipy_with_renamed_time(csv_twin, tmp_path):
    import scipy.io

    path = tmp_path / "rig.mat"
    scipy.io.savemat(path, {"t": csv_twin.time, **csv_twin.channels, "notes": "rig 3"})
    with pytest.warns(UserWarning, match="notes"):
        back = Recording.read(path, ["LO", "NO"], channel_map={"t": "time"})
    _same_numbers(csv_twin, back)


def test_uff_channel_named_from_node_and_type(csv_twin, tmp_path):
    """id1 that is not a column name: the name comes from the ordinate type and node."""
    import pyuff

    path = tmp_path / "hammer.uff"
    uff = pyuff.UFF(str(path))
    for node, (col, qty) in enumerate([("acc_LO", 12), ("acc_NO", 12), ("force_NO", 13)], 1):
        uff.write_sets({
            "type": 58, "binary": 1, "id1": f"Point {node}", "func_type": 1,
            "rsp_node": node, "rsp_dir": 3, "ref_node": 0, "ref_dir": 0,
            "ordinate_spec_data_type": qty, "orddenom_spec_data_type": 0,
            "abscissa_min": 0.0, "abscissa_inc": csv_twin.dt, "abscissa_spacing": 1,
            "data": csv_twin.channels[col], "x": csv_twin.time - csv_twin.time[0]},
            mode="add")
    back = Recording.read(path, ["LO", "NO"], channel_map={
        "acc_1z": "acc_LO", "acc_2z": "acc_NO", "force_3z": "force_NO"})
    np.testing.assert_allclose(back.channels["acc_NO"], csv_twin.channels["acc_NO"], rtol=1e-12)
    np.testing.assert_allclose(back.time, csv_twin.time - csv_twin.time[0], atol=1e-12)


def test_real_labview_file(shared_data):
    """The measured cantilever decay (LabVIEW 2023): 12 channels, ragged 1-sample columns."""
    path = shared_data / "real" / "magnetomechanical_decay" / "decay_f_42p05_ampl_2p0_0.lvm"
    with pytest.warns(UserWarning, match="Strain_1"):
        rec = Recording.read(path, ["x"], channel_map={"Strain_0": "disp_x"})
    assert len(rec) == 29000 and rec.fs == pytest.approx(1000.0)
    assert rec.channels["disp_x"][:3] == pytest.approx([0.000211, 0.000219, 0.000211])
    with pytest.raises(RecordingError, match="DOF 'x' has no column"):
        Recording.read(path, ["x"])  # no channel named like a column without the map


def test_lvm_unit_label_is_checked(csv_twin):
    raw = csv_twin.to_bytes("lvm").replace(b"m/s^2", b"g", 1)
    with pytest.raises(RecordingError, match=r"unit \[g\]"):
        Recording.read(raw, ["LO", "NO"], fmt="lvm")


def test_lvm_bad_cell_names_row_and_column(csv_twin):
    lines = csv_twin.to_bytes("lvm").decode().splitlines()
    first_data = next(i for i, l in enumerate(lines) if l.startswith("X_Value")) + 1
    cells = lines[first_data + 4].split("\t")
    cells[1] = "1_0"
    lines[first_data + 4] = "\t".join(cells)
    with pytest.raises(RecordingError, match=rf"acc_LO', row {first_data + 5}: '1_0'"):
        Recording.read("\n".join(lines).encode(), ["LO", "NO"], name="r.lvm", fmt="lvm")


def test_mat_v73_refused_clearly():
    raw = b"MATLAB 7.3 MAT-file, Platform: GLNXA64" + b" " * 474 + b"\x89HDF\r\n\x1a\n" + b"\0" * 64
    assert sniff_format(raw) == "mat"
    with pytest.raises(RecordingError, match="v7.3 .*not supported.*-v7"):
        Recording.read(raw, ["x"], name="run.mat")


@pytest.mark.parametrize("media,filename,head,expected", [
    ("text/plain", "run.lvm", b"LabVIEW Measurement\t\n", "lvm"),
    ("text/plain", None, b"LabVIEW Measurement\t\n", "lvm"),
    ("text/csv", None, b"time,acc_x\n", "csv"),
    (None, "r.tdms", b"TDSm", "tdms"),
    ("application/x-mcap", None, b"junk", "mcap"),
    (None, None, b"    -1\n    58\n", "uff58"),
    (None, None, b"\x89MCAP0\r\n", "mcap"),
    (None, None, b'  {"time": []}', "json"),
])
def test_resolve_format(media, filename, head, expected):
    assert resolve_format(media, filename, head) == expected


def test_every_format_has_a_writer_and_round_trips(csv_twin):
    for fmt in REGISTRY:
        back = Recording.read(io.BytesIO(csv_twin.to_bytes(fmt)).getvalue(), ["LO", "NO"],
                              fmt=fmt)
        np.testing.assert_allclose(back.channels["acc_NO"], csv_twin.channels["acc_NO"],
                                   rtol=1e-10, err_msg=fmt)
