"""Compatibility: the trainer moved to ``service/trainer/`` (one module per concern)."""
from __future__ import annotations

from .checkpoints import CHECKPOINT_VERSION
from .estimate import estimate_parameters, estimate_view, jsonable
from .trainer import REFINE_MIN_SAMPLES, SystemWorker, base_snapshot, default_trainer, stop_workers
from .uploads import parse_upload, processing_for

__all__ = ["SystemWorker", "default_trainer", "base_snapshot", "stop_workers", "CHECKPOINT_VERSION",
           "REFINE_MIN_SAMPLES", "parse_upload", "processing_for", "estimate_view",
           "estimate_parameters", "jsonable"]
