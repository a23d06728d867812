"""Recording: one measured record (time + acc/vel/disp per DOF + optional force), validated.

The formats (CSV, JSON, NPZ, MCAP, LabVIEW .lvm, UFF58, TDMS, MATLAB .mat) live in
:mod:`.formats`, one module each; they return named columns, and :meth:`Recording.from_columns`
validates them the same way for all.  Errors name the file, the column and the row.  What is
missing per DOF is derived later by the processing chain.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from .formats import (DEFAULT_LIMITS, QUANTITIES, ColumnSelector, ReadLimits, RecordingError,
                      check_unit, format_of_suffix, read_columns, sniff_format, split_unit,
                      write_bytes)
from .formats.json import columns_from_object

MIN_SAMPLES = 16
UNIFORM_RTOL = 1e-3


@dataclass
class Recording:
    """Time series of one test: ``channels`` maps e.g. ``acc_x`` -> array (same length)."""

    time: np.ndarray
    channels: dict[str, np.ndarray]
    name: str = "recording"
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def dt(self) -> float:
        """Sampling step [s]: the mean step (time is validated uniform)."""
        return float((self.time[-1] - self.time[0]) / (len(self.time) - 1))

    @property
    def fs(self) -> float:
        return 1.0 / self.dt

    def __len__(self) -> int:
        return len(self.time)

    def get(self, quantity: str, dof: str) -> np.ndarray | None:
        return self.channels.get(f"{quantity}_{dof}")

    def stack(self, quantity: str, dofs: Sequence[str],
              fill: float | None = None) -> np.ndarray | None:
        """(T, n_dof) array of one quantity; None if any DOF lacks it and no ``fill``."""
        cols = []
        for d in dofs:
            x = self.get(quantity, d)
            if x is None:
                if fill is None:
                    return None
                x = np.full(len(self.time), fill)
            cols.append(x)
        return np.stack(cols, axis=-1)

    def has_force(self, dofs: Sequence[str]) -> bool:
        return any(self.get("force", d) is not None for d in dofs)

    def to_columns(self) -> dict[str, list[float]]:
        return {"time": self.time.tolist(), **{k: v.tolist() for k, v in self.channels.items()}}

    def to_bytes(self, fmt: str) -> bytes:
        """This record in any registered format (csv, json, npz, mcap, lvm, uff58, tdms, mat)."""
        return write_bytes(self, fmt)

    def to_csv(self) -> str:
        return self.to_bytes("csv").decode()

    def to_json(self) -> str:
        """The JSON format: an object of equal-length columns (round-trips exactly)."""
        return self.to_bytes("json").decode()

    def to_npz(self) -> bytes:
        return self.to_bytes("npz")

    def to_mcap(self) -> bytes:
        return self.to_bytes("mcap")

    def write(self, path: str | Path) -> None:
        """Write in the format of the file suffix (any registered format)."""
        path = Path(path)
        fmt = format_of_suffix(path.name)
        if fmt is None:
            raise RecordingError(f"{path}: unknown recording format {path.suffix!r}")
        path.write_bytes(self.to_bytes(fmt))

    def slice(self, start: int, stop: int | None = None) -> "Recording":
        return Recording(self.time[start:stop].copy(),
                         {k: v[start:stop].copy() for k, v in self.channels.items()},
                         self.name, dict(self.meta))

    # ---------------------------------------------------------------- readers
    @classmethod
    def read(cls, source: str | Path | bytes, dofs: Sequence[str] | None = None, *,
             name: str | None = None, fmt: str | None = None,
             channel_map: Mapping[str, str] | None = None,
             limits: ReadLimits = DEFAULT_LIMITS) -> "Recording":
        """Read any registered format from a path or bytes.

        ``fmt`` overrides the file suffix; for bytes without ``fmt`` the content decides.
        ``channel_map`` renames stored channels to column names (``{"Strain_0": "disp_x"}``);
        ``limits`` bound what a file may make the reader allocate.
        """
        if isinstance(source, (str, Path)):
            path = Path(source)
            name = name or path.name
            fmt = fmt or format_of_suffix(path.name) or (path.suffix.lstrip(".") or "csv")
            try:
                raw = path.read_bytes()
            except OSError as exc:
                raise RecordingError(f"{path}: cannot read ({exc.strerror})") from None
        else:
            raw = source
            name = name or "upload"
            fmt = fmt or sniff_format(raw)
        cols, skipped = read_columns(raw, fmt, name, dofs, channel_map=channel_map,
                                     limits=limits)
        return cls.from_columns(cols.data, dofs, name=name, row_offset=cols.row_offset,
                                skipped=skipped)

    @classmethod
    def from_csv(cls, raw: bytes | str, dofs: Sequence[str] | None = None, *,
                 name: str = "upload") -> "Recording":
        """CSV with a header row; rows in messages are file lines (header = row 1)."""
        return cls.read(raw.encode() if isinstance(raw, str) else raw, dofs, name=name,
                        fmt="csv")

    @classmethod
    def from_json(cls, raw: bytes | str | Mapping[str, Any], dofs: Sequence[str] | None = None, *,
                  name: str = "upload") -> "Recording":
        """JSON object of columns (optionally under ``"columns"``); rows count from 0."""
        if isinstance(raw, (bytes, bytearray, str)):
            return cls.read(raw.encode() if isinstance(raw, str) else raw, dofs, name=name,
                            fmt="json")
        select = ColumnSelector(dofs)
        columns = columns_from_object(raw, name, select)
        return cls.from_columns(columns, dofs, name=name, skipped=select.skipped)

    @classmethod
    def from_npz(cls, raw: bytes, dofs: Sequence[str] | None = None, *,
                 name: str = "upload") -> "Recording":
        """NPZ archive, one 1-D numeric array per column; rows count from 0."""
        return cls.read(bytes(raw), dofs, name=name, fmt="npz")

    @classmethod
    def from_columns(cls, columns: Mapping[str, Any], dofs: Sequence[str] | None = None, *,
                     name: str = "recording", row_offset: int = 0,
                     skipped: Sequence[str] = ()) -> "Recording":
        """Validate named columns; ``row_offset`` maps array index -> row number in messages.

        ``skipped``: channels a reader left unread (reported with the ignored columns).
        """
        parsed: dict[str, np.ndarray] = {}
        ignored: list[str] = list(skipped)
        for raw_name, arr in columns.items():
            col, unit = split_unit(str(raw_name))
            try:
                arr = np.asarray(arr, dtype=float)
            except (TypeError, ValueError):
                raise RecordingError(f"{name}: column {raw_name!r} is not numeric") from None
            if arr.ndim != 1:
                raise RecordingError(f"{name}: column {raw_name!r} has shape {arr.shape}, "
                                     "expected one value per row")
            if col == "time":
                check_unit(unit, "time", raw_name, name)
                if "time" in parsed:
                    raise RecordingError(f"{name}: column 'time' appears twice")
                parsed["time"] = arr
                continue
            qty, _, dof = col.partition("_")
            if qty not in QUANTITIES or not dof or (dofs is not None and dof not in dofs):
                ignored.append(str(raw_name))
                continue
            check_unit(unit, qty, raw_name, name)
            if col in parsed:
                raise RecordingError(f"{name}: column {col!r} appears twice")
            parsed[col] = arr
        if "time" not in parsed:
            raise RecordingError(f"{name}: no 'time' column (columns: {[*skipped, *columns]})")
        t = parsed.pop("time")
        n = len(t)
        for col, arr in parsed.items():
            if len(arr) != n:
                raise RecordingError(f"{name}: column {col!r} has {len(arr)} values, "
                                     f"'time' has {n}")
        if n < MIN_SAMPLES:
            raise RecordingError(f"{name}: {n} samples, at least {MIN_SAMPLES} needed")
        for col, arr in {"time": t, **parsed}.items():
            bad = np.flatnonzero(~np.isfinite(arr))
            if bad.size:
                raise RecordingError(f"{name}: column {col!r}, row {bad[0] + row_offset}: "
                                     f"value {arr[bad[0]]} is not finite")
        dt = np.diff(t)
        nonpos = np.flatnonzero(dt <= 0)
        if nonpos.size:
            r = nonpos[0] + 1 + row_offset
            raise RecordingError(f"{name}: column 'time', row {r}: time does not increase "
                                 f"({t[nonpos[0]]} then {t[nonpos[0] + 1]})")
        step = float(np.median(dt))  # robust: one bad step is reported where it is
        off = np.flatnonzero(np.abs(dt - step) > UNIFORM_RTOL * step)
        if off.size:
            r = off[0] + 1 + row_offset
            raise RecordingError(f"{name}: column 'time', row {r}: non-uniform sampling "
                                 f"(step {dt[off[0]]:.6g} s, expected {step:.6g} s)")
        if dofs is not None:
            for d in dofs:
                if not any(f"{q}_{d}" in parsed for q in ("disp", "vel", "acc")):
                    raise RecordingError(f"{name}: DOF {d!r} has no column (need one of "
                                         f"acc_{d}, vel_{d}, disp_{d})")
        elif not any(c.partition("_")[0] in ("disp", "vel", "acc") for c in parsed):
            raise RecordingError(f"{name}: no response column (acc_<dof>, vel_<dof> or "
                                 f"disp_<dof>; columns: {list(columns)})")
        if ignored:
            warnings.warn(f"{name}: ignoring unknown column(s) {ignored}", stacklevel=3)
        return cls(t, parsed, name, {"ignored_columns": ignored})


__all__ = ["Recording", "RecordingError", "MIN_SAMPLES", "sniff_format", "QUANTITIES"]
