"""Text recordings read in blocks of lines, never whole (CSV, LabVIEW .lvm).

Why: ``bytes.decode().splitlines()`` of a 60 MB file holds the text twice plus one Python
string per line (1.5 GB for a 60 MB CSV of short rows, issue 19).  Here the body is checked
as UTF-8 block by block, rows are counted with ``bytes.count`` (no copy) so the caller can
check the value count before allocating its arrays, and lines are handed out 256 KiB at a
time, each at most ``max_line`` bytes (a 60 MB line is refused, not tokenised).
"""
from __future__ import annotations

import codecs
from typing import Iterator

from ._base import RecordingError, RecordingTooLarge

BOM = b"\xef\xbb\xbf"
BLOCK = 1 << 18  # 256 KiB: its list of line strings stays a few MB
_WS = b" \t\r\n\x0b\x0c"


def check_text(raw: bytes, name: str, what: str) -> int:
    """Refuse binary or non-UTF-8 data (by byte offset); returns where the text starts."""
    if b"\x00" in raw[:65536]:
        raise RecordingError(f"{name}: not a text {what} file (binary data)")
    start = len(BOM) if raw.startswith(BOM) else 0
    decoder = codecs.getincrementaldecoder("utf-8")()
    for pos in range(start, len(raw), BLOCK):
        try:
            decoder.decode(raw[pos:pos + BLOCK], final=pos + BLOCK >= len(raw))
        except UnicodeDecodeError as exc:
            raise RecordingError(f"{name}: not UTF-8 text (byte {pos + exc.start}); expected "
                                 f"a {what} file") from None
    return start


def end_of_content(raw: bytes, start: int) -> int:
    """Index after the last non-blank byte at or after ``start`` (trailing blanks cut)."""
    end = len(raw)
    while end > start:
        lo = max(start, end - 65536)
        kept = raw[lo:end].rstrip(_WS)
        if kept:
            return lo + len(kept)
        end = lo
    return start


def next_line(raw: bytes, start: int, end: int) -> int:
    """Index of the newline ending the line at ``start`` (``end`` when there is none)."""
    nl = raw.find(b"\n", start, end)
    return end if nl < 0 else nl


def count_lines(raw: bytes, start: int, end: int) -> int:
    """Lines in ``raw[start:end]`` (a last line without a newline counts)."""
    return 0 if end <= start else raw.count(b"\n", start, end) + 1


def line_blocks(raw: bytes, start: int, end: int, max_line: int, name: str,
                first_row: int) -> Iterator[tuple[int, list[str]]]:
    """(file row of the first line, lines) for ``raw[start:end]``, ~1 MiB at a time.

    ``first_row`` is the 1-based file row of the line at ``start``; a line longer than
    ``max_line`` bytes is refused with its row."""
    pos, row = start, first_row
    while pos < end:
        cut = min(end, pos + BLOCK)
        if cut < end:
            nl = raw.find(b"\n", cut, min(end, cut + max_line + 1))
            if nl < 0:
                last = raw.rfind(b"\n", pos, cut)
                at = row + (0 if last < 0 else raw.count(b"\n", pos, last + 1))
                raise RecordingTooLarge(f"{name}: row {at}: a line of more than {max_line} "
                                        "bytes, longer than any row of numbers this header "
                                        "allows")
            cut = nl
        lines = raw[pos:cut].decode("utf-8").split("\n")
        longest = max(map(len, lines))
        if longest > max_line:
            k = next(i for i, line in enumerate(lines) if len(line) > max_line)
            raise RecordingTooLarge(f"{name}: row {row + k}: a line of {len(lines[k])} bytes, "
                                    f"at most {max_line} for this header")
        yield row, [line.rstrip("\r") for line in lines]
        row += len(lines)
        pos = cut + 1


__all__ = ["check_text", "end_of_content", "next_line", "count_lines", "line_blocks", "BOM"]
