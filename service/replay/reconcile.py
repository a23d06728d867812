"""Start-up reconciliation: a system's event log is made to agree with the store.

Why: the store is the truth (a recording exists iff its meta file does) and the event log
is its audit trail and the input of ``siva replay``.  Damage to the log - its last chunks
lost, the newest file truncated or deleted, the log folder deleted, a data dir from before
the log existed - must not leave a system whose log no longer replays.  So before a
system's trainer starts, :func:`reconcile` compares the two and repairs the log in the
segment this process has just opened (its spec is already there):

- every stored recording the log lacks is logged, from the stored bytes, as at upload;
- when the checkpoint the trainer will resume from is no longer explained by the log
  (:func:`service.replay.run.explains`: the data set logged last before its epoch is not the
  one it trained on, a data-set event it counted is gone, the earlier logs are missing),
  its trainer state is logged as the *baseline* of a ``/siva/repair`` event: a replay of
  the folder starts there, so what the service does from now on replays bit for bit, and
  the lost history is stated, not silently approximated;
- the repair itself is the ``/siva/repair`` event (reasons, recordings added) and a
  warning in the service log.

A log that already agrees gets no event at all.
"""
from __future__ import annotations

import io
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from ..storage.checkpoints import matches
from ..storage.eventlog import TOPIC_DATASET, TOPIC_RECORDING, EventLog, read_events
from ..storage.store import Store
from .run import explains

log = logging.getLogger("siva.service.reconcile")


@dataclass
class Repair:
    """What :func:`reconcile` did for one system (empty: the log agreed)."""

    system: str
    reasons: list[str] = field(default_factory=list)
    recordings: list[str] = field(default_factory=list)
    baseline_epoch: int | None = None

    def __bool__(self) -> bool:
        return bool(self.reasons)


def _logged(files: list[Path]) -> tuple[dict[str, str], dict[str, int]]:
    """Recording ids -> sha256, and data-set events per file name, over a folder's logs."""
    recs: dict[str, str] = {}
    datasets: dict[str, int] = {}
    for f in files:
        try:
            events = read_events(f)
        except Exception as exc:  # noqa: BLE001 - an unreadable file explains nothing
            log.warning("%s: unreadable (%s); treated as lost", f, exc)
            continue
        datasets[f.name] = sum(1 for e in events if e.topic == TOPIC_DATASET)
        for e in events:
            if e.topic == TOPIC_RECORDING:
                recs.setdefault(e.event.id, e.event.sha256)
    return recs, datasets


def _checkpoint_problem(ckpt: Mapping[str, Any], files: list[Path],
                        datasets: Mapping[str, int], stored: set[str]) -> str | None:
    """Why the logs cannot reproduce ``ckpt`` (None: they can)."""
    epoch = int(ckpt["trainer"].get("epoch", 0))
    if epoch == 0:
        return None
    pos = ckpt.get("log")
    if isinstance(pos, Mapping) and pos.get("file"):
        have = datasets.get(str(pos["file"]))
        if have is None:
            return (f"the log file {pos['file']} that the checkpoint (epoch {epoch}) was "
                    "written beside is gone")
        if have < int(pos.get("datasets", 0)):
            return (f"{pos['file']} lost data-set events the checkpoint (epoch {epoch}) "
                    f"counted ({have} of {pos['datasets']})")
    data = ckpt.get("data") or {}
    return explains(files, epoch, data.get("train", []), data.get("validation", []),
                    available=stored)


def reconcile(events: EventLog, store: Store, name: str) -> Repair:
    """Make the log of ``name`` agree with the store before its trainer starts (the
    caller has logged the spec, so this process's segment is open)."""
    import torch

    rep = Repair(name)
    folder = events.folder(name)
    files = sorted(folder.glob("*.mcap")) if folder.is_dir() else []
    logged, datasets = _logged(files)
    missing = [m for m in store.recordings(name) if m.id not in logged]
    if missing:
        rep.reasons.append(f"{len(missing)} stored recording(s) missing from the log")
    wrong = [m.id for m in store.recordings(name) if m.id in logged and logged[m.id] != m.sha256]
    if wrong:  # never expected: the log holds other bytes under a stored id
        rep.reasons.append(f"recording(s) {wrong} logged with other bytes than stored")
    baseline = None
    ckpt = store.load_checkpoint(name)
    if ckpt is not None and matches(ckpt, store.spec(name)) and "trainer" in ckpt:
        ids = {m.id for m in store.recordings(name)}
        # the recordings logged below count as present: the replay parses the same bytes
        problem = _checkpoint_problem(ckpt, files, datasets, ids)
        if problem is not None:
            data = ckpt.get("data") or {}
            buf = io.BytesIO()
            torch.save(ckpt["trainer"], buf)
            baseline = {"epoch": int(ckpt["trainer"]["epoch"]), "state": buf.getvalue(),
                        "train": [i for i in data.get("train", []) if i in ids],
                        "validation": [i for i in data.get("validation", []) if i in ids]}
            rep.reasons.append(f"the log cannot reproduce the checkpoint: {problem}")
            rep.baseline_epoch = baseline["epoch"]
    if not rep:
        return rep
    for m in missing:
        events.log_recording(name, m.id, m.role, store.read_raw(name, m), m.fmt,
                             epoch=rep.baseline_epoch or 0, name=m.filename)
        rep.recordings.append(m.id)
    events.log_repair(name, rep.reasons, rep.recordings, baseline)
    log.warning("event log of %r repaired at start-up: %s%s", name, "; ".join(rep.reasons),
                f" (replay starts from the checkpoint of epoch {rep.baseline_epoch})"
                if baseline is not None else "")
    return rep
