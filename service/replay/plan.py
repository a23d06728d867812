"""What a replay will do, read from one system's logs: the segments (one log per process
start), the data set in use at each epoch and where to stop.  ``run.py`` executes the
plan."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Sequence

from ..storage.eventlog import (PLATFORM_METADATA, TOPIC_ANCHOR, TOPIC_DATASET, TOPIC_RECORDING,
                                 TOPIC_REPAIR, TOPIC_SNAPSHOT, TOPIC_SPEC, AnchorEvent, LogEvent,
                                 RecordingEvent, RepairEvent, SnapshotEvent, SpecEvent, read_events,
                                 read_metadata)


class ReplayError(ValueError):
    """A log that cannot be replayed; the message says what is missing and where."""


@dataclass
class LogSegment:
    """The events of one log file (one process start)."""

    path: Path
    events: list[LogEvent]

    def of(self, topic: str) -> list[Any]:
        return [e.event for e in self.events if e.topic == topic]


@dataclass
class PlannedDataSet:
    """Before epoch ``epoch + 1`` the trainer got these records, prepared with ``processing``
    (Processing fields; None: choose it as the worker does)."""

    epoch: int
    train: list[str]
    validation: list[str]
    processing: dict[str, Any] | None = None
    anchor: AnchorEvent | None = None  # not a data set: the output-error phase's anchor


@dataclass
class ReplayPlan:
    spec: SpecEvent
    recordings: dict[str, RecordingEvent]
    # data-set changes in the order applied, after resume stitching
    datasets: list["PlannedDataSet"]
    restarts: list[int]                      # indices into datasets where training restarts
    final_epoch: int
    final_snapshot: SnapshotEvent | None
    counts: dict[str, int]
    files: list[str] = field(default_factory=list)
    exact: bool = True
    platforms: list[dict[str, str] | None] = field(default_factory=list)  # per file
    # restart index -> the repair whose baseline trainer state that block starts from
    baselines: dict[int, RepairEvent] = field(default_factory=dict)


def log_files(path: str | Path | Sequence[str | Path]) -> list[Path]:
    """The log files to replay: a file, several files, or a directory of one system."""
    if isinstance(path, (str, Path)):
        p = Path(path)
        if p.is_dir():
            files = sorted(q for q in p.glob("*.mcap"))
            if not files:
                raise ReplayError(f"{p}: no .mcap logs in this folder")
            return files
        if not p.exists():
            raise ReplayError(f"{p}: no such log file")
        return [p]
    files = [Path(x) for x in path]
    for f in files:
        if not f.exists():
            raise ReplayError(f"{f}: no such log file")
    return sorted(files, key=lambda f: f.name)


def plan_replay(files: Sequence[Path]) -> ReplayPlan:
    segments = [LogSegment(f, read_events(f)) for f in files]
    platforms = [read_metadata(f).get(PLATFORM_METADATA) for f in files]
    spec: SpecEvent | None = None
    recordings: dict[str, RecordingEvent] = {}
    systems: set[str] = set()
    # a repair's baseline supersedes every earlier file (their training history is what
    # the repair found lost); they still lend their recordings, the same bytes by id
    first = max((k for k, seg in enumerate(segments)
                 if any(r.baseline_state is not None for r in seg.of(TOPIC_REPAIR))), default=0)
    for seg in segments[:first]:
        systems.update(e.event.system for e in seg.events)
        for ev in seg.of(TOPIC_RECORDING):
            recordings.setdefault(ev.id, ev)
    segments = segments[first:]
    platforms = platforms[first:]
    for seg in segments:
        systems.update(e.event.system for e in seg.events)
        for ev in seg.of(TOPIC_SPEC):
            if spec is not None and ev.spec != spec.spec:
                raise ReplayError(f"{seg.path}: the spec of {ev.system!r} changed between logs "
                                  "(a re-created system): replay its logs since then only")
            spec = ev
        for ev in seg.of(TOPIC_RECORDING):
            recordings.setdefault(ev.id, ev)
    if len(systems) > 1:
        raise ReplayError(f"logs of several systems {sorted(systems)}: replay one at a time")
    if spec is None:
        raise ReplayError(f"{', '.join(str(f) for f in files)}: no /siva/spec event "
                          "(pass the system's earlier logs too, or its log folder)")

    datasets: list[PlannedDataSet] = []
    restarts: list[int] = [0]
    final_snap: SnapshotEvent | None = None
    exact = any(seg.of(TOPIC_DATASET) for seg in segments)
    if not exact:  # not written by the service's worker: arrival epochs, all records
        datasets = arrival_datasets(
            [r for seg in segments for r in seg.of(TOPIC_RECORDING)])
        snaps = [s for seg in segments for s in seg.of(TOPIC_SNAPSHOT)]
        final_snap = snaps[-1] if snaps else None
    baselines: dict[int, RepairEvent] = {}
    for seg in segments if exact else []:
        seg_sets = segment_datasets(seg, final=seg is segments[-1])
        snaps = seg.of(TOPIC_SNAPSHOT)
        base = next((r for r in seg.of(TOPIC_REPAIR) if r.baseline_state is not None), None)
        if base is not None:
            # start-up repaired a log that could not explain the checkpoint: training
            # resumed from this logged state, so the replay does too (and what came before
            # is superseded)
            seg_sets = [d for d in seg_sets if d.epoch >= (base.baseline_epoch or 0)]
            if datasets:
                restarts.append(len(datasets))
            baselines[restarts[-1]] = base
            datasets.extend(seg_sets)
            final_snap = None
            if snaps:
                final_snap = snaps[-1]
            continue
        if seg_sets:
            start = seg_sets[0].epoch
            if not datasets and start > 0 and not baselines:
                raise ReplayError(f"{seg.path}: the service resumed from a checkpoint at epoch "
                                  f"{start}; pass the earlier logs of this system too "
                                  "(e.g. its log folder)")
            if start == 0 and datasets:
                restarts.append(len(datasets))  # that process started from scratch
            else:
                # resumed at `start` from a checkpoint: what the earlier process did from
                # `start` on is superseded (its checkpoint was taken before those changes)
                while len(datasets) > restarts[-1] and datasets[-1].epoch >= start:
                    datasets.pop()
            datasets.extend(seg_sets)
            final_snap = None  # a snapshot of an earlier process describes a superseded run
        if snaps:
            final_snap = snaps[-1]
    if final_snap is not None:
        final_epoch = final_snap.epoch
    else:
        final_epoch = max((d.epoch for d in datasets[restarts[-1]:]), default=0)
    counts: dict[str, int] = {"train": 0, "validation": 0}
    for r in recordings.values():
        counts[r.role] = counts.get(r.role, 0) + 1
    if final_snap is not None:
        counts = {k: int(v) for k, v in final_snap.estimate.n_recordings.items()}
    return ReplayPlan(spec, recordings, datasets, restarts, final_epoch, final_snap, counts,
                 [str(f) for f in files], exact, platforms, baselines)


def segment_datasets(seg: LogSegment, final: bool = False) -> list[PlannedDataSet]:
    """The data-set changes of one log, each with the processing chain it used: logged with
    the event, else the one the next snapshot on the same records reports (``data``).

    The ``final`` log, when it has snapshots, ends for replay at its last one: data-set
    changes logged after it (a process killed before publishing again) describe training
    nobody saw, and replaying them would run past the published estimate.  (In an earlier
    log they stay: a checkpoint taken after them carries their effect into the next log.)"""
    out: list[PlannedDataSet] = []
    last_snap = len(seg.events)
    if final:
        last_snap = max((k for k, le in enumerate(seg.events) if le.topic == TOPIC_SNAPSHOT),
                        default=last_snap)
    for k, le in enumerate(seg.events[:last_snap]):
        if le.topic == TOPIC_ANCHOR:
            a = le.event
            out.append(PlannedDataSet(a.epoch, list(a.train), list(a.validation), a.processing, a))
            continue
        if le.topic != TOPIC_DATASET:
            continue
        d = le.event
        proc = d.processing
        if proc is None:
            for later in seg.events[k + 1:]:
                if later.topic == TOPIC_DATASET:
                    break
                if later.topic == TOPIC_SNAPSHOT:
                    data = later.event.estimate_dict().get("data") or {}
                    if data.get("train") == d.train and data.get("validation") == d.validation:
                        proc = data.get("processing")
                        break
        out.append(PlannedDataSet(d.epoch, list(d.train), list(d.validation), proc))
    return out


def arrival_datasets(recs: Iterable[RecordingEvent]) -> list[PlannedDataSet]:
    """Fallback: every recording joins at its arrival epoch, once both roles exist."""
    out: list[PlannedDataSet] = []
    train: list[str] = []
    val: list[str] = []
    for r in recs:
        (train if r.role == "train" else val).append(r.id)
        if train and val:
            if out and out[-1].epoch == r.epoch:
                out[-1] = PlannedDataSet(r.epoch, list(train), list(val))
            else:
                out.append(PlannedDataSet(r.epoch, list(train), list(val)))
    return out


def json_tuples(v: Any) -> Any:
    """JSON lists back to the tuples the Processing dataclass holds (bandpass, notch)."""
    return tuple(json_tuples(x) for x in v) if isinstance(v, list) else v
