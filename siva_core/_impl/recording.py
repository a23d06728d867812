"""Recording: one measured record (time + acc/vel/disp per DOF + optional force), validated.

Formats (CONTRACT.md): CSV with a header row; JSON ``{"time": [...], "acc_x": [...], ...}``
(or the same under ``"columns"``); NPZ with one array per column.  Errors name the file,
the column and the row.  What is missing per DOF is derived later by the processing chain.
"""
from __future__ import annotations

import csv
import io
import json
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

QUANTITIES = ("disp", "vel", "acc", "force")
UNITS = {"disp": {"m"}, "vel": {"m/s"}, "acc": {"m/s^2", "m/s2", "m/s**2", "m/s²"},
         "force": {"n"}, "time": {"s"}}
MIN_SAMPLES = 16
UNIFORM_RTOL = 1e-3
_UNIT_RE = re.compile(r"^\s*([A-Za-z0-9_]+)\s*(?:\[([^\]]*)\]|\(([^)]*)\))?\s*$")


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

    def to_csv(self) -> str:
        names = ["time", *self.channels]
        data = np.column_stack([self.time, *self.channels.values()])
        buf = io.StringIO()
        buf.write(",".join(names) + "\n")
        np.savetxt(buf, data, delimiter=",", fmt="%.10e")
        return buf.getvalue()

    def to_json(self) -> str:
        """The JSON format: an object of equal-length columns (round-trips exactly)."""
        return json.dumps(self.to_columns())

    def to_npz(self) -> bytes:
        """The NPZ format: one 1-D float array per column."""
        buf = io.BytesIO()
        np.savez(buf, time=self.time, **self.channels)
        return buf.getvalue()

    def to_mcap(self) -> bytes:
        """The MCAP format (see mcap_recording)."""
        from .mcap_recording import mcap_bytes

        return mcap_bytes(self)

    def write(self, path: str | Path) -> None:
        """Write in the format of the file suffix (.csv, .json, .npz, .mcap)."""
        path = Path(path)
        fmt = path.suffix.lower().lstrip(".")
        if fmt == "csv":
            path.write_text(self.to_csv())
        elif fmt == "json":
            path.write_text(self.to_json())
        elif fmt == "npz":
            path.write_bytes(self.to_npz())
        elif fmt == "mcap":
            path.write_bytes(self.to_mcap())
        else:
            raise RecordingError(f"{path}: unknown recording format {fmt!r} (csv, json, npz, mcap)")

    def slice(self, start: int, stop: int | None = None) -> "Recording":
        return Recording(self.time[start:stop].copy(),
                         {k: v[start:stop].copy() for k, v in self.channels.items()},
                         self.name, dict(self.meta))

    # ---------------------------------------------------------------- readers
    @classmethod
    def read(cls, source: str | Path | bytes, dofs: Sequence[str] | None = None, *,
             name: str | None = None, fmt: str | None = None) -> "Recording":
        """Read CSV / JSON / NPZ / MCAP from a path or bytes.

        ``fmt`` overrides the file suffix; for bytes without ``fmt`` the content decides
        (MCAP and NPZ magic bytes, a JSON object, else CSV).
        """
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
            fmt = fmt or sniff_format(raw)
        fmt = fmt.lower()
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
        """CSV with a header row; rows in messages are file lines (header = row 1)."""
        if isinstance(raw, (bytes, bytearray, memoryview)):
            raw = bytes(raw)
            if b"\x00" in raw[:65536]:
                raise RecordingError(f"{name}: not a text CSV file (binary data)")
            try:
                text = raw.decode("utf-8-sig")
            except UnicodeDecodeError as exc:
                raise RecordingError(f"{name}: not UTF-8 text (byte {exc.start}); "
                                     "expected a CSV file") from None
        else:
            text = raw
        if not text.strip():
            raise RecordingError(f"{name}: empty file, expected a header row")
        lines = text.splitlines()
        while lines and not lines[-1].strip():
            lines.pop()
        header = [h.strip() for h in next(csv.reader([lines[0]]))]
        while header and header[-1] == "":
            header.pop()
        if not header:
            raise RecordingError(f"{name}: empty header row")
        if len(header) == 1 and any(sep in header[0] for sep in (";", "\t")):
            raise RecordingError(f"{name}: row 1: columns must be separated by ',' "
                                 f"(header {header[0][:60]!r})")
        seen: set[str] = set()
        for h in header:
            col = _split_unit(h, name)[0]
            if col in seen:
                raise RecordingError(f"{name}: row 1: column {h!r} appears twice")
            if h == "":
                raise RecordingError(f"{name}: row 1: empty column name in the header")
            seen.add(col)
        width = len(header)
        values = _fast_parse(lines[1:], width)
        if values is None:
            values = _slow_parse(lines[1:], header, name)
        columns = {h: values[:, c] for c, h in enumerate(header)}
        return cls.from_columns(columns, dofs, name=name, row_offset=2)

    @classmethod
    def from_json(cls, raw: bytes | str | Mapping[str, Any], dofs: Sequence[str] | None = None, *,
                  name: str = "upload") -> "Recording":
        """JSON object of columns (optionally under ``"columns"``); rows count from 0."""
        if isinstance(raw, (bytes, bytearray, str)):
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
        if not data:
            raise RecordingError(f"{name}: no columns (empty JSON object)")
        columns = {}
        for k, v in data.items():
            if isinstance(v, np.ndarray) and v.ndim == 1:
                v = v.tolist()
            if not isinstance(v, list):
                raise RecordingError(f"{name}: column {k!r} must be a list of numbers")
            bad = next((i for i, x in enumerate(v)
                        if x is not None and (isinstance(x, bool)
                                              or not isinstance(x, (int, float)))), None)
            if bad is not None:
                raise RecordingError(f"{name}: column {k!r}, row {bad}: "
                                     f"{str(v[bad])[:40]!r} is not a number")
            columns[k] = np.array([np.nan if x is None else x for x in v], dtype=float)
        return cls.from_columns(columns, dofs, name=name, row_offset=0)

    @classmethod
    def from_npz(cls, raw: bytes | str | Path, dofs: Sequence[str] | None = None, *,
                 name: str = "upload") -> "Recording":
        """NPZ archive, one 1-D numeric array per column; rows count from 0."""
        columns: dict[str, np.ndarray] = {}
        try:
            src = io.BytesIO(bytes(raw)) if isinstance(raw, (bytes, bytearray)) else raw
            with np.load(src, allow_pickle=False) as z:
                if not hasattr(z, "files"):
                    raise RecordingError(f"{name}: a single .npy array, expected an NPZ "
                                         "archive of named columns")
                for k in z.files:
                    arr = np.asarray(z[k])
                    if arr.ndim > 1 and max(arr.shape) != arr.size:
                        raise RecordingError(f"{name}: column {k!r} has shape {arr.shape}, "
                                             "expected one dimension")
                    if not (np.issubdtype(arr.dtype, np.number) or arr.dtype == bool):
                        raise RecordingError(f"{name}: column {k!r} has dtype {arr.dtype}, "
                                             "expected numbers")
                    columns[k] = arr.astype(float).ravel()
        except RecordingError:
            raise
        except Exception as exc:  # noqa: BLE001 - any unreadable archive is a user error
            raise RecordingError(f"{name}: not a readable NPZ archive ({exc})") from None
        if not columns:
            raise RecordingError(f"{name}: empty NPZ archive")
        return cls.from_columns(columns, dofs, name=name, row_offset=0)

    @classmethod
    def from_columns(cls, columns: Mapping[str, Any], dofs: Sequence[str] | None = None, *,
                     name: str = "recording", row_offset: int = 0) -> "Recording":
        """Validate named columns; ``row_offset`` maps array index -> row number in messages."""
        parsed: dict[str, np.ndarray] = {}
        ignored: list[str] = []
        for raw_name, arr in columns.items():
            col, unit = _split_unit(str(raw_name), name)
            try:
                arr = np.asarray(arr, dtype=float)
            except (TypeError, ValueError):
                raise RecordingError(f"{name}: column {raw_name!r} is not numeric") from None
            if arr.ndim != 1:
                raise RecordingError(f"{name}: column {raw_name!r} has shape {arr.shape}, "
                                     "expected one value per row")
            if col == "time":
                _check_unit(unit, "time", raw_name, name)
                if "time" in parsed:
                    raise RecordingError(f"{name}: column 'time' appears twice")
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


def sniff_format(raw: bytes | str) -> str:
    """Format of uploaded bytes from their content: mcap, npz, json or csv."""
    if isinstance(raw, str):
        return "json" if raw.lstrip().startswith("{") else "csv"
    head = bytes(raw[:16])
    if head.startswith(b"\x89MCAP"):
        return "mcap"
    if head.startswith(b"PK\x03\x04") or head.startswith(b"PK\x05\x06"):
        return "npz"
    if head.lstrip(b"\xef\xbb\xbf \t\r\n").startswith(b"{"):
        return "json"
    return "csv"


def _fast_parse(lines: list[str], width: int) -> np.ndarray | None:
    """All rows at once when the file is well formed (None: let the slow path explain)."""
    if not lines:
        return np.empty((0, width))
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            values = np.loadtxt(lines, delimiter=",", ndmin=2, dtype=float, comments=None)
    except (ValueError, TypeError):
        return None
    if values.shape != (len(lines), width):
        return None
    return values


def _slow_parse(lines: list[str], header: list[str], name: str) -> np.ndarray:
    """Cell by cell, to name the row and column of the first problem."""
    width = len(header)
    values = np.empty((len(lines), width))
    for r, row in enumerate(csv.reader(lines), start=2):
        cells = row
        if len(row) > width and not any(c.strip() for c in row[width:]):
            cells = row[:width]  # trailing separators
        if len(cells) < width:
            missing = header[len(cells)] if cells else header[0]
            raise RecordingError(f"{name}: row {r}: {len(cells)} values, header has {width} "
                                 f"(no value for column {missing!r})")
        if len(cells) > width:
            raise RecordingError(f"{name}: row {r}: {len(cells)} values, header has {width} "
                                 f"(extra value {cells[width].strip()[:40]!r} after column "
                                 f"{header[-1]!r})")
        for c, cell in enumerate(cells):
            try:
                values[r - 2, c] = float(cell)
            except ValueError:
                raise RecordingError(f"{name}: column {header[c]!r}, row {r}: "
                                     f"{cell.strip()[:40]!r} is not a number") from None
    return values


def _split_unit(raw: str, name: str) -> tuple[str, str | None]:
    m = _UNIT_RE.match(raw)
    if not m:
        return raw.strip(), None
    unit = m.group(2) if m.group(2) is not None else m.group(3)
    col = m.group(1)
    return ("time" if col.lower() == "time" else col), unit


def _check_unit(unit: str | None, qty: str, col: str, name: str) -> None:
    if unit is None:
        return
    u = unit.strip().lower().replace(" ", "")
    if u not in UNITS[qty]:
        raise RecordingError(f"{name}: column {col!r}: unit [{unit}] is not the expected "
                             f"{sorted(UNITS[qty])[0]} (convert to SI units)")
