"""The channels of the event log: topics, message models, their JSON Schemas (the file format).

The writer (``writer.py``), the reader (``reader.py``) and ``siva replay`` share these;
they are the log's own models (the log does not import the HTTP API's schemas: the
snapshot's estimate is described by :class:`LoggedEstimate`, the contract keys of
``GET .../estimate``, every other key kept as logged).

One MCAP file per system per process start.

Why MCAP: the log is both the audit trail of a running identification (what arrived, when,
and what the service estimated) and the input of ``siva replay``, so it must be a standard,
self-describing container that outside tools (``mcap info``, Foxglove) open.

Layout: ``<data>/logs/<system>/<UTC start time>-<pid>.mcap``.  Topics (message encoding
``json``, schema encoding ``jsonschema``, schemas generated from the pydantic models below):

- ``/siva/spec``       :class:`SpecEvent` - the model spec (+ trainer settings, e.g. seed)
- ``/siva/recording``  :class:`RecordingEvent` - one accepted recording: the uploaded bytes
  exactly as received (base64), their format, role, and the training epoch at arrival
- ``/siva/dataset``    :class:`DatasetEvent` - (optional) the moment the trainer's data set
  changed: the epoch and the recording ids in use; replay prefers it over arrival epochs
- ``/siva/anchor``     :class:`AnchorEvent` - the trainer entered (or re-anchored) the
  output-error phase after ``epoch`` epochs: the anchor theta, the records and chain it was
  linearised on, the bootstrap replicate count and seed (replay recomputes it exactly)
- ``/siva/snapshot``   :class:`SnapshotEvent` - an estimate as served by GET .../estimate
- ``/siva/repair``     :class:`RepairEvent` - start-up found the log behind the store and
  repaired it (service/replay/reconcile.py): what was missing, and - when the log can no longer
  explain the checkpoint training resumes from - that trainer state, so replay starts there

Recordings are logged as the original bytes (not re-encoded float arrays) so that a replay
parses exactly what the live service parsed - bit-identical states - and the file stays
compact: every message is its own zstd-compressed chunk, which packs the base64 text back
to below the size of the raw CSV.

Crash safety: every message is written as one complete chunk, then the file is flushed and
fsync'ed, so a process killed mid-write loses at most the message being written.  A file
without footer (the process died) is still readable (:func:`read_events` keeps every
complete record, resynchronising after a torn one) and :func:`recover` rewrites it as a
finished file.  A write that fails (disk full, read-only) abandons the file - its tail may
be torn - and the next event opens a new file that starts with the spec again.

Write-ahead: the service logs a recording *before* the store commits it and before the
HTTP 202, and a failed log write fails the upload (507), so every acknowledged recording
is in the log of its system (see docs/reliability.md).
"""
from __future__ import annotations

import base64
import hashlib
import json
from dataclasses import dataclass
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from siva_core import MCAP_MAGIC

FORMAT_VERSION = "siva-log/1"
TOPIC_SPEC = "/siva/spec"
TOPIC_RECORDING = "/siva/recording"
TOPIC_DATASET = "/siva/dataset"
TOPIC_SNAPSHOT = "/siva/snapshot"
TOPIC_ANCHOR = "/siva/anchor"
TOPIC_REPAIR = "/siva/repair"
PLATFORM_METADATA = "siva.platform"
MAGIC = MCAP_MAGIC


# ------------------------------------------------------------------------ message models
class SpecEvent(BaseModel):
    """The model spec of a system, as registered (CONTRACT.md structure)."""

    system: str
    spec: dict[str, Any] = Field(description="model spec, the JSON form of the TOML file")
    settings: dict[str, Any] = Field(default_factory=dict,
                                     description="trainer settings needed to replay (seed, preset)")
    wall_time: float = Field(description="UNIX time [s] when logged")


class RecordingEvent(BaseModel):
    """One accepted recording, byte for byte as uploaded."""

    system: str
    id: str
    role: Literal["train", "validation"]
    format: str = Field(description="csv, json, npz or mcap: how to parse `data`")
    epoch: int = Field(ge=0, description="training epochs completed when it arrived")
    name: str | None = None
    size: int = Field(ge=0, description="bytes of the decoded payload")
    sha256: str
    data: str = Field(description="the uploaded bytes, base64 (RFC 4648)")
    wall_time: float
    channel_map: dict[str, str] | None = Field(
        None, description="the upload's ?map= channel renames (stored name -> column)")
    units: dict[str, str] | None = Field(None, description="the upload's ?unit= declarations")

    def payload(self) -> bytes:
        """The uploaded bytes; checked against the logged hash so corruption is loud."""
        raw = base64.b64decode(self.data)
        if hashlib.sha256(raw).hexdigest() != self.sha256:
            raise ValueError(f"recording {self.id}: payload does not match its sha256")
        return raw


class DatasetEvent(BaseModel):
    """The trainer's data set changed before training epoch ``epoch + 1``."""

    system: str
    epoch: int = Field(ge=0, description="epochs completed when the new data set took effect")
    train: list[str]
    validation: list[str]
    processing: dict[str, Any] | None = Field(
        None, description="the processing chain's settings (siva_core Processing fields)")
    wall_time: float


class AnchorEvent(BaseModel):
    """The output-error phase was anchored (linearised) before training epoch ``epoch + 1``."""

    system: str
    epoch: int = Field(ge=0, description="epochs completed when the anchor took effect")
    theta: list[float] = Field(description="anchor parameters, in the model's free order")
    train: list[str] = Field(description="records the output error was linearised on")
    validation: list[str] = Field(description="records the discriminator judges")
    processing: dict[str, Any] | None = None
    source: str = Field(description="best (the first recommend_best) | headline | given")
    n_noise: int = Field(ge=0, description="parametric-bootstrap replicates")
    seed: int
    resume: bool = Field(False, description="restored from a checkpoint (no state reset)")
    wall_time: float


class LoggedEstimate(BaseModel):
    """The estimate in a snapshot event: the contract keys of ``GET .../estimate`` (typed),
    every other key of the body kept as served (``extra="allow"``)."""

    model_config = ConfigDict(extra="allow")
    parameters: dict[str, dict[str, Any]]
    discriminator: dict[str, Any]
    epoch: int
    converged: bool
    n_recordings: dict[str, int]


class SnapshotEvent(BaseModel):
    """An estimate as served by GET /v1/systems/{name}/estimate at ``epoch``."""

    system: str
    epoch: int = Field(ge=0)
    estimate: LoggedEstimate
    wall_time: float

    def estimate_dict(self) -> dict[str, Any]:
        """The logged estimate as plain JSON types (extra keys included)."""
        return self.estimate.model_dump(mode="json")


class RepairEvent(BaseModel):
    """Start-up found this system's log behind the store (the truth) and repaired it.

    ``recordings``: stored recordings the log lacked, logged just before this event.
    ``baseline_*``: when the remaining log cannot reproduce the checkpoint the trainer
    resumes from (its history was lost), that trainer state (``torch.save`` bytes, base64)
    at ``baseline_epoch``: a replay starts from it instead of from scratch."""

    system: str
    reasons: list[str] = Field(description="what was found missing or inconsistent")
    recordings: list[str] = Field(default_factory=list,
                                  description="ids of the recordings logged by this repair")
    baseline_epoch: int | None = Field(None, ge=0)
    baseline_train: list[str] = Field(default_factory=list)
    baseline_validation: list[str] = Field(default_factory=list)
    baseline_sha256: str | None = None
    baseline_state: str | None = Field(None, description="torch.save of the trainer state, base64")
    wall_time: float

    def state_bytes(self) -> bytes | None:
        """The baseline trainer state; checked against its hash so corruption is loud."""
        if self.baseline_state is None:
            return None
        raw = base64.b64decode(self.baseline_state)
        if hashlib.sha256(raw).hexdigest() != self.baseline_sha256:
            raise ValueError(f"repair of {self.system}: baseline state does not match its sha256")
        return raw


TOPICS: dict[str, type[BaseModel]] = {
    TOPIC_SPEC: SpecEvent,
    TOPIC_RECORDING: RecordingEvent,
    TOPIC_DATASET: DatasetEvent,
    TOPIC_SNAPSHOT: SnapshotEvent,
    TOPIC_ANCHOR: AnchorEvent,
    TOPIC_REPAIR: RepairEvent,
}


def schema_bytes(model: type[BaseModel]) -> bytes:
    return json.dumps(model.model_json_schema(), separators=(",", ":")).encode()



@dataclass
class LogEvent:
    """One decoded message: topic, log time [ns] and the typed event."""

    topic: str
    log_time: int
    event: SpecEvent | RecordingEvent | DatasetEvent | SnapshotEvent | RepairEvent

