"""The per-system trainer: ``siva identify``'s two-phase SIVA, run as records stream.

Parts (one concern each, frozen values between them: ``types.py``):

- ``worker.py``     SystemWorker: its state, control calls and the trainer thread's loop
- ``phases.py``     its phase steps: the first ``best`` job, anchors, validation jobs
- ``lifecycle.py``  its set-up from a checkpoint, checkpoints, idling
- ``publishing.py`` its snapshots, drift report and per-record monitoring step
- ``data.py``       DataFeed: replay buffer, parsed records, processing chain -> DataSet
- ``refiner.py``    Refiner: the second thread (first ``best``, anchors, monitoring,
                    validation)
- ``anchoring.py``  the output-error linearisation at an anchor (shared with replay)
- ``readout.py``    the ensemble read-out, provisional until final (shared with replay)
- ``validation.py`` the held-out test (T, p-value, verdict) for headline and ensemble
- ``published.py``  Snapshot: the frozen value a trainer publishes (JSON at the edge)
- ``snapshot.py``   building the snapshot, agreement of ensemble and headline
- ``factory.py``    making and stopping trainers
- ``estimate.py``   reading an estimate out, the headline keys (shared with replay)
- ``replay_buffer.py`` which records are held in memory (window + reservoir)
"""
from __future__ import annotations

from .factory import base_snapshot, default_trainer, stop_workers
from .published import DriftReport, Snapshot
from .readout import ENSEMBLE_MIN_SAMPLES, REFINE_MIN_SAMPLES
from .worker import SystemWorker

__all__ = ["SystemWorker", "Snapshot", "DriftReport", "default_trainer", "base_snapshot", "stop_workers",
           "REFINE_MIN_SAMPLES", "ENSEMBLE_MIN_SAMPLES"]
