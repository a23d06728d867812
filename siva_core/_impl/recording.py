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

from .formats import (DEFAULT_LIMITS, QUANTITIES, UNIT_FACTORS, ColumnSelector, ReadLimits,
                      RecordingError, check_unit, exact_step, format_of_suffix, read_columns,
                      sniff_format, split_unit, unit_factor, write_bytes)
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
             units: Mapping[str, str] | None = None,
             limits: ReadLimits = DEFAULT_LIMITS) -> "Recording":
        """Read any registered format from a path or bytes.

        ``fmt`` overrides the file suffix; for bytes without ``fmt`` the content decides.
        ``channel_map`` renames stored channels to column names (``{"Strain_0": "disp_x"}``;
        a name the file does not have is an error listing the file's channels);
        ``units`` declares the unit a column was recorded in (``{"acc_x": "g"}``, keyed by
        the column name or the stored channel name), converted to SI on reading;
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
        if units:  # a unit may be declared under the stored name ("Accel LO") too
            cmap = dict(channel_map or {})
            units = {split_unit(cmap.get(k, k))[0]: u for k, u in units.items()}
        return cls.from_columns(cols.data, dofs, name=name, row_offset=cols.row_offset,
                                skipped=skipped, units=units,
                                channels=cols.meta.get("channels"))

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
                     skipped: Sequence[str] = (), units: Mapping[str, str] | None = None,
                     channels: Sequence[str] | None = None) -> "Recording":
        """Validate named columns; ``row_offset`` maps array index -> row number in messages.

        ``skipped``: channels a reader left unread (reported with the ignored columns).
        ``units``: declared unit per column name (``{"acc_x": "g"}``), converted to SI.
        ``channels``: the file's own channel names, listed when no time column is found.
        """
        parsed: dict[str, np.ndarray] = {}
        ignored: list[str] = list(skipped)
        units = dict(units or {})
        converted: dict[str, str] = {}
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
                arr = _to_si(arr, unit, units.pop("time", None), "time", raw_name, name,
                             converted)
                if "time" in parsed:
                    raise RecordingError(f"{name}: column 'time' appears twice")
                parsed["time"] = arr
                continue
            qty, _, dof = col.partition("_")
            if qty not in QUANTITIES or not dof or (dofs is not None and dof not in dofs):
                ignored.append(str(raw_name))
                continue
            arr = _to_si(arr, unit, units.pop(col, None), qty, raw_name, name, converted)
            if col in parsed:
                raise RecordingError(f"{name}: column {col!r} appears twice")
            parsed[col] = arr
        if units:
            col = next(iter(units))
            raise RecordingError(f"{name}: a unit is declared for {col!r}, which the file does "
                                 f"not have (columns: {sorted(['time', *parsed])})")
        if "time" not in parsed:
            listed = list(channels) if channels else [*skipped, *columns]
            raise RecordingError(f"{name}: no 'time' column (the file's channels: {listed}); "
                                 "name it time, t or X_Value, or map it: --map \"NAME=time\"")
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
        quantum = printed_quantum(t)
        # a writer that prints time with few decimals (LabVIEW: 6) makes the steps differ
        # by up to one printed unit: uniform within that precision is uniform
        tol = UNIFORM_RTOL * step + (1.0001 * quantum if quantum is not None else 0.0)
        off = np.flatnonzero(np.abs(dt - step) > tol)
        if off.size:
            r = off[0] + 1 + row_offset
            raise RecordingError(f"{name}: column 'time', row {r}: non-uniform sampling "
                                 f"(step {dt[off[0]]:.6g} s, expected {step:.6g} s)")
        meta_time: dict[str, Any] = {}
        if quantum is not None and n > 1:
            # the true step is the span over the count (known to quantum / (n-1)), not a
            # rounded step: 0.000488 s printed steps are 1/2048 s
            true = exact_step(float(t[-1] - t[0]) / (n - 1), quantum / (n - 1))
            grid = t[0] + true * np.arange(n)
            if np.max(np.abs(grid - t)) <= 0.5001 * quantum + 1e-12 * abs(t[-1]):
                if not np.array_equal(grid, t):
                    meta_time = {"time_rebuilt": f"time printed to {quantum:g} s: read as "
                                                 f"uniform at {1.0 / true:.10g} Hz"}
                t = grid
        if dofs is not None:
            for d in dofs:
                if not any(f"{q}_{d}" in parsed for q in ("disp", "vel", "acc")):
                    listed = list(channels) if channels else [*ignored]
                    raise RecordingError(
                        f"{name}: DOF {d!r} has no column (need one of acc_{d}, vel_{d}, "
                        f"disp_{d}; the file's channels: {listed}; map one, e.g. --map "
                        f"\"NAME=acc_{d}\")")
        elif not any(c.partition("_")[0] in ("disp", "vel", "acc") for c in parsed):
            raise RecordingError(f"{name}: no response column (acc_<dof>, vel_<dof> or "
                                 f"disp_<dof>; columns: {list(columns)})")
        if ignored:
            warnings.warn(f"{name}: ignoring unknown column(s) {ignored}", stacklevel=3)
        meta: dict[str, Any] = {"ignored_columns": ignored, **meta_time}
        if converted:
            meta["converted_units"] = converted
        return cls(t, parsed, name, meta)


def printed_quantum(t: np.ndarray) -> float | None:
    """The last printed decimal of a time column (1e-6 for LabVIEW's 6 decimals), or None
    when the values are not all multiples of a power of ten down to 1e-9."""
    eps = 8 * np.finfo(float).eps * max(1.0, float(np.max(np.abs(t))))
    for d in range(0, 10):
        q = 10.0 ** -d
        if eps > 0.01 * q:  # finer than the numbers can hold: cannot tell
            return None
        r = t / q
        if np.max(np.abs(r - np.round(r))) * q <= 1e-3 * q + eps:
            return q
    return None


def _to_si(arr: np.ndarray, hint: str | None, declared: str | None, qty: str, raw_name: Any,
           name: str, converted: dict[str, str]) -> np.ndarray:
    """The column in SI units: a declared unit converts (and must agree with a unit the
    file states); otherwise a unit hint must already be SI (CONTRACT)."""
    if declared is None:
        check_unit(hint, qty, str(raw_name), name)
        return arr
    factor = unit_factor(declared, qty)
    if factor is None:
        raise RecordingError(f"{name}: column {raw_name!r}: unit {declared!r} is not a unit of "
                             f"{qty} (known: {', '.join(UNIT_FACTORS[qty])})")
    if hint is not None:
        stated = unit_factor(hint, qty)
        if stated is None or not np.isclose(stated, factor):
            raise RecordingError(f"{name}: column {raw_name!r}: the file says [{hint}] but "
                                 f"{declared!r} was declared; drop one")
    if factor != 1.0:
        converted[split_unit(str(raw_name))[0]] = f"{declared} -> SI (x {factor:g})"
        return arr * factor
    return arr


__all__ = ["Recording", "RecordingError", "MIN_SAMPLES", "sniff_format", "QUANTITIES"]
