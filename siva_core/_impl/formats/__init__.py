"""Recording formats, one module each, chosen by name from :data:`REGISTRY` (like element kinds).

Each format module registers a :class:`Format`: a reader (bytes -> named columns, bounded by
:class:`ReadLimits`), a writer, file suffixes, media types and a content test.  This package
holds the one sniffer (:func:`sniff_format`) and the one way from an upload's content type,
file name and bytes to a format (:func:`resolve_format`).  Validation of the columns is
:meth:`Recording.from_columns`, the same for every format.
"""
from __future__ import annotations

from typing import Mapping, Sequence

from ._base import (DEFAULT_LIMITS, QUANTITIES, REGISTRY, SI_UNIT, UNITS, ColumnSelector, Columns,
                    Format, ReadLimits, RecordingError, RecordingTooLarge, TIME_ALIASES,
                    UNIT_FACTORS, check_unit, exact_step, register_format, split_unit,
                    unit_factor)
from . import csv, json, npz, mcap, lvm, uff58, tdms, mat  # noqa: F401,E402  (registers)
from .mcap import MCAP_MAGIC

# content tests, most specific first; CSV is what is left
_SNIFF_ORDER = ("mcap", "npz", "tdms", "mat", "lvm", "uff58", "json")


def sniff_format(raw: bytes | str) -> str:
    """Format of uploaded bytes from their content (magic bytes, first lines); else csv."""
    if isinstance(raw, str):
        raw = raw[:4096].encode("utf-8", "replace")
    head = bytes(raw[:4096]) if len(raw) > 4096 else bytes(raw)
    for name in _SNIFF_ORDER:
        test = REGISTRY[name].sniff
        if test is not None and test(head):
            return name
    return "csv"


def format_of_suffix(filename: str | None) -> str | None:
    """``run.tdms`` -> ``tdms``; None for no or an unknown suffix."""
    if not filename or "." not in filename:
        return None
    suffix = "." + filename.rsplit(".", 1)[1].lower()
    return next((f.name for f in REGISTRY.values() if suffix in f.suffixes), None)


def media_types() -> dict[str, str]:
    """Content type -> format name, over every registered format."""
    return {m: f.name for f in REGISTRY.values() for m in f.media_types}


def resolve_format(media: str | None, filename: str | None, raw: bytes) -> str:
    """An upload's format: a specific content type, else the file suffix, else the content.

    Generic text (``text/plain``, ``text/csv``) names no format for sure: a LabVIEW or UFF
    file sent as text is recognised by its content.
    """
    by_media = media_types().get(media or "")
    if by_media and media not in ("text/plain", "text/csv", "application/csv"):
        return by_media
    by_suffix = format_of_suffix(filename)
    if by_suffix:
        return by_suffix
    sniffed = sniff_format(raw)
    return sniffed if sniffed != "csv" or not by_media else by_media


def read_columns(raw: bytes, fmt: str, name: str, dofs: Sequence[str] | None = None, *,
                 channel_map: Mapping[str, str] | None = None,
                 limits: ReadLimits = DEFAULT_LIMITS) -> tuple[Columns, list[str]]:
    """Columns of a recording in format ``fmt`` and the channels skipped unread."""
    fmt = fmt.lower().lstrip(".")
    if fmt == "txt":
        fmt = "csv"
    if fmt not in REGISTRY:
        raise RecordingError(f"{name}: unknown recording format {fmt!r} "
                             f"({', '.join(REGISTRY)})")
    select = ColumnSelector(dofs, channel_map)
    cols = REGISTRY[fmt].read(bytes(raw), name, select, limits)
    unknown = [k for k in select.unmatched()
               if not (split_unit(select.channel_map[k])[0] == "time" and "time" in
                       {split_unit(c)[0] for c in cols.data})]
    if unknown:
        raise RecordingError(f"{name}: no channel named {unknown[0]!r} to map to "
                             f"{select.channel_map[unknown[0]]!r}; the file's channels: "
                             f"{_listing(select.seen)}")
    cols.meta.setdefault("channels", list(select.seen))
    return cols, select.skipped


def _listing(names: Sequence[str], limit: int = 40) -> str:
    shown = ", ".join(repr(n) for n in names[:limit])
    return shown + (f" ... ({len(names)} in all)" if len(names) > limit else "") if names \
        else "(none)"


def write_bytes(rec, fmt: str) -> bytes:
    """``rec`` in format ``fmt`` (every registered format has a writer)."""
    fmt = fmt.lower().lstrip(".")
    if fmt == "txt":
        fmt = "csv"
    f = REGISTRY.get(fmt)
    if f is None or f.write is None:
        raise RecordingError(f"{rec.name}: cannot write format {fmt!r} "
                             f"({', '.join(n for n, g in REGISTRY.items() if g.write)})")
    return f.write(rec)


__all__ = ["REGISTRY", "Format", "ReadLimits", "DEFAULT_LIMITS", "ColumnSelector", "Columns",
           "RecordingError", "RecordingTooLarge", "register_format", "sniff_format",
           "format_of_suffix", "media_types", "resolve_format", "read_columns", "write_bytes",
           "MCAP_MAGIC", "QUANTITIES", "UNITS", "SI_UNIT", "split_unit", "check_unit",
           "UNIT_FACTORS", "TIME_ALIASES", "unit_factor", "exact_step"]
