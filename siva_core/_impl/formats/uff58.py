"""Universal File Format dataset 58 (``.uff``/``.unv``), read and written with pyuff.

Each dataset 58 (ASCII or binary ``58b``) is one channel: a function of time
(``func_type`` 1, evenly spaced abscissa).  Channel mapping:

- name: record 1 (``id1``) when it is a column name (``acc_x``, ``force_x [N]``); otherwise
  ``<quantity>_<rsp_node><dir>`` with the quantity from the ordinate data type (8
  displacement, 11 velocity, 12 acceleration, 13 excitation force) and the direction as
  ``x``/``y``/``z`` (``rsp_dir`` ±1..3), e.g. ``acc_3z``; ``channel_map`` renames either.
- ``time = abscissa_min + i * abscissa_inc``, the same for every channel kept.  The format
  stores the step with 6 significant digits; when ``1 / abscissa_inc`` rounds to a sampling
  rate of at most 6 significant digits, that rate is used (2048 Hz exactly, not 2048.0008).
- SI units are assumed (pyuff does not carry the unit system); complex data is refused.
"""
from __future__ import annotations

import os
import tempfile

import numpy as np

from ._base import (ColumnSelector, Columns, Format, ReadLimits, RecordingError, RecordLike,
                    register_format, split_unit)

ORDINATE_QUANTITY = {8: "disp", 11: "vel", 12: "acc", 13: "force"}
QUANTITY_ORDINATE = {v: k for k, v in ORDINATE_QUANTITY.items()}
_DIRS = {1: "x", 2: "y", 3: "z"}


def _channel_name(ds: dict) -> str:
    id1 = str(ds.get("id1", "")).strip()
    col = split_unit(id1)[0]
    if id1 and col.partition("_")[0] in ORDINATE_QUANTITY.values() and col.partition("_")[2]:
        return id1
    qty = ORDINATE_QUANTITY.get(int(ds.get("ordinate_spec_data_type", 0) or 0))
    node = ds.get("rsp_node", 0)
    direction = _DIRS.get(abs(int(ds.get("rsp_dir", 0) or 0)), "")
    return f"{qty}_{node}{direction}" if qty else (id1 or f"node{node}{direction}")


def _with_file(raw: bytes, fn):
    fd, path = tempfile.mkstemp(suffix=".uff")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(raw)
        return fn(path)
    finally:
        os.unlink(path)


def read_uff58(raw: bytes, name: str, select: ColumnSelector, limits: ReadLimits) -> Columns:
    import pyuff

    def load(path: str) -> list[dict]:
        uff = pyuff.UFF(path)
        types = list(uff.get_set_types())
        limits.check_members("UFF datasets", len(types), name)
        idx = [i for i, t in enumerate(types) if int(t) == 58]
        if not idx:
            raise RecordingError(f"{name}: no UFF dataset 58 (found types "
                                 f"{sorted({int(t) for t in types})})")
        sets = uff.read_sets(idx)
        return sets if isinstance(sets, list) else [sets]

    try:
        sets = _with_file(raw, load)
    except RecordingError:
        raise
    except Exception as exc:  # noqa: BLE001 - pyuff raises anything on a malformed file
        raise RecordingError(f"{name}: not a readable UFF file ({type(exc).__name__}: "
                             f"{str(exc)[:200]})") from None
    data: dict[str, np.ndarray] = {}
    axis: tuple[float, float, int] | None = None
    for k, ds in enumerate(sets):
        cname = _channel_name(ds)
        target = select.target(cname)
        if target is None:
            continue
        if int(ds.get("func_type", 1)) not in (0, 1):
            raise RecordingError(f"{name}: dataset {k} ({cname!r}) is function type "
                                 f"{ds.get('func_type')}, expected a time response (1)")
        y = np.asarray(ds["data"])
        if np.iscomplexobj(y):
            raise RecordingError(f"{name}: dataset {k} ({cname!r}) is complex, expected a "
                                 "real time series")
        this = (float(ds["abscissa_min"]), float(ds["abscissa_inc"]), len(y))
        if axis is None:
            axis = this
        elif not np.allclose(this[:2], axis[:2], rtol=1e-9, atol=0) or this[2] != axis[2]:
            raise RecordingError(f"{name}: dataset {k} ({cname!r}) has time axis start "
                                 f"{this[0]}, step {this[1]}, {this[2]} samples; the first "
                                 f"kept one has {axis}")
        if target in data:
            raise RecordingError(f"{name}: channel {target!r} appears twice (dataset {k})")
        data[target] = y.astype(float)
    if axis is not None and "time" not in data:
        if not axis[1] > 0:
            raise RecordingError(f"{name}: abscissa increment {axis[1]} (uneven spacing is "
                                 "not supported)")
        data["time"] = axis[0] + _step(axis[1]) * np.arange(axis[2])
    return Columns(data)


def _step(inc: float) -> float:
    """The sampling step, undoing record 7's 6-digit rounding (E13.5) when the sampling rate
    has at most 6 significant digits (2048 Hz: 4.88281e-04 s -> 1/2048 s exactly)."""
    fs = float(f"{1.0 / inc:.6g}")
    return 1.0 / fs if abs(1.0 / fs - inc) <= 5e-6 * inc else inc


def write_uff58(rec: RecordLike) -> bytes:
    """One ASCII dataset 58 per channel, ``id1`` = column name, double precision."""
    import pyuff

    dt = float((rec.time[-1] - rec.time[0]) / (len(rec.time) - 1))

    def write(path: str) -> bytes:
        os.unlink(path)
        uff = pyuff.UFF(path)
        for k, (col, y) in enumerate(rec.channels.items()):
            qty, _, dof = col.partition("_")
            ds = {"type": 58, "binary": 0, "id1": col, "id2": str(rec.name)[:80],
                  "func_type": 1, "rsp_node": k + 1, "rsp_dir": 1,
                  "rsp_ent_name": dof[:10] or "dof", "ref_node": 0, "ref_dir": 0,
                  "ordinate_spec_data_type": QUANTITY_ORDINATE.get(qty, 0),
                  "orddenom_spec_data_type": 0, "abscissa_spec_data_type": 17,
                  "abscissa_spacing": 1, "abscissa_min": float(rec.time[0]),
                  "abscissa_inc": dt, "data": np.asarray(y, dtype=float),
                  "x": np.asarray(rec.time, dtype=float)}
            uff.write_sets(ds, mode="add")
        with open(path, "rb") as fh:
            return fh.read()

    return _with_file(b"", write)


def looks_like_uff(raw: bytes) -> bool:
    lines = raw[:200].lstrip(b"\r\n").splitlines()
    return len(lines) >= 2 and lines[0].strip() == b"-1" and lines[1].strip()[:2].isdigit()


FORMAT = register_format(Format(
    "uff58", (".uff", ".unv", ".uff58"), read_uff58, write_uff58,
    media_types=("application/x-uff",), sniff=looks_like_uff,
    description="Universal File Format dataset 58 (pyuff)"))
