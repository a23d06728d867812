"""MATLAB ``.mat`` files (scipy.io): one variable per column, named like the CSV columns.

Channel mapping: each variable that is a real numeric vector (``n``, ``n x 1`` or ``1 x n``)
is a channel named by the variable (``time``, ``acc_x``, ...; ``channel_map`` renames, e.g.
``{"t": "time"}``).  Variables the model does not need are not loaded (their sizes are checked
from the file's directory first).  Versions 4 to 7 (``-v7``, compressed) are read; version 7.3
is HDF5 and needs h5py, which this installation does not ship: it is refused with a message
saying so (save with ``-v7`` instead).
"""
from __future__ import annotations

import io
import struct
import zlib

import numpy as np

from ._base import (ColumnSelector, Columns, Format, ReadLimits, RecordingError, RecordLike,
                    register_format)

HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"
_BYTES = {"double": 8, "single": 4, "int8": 1, "uint8": 1, "int16": 2, "uint16": 2,
          "int32": 4, "uint32": 4, "int64": 8, "uint64": 8, "logical": 1}


def _is_v73(raw: bytes) -> bool:
    return raw[:20].startswith(b"MATLAB 7.3") or raw[512:520] == HDF5_MAGIC \
        or raw[:8] == HDF5_MAGIC


def read_mat(raw: bytes, name: str, select: ColumnSelector, limits: ReadLimits) -> Columns:
    import scipy.io

    if _is_v73(raw):
        raise RecordingError(f"{name}: MATLAB v7.3 (HDF5) files are not supported here "
                             "(h5py is not installed); save with  save(file, '-v7')")
    # scipy inflates every compressed variable whole, even to list it: measure first
    limits.check_expansion("the variables", _v5_inflated_size(raw, limits, name), len(raw),
                           name)
    try:
        info = scipy.io.whosmat(io.BytesIO(raw))
    except Exception as exc:  # noqa: BLE001 - scipy raises anything on a malformed file
        raise RecordingError(f"{name}: not a readable MATLAB file ({type(exc).__name__}: "
                             f"{str(exc)[:200]})") from None
    limits.check_members("MATLAB variables", len(info), name)
    wanted: dict[str, str] = {}
    total = values = 0
    for var, shape, cls in info:
        target = select.target(var)
        if target is None:
            continue
        if cls not in _BYTES:
            raise RecordingError(f"{name}: variable {var!r} is a MATLAB {cls}, expected a "
                                 "real numeric vector")
        if len(shape) > 2 or (len(shape) == 2 and min(shape) > 1):
            raise RecordingError(f"{name}: variable {var!r} has shape {shape}, expected a "
                                 "vector")
        total += int(np.prod(shape)) * _BYTES[cls]
        values += int(np.prod(shape))
        wanted[var] = target
    limits.check_expansion(f"{len(wanted)} variable(s)", total, len(raw), name)
    limits.check_values(values, name)
    if not wanted:
        return Columns({})
    try:
        mat = scipy.io.loadmat(io.BytesIO(raw), variable_names=list(wanted))
    except Exception as exc:  # noqa: BLE001
        raise RecordingError(f"{name}: not a readable MATLAB file ({type(exc).__name__}: "
                             f"{str(exc)[:200]})") from None
    data = {}
    for var, target in wanted.items():
        arr = np.asarray(mat[var])
        if np.iscomplexobj(arr):
            raise RecordingError(f"{name}: variable {var!r} is complex, expected real "
                                 "numbers")
        data[target] = arr.astype(float).ravel()
    return Columns(data)


def _v5_inflated_size(raw: bytes, limits: ReadLimits, name: str) -> int:
    """Bytes a v5 file's data elements take once inflated, counted by streaming each
    compressed element through zlib in 1 MiB pieces (nothing kept), stopping as soon as the
    count passes what the file may expand to.  0 for other versions (not compressed)."""
    if len(raw) < 128 or raw[126:128] not in (b"IM", b"MI"):
        return 0
    order = "<" if raw[126:128] == b"IM" else ">"
    cap = max(limits.expansion_floor, int(limits.max_expansion * len(raw)))
    cap = min(cap, limits.max_decompressed_bytes) + 1
    pos, total = 128, 0
    while pos + 8 <= len(raw):
        kind, nbytes = struct.unpack(order + "II", raw[pos:pos + 8])
        body = raw[pos + 8:pos + 8 + nbytes]
        if kind == 15:  # miCOMPRESSED
            inflate = zlib.decompressobj()
            chunk = inflate.decompress(body, 1 << 20)
            while chunk:
                total += len(chunk)
                if total > cap:
                    return total
                chunk = inflate.decompress(inflate.unconsumed_tail, 1 << 20)
            pos += 8 + nbytes
        else:
            total += nbytes
            pos += 8 + nbytes + (-nbytes) % 8
    return total


def write_mat(rec: RecordLike) -> bytes:
    """MATLAB v5 (``-v7`` compatible, compressed): one column vector per column."""
    import scipy.io

    buf = io.BytesIO()
    scipy.io.savemat(buf, {"time": np.asarray(rec.time, dtype=float),
                           **{k: np.asarray(v, dtype=float) for k, v in rec.channels.items()}},
                     do_compression=True, oned_as="column")
    return buf.getvalue()


FORMAT = register_format(Format(
    "mat", (".mat",), read_mat, write_mat, media_types=("application/x-matlab-data",),
    sniff=lambda raw: raw[:6] == b"MATLAB" or raw[:8] == HDF5_MAGIC,
    description="MATLAB v4-v7 (scipy.io); v7.3 needs h5py"))
