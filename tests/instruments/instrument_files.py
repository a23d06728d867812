"""Files as instruments and their users write them, from records our own simulator makes.

Each writer uses the instrument's own library or header spec, not siva's writers:
- TDMS (npTDMS): group ``Untitled``, channels ``Accel LO``, ``Accel NO``, ``Hammer`` as
  LabVIEW's waveform channels (``wf_increment``, ``wf_start_offset``, ``unit_string`` g / N,
  ``NI_ChannelName``), accelerations in g.
- LVM (LabVIEW "Write To Measurement File" text, header spec v2): ``X_Value`` printed with
  6 decimals, ``Delta_X`` 6 decimals, ``Y_Unit_Label`` g g N, real channel names.
- UFF 58 (pyuff): one dataset per channel, response nodes 1 and 2 in +Z (``acc_1z``,
  ``acc_2z``, force ``force_2z``), ``id1`` a free-text point name, SI units.
- MAT (scipy.io.savemat): variables ``t``, ``accLO``, ``accNO`` (g), ``hammer`` (N).
The mappings a user gives for each are in :data:`MAPS` and :data:`UNITS`.
"""
from __future__ import annotations

import io
from pathlib import Path

import numpy as np

G = 9.80665
#: what a user passes as --map for each file kind (stored name -> column)
MAPS = {
    "tdms": {"Accel LO": "acc_LO", "Accel NO": "acc_NO", "Hammer": "force_NO"},
    "lvm": {"Accel LO": "acc_LO", "Accel NO": "acc_NO", "Hammer": "force_NO"},
    "uff": {"acc_1z": "acc_LO", "acc_2z": "acc_NO", "force_2z": "force_NO"},
    "mat": {"t": "time", "accLO": "acc_LO", "accNO": "acc_NO", "hammer": "force_NO"},
}
#: and as --unit
UNITS = {"tdms": {"acc_LO": "g", "acc_NO": "g"}, "lvm": {"acc_LO": "g", "acc_NO": "g"},
         "uff": {}, "mat": {"acc_LO": "g", "acc_NO": "g"}}


def _columns(rec, force: bool = True) -> dict[str, np.ndarray]:
    out = {"Accel LO": rec.channels["acc_LO"] / G, "Accel NO": rec.channels["acc_NO"] / G}
    if force:
        out["Hammer"] = rec.channels["force_NO"]
    return out


def write_tdms(rec, path: Path, *, force: bool = True, increment: float | None = None) -> Path:
    from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

    inc = rec.dt if increment is None else increment
    units = {"Accel LO": "g", "Accel NO": "g", "Hammer": "N"}
    with TdmsWriter(str(path)) as w:
        objs = [RootObject({"name": "impact test", "author": "LabVIEW user"}),
                GroupObject("Untitled")]
        for name, y in _columns(rec, force).items():
            objs.append(ChannelObject("Untitled", name, np.asarray(y, dtype=np.float64),
                                      properties={"wf_increment": inc, "wf_start_offset": 0.0,
                                                  "wf_samples": len(y),
                                                  "unit_string": units[name],
                                                  "NI_ChannelName": name}))
        w.write_segment(objs)
    return path


def write_lvm(rec, path: Path, *, x_column: bool = True, force: bool = True) -> Path:
    """LabVIEW Measurement file, header spec v2, as LabVIEW prints it (6 decimals)."""
    cols = _columns(rec, force)
    names = list(cols)
    n, tab = len(rec.time), "\t".join

    def per(value: str) -> str:
        return tab([value] * len(names))

    units = tab({"Accel LO": "g", "Accel NO": "g", "Hammer": "N"}[c] for c in names)
    head = ["LabVIEW Measurement\t", "Writer_Version\t2", "Reader_Version\t2",
            "Separator\tTab", "Decimal_Separator\t.", "Multi_Headings\tNo",
            f"X_Columns\t{'One' if x_column else 'No'}", "Time_Pref\tRelative",
            "Operator\tlab", "Date\t2026/11/25", "Time\t09:00:00.000000",
            "***End_of_Header***\t", "", f"Channels\t{len(names)}", f"Samples\t{per(str(n))}",
            f"Date\t{per('2026/11/25')}", f"Time\t{per('09:00:00.000000')}",
            f"Y_Unit_Label\t{units}", f"X_Dimension\t{per('Time')}",
            f"X0\t{per('0.0000000000000000E+0')}", f"Delta_X\t{per(f'{rec.dt:.6f}')}",
            "***End_of_Header***\t"]
    head.append(tab((["X_Value"] if x_column else []) + names + ["Comment"]))
    data = np.column_stack(([np.round(rec.time - rec.time[0], 6)] if x_column else [])
                           + [cols[c] for c in names])
    fmt = (["%.6f"] if x_column else []) + ["%.6f"] * len(names)
    buf = io.StringIO()
    np.savetxt(buf, data, fmt=fmt, delimiter="\t")
    path.write_text("\n".join(head) + "\n" + buf.getvalue())
    return path


def write_uff(rec, path: Path) -> Path:
    import pyuff

    if path.exists():
        path.unlink()
    uff = pyuff.UFF(str(path))
    chans = [(rec.channels["acc_LO"], 1, 12), (rec.channels["acc_NO"], 2, 12),
             (rec.channels["force_NO"], 2, 13)]
    for y, node, ordinate in chans:
        uff.write_sets({"type": 58, "binary": 0, "id1": f"Point{node} +Z",
                        "id2": "impact test", "func_type": 1, "rsp_node": node, "rsp_dir": 3,
                        "rsp_ent_name": "rig", "ref_node": 2, "ref_dir": 3,
                        "ordinate_spec_data_type": ordinate, "orddenom_spec_data_type": 0,
                        "abscissa_spec_data_type": 17, "abscissa_spacing": 1,
                        "abscissa_min": 0.0, "abscissa_inc": rec.dt,
                        "data": np.asarray(y, dtype=float),
                        "x": np.asarray(rec.time - rec.time[0], dtype=float)}, mode="add")
    return path


def write_mat(rec, path: Path) -> Path:
    import scipy.io

    scipy.io.savemat(str(path), {"t": rec.time - rec.time[0],
                                 "accLO": rec.channels["acc_LO"] / G,
                                 "accNO": rec.channels["acc_NO"] / G,
                                 "hammer": rec.channels["force_NO"]}, oned_as="column")
    return path


WRITERS = {"tdms": write_tdms, "lvm": write_lvm, "uff": write_uff, "mat": write_mat}


def cli_mapping(kind: str) -> list[str]:
    """The command-line options a user types for this kind of file."""
    args: list[str] = []
    for src, dst in MAPS[kind].items():
        args += ["--map", f"{src}={dst}"]
    for col, unit in UNITS[kind].items():
        args += ["--unit", f"{col}={unit}"]
    return args


def http_mapping(kind: str) -> list[tuple[str, str]]:
    """The same as upload query parameters."""
    return ([("map", f"{s}={d}") for s, d in MAPS[kind].items()]
            + [("unit", f"{c}={u}") for c, u in UNITS[kind].items()])


__all__ = ["WRITERS", "MAPS", "UNITS", "cli_mapping", "http_mapping", "G"]
