"""Service settings, read from the environment (``SIVA_*``) with explicit overrides.

A plain frozen dataclass rather than pydantic-settings: one less dependency, and every
value is validated here so a typo in an environment variable stops ``siva serve`` with a
message naming the variable instead of surfacing later inside a worker thread.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any, Mapping

# Environment variable -> field name.  Documented in docs/service.md.
ENV_VARS: dict[str, str] = {
    "SIVA_DATA_DIR": "data_dir",
    "SIVA_MAX_UPLOAD_BYTES": "max_upload_bytes",
    "SIVA_API_TOKEN": "api_token",
    "SIVA_SEED": "seed",
    "SIVA_PRESET": "preset",
    "SIVA_REPLAY_WINDOW": "replay_window",
    "SIVA_REPLAY_RESERVOIR": "replay_reservoir",
    "SIVA_VALIDATION_WINDOW": "validation_window",
    "SIVA_AUTO_VALIDATION_EVERY": "auto_validation_every",
    "SIVA_SNAPSHOT_EVERY": "snapshot_every",
    "SIVA_SNAPSHOT_MAX_INTERVAL_S": "snapshot_max_interval_s",
    "SIVA_CHECKPOINT_EVERY_S": "checkpoint_every_s",
    "SIVA_IDLE_SLEEP_S": "idle_sleep_s",
    "SIVA_EPOCH_PAUSE_S": "epoch_pause_s",
    "SIVA_MONITOR_YIELD_S": "monitor_yield_s",
    "SIVA_MONITOR_FITS": "monitor_fits",
    "SIVA_HISTORY_LIMIT": "history_limit",
    "SIVA_DRIFT_CONSECUTIVE": "drift_consecutive",
    "SIVA_DRIFT_REL_TOL": "drift_rel_tol",
    "SIVA_DRIFT_REFERENCE_AFTER": "drift_reference_after",
    "SIVA_DRIFT_BASELINE_RECORDS": "drift_baseline_records",
    "SIVA_DRIFT_ARL0_RECORDS": "drift_arl0_records",
    "SIVA_DRIFT_MIN_REL_SCATTER": "drift_min_rel_scatter",
    "SIVA_HEADLINE_WINDOW": "headline_window",
    "SIVA_RECORD_MAX_NFEV": "record_max_nfev",
    "SIVA_IDLE_AFTER_EPOCHS": "idle_after_epochs",
    "SIVA_TORCH_THREADS": "torch_threads",
    "SIVA_REFINE_EVERY_S": "refine_every_s",
    "SIVA_REFINE_MAX_RECORDS": "refine_max_records",
    "SIVA_REFINE_CANDIDATES": "refine_candidates",
    "SIVA_API_TOKEN_READS": "token_for_reads",
    "SIVA_MAX_SPEC_BYTES": "max_spec_bytes",
    "SIVA_MAX_SPEC_DEPTH": "max_spec_depth",
    "SIVA_MAX_DOFS": "max_dofs",
    "SIVA_MAX_ELEMENTS": "max_elements",
    "SIVA_MAX_PARAMETERS": "max_parameters",
    "SIVA_MIN_SAMPLING_RATE_HZ": "min_sampling_rate_hz",
    "SIVA_MAX_SAMPLING_RATE_HZ": "max_sampling_rate_hz",
    "SIVA_STOP_TIMEOUT_S": "stop_timeout_s",
    "SIVA_STUCK_AFTER_S": "stuck_after_s",
    "SIVA_EXECUTOR": "executor",
    "SIVA_RAY_ADDRESS": "ray_address",
    "SIVA_RAY_NAMESPACE": "ray_namespace",
    "SIVA_RAY_SYSTEMS_PER_ACTOR": "ray_systems_per_actor",
    "SIVA_RAY_CPUS_PER_ACTOR": "ray_cpus_per_actor",
    "SIVA_RAY_POLL_S": "ray_poll_s",
    "SIVA_RAY_KEEP_ACTORS": "ray_keep_actors",
    "SIVA_RAY_START_DELAY_S": "ray_start_delay_s",
    "SIVA_ALLOWED_HOSTS": "allowed_hosts",
    "SIVA_ALLOWED_ORIGINS": "allowed_origins",
    "SIVA_MAX_CONCURRENT_UPLOADS": "max_concurrent_uploads",
    "SIVA_UPLOAD_QUEUE_S": "upload_queue_s",
    "SIVA_UPLOAD_BYTES_IN_FLIGHT": "upload_bytes_in_flight",
}


@dataclass(frozen=True)
class Settings:
    """Everything the service needs to know; see docs/service.md for the policies."""

    data_dir: Path = field(default_factory=lambda: Path("./siva-data"))
    max_upload_bytes: int = 64 * 1024 * 1024
    api_token: str | None = None
    seed: int = 42
    preset: str = "fast"                # SivaSettings.<preset>(seed=...)
    # Replay buffer (in memory; everything stays on disk).
    replay_window: int = 8              # most recent train records kept
    replay_reservoir: int = 4           # + a reservoir sample of older train records
    validation_window: int = 8          # most recent validation records kept
    auto_validation_every: int = 4      # role omitted: every k-th arrival -> validation
    # Worker cadence.
    snapshot_every: int = 5             # epochs between published snapshots
    snapshot_max_interval_s: float = 10.0  # ... or sooner: at most this long between them
    checkpoint_every_s: float = 30.0    # seconds between durable trainer checkpoints
    idle_sleep_s: float = 0.5           # wait when there is nothing to train on
    epoch_pause_s: float = 0.0          # pause between epochs once converged (CPU sharing)
    monitor_yield_s: float = 15.0       # trainers wait this long at most per epoch while a
                                        # per-record fit (any system's) runs; 0: never
    monitor_fits: int = 2               # per-record fits of different systems at once
    # Drift detection (service/detector.py: CUSUM on per-record estimates).
    history_limit: int = 2000           # snapshots / per-record estimates kept
    drift_baseline_records: int = 10    # first records forming the reference
    drift_arl0_records: float = 20000.0 # nominal in-control ARL: 1000/this false alarms per 1000
    drift_min_rel_scatter: float = 0.005  # changes well below this fraction are not alarmed
    drift_consecutive: int = 5          # unused since the CUSUM rule (accepted for old configs)
    drift_rel_tol: float = 0.05         # unused since the CUSUM rule
    drift_reference_after: int = 10     # unused since the CUSUM rule
    # Headline estimate and idling.
    headline_window: int = 8            # per-record fits averaged into the headline
    record_max_nfev: int = 20           # cost evaluations of one per-record fit
    idle_after_epochs: int = 200        # converged + data unchanged this long: pause; 0: never
    torch_threads: int = 0              # 0: torch's default
    # Output-error refinement (``best``), in a background thread per system.
    refine_every_s: float = 60.0        # first best: at most one job per this; 0: no best
    refine_max_records: int = 3         # most recent train records it fits
    refine_candidates: int = 150        # last ensemble samples tried by Approach III
    # Access and input limits (docs/reliability.md).
    token_for_reads: bool = False       # SIVA_API_TOKEN_READS=1: reads need the token too
    max_spec_bytes: int = 64 * 1024     # body of PUT /v1/systems/{name}
    max_spec_depth: int = 8             # nesting of objects/arrays in a spec
    max_dofs: int = 16
    max_elements: int = 64
    max_parameters: int = 32            # free parameters (each costs training time)
    min_sampling_rate_hz: float = 1.0   # recordings outside this range are refused (422)
    max_sampling_rate_hz: float = 1.0e6
    max_concurrent_uploads: int = 16    # recordings read and parsed at once; others wait
    upload_bytes_in_flight: int = 128 * 1024 * 1024  # ... declaring at most this together
    upload_queue_s: float = 30.0        # ... at most this long, then 503 with Retry-After
    # Browser safety (service/security.py, docs/reliability.md).
    allowed_hosts: str = ""             # comma list of Host names; "": loopback + bound host
    allowed_origins: str = ""           # comma list of extra origins allowed to write
    bind_host: str = "127.0.0.1"        # the address `siva serve --host` binds (not an env var)
    # Supervision.
    stop_timeout_s: float = 10.0        # DELETE / SIGTERM wait at most this for a trainer
    stuck_after_s: float = 600.0        # /healthz: a trainer without progress this long is stuck
    # Where trainers run (docs/fleet.md): "threads" in this process, or "ray" actors.
    executor: str = "threads"
    ray_address: str | None = None      # None: a running cluster ("auto") else a local one
    ray_namespace: str = "siva"
    ray_systems_per_actor: int = 8      # systems per trainer actor (bounds processes/memory)
    ray_cpus_per_actor: float = 1.0     # logical CPUs an actor asks for; torch threads follow
    ray_poll_s: float = 0.5             # how often the front fetches snapshots and events
    ray_keep_actors: bool = False       # leave the trainer actors running after a clean stop
    ray_start_delay_s: float = 0.0      # tests only: a trainer host's construction waits this
                                        # long first (a cold actor on a loaded cluster)

    def __post_init__(self) -> None:
        object.__setattr__(self, "data_dir", Path(self.data_dir))
        if self.api_token == "":
            object.__setattr__(self, "api_token", None)
        positive = ("max_upload_bytes", "replay_window", "validation_window",
                    "auto_validation_every", "snapshot_every", "history_limit",
                    "drift_consecutive", "drift_reference_after", "refine_max_records",
                    "refine_candidates", "drift_baseline_records", "headline_window",
                    "monitor_fits",
                    "record_max_nfev", "drift_arl0_records", "max_spec_bytes", "max_spec_depth",
                    "max_dofs", "max_elements", "max_parameters", "ray_systems_per_actor",
                    "max_concurrent_uploads", "upload_bytes_in_flight")
        for name in positive:
            if getattr(self, name) < 1:
                raise ValueError(f"setting {name} must be >= 1, got {getattr(self, name)}")
        for name in ("replay_reservoir", "checkpoint_every_s", "snapshot_max_interval_s", "idle_sleep_s", "epoch_pause_s",
                     "monitor_yield_s",
                     "drift_rel_tol", "torch_threads", "refine_every_s", "idle_after_epochs",
                     "drift_min_rel_scatter", "stop_timeout_s", "stuck_after_s",
                     "upload_queue_s", "ray_start_delay_s"):
            if getattr(self, name) < 0:
                raise ValueError(f"setting {name} must be >= 0, got {getattr(self, name)}")
        if self.executor not in ("threads", "ray"):
            raise ValueError(f"setting executor must be 'threads' or 'ray', got {self.executor!r}")
        if not (self.ray_cpus_per_actor > 0 and self.ray_poll_s > 0):
            raise ValueError("settings ray_cpus_per_actor and ray_poll_s must be > 0")
        if self.ray_address == "":
            object.__setattr__(self, "ray_address", None)
        if not 0 < self.min_sampling_rate_hz < self.max_sampling_rate_hz:
            raise ValueError("settings min_sampling_rate_hz < max_sampling_rate_hz, both > 0")
        if self.auto_validation_every < 2:
            raise ValueError("setting auto_validation_every must be >= 2 "
                             "(otherwise every record would go to validation)")

    @classmethod
    def from_env(cls, env: Mapping[str, str] | None = None, **overrides: Any) -> "Settings":
        """Defaults, then ``SIVA_*`` variables, then ``overrides`` (e.g. CLI flags)."""
        env = os.environ if env is None else env
        types = {f.name: f.type for f in fields(cls)}
        values: dict[str, Any] = {}
        for var, name in ENV_VARS.items():
            raw = env.get(var)
            if raw is None or (raw.strip() == "" and name != "api_token"):
                continue
            values[name] = _convert(raw.strip(), types[name], var)
        values.update({k: v for k, v in overrides.items() if v is not None})
        return cls(**values)

    def with_(self, **kw: Any) -> "Settings":
        return replace(self, **kw)


def _convert(raw: str, typ: Any, var: str) -> Any:
    typ = str(typ)
    try:
        if typ == "int":
            try:
                return int(raw)
            except ValueError:
                x = float(raw)  # accept "64e6"
                if not x.is_integer():
                    raise
                return int(x)
        if typ == "bool":
            if raw.lower() in ("1", "true", "yes", "on"):
                return True
            if raw.lower() in ("0", "false", "no", "off"):
                return False
            raise ValueError(raw)
        if typ == "float":
            return float(raw)
        if typ == "Path":
            return Path(raw)
    except ValueError:
        raise ValueError(f"environment variable {var}={raw!r} is not a valid {typ}") from None
    return raw
