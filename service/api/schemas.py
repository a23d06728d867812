"""Pydantic models of the HTTP API: what /openapi.json documents and responses follow.

The contract fixes some keys and lets us add more, so every response model allows extra
keys (``extra="allow"``); the spec body is validated by ``Structure.from_dict``, whose
messages name what and where, so ``SystemSpec`` only documents its shape.
"""
from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field


class _Open(BaseModel):
    model_config = ConfigDict(extra="allow")


class SystemSpec(_Open):
    """The model spec: the JSON form of the TOML of CONTRACT.md (validated by siva_core)."""

    name: str | None = Field(None, description="model name (the URL names the system)")
    dofs: list[str] = Field(description="degree-of-freedom names")
    mass: dict[str, float] = Field(description="kg per DOF")
    elements: list[dict[str, Any]] = Field(
        description='[{"kind": ..., "between": [dof, dof|"ground"], "params": {coef: name}}]')
    parameters: dict[str, dict[str, float]] | None = Field(
        None, description="per-parameter settings: scale, fixed, lower, upper")
    forces: dict[str, Any] | None = Field(None, description="force gains per DOF")


class SystemAck(_Open):
    name: str
    created: bool
    dofs: list[str]
    free_parameters: list[str]
    spec: dict[str, Any]


class RecordingAck(_Open):
    """202 body: sent only once the recording is durably stored."""

    id: str
    role: Literal["train", "validation"]
    role_source: Literal["explicit", "auto"]
    index: int
    sha256: str
    duplicate: bool = Field(description="true when these exact bytes were already stored")
    warnings: list[str] = []


class RecordingInfo(_Open):
    id: str
    index: int
    role: Literal["train", "validation"]
    role_source: str
    sha256: str
    fmt: str
    filename: str
    bytes: int
    n_samples: int
    fs: float
    duration_s: float
    columns: list[str]
    received_at: float
    in_memory: bool = Field(description="held in the replay buffer (used for training now)")


class RecordingList(_Open):
    system: str
    recordings: list[RecordingInfo]
    n_recordings: dict[str, int]


class ParameterSummary(_Open):
    mean: float | None
    std: float | None
    ci95: list[float | None] | None


class BestParameter(_Open):
    value: float | None
    std: float | None = Field(None, description="Gauss-Newton std (inflated for correlated "
                                                "residuals); null when not refined")
    ci95: list[float | None] | None = None


class Best(_Open):
    """The output-error estimate: first ``recommend_best`` (Approach III over the running
    ensemble, then the refinement; ``source = "recommend_best"``), then the precision-
    weighted mean of the per-record fits over a recent window (``source = "records"``)."""

    parameters: dict[str, BestParameter]
    epoch: int = Field(description="trainer epoch when it was computed")
    n_records: int = Field(description="records it was fitted on")
    time: float = Field(description="Unix time it was computed")
    output_error: float | None = Field(description="normalised output error on those records "
                                                   "(recommend_best only)")
    refined: bool | None = Field(None, description="false: the refinement did not lower the "
                                                   "output error, Approach III's winner is kept")
    source: str | None = Field(None, description="recommend_best | records")
    records: list[str] | None = Field(None, description="ids of the records it used")


class EstimateInfo(_Open):
    source: str | None = Field(description="best | ensemble | generator")
    time: float | None = Field(description="Unix time the published values were computed")
    age_s: float | None = Field(description="seconds since then, at publication")
    records: list[str] | None = Field(description="records behind the values (best)")
    method: str | None
    note: str | None


class Estimate(_Open):
    """GET .../estimate: the contract keys, plus state, modal, losses, data, alarms...

    ``parameters`` is the headline: ``best`` once there is one, else the running ensemble
    (``estimate_source`` says which); the ensemble itself is always under ``ensemble``."""

    parameters: dict[str, ParameterSummary]
    discriminator: dict[str, Any]
    epoch: int
    converged: bool
    n_recordings: dict[str, int]
    estimate_source: str | None = Field(None, description="best | ensemble | generator")
    estimate: EstimateInfo | None = None
    ensemble: dict[str, dict[str, Any]] | None = Field(
        None, description="the running Approach II ensemble {mean, std, ci95, ess, n}")
    best: Best | None = Field(None, description="the output-error estimate (null until the "
                                                "first one finished)")
    provisional: bool | None = Field(None, description="true while the headline is neither "
                                     "best nor a final ensemble: then no ci95 (null)")
    ensemble_state: str | None = Field(None, description="provisional | final (only a final "
                                       "ensemble has ci95)")
    phase: str | None = Field(None, description="equation_error | output_error")
    validation: dict[str, Any] | None = Field(
        None, description="the held-out test: verdict (accepted | rejected | null), T, "
                          "p_value, per_record, headline, ensemble, discriminator (its own "
                          "numbers, labelled)")
    model_rejected: bool | None = Field(None, description="validation.verdict == rejected")
    agreement: dict[str, Any] | None = Field(None, description="ensemble vs headline: agree | "
                                             "differ (with why) | pending | n/a")
    drift_status: dict[str, Any] | None = Field(None, description="too_short | forming | "
                                                "monitoring, in words")


class ChangePoint(_Open):
    record_index: int | None = Field(description="first record (store index) after the change")
    interval_records: list[int | None] = Field(description="95 % set of change positions")
    change: float = Field(description="mean after - mean before")
    change_ci95: list[float]


class Alarm(_Open):
    id: int
    parameter: str = Field(description="the quantity: a parameter, or fK_hz / zetaK of mode K")
    kind: Literal["parameter", "modal"] = "parameter"
    state: Literal["raised", "confirmed", "cleared"]
    direction: Literal["decrease", "increase"]
    active: bool
    value: float | None
    reference: float | None = Field(description="baseline centre")
    change_rel: float | None
    change_point: ChangePoint | None = None
    message: str


class Snapshot(_Open):
    """One published estimate: the headline (``parameters``) and the running ensemble, each
    {mean, std, ci95} (ci95 null while provisional)."""

    epoch: int
    time: float
    converged: bool | None = None
    parameters: dict[str, dict[str, Any]]
    ensemble: dict[str, dict[str, Any]] | None = None
    ensemble_state: str | None = None
    modal: dict[str, list[float | None]] | None = None


class DriftReport(_Open):
    """The detector's rule and baseline (``reference``), every alarm with its state history
    (``alarms``), the per-record estimates (``records``), the headline estimate, and the
    history of published estimates (``history``)."""

    system: str
    rule: dict[str, Any] | None
    reference: dict[str, Any] | None
    history: list[Snapshot]
    alarms: list[Alarm]
    active_alarms: list[str]
    records: list[dict[str, Any]] = []
    headline: dict[str, Any] | None = None


class SystemSummary(_Open):
    name: str
    state: str
    epoch: int
    converged: bool
    n_recordings: dict[str, int]
    active_alarms: list[str]


class SystemList(_Open):
    systems: list[SystemSummary]


class Health(_Open):
    status: Literal["ok", "unhealthy"]
    systems: int
    workers_alive: int
    problems: list[str] = Field(default_factory=list,
                                description="why the service is unhealthy (503), one per problem")
    executor: dict[str, Any] | None = Field(
        None, description="where the trainers run: threads, or Ray trainer hosts with their "
                          "process, node, systems and restarts (docs/fleet.md)")


class ErrorDetail(BaseModel):
    detail: str = Field(description="what is wrong, and where")
