"""CSV: a header row of column names (optional unit hints), ``,``-separated numbers.

Rows in messages are file lines (header = row 1).  Bounded (issue 19): the body is read in
~1 MiB blocks of lines (``_lines``), the rows are counted and the value count checked before
the columns are allocated, and a line longer than any row of numbers the header allows is
refused.  Each well-formed block is parsed at once by NumPy; otherwise a cell-by-cell pass
names the first bad row and column.
"""
from __future__ import annotations

import csv as _csv
import io
import warnings

import numpy as np

from ._base import (ColumnSelector, Columns, Format, ReadLimits, RecordingError, RecordLike,
                    parse_number, register_format, split_unit)
from ._lines import check_text, count_lines, end_of_content, line_blocks, next_line


def read_csv(raw: bytes, name: str, select: ColumnSelector, limits: ReadLimits) -> Columns:
    start = check_text(raw, name, "CSV")
    end = end_of_content(raw, start)
    if end <= start:
        raise RecordingError(f"{name}: empty file, expected a header row")
    head_end = next_line(raw, start, end)
    if head_end - start > 1 << 20:
        raise RecordingError(f"{name}: row 1: a header of more than 1 MiB")
    header = [h.strip() for h in next(_csv.reader([raw[start:head_end].decode("utf-8")
                                                   .rstrip("\r")]))]
    while header and header[-1] == "":
        header.pop()
    if not header:
        raise RecordingError(f"{name}: empty header row")
    if len(header) == 1 and any(sep in header[0] for sep in (";", "\t")):
        raise RecordingError(f"{name}: row 1: columns must be separated by ',' "
                             f"(header {header[0][:60]!r})")
    seen: set[str] = set()
    for h in header:
        col = split_unit(h)[0]
        if col in seen:
            raise RecordingError(f"{name}: row 1: column {h!r} appears twice")
        if h == "":
            raise RecordingError(f"{name}: row 1: empty column name in the header")
        seen.add(col)
    width = len(header)
    kept = [(c, t) for c, t in enumerate(select.target(h) for h in header) if t is not None]
    n = count_lines(raw, head_end + 1, end)
    limits.check_values(n * len(kept), name)
    data = {t: np.empty(n) for _, t in kept}
    # a row of numbers: each cell at most max_number_chars, some blanks and separators
    max_line = (limits.max_number_chars + 16) * (width + 1) + 256
    for row, lines in line_blocks(raw, head_end + 1, end, max_line, name, first_row=2):
        values = _fast_parse(lines, width)
        if values is None:
            values = _slow_parse(lines, header, name, first_row=row)
        for c, t in kept:
            data[t][row - 2:row - 2 + len(lines)] = values[:, c]
    return Columns(data, row_offset=2)


def write_csv(rec: RecordLike) -> bytes:
    names = ["time", *rec.channels]
    values = np.column_stack([rec.time, *rec.channels.values()])
    buf = io.StringIO()
    buf.write(",".join(names) + "\n")
    np.savetxt(buf, values, delimiter=",", fmt="%.10e")
    return buf.getvalue().encode()


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


def _slow_parse(lines: list[str], header: list[str], name: str,
                first_row: int = 2) -> np.ndarray:
    """Cell by cell, to name the row and column of the first problem."""
    width = len(header)
    values = np.empty((len(lines), width))
    for r, row in enumerate(_csv.reader(lines), start=first_row):
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
                values[r - first_row, c] = parse_number(cell)
            except ValueError:
                raise RecordingError(f"{name}: column {header[c]!r}, row {r}: "
                                     f"{cell.strip()[:40]!r} is not a number") from None
    return values


FORMAT = register_format(Format(
    "csv", (".csv", ".txt"), read_csv, write_csv,
    media_types=("text/csv", "application/csv", "text/plain"),
    description="header row + comma-separated numbers"))
