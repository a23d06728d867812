"""What every recording format shares: the column naming rules, the error, the read limits,
the column selector and the :class:`Format` registry entry.

Readers return plain named columns; :meth:`Recording.from_columns` validates them, so every
format refuses the same things with the same messages.  This module imports nothing from
``recording`` (the registry sits below the Recording class: no import cycle).
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Protocol, Sequence

import numpy as np

QUANTITIES = ("disp", "vel", "acc", "force")
# SI unit of each quantity and the accepted spellings of a unit hint (lower case).
UNITS = {"disp": {"m"}, "vel": {"m/s"}, "acc": {"m/s^2", "m/s2", "m/s**2", "m/s²"},
         "force": {"n"}, "time": {"s"}}
SI_UNIT = {"time": "s", "disp": "m", "vel": "m/s", "acc": "m/s^2", "force": "N"}
_UNIT_RE = re.compile(r"^\s*([A-Za-z0-9_]+)\s*(?:\[([^\]]*)\]|\(([^)]*)\))?\s*$")


class RecordingError(ValueError):
    """A recording that cannot be used; the message names the file, column and row."""


class RecordingTooLarge(RecordingError):
    """A recording over a size limit (decompressed size, members, chunk): HTTP 413."""


@dataclass(frozen=True)
class ReadLimits:
    """Bounds checked *before* allocating, so that a small upload cannot claim a lot of memory.

    Why these numbers: a float64 record of 8 M samples is 64 MiB, the service's default
    upload limit, so a legitimate record never needs more; a compression bomb needs far more.
    """

    max_decompressed_bytes: int = 128 * 2**20   # sum over the columns read (NPZ, MCAP, MAT)
    max_members: int = 256                      # NPZ members / MAT variables / TDMS channels
    max_json_depth: int = 16                    # nesting of [ and {
    max_number_chars: int = 64                  # digits of one JSON number
    #: numbers over the columns read (all formats): 8 Mi float64 = 64 MiB, checked before
    #: the arrays are allocated
    max_values: int = 8 * 2**20
    #: compressed content (NPZ, MCAP, MAT) may decompress to this many times the file, or
    #: to ``expansion_floor`` bytes, whichever is more (and never above
    #: ``max_decompressed_bytes``): measured data compresses 1-4x, a bomb 1000x
    max_expansion: float = 16.0
    expansion_floor: int = 4 * 2**20

    def check_total(self, what: str, total: int, name: str) -> None:
        if total > self.max_decompressed_bytes:
            raise RecordingTooLarge(
                f"{name}: {what} would decompress to {total / 2**20:.1f} MiB, above the limit "
                f"of {self.max_decompressed_bytes / 2**20:.0f} MiB")

    def check_expansion(self, what: str, total: int, body_bytes: int, name: str) -> None:
        """Decompressed ``total`` bytes from a ``body_bytes`` file, checked before inflating."""
        self.check_total(what, total, name)
        allowed = max(self.expansion_floor, int(self.max_expansion * body_bytes))
        if total > allowed:
            raise RecordingTooLarge(
                f"{name}: {what} would decompress to {total / 2**20:.1f} MiB from a "
                f"{body_bytes / 2**20:.2f} MiB file ({total / max(body_bytes, 1):.0f} x); at "
                f"most {self.max_expansion:g} x (or {self.expansion_floor / 2**20:.0f} MiB) "
                "is accepted: a compression bomb, not a recording")

    def check_values(self, count: int, name: str) -> None:
        """At most ``max_values`` numbers over the columns, checked before allocating."""
        if count > self.max_values:
            raise RecordingTooLarge(f"{name}: {count} values in the columns read, at most "
                                    f"{self.max_values} ({self.max_values * 8 / 2**20:.0f} "
                                    "MiB as float64)")

    def check_members(self, what: str, count: int, name: str) -> None:
        if count > self.max_members:
            raise RecordingTooLarge(f"{name}: {count} {what}, at most {self.max_members} allowed")


DEFAULT_LIMITS = ReadLimits()


def split_unit(raw: str) -> tuple[str, str | None]:
    """``'acc_x [m/s^2]'`` -> ``('acc_x', 'm/s^2')``; ``'Time (s)'`` -> ``('time', 's')``."""
    m = _UNIT_RE.match(raw)
    if not m:
        return raw.strip(), None
    unit = m.group(2) if m.group(2) is not None else m.group(3)
    col = m.group(1)
    return ("time" if col.lower() == "time" else col), unit


def check_unit(unit: str | None, qty: str, col: str, name: str) -> None:
    if unit is None:
        return
    u = unit.strip().lower().replace(" ", "")
    if u not in UNITS[qty]:
        raise RecordingError(f"{name}: column {col!r}: unit [{unit}] is not the expected "
                             f"{sorted(UNITS[qty])[0]} (convert to SI units)")


class ColumnSelector:
    """Which stored channels a reader keeps, and under which column name.

    ``channel_map`` renames a format's channels to the column names (``{"Strain_0":
    "disp_x"}``); a channel is kept when its (renamed) name is ``time`` or
    ``<quantity>_<dof>`` for a DOF of the model (any DOF when ``dofs`` is None).
    Everything else is skipped unread and reported in ``skipped`` (a warning later).
    """

    def __init__(self, dofs: Sequence[str] | None = None,
                 channel_map: Mapping[str, str] | None = None) -> None:
        self.dofs = None if dofs is None else set(dofs)
        self.channel_map = dict(channel_map or {})
        self.skipped: list[str] = []

    def target(self, raw_name: str) -> str | None:
        """Column name for a stored channel, or None (skipped)."""
        raw_name = str(raw_name)
        mapped = self.channel_map.get(raw_name, raw_name)
        col = split_unit(mapped)[0]
        if col == "time":
            return mapped
        qty, _, dof = col.partition("_")
        if qty in QUANTITIES and dof and (self.dofs is None or dof in self.dofs):
            return mapped
        self.skipped.append(raw_name)
        return None

    def mapped(self, raw_name: str) -> bool:
        """Did the user rename this channel (then its stored unit label is not checked)?"""
        return str(raw_name) in self.channel_map


@dataclass
class Columns:
    """What a reader returns: named 1-D columns and how array index maps to a row number."""

    data: dict[str, Any]
    row_offset: int = 0
    meta: dict[str, Any] = field(default_factory=dict)


class RecordLike(Protocol):
    """What a writer needs of a Recording (kept structural to avoid importing it)."""

    time: np.ndarray
    channels: dict[str, np.ndarray]
    name: str


Reader = Callable[[bytes, str, ColumnSelector, ReadLimits], Columns]
Writer = Callable[[RecordLike], bytes]


@dataclass(frozen=True)
class Format:
    """One recording format: how to recognise, read and write it."""

    name: str
    suffixes: tuple[str, ...]
    read: Reader
    write: Writer | None = None
    media_types: tuple[str, ...] = ()
    sniff: Callable[[bytes], bool] | None = None   # does the content look like this format?
    description: str = ""


REGISTRY: dict[str, Format] = {}


def register_format(fmt: Format) -> Format:
    """Add a format (name and suffixes must be new); returns it for module-level use."""
    if fmt.name in REGISTRY:
        raise ValueError(f"recording format {fmt.name!r} is already registered")
    REGISTRY[fmt.name] = fmt
    return fmt


def as_bytes(raw: bytes | bytearray | memoryview | str) -> bytes:
    return raw.encode() if isinstance(raw, str) else bytes(raw)


def decode_text(raw: bytes, name: str, what: str) -> str:
    """UTF-8 text (optional BOM); binary data or another encoding is refused by name."""
    if b"\x00" in raw[:65536]:
        raise RecordingError(f"{name}: not a text {what} file (binary data)")
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise RecordingError(f"{name}: not UTF-8 text (byte {exc.start}); expected a "
                             f"{what} file") from None


def parse_number(cell: str) -> float:
    """``float()`` without Python's extras: ``1_0`` is not the number 10 in a data file."""
    if "_" in cell:
        raise ValueError(cell)
    return float(cell)
