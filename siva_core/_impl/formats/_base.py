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
#: units a channel may be *declared* in (``--unit acc_x=g``, ``units=`` of Recording.read, the
#: spec's ``[channels] units``) and the factor to SI; keys lower case, spaces removed.  A unit
#: written in the file itself is still refused unless it is SI or declared (CONTRACT: a
#: wrong unit hint is refused), so nothing is converted without the user saying so.
UNIT_FACTORS: dict[str, dict[str, float]] = {
    "time": {"s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "min": 60.0},
    "disp": {"m": 1.0, "mm": 1e-3, "cm": 1e-2, "um": 1e-6, "µm": 1e-6, "in": 0.0254,
             "inch": 0.0254},
    "vel": {"m/s": 1.0, "mm/s": 1e-3, "cm/s": 1e-2, "um/s": 1e-6, "µm/s": 1e-6,
            "in/s": 0.0254, "ips": 0.0254},
    "acc": {"m/s^2": 1.0, "m/s2": 1.0, "m/s**2": 1.0, "m/s²": 1.0, "g": 9.80665,
            "g0": 9.80665, "mg": 9.80665e-3, "mm/s^2": 1e-3, "mm/s2": 1e-3, "mm/s²": 1e-3,
            "in/s^2": 0.0254, "in/s2": 0.0254, "gal": 1e-2},
    "force": {"n": 1.0, "kn": 1e3, "lbf": 4.4482216152605, "kgf": 9.80665},
}
#: other names of the time column (compared lower case, spaces and units removed)
TIME_ALIASES = frozenset({"time", "t", "x_value", "time_s", "zeit", "temps", "tiempo"})
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
    return ("time" if col.lower() in TIME_ALIASES else col), unit


def unit_key(unit: str) -> str:
    return unit.strip().lower().replace(" ", "")


def unit_factor(unit: str, qty: str) -> float | None:
    """Factor from ``unit`` to the SI unit of ``qty`` (``g`` for acc: 9.80665); None when
    ``unit`` is not a unit of that quantity."""
    return UNIT_FACTORS.get(qty, {}).get(unit_key(unit))


def known_unit(unit: str) -> bool:
    """Is ``unit`` a unit of any quantity (then a mapped channel keeps its file label)?"""
    return any(unit_key(unit) in table for table in UNIT_FACTORS.values())


def check_unit(unit: str | None, qty: str, col: str, name: str) -> None:
    if unit is None:
        return
    u = unit_key(unit)
    if u not in UNITS[qty]:
        hint = ""
        if unit_factor(unit, qty) is not None:
            target = split_unit(col)[0]
            hint = (f", or declare it to convert on reading: --unit {target}={unit.strip()} "
                    f"(HTTP: ?unit={target}={unit.strip()})")
        raise RecordingError(f"{name}: column {col!r}: unit [{unit}] is not the expected "
                             f"{SI_UNIT[qty]} (convert to SI units{hint})")


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
        # the file's names are matched exactly, else ignoring case and repeated spaces
        self._loose = {_loose(k): v for k, v in self.channel_map.items()}
        self.skipped: list[str] = []
        self.seen: list[str] = []      # every stored channel name the reader offered
        self.used: set[str] = set()    # channel_map keys that matched a stored channel

    def _lookup(self, raw_name: str) -> str | None:
        if raw_name in self.channel_map:
            self.used.add(raw_name)
            return self.channel_map[raw_name]
        loose = _loose(raw_name)
        if loose in self._loose:
            self.used.update(k for k in self.channel_map if _loose(k) == loose)
            return self._loose[loose]
        return None

    def target(self, raw_name: str) -> str | None:
        """Column name for a stored channel, or None (skipped)."""
        raw_name = str(raw_name)
        self.seen.append(raw_name)
        mapped = self._lookup(raw_name) or raw_name
        col = split_unit(mapped)[0]
        if col == "time":
            return mapped if split_unit(mapped)[1] is not None else "time"
        qty, _, dof = col.partition("_")
        if qty in QUANTITIES and dof and (self.dofs is None or dof in self.dofs):
            return mapped
        self.skipped.append(raw_name)
        return None

    def mapped(self, raw_name: str) -> bool:
        """Did the user rename this channel (then a stored unit label this program does not
        know, e.g. a sensor's ``V``, is not checked)?"""
        raw_name = str(raw_name)
        return raw_name in self.channel_map or _loose(raw_name) in self._loose

    def labelled(self, raw_name: str, target: str, unit: str | None) -> str:
        """``target`` with the file's unit label as a hint (``acc_LO [g]``), so that
        :meth:`Recording.from_columns` checks or converts it; a renamed channel keeps a label
        only when it is a known unit (``g``, ``N``), not e.g. a sensor's ``V``."""
        unit = (unit or "").strip()
        if not unit or split_unit(target)[1] is not None:
            return target
        if self.mapped(raw_name) and not known_unit(unit):
            return target
        return f"{target} [{unit}]"

    def unmatched(self) -> list[str]:
        """``channel_map`` keys that named no stored channel (a typo, or another file's)."""
        return [k for k in self.channel_map if k not in self.used]


def _loose(name: str) -> str:
    return " ".join(str(name).split()).casefold()


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


#: sampling rates data-acquisition hardware uses [Hz] (powers of two, the 51.2 kHz family,
#: audio rates, 1-2-2.5-5 decades): the step a file prints with few digits is snapped to one
#: of these when it lies within the printed precision
COMMON_RATES = tuple(sorted({2.0 ** j for j in range(4, 19)}
                            | {51200.0 / 2 ** j for j in range(0, 7)}
                            | {22050.0, 44100.0, 48000.0, 96000.0, 192000.0}
                            | {m * 10.0 ** k for m in (1, 2, 2.5, 5) for k in range(1, 6)}))


def printed_half_unit(text: str) -> float:
    """Half a unit of the last printed digit of a number (``'0.000488'`` -> 5e-7): how far
    the printed value may be from the true one."""
    t = text.strip().lower().replace(",", ".")
    mant, _, exp = t.partition("e")
    decimals = len(mant.partition(".")[2]) if "." in mant else 0
    try:
        e = int(exp) if exp else 0
    except ValueError:
        e = 0
    return 0.5 * 10.0 ** (e - decimals)


def exact_step(step: float, tol: float) -> float:
    """The sampling step ``step`` stands for when it is known only to +-``tol`` [s]: a common
    DAQ rate inside that range (nearest first), else the rate with the fewest significant
    digits inside it, else ``step`` itself."""
    if not (step > 0 and tol >= 0) or tol >= step:
        return step
    lo, hi = 1.0 / (step + tol), 1.0 / (step - tol)
    inside = [fs for fs in COMMON_RATES if lo <= fs <= hi]
    if inside:
        return 1.0 / min(inside, key=lambda fs: abs(fs - 1.0 / step))
    for digits in range(1, 7):
        fs = float(f"{1.0 / step:.{digits}g}")
        if lo <= fs <= hi:
            return 1.0 / fs
    return step
