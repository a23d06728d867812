"""LabVIEW Measurement (``.lvm``): the text file LabVIEW's "Write To Measurement File" makes.

Layout: a file header and a segment header, each ending with ``***End_of_Header***``, then
a line of channel names and the data rows.  Channel mapping:

- ``X_Columns`` ``One``: the first column (``X_Value``) is ``time``; ``Multi``: the X column
  before the first kept channel is ``time``; ``No``: ``time = X0 + i * Delta_X`` of the first
  kept channel.
- every other column is a channel named by the names line (a trailing ``Comment`` column is
  ignored); channels named like CSV columns (``acc_x``) are used as such, others only through
  ``channel_map`` (``{"Strain_0": "disp_x"}``), the rest are skipped unread.
- ``Y_Unit_Label`` of a channel is its unit hint (checked like a CSV unit hint) unless the
  channel was renamed by ``channel_map`` (then the user vouches for it).
- separators ``Tab``/``Comma``/``Semicolon`` and decimal separator ``.`` or ``,`` as declared.

Only one data segment is read; rows in messages are file lines (1-based).  Bounded like
CSV (``_lines``): the data rows are read in blocks, counted before the columns are allocated.
"""
from __future__ import annotations

import numpy as np

from ._base import (ColumnSelector, Columns, Format, ReadLimits, RecordingError, RecordLike,
                    SI_UNIT, exact_step, parse_number, printed_half_unit, register_format,
                    split_unit)
from ._lines import check_text, count_lines, end_of_content, line_blocks, next_line

MAGIC = "LabVIEW Measurement"
_END = "***End_of_Header***"
_SEPARATORS = {"tab": "\t", "comma": ",", "semicolon": ";", "space": " "}


def read_lvm(raw: bytes, name: str, select: ColumnSelector, limits: ReadLimits) -> Columns:
    start = check_text(raw, name, "LabVIEW .lvm")
    if not raw.startswith(MAGIC.encode(), start):
        raise RecordingError(f"{name}: not a LabVIEW measurement file (no '{MAGIC}' line)")
    end = end_of_content(raw, start)
    marks, pos = [], start
    while len(marks) < 3:
        at = raw.find(_END.encode(), pos, end)
        if at < 0:
            break
        marks.append(at)
        pos = at + len(_END)
    if len(marks) < 2:
        raise RecordingError(f"{name}: LabVIEW header incomplete (expected two "
                             f"'{_END}' lines, found {len(marks)})")
    if len(marks) > 2:
        raise RecordingError(f"{name}: row {count_lines(raw, start, marks[2])}: more than one "
                             "data segment; export one segment per file")
    head_end = next_line(raw, next_line(raw, marks[1], end) + 1, end)  # + the names line
    lines = raw[start:head_end].decode("utf-8").splitlines()
    ends = [i for i, line in enumerate(lines) if line.strip().startswith(_END)]
    file_hdr = _header(lines[:ends[0]], None)
    sep = _SEPARATORS.get(file_hdr.get("Separator", ["Tab"])[0].strip().lower())
    if sep is None:
        raise RecordingError(f"{name}: unknown LabVIEW separator {file_hdr['Separator']}")
    decimal = file_hdr.get("Decimal_Separator", ["."])[0].strip() or "."
    x_columns = file_hdr.get("X_Columns", ["One"])[0].strip().lower()
    seg = _header(lines[ends[0] + 1:ends[1]], sep)
    names_row = ends[1] + 1
    if names_row >= len(lines):
        raise RecordingError(f"{name}: no channel-name line after the header")
    names = [c.strip() for c in lines[names_row].split(sep)]
    while names and names[-1] in ("", "Comment"):
        names.pop()
    units = [u.strip() for u in seg.get("Y_Unit_Label", [])]
    x0 = [_float(v) for v in seg.get("X0", [])]
    dx = [_float(v) for v in seg.get("Delta_X", [])]
    # channel index (for the per-channel header fields) of each column
    chan_of, chan, x_cols = [], -1, []
    for c, n in enumerate(names):
        is_x = (x_columns == "one" and c == 0) or (x_columns == "multi" and n == "X_Value")
        if is_x:
            x_cols.append(c)
            chan_of.append(None)
        else:
            chan += 1
            chan_of.append(chan)
    keep: dict[int, str] = {}
    for c, n in enumerate(names):
        if chan_of[c] is None:
            continue
        target = select.target(n)
        if target is None or target in keep.values():
            continue
        unit = units[chan_of[c]] if chan_of[c] < len(units) else ""
        keep[c] = select.labelled(n, target, unit)
    time_col = None
    first = min((c for c in keep if split_unit(keep[c])[0] != "time"), default=None)
    if x_cols and not any(split_unit(t)[0] == "time" for t in keep.values()):
        before = [c for c in x_cols if first is None or c < first]
        time_col = before[-1] if before else x_cols[0]
    wanted = sorted(keep) + ([time_col] if time_col is not None else [])
    n_rows = count_lines(raw, head_end + 1, end)
    limits.check_values(n_rows * len(wanted), name)
    values = {c: np.empty(n_rows) for c in wanted}
    first_row = names_row + 2  # 1-based line number of the first data row
    max_line = (limits.max_number_chars + 16) * (len(names) + 2) + 256
    for row0, block in line_blocks(raw, head_end + 1, end, max_line, name, first_row):
        for i, line in enumerate(block):
            r = row0 - first_row + i
            cells = line.split(sep)
            for c in wanted:
                cell = cells[c].strip() if c < len(cells) else ""
                if decimal != ".":
                    cell = cell.replace(decimal, ".")
                try:
                    values[c][r] = parse_number(cell) if cell else np.nan
                except ValueError:
                    raise RecordingError(f"{name}: column {names[c]!r}, row {r + first_row}: "
                                         f"{cell[:40]!r} is not a number") from None
    data_lines = range(n_rows)
    data = {keep[c]: values[c] for c in sorted(keep)}
    if time_col is not None:
        data["time"] = values[time_col]
    elif first is not None and not any(split_unit(t)[0] == "time" for t in data):
        ch = chan_of[first]
        if ch >= len(dx) or ch >= len(x0) or not dx[ch] > 0:
            raise RecordingError(f"{name}: no X column and no Delta_X for channel "
                                 f"{names[first]!r}")
        # Delta_X is printed with a few decimals (LabVIEW: 6): 0.000488 is 1/2048 s, not
        # 1/2049.18 s; the step is the sampling rate's, within the printed precision
        step = exact_step(dx[ch], printed_half_unit(seg["Delta_X"][ch]))
        data["time"] = x0[ch] + step * np.arange(len(data_lines))
    return Columns(data, row_offset=first_row)


def _header(lines: list[str], sep: str | None) -> dict[str, list[str]]:
    out = {}
    for line in lines:
        parts = line.split(sep if sep else "\t")
        if parts and parts[0].strip():
            out[parts[0].strip()] = [p for p in parts[1:]]
    return out


def _float(text: str) -> float:
    try:
        return float(text.strip().replace(",", "."))
    except ValueError:
        return float("nan")


def write_lvm(rec: RecordLike) -> bytes:
    """One segment, tab-separated, one X column, SI unit labels, 17 significant digits."""
    names = list(rec.channels)
    n, dt = len(rec.time), float((rec.time[-1] - rec.time[0]) / (len(rec.time) - 1))
    tab = "\t".join

    def per_channel(value: str) -> str:
        return tab([value] * len(names))

    units = tab(SI_UNIT.get(c.partition("_")[0], "") for c in names)
    head = [MAGIC + "\t", "Writer_Version\t2", "Reader_Version\t2", "Separator\tTab",
            "Decimal_Separator\t.", "Multi_Headings\tNo", "X_Columns\tOne",
            "Time_Pref\tRelative", f"Operator\tsiva ({rec.name})", _END + "\t",
            f"Channels\t{len(names)}", f"Samples\t{per_channel(str(n))}",
            f"Y_Unit_Label\t{units}", f"X_Dimension\t{per_channel('Time')}",
            f"X0\t{per_channel(repr(float(rec.time[0])))}",
            f"Delta_X\t{per_channel(repr(dt))}", _END + "\t",
            tab(["X_Value", *names, "Comment"])]
    values = np.column_stack([rec.time, *rec.channels.values()])
    body = "\n".join(tab(repr(float(v)) for v in row) for row in values)
    return ("\n".join(head) + "\n" + body + "\n").encode()


FORMAT = register_format(Format(
    "lvm", (".lvm",), read_lvm, write_lvm,
    media_types=("application/x-lvm",),
    sniff=lambda raw: raw.lstrip(b"\xef\xbb\xbf").startswith(MAGIC.encode()),
    description="LabVIEW Measurement text file"))
