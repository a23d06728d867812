"""Recording: one measured record (time + acc/vel/disp per DOF + optional force), validated.

Formats (CONTRACT.md): CSV with a header row; JSON ``{"time": [...], "acc_x": [...], ...}``
(or the same under ``"columns"``); NPZ with one array per column.  Errors name the file,
the column and the row.  What is missing per DOF is derived later by the processing chain.
"""
from __future__ import annotations

import csv
import io
import json
import math
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

QUANTITIES = ("disp", "vel", "acc", "force")
UNITS = {"disp": {"m"}, "vel": {"m/s"}, "acc": {"m/s^2", "m/s2", "m/s**2"}, "force": {"n"},
         "time": {"s"}}
MIN_SAMPLES = 16
UNIFORM_RTOL = 1e-3
_UNIT_RE = re.compile(r"^\s*([A-Za-z0-9_]+)\s*(?:\[([^\]]*)\])?\s*$")


class RecordingError(ValueError):
    """A recording that cannot be used; the message names the file, column and row."""


@dataclass
class Recording:
    """Time series of one test: ``channels`` maps e.g. ``acc_x`` -> array (same length)."""

    time: np.ndarray
    channels: dict[str, np.ndarray]
    name: str = "recording"
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def dt(self) -> float:
        return float(self.time[1] - self.time[0])

    @property
    def fs(self) -> float:
        return 1.0 / self.dt

    def __len__(self) -> int:
        return len(self.time)

    def get(self, quantity: str, dof: str) -> np.ndarray | None:
        return self.channels.get(f"{quantity}_{dof}")

    def stack(self, quantity: str, dofs: Sequence[str], fill: float | None = None) -> np.ndarray | None:
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

    def to_csv(self) -> str:
        names = ["time", *self.channels]
        data = np.column_stack([self.time, *self.channels.values()])
        buf = io.StringIO()
        buf.write(",".join(names) + "\n")
        np.savetxt(buf, data, delimiter=",", fmt="%.10e")
        return buf.getvalue()

    def slice(self, start: int, stop: int | None = None) -> "Recording":
        return Recording(self.time[start:stop].copy(),
                         {k: v[start:stop].copy() for k, v in self.channels.items()},
                         self.name, dict(self.meta))

    # ---------------------------------------------------------------- readers
    @classmethod
    def read(cls, source: str | Path | bytes, dofs: Sequence[str] | None = None, *,
             name: str | None = None, fmt: str | None = None) -> "Recording":
        """Read CSV / JSON / NPZ from a path or bytes; ``fmt`` overrides the suffix."""
        if isinstance(source, (str, Path)):
            path = Path(source)
            name = name or path.name
            fmt = fmt or path.suffix.lower().lstrip(".") or "csv"
            try:
                raw = path.read_bytes()
            except OSError as exc:
                raise RecordingError(f"{path}: cannot read ({exc.strerror})") from None
        else:
            raw = source
            name = name or "upload"
            fmt = fmt or "csv"
        if fmt in ("csv", "txt"):
            return cls.from_csv(raw, dofs, name=name)
        if fmt == "json":
            return cls.from_json(raw, dofs, name=name)
        if fmt == "npz":
            return cls.from_npz(raw, dofs, name=name)
        if fmt == "mcap":
            from .mcap_recording import read_mcap_recording

            return read_mcap_recording(raw, dofs, name=name)
        raise RecordingError(f"{name}: unknown recording format {fmt!r} (csv, json, npz, mcap)")

    @classmethod
    def from_csv(cls, raw: bytes | str, dofs: Sequence[str] | None = None, *,
                 name: str = "upload") -> "Recording":
        if isinstance(raw, bytes):
            if b"\x00" in raw[:65536]:
                raise RecordingError(f"{name}: not a text CSV file (binary data)")
            try:
                text = raw.decode("utf-8-sig")
            except UnicodeDecodeError as exc:
                raise RecordingError(f"{name}: not UTF-8 text (byte {exc.start})") from None
        else:
            text = raw
        rows = list(csv.reader(io.StringIO(text)))
        while rows and not any(c.strip() for c in rows[-1]):
            rows.pop()
        if not rows:
            raise RecordingError(f"{name}: empty file, expected a header row")
        header = [h.strip() for h in rows[0]]
        while header and header[-1] == "":
            header.pop()
        if not header:
            raise RecordingError(f"{name}: empty header row")
        width = len(header)
        values = np.empty((len(rows) - 1, width))
        for r, row in enumerate(rows[1:], start=2):
            cells = row[:width] if len(row) > width and not any(c.strip() for c in row[width:]) else row
            if len(cells) != width:
                raise RecordingError(f"{name}: row {r}: {len(cells)} values, header has {width}")
            for c, cell in enumerate(cells):
                try:
                    values[r - 2, c] = float(cell)
                except ValueError:
                    raise RecordingError(f"{name}: column {header[c]!r}, row {r}: "
                                         f"{cell.strip()[:40]!r} is not a number") from None
        columns = {h: values[:, c] for c, h in enumerate(header)}
        return cls.from_columns(columns, dofs, name=name, row_offset=2)

    @classmethod
    def from_json(cls, raw: bytes | str | Mapping[str, Any], dofs: Sequence[str] | None = None, *,
                  name: str = "upload") -> "Recording":
        if isinstance(raw, (bytes, str)):
            try:
                data = json.loads(raw)
            except (json.JSONDecodeError, UnicodeDecodeError) as exc:
                raise RecordingError(f"{name}: invalid JSON ({exc})") from None
        else:
            data = raw
        if isinstance(data, Mapping) and isinstance(data.get("columns"), Mapping):
            data = data["columns"]
        if not isinstance(data, Mapping):
            raise RecordingError(f"{name}: JSON must be an object of columns {{name: [values]}}")
        columns = {}
        for k, v in data.items():
            if not isinstance(v, list):
                raise RecordingError(f"{name}: column {k!r} must be a list of numbers")
            try:
                columns[k] = np.array([np.nan if x is None else x for x in v], dtype=float)
            except (TypeError, ValueError):
                bad = next((i for i, x in enumerate(v) if not isinstance(x, (int, float))), 0)
                raise RecordingError(f"{name}: column {k!r}, row {bad}: "
                                     f"{str(v[bad])[:40]!r} is not a number") from None
        return cls.from_columns(columns, dofs, name=name, row_offset=0)

    @classmethod
    def from_npz(cls, raw: bytes | str | Path, dofs: Sequence[str] | None = None, *,
                 name: str = "upload") -> "Recording":
        try:
            with np.load(io.BytesIO(raw) if isinstance(raw, bytes) else raw, allow_pickle=False) as z:
                columns = {k: np.asarray(z[k], dtype=float).ravel() for k in z.files}
        except Exception as exc:  # noqa: BLE001 - any unreadable archive is a user error
            raise RecordingError(f"{name}: not a readable NPZ archive ({exc})") from None
        return cls.from_columns(columns, dofs, name=name, row_offset=0)

    @classmethod
    def from_columns(cls, columns: Mapping[str, Any], dofs: Sequence[str] | None = None, *,
                     name: str = "recording", row_offset: int = 0) -> "Recording":
        """Validate named columns; ``row_offset`` maps array index -> row number in messages."""
        parsed: dict[str, np.ndarray] = {}
        ignored: list[str] = []
        for raw_name, arr in columns.items():
            col, unit = _split_unit(str(raw_name), name)
            arr = np.asarray(arr, dtype=float)
            if col == "time":
                _check_unit(unit, "time", raw_name, name)
                parsed["time"] = arr
                continue
            qty, _, dof = col.partition("_")
            if qty not in QUANTITIES or not dof or (dofs is not None and dof not in dofs):
                ignored.append(str(raw_name))
                continue
            _check_unit(unit, qty, raw_name, name)
            if col in parsed:
                raise RecordingError(f"{name}: column {col!r} appears twice")
            parsed[col] = arr
        if "time" not in parsed:
            raise RecordingError(f"{name}: no 'time' column (columns: {list(columns)})")
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
        step = (t[-1] - t[0]) / (n - 1)
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
        if ignored:
            warnings.warn(f"{name}: ignoring unknown column(s) {ignored}", stacklevel=3)
        return cls(t, parsed, name, {"ignored_columns": ignored})


def _split_unit(raw: str, name: str) -> tuple[str, str | None]:
    m = _UNIT_RE.match(raw)
    if not m:
        return raw.strip(), None
    return m.group(1), m.group(2)


def _check_unit(unit: str | None, qty: str, col: str, name: str) -> None:
    if unit is None:
        return
    u = unit.strip().lower().replace(" ", "")
    if u not in UNITS[qty]:
        raise RecordingError(f"{name}: column {col!r}: unit [{unit}] is not the expected "
                             f"{sorted(UNITS[qty])[0]} (convert to SI units)")


def read_recordings(paths: Iterable[str | Path], dofs: Sequence[str] | None = None) -> list[Recording]:
    return [Recording.read(p, dofs) for p in paths]


def sampling_consistent(recs: Sequence[Recording]) -> bool:
    return all(math.isclose(r.dt, recs[0].dt, rel_tol=1e-6) for r in recs)
