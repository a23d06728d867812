"""What the store knows about one recording, and the rule giving uploads without a role one."""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Iterable, Literal

from siva_core import RECORDING_FORMATS as REGISTRY

from ..errors import UnknownRecording

Role = Literal["train", "validation"]
ROLES: tuple[str, ...] = ("train", "validation")
FORMATS = tuple(REGISTRY)  # every registered recording format


@dataclass(frozen=True)
class RecordingMeta:
    """What the store knows about one acknowledged recording (immutable)."""

    id: str
    system: str
    index: int              # arrival index within the system, 1-based, never reused
    role: str
    role_source: str        # "explicit" (the ?role= of the upload) or "auto" (the split rule)
    sha256: str
    fmt: str
    filename: str
    bytes: int
    n_samples: int
    fs: float
    duration_s: float
    columns: tuple[str, ...]
    received_at: float      # unix time of the acknowledgement
    channel_map: dict[str, str] | None = None  # the upload's ?map= (stored name -> column)
    units: dict[str, str] | None = None        # the upload's ?unit= (column -> unit)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["columns"] = list(self.columns)
        return d

    def read_options(self, structure: Any) -> dict[str, Any]:
        """``Recording.read`` keywords for this stored file: the system's ``[channels]``
        overridden by the upload's own mapping."""
        return structure.read_options(self.channel_map, self.units)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "RecordingMeta":
        d = dict(d)
        d["columns"] = tuple(d.get("columns", ()))
        return cls(**{k: d[k] for k in cls.__dataclass_fields__ if k in d})


@dataclass(frozen=True)
class UploadFacts:
    """What parsing an upload found (``uploads.parse_upload``), recorded in its meta."""

    n_samples: int = 0
    fs: float = 0.0
    duration_s: float = 0.0
    columns: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()
    channel_map: dict[str, str] | None = None
    units: dict[str, str] | None = None


def role_counts(metas: Iterable[RecordingMeta]) -> dict[str, int]:
    c = {r: 0 for r in ROLES}
    for m in metas:
        c[m.role] += 1
    return c


def auto_role(index: int, counts: dict[str, int], every: int) -> str:
    """The documented split for uploads without ``role``.

    The first record goes to train; while there is train data but no validation record, the
    next goes to validation; after that, arrival ``index`` goes to validation when
    ``index % every == 0`` (so 1 in ``every`` records validates) and to train otherwise.
    """
    if counts.get("train", 0) == 0:
        return "train"
    if counts.get("validation", 0) == 0:
        return "validation"
    return "validation" if index % every == 0 else "train"


def find_recording(metas: list[RecordingMeta], name: str, rid: str) -> RecordingMeta:
    for m in metas:
        if m.id == rid:
            return m
    raise UnknownRecording(f"system {name!r} has no recording {rid!r}")


def raw_name(rid: str, fmt: str) -> str:
    return f"{rid}.data.{fmt}"
