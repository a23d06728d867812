"""NPZ: a NumPy ``.npz`` archive, one 1-D real numeric array per column.

Bounded: the member count and each kept member's declared (uncompressed) size are checked
from the ZIP directory and the ``.npy`` header *before* anything is decompressed; members
the model does not need are never opened; pickles are never loaded; complex arrays are
refused (not silently reduced to their real part).  Rows count from 0.
"""
from __future__ import annotations

import io
import zipfile

import numpy as np

from ._base import (ColumnSelector, Columns, Format, ReadLimits, RecordingError, RecordLike,
                    register_format)

ZIP_MAGIC = (b"PK\x03\x04", b"PK\x05\x06")


def read_npz(raw: bytes, name: str, select: ColumnSelector, limits: ReadLimits) -> Columns:
    if raw[:6] == b"\x93NUMPY":
        raise RecordingError(f"{name}: a single .npy array, expected an NPZ archive of "
                             "named columns")
    try:
        archive = zipfile.ZipFile(io.BytesIO(raw))
    except (zipfile.BadZipFile, ValueError, OSError) as exc:
        raise RecordingError(f"{name}: not a readable NPZ archive ({exc})") from None
    with archive:
        members = archive.infolist()
        limits.check_members("archive members", len(members), name)
        kept: list[tuple[str, zipfile.ZipInfo]] = []
        for info in members:
            key = info.filename[:-4] if info.filename.endswith(".npy") else info.filename
            target = select.target(key)
            if target is not None:
                kept.append((target, info))
        limits.check_expansion(f"{len(kept)} column(s)", sum(i.file_size for _, i in kept),
                               len(raw), name)
        columns = {}
        for target, info in kept:
            columns[target] = _read_member(archive, info, name, limits)
    if not members:
        raise RecordingError(f"{name}: empty NPZ archive")
    return Columns(columns, meta={"skipped": list(select.skipped)})


def _read_member(archive: zipfile.ZipFile, info: zipfile.ZipInfo, name: str,
                 limits: ReadLimits) -> np.ndarray:
    col = info.filename.removesuffix(".npy")
    fmt = np.lib.format
    try:
        with archive.open(info) as fh:
            version = fmt.read_magic(fh)
            reader = fmt.read_array_header_1_0 if version == (1, 0) else \
                fmt.read_array_header_2_0
            shape, fortran, dtype = reader(fh, max_header_size=10000)
            header_bytes = fh.tell()
            if dtype.hasobject:
                raise RecordingError(f"{name}: column {col!r} holds Python objects (pickles "
                                     "are never loaded), expected numbers")
            if dtype.kind == "c":
                raise RecordingError(f"{name}: column {col!r} is complex ({dtype}); a "
                                     "recording holds real numbers (store the real part if "
                                     "that is what you mean)")
            if dtype.kind not in "biuf":
                raise RecordingError(f"{name}: column {col!r} has dtype {dtype}, expected "
                                     "numbers")
            count = int(np.prod(shape, dtype=np.int64)) if shape else 1
            if len(shape) > 1 and max(shape) != count:
                raise RecordingError(f"{name}: column {col!r} has shape {shape}, expected "
                                     "one dimension")
            nbytes = count * dtype.itemsize
            if nbytes > info.file_size - header_bytes:
                raise RecordingError(f"{name}: column {col!r}: header declares {count} "
                                     "values, more than the member holds")
            limits.check_total(f"column {col!r}", nbytes, name)
            limits.check_values(count, name)
            data = fh.read(nbytes)
    except RecordingError:
        raise
    except (ValueError, OSError, zipfile.BadZipFile, EOFError, RuntimeError) as exc:
        raise RecordingError(f"{name}: column {col!r}: not a readable .npy member "
                             f"({type(exc).__name__}: {exc})") from None
    if len(data) != nbytes:
        raise RecordingError(f"{name}: column {col!r}: truncated ({len(data)} of {nbytes} "
                             "bytes)")
    return np.frombuffer(data, dtype=dtype).astype(float)


def write_npz(rec: RecordLike) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, time=rec.time, **rec.channels)
    return buf.getvalue()


FORMAT = register_format(Format(
    "npz", (".npz",), read_npz, write_npz,
    media_types=("application/x-npz", "application/npz"),
    sniff=lambda raw: raw[:4] in ZIP_MAGIC,
    description="numpy.savez archive, one array per column"))
