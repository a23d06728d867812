"""`siva replay LOG.mcap`: re-run what a service event log recorded, offline.

Why: an estimate the service published should be reproducible by anyone holding the log -
to audit it, to re-run it with a fixed bug, or to reproduce a drift alarm.  The service is
deterministic given (spec, trainer preset and seed, the data set used at each epoch), and
the log holds all three, so on the same platform a replay reproduces the live estimate
bit for bit.  On another platform (library builds, CPU kernels: the fingerprint every log
records, service/storage/eventlog/fingerprint.py) float rounding differs and training amplifies it; the replay then says
``reproduced`` when it lands within a stated tolerance of the published spread, else
``differs`` with where (``compared_to_log.verdict``).

How: the spec event rebuilds the Structure; a fresh trainer (the service's own factory,
preset and seed from the log) is trained epoch by epoch; at each ``/siva/dataset`` event
(the epoch at which the live trainer's data set changed and the recording ids it used) the
same recordings are parsed from their logged bytes, processed with the service's own chain
and passed to ``set_data``; training stops at the epoch of the last snapshot, and the
estimate is read out with the service's own code (``trainer/estimate.py``).

Several logs of one system (one per process start) replay as one run: pass them all, or
their directory.  A process that resumed from a checkpoint at epoch E logs its first data
set at E, so the replay runs the earlier log to E and continues with the later one - the
trainer state at E is the one the checkpoint held.  A later log starting at epoch 0 means
the service started over from scratch (no checkpoint): so does the replay.

Logs without dataset events (written by something other than the service's worker) fall
back to what the brief of the log format promises: recordings join at their arrival epoch,
train and validation by role, all of them - an approximation of the service's buffer.
"""
from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path
from typing import Any, Iterable, Sequence

from ..storage.eventlog import AnchorEvent, RepairEvent, SnapshotEvent, SpecEvent
from .plan import PlannedDataSet, ReplayError, ReplayPlan, json_tuples, log_files, plan_replay
from .verdict import REPRODUCED_TOLERANCE_IN_STD, compare_to_log, platform_comparison, summary_line

__all__ = ["REPRODUCED_TOLERANCE_IN_STD", "ReplayError", "explains", "log_files", "replay",
           "summary_line", "write_replay"]


def _service_settings(spec: SpecEvent) -> Any:
    from ..settings import Settings

    s = spec.settings
    kw: dict[str, Any] = {}
    if "seed" in s:
        kw["seed"] = int(s["seed"])
    if "preset" in s:
        kw["preset"] = str(s["preset"])
    return Settings(**kw)


class _Replayer:
    """The service's data path for one system, driven by the plan instead of HTTP."""

    def __init__(self, plan: ReplayPlan, trainer_factory: Any = None) -> None:
        from siva_core import Structure

        from ..trainer import default_trainer

        self.plan = plan
        self.structure = Structure.from_dict(plan.spec.spec)
        self.settings = _service_settings(plan.spec)
        self.factory = trainer_factory or default_trainer
        self._recs: dict[str, Any] = {}

    def recording(self, rid: str) -> Any:
        from siva_core import Recording

        if rid not in self._recs:
            ev = self.plan.recordings.get(rid)
            if ev is None:
                raise ReplayError(f"recording {rid!r} was used for training but is not in the "
                                  "log(s): pass the system's earlier logs too (its log folder)")
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                self._recs[rid] = Recording.read(
                    ev.payload(), self.structure.dofs, name=rid, fmt=ev.format,
                    **self.structure.read_options(ev.channel_map, ev.units))
        return self._recs[rid]

    def states(self, ds: PlannedDataSet) -> tuple[list[Any], list[Any]]:
        """Exactly the worker's refresh: the logged chain (or one chosen, as the worker
        does, on all selected records) applied to each record."""
        from siva_core import Processing

        from ..storage.uploads import processing_for

        train, val = ds.train, ds.validation
        recs = [self.recording(i) for i in train + val]
        if ds.processing is not None:
            fields = {f.name for f in dataclasses.fields(Processing) if f.compare}
            proc = Processing(**{k: json_tuples(v) for k, v in ds.processing.items() if k in fields})
        else:
            try:
                proc = processing_for(recs, self.structure.dofs)
            except Exception:  # noqa: BLE001 - the worker falls back the same way
                proc = Processing()
        st = {r.name: proc.apply(r, self.structure.dofs) for r in recs}
        return [st[i] for i in train], [st[i] for i in val]

    def anchor(self, trainer: Any, ev: AnchorEvent) -> None:
        """The live trainer's output-error anchor, recomputed from the logged records."""
        import numpy as np

        from ..trainer.anchoring import linearize_anchor, processing_from

        if ev.resume and getattr(trainer, "oe", None) is not None:
            return  # restored from a checkpoint: this replay's trainer never lost it
        lin_tr, lin_va = linearize_anchor(
            self.structure, np.asarray(ev.theta, dtype=float),
            [self.recording(i) for i in ev.train], [self.recording(i) for i in ev.validation],
            processing_from(ev.processing), n_noise=ev.n_noise, seed=ev.seed)
        trainer.use_output_error(lin_tr, lin_va, resume=ev.resume)

    def run(self) -> tuple[Any, Any]:
        """Train to the final epoch; returns (trainer, last EpochLog or None)."""
        plan = self.plan
        trainer = None
        last_log = None
        bounds = plan.restarts + [len(plan.datasets)]
        for k in range(len(plan.restarts)):
            block = plan.datasets[bounds[k]:bounds[k + 1]]
            if not block:
                continue
            trainer = self.factory(self.structure, self.settings)
            base = plan.baselines.get(bounds[k])
            if base is not None:
                trainer.load_state_dict(_load_state(base))
            last_log = None
            last_block = k == len(plan.restarts) - 1
            for ds in block:
                if (last_block and plan.final_snapshot is not None and 0 < plan.final_epoch
                        <= ds.epoch):
                    # the live trainer publishes after epoch E and applies what arrived
                    # between epochs E and E + 1 afterwards: the final snapshot predates it
                    break
                while trainer.epoch < ds.epoch:
                    last_log = trainer.run_epoch()
                if ds.anchor is not None:
                    self.anchor(trainer, ds.anchor)
                else:
                    trainer.set_data(*self.states(ds))
        if trainer is not None:
            while trainer.epoch < plan.final_epoch:
                last_log = trainer.run_epoch()
        return trainer, last_log


def _load_state(base: RepairEvent) -> dict[str, Any]:
    """The baseline trainer state of a repair; loaded with torch's restricted unpickler
    (tensors, plain containers and the numpy arrays a trainer state holds - nothing that
    runs code), so a log from elsewhere cannot execute anything."""
    import io

    import numpy as np
    import torch

    raw = base.state_bytes()
    assert raw is not None
    allowed = [np.core.multiarray._reconstruct, np.ndarray, np.dtype,
               type(np.dtype("float64")), type(np.dtype("uint32")), type(np.dtype("int64")),
               type(np.dtype("bool")), type(np.dtype("float32")), type(np.dtype("int32"))]
    with torch.serialization.safe_globals(allowed):
        try:
            return torch.load(io.BytesIO(raw), map_location="cpu", weights_only=True)
        except Exception as exc:  # noqa: BLE001 - say which log holds the bad state
            raise ReplayError(f"repair of {base.system} at epoch {base.baseline_epoch}: its "
                              f"baseline trainer state cannot be loaded ({exc})") from exc


def explains(files: Sequence[Path], epoch: int, train: Sequence[str],
             validation: Sequence[str], available: Iterable[str] = ()) -> str | None:
    """Whether these logs reproduce a trainer resumed at ``epoch`` with this data set:
    None when they do, else why not (used by start-up reconciliation; ``available``:
    recording ids about to be logged, which count as present)."""
    try:
        plan = plan_replay(files)
    except ReplayError as exc:
        return str(exc)
    block = plan.datasets[plan.restarts[-1]:]
    before = [d for d in block if d.epoch <= epoch]
    if not before:
        return f"no data set logged at or before the checkpoint's epoch {epoch}"
    last = before[-1]
    if (last.train, last.validation) != (list(train), list(validation)):
        return (f"the data set logged last before epoch {epoch} (at {last.epoch}) is not the "
                "one the checkpoint trained on")
    have = set(plan.recordings) | set(available)
    missing = [r for d in before for r in d.train + d.validation if r not in have]
    if missing:
        return f"recordings used before epoch {epoch} are not in the log: {sorted(set(missing))}"
    return None


def _counting(factory: Any, progress: Any) -> Any:
    """``factory`` whose trainers report each epoch to ``progress.update(epoch)``."""
    def make(*args: Any) -> Any:
        trainer = factory(*args)
        run_epoch = trainer.run_epoch

        def counted() -> Any:
            log = run_epoch()
            progress.update(trainer.epoch)
            return log

        trainer.run_epoch = counted
        return trainer
    return make


def replay(path: str | Path | Sequence[str | Path], *, trainer_factory: Any = None,
           progress: bool = False,
           tolerance_in_std: float = REPRODUCED_TOLERANCE_IN_STD) -> dict[str, Any]:
    """Re-run the log(s) and return the final estimate in the shape of GET .../estimate.

    Extra key ``replay``: the files, the epochs trained, and how the result compares with
    the last snapshot the live service logged (``compared_to_log``: ``identical`` bits,
    ``max_diff_in_std`` - the largest difference of a parameter mean, in units of that
    parameter's std, 0 when identical - and the ``verdict`` identical / reproduced /
    differs, with the platform comparison that says which one was to be expected).
    """
    from ..trainer.estimate import jsonable
    from ..trainer.published import estimate_body
    from ..trainer.readout import read_ensemble

    files = log_files(path)
    plan = plan_replay(files)
    rp = _Replayer(plan, trainer_factory)
    if progress:  # stderr lines "replay: epoch 120/600 (20 %), ..., ETA 14 s"
        from siva_core import EpochProgress

        rp.factory = _counting(rp.factory, EpochProgress("replay", plan.final_epoch))
    trainer, _last = rp.run()
    if trainer is None:
        raise ReplayError(f"{', '.join(plan.files)}: the log has no training (no data set with "
                          "both a train and a validation recording)")
    ens = read_ensemble(rp.structure, trainer)  # the service's own read-out
    disc = trainer.discriminator_scores() if trainer.epoch > 0 else {}
    snap = {"parameters": ens.to_json(), "estimate_source": ens.source, "discriminator": disc,
            "epoch": int(trainer.epoch), "converged": bool(trainer.converged),
            "system": plan.spec.system, "ensemble": ens.to_json(), "ensemble_source": ens.source,
            "ensemble_state": ens.state, "phase": ens.phase,
            **_logged_monitoring(plan.final_snapshot)}
    out = jsonable(estimate_body(snap, plan.counts))
    out["replay"] = jsonable({
        "files": plan.files, "epochs": int(trainer.epoch),
        "data_changes": len(plan.datasets), "exact": plan.exact,
        "settings": plan.spec.settings,
        "compared_to_log": compare_to_log(out, plan.final_snapshot,
                                          platform_comparison(plan.platforms),
                                          tolerance_in_std),
    })
    return out


def _logged_monitoring(snap: SnapshotEvent | None) -> dict[str, Any]:
    """The headline estimate and alarm history as the live service last logged them.

    Monitoring (``best``, per-record fits, alarms) runs beside the trainer on its own
    schedule, so it is reported from the log, not re-run: ``parameters`` is the logged
    headline when it was ``best``; the replayed ensemble is under ``ensemble``."""
    if snap is None:
        return {}
    est = snap.estimate_dict()
    out = {k: est[k] for k in ("best", "alarms", "alarm_history", "monitoring", "estimate",
                               "validation", "model_rejected", "provisional", "agreement",
                               "drift_status")
           if k in est}
    if est.get("estimate_source") == "best":
        out.update(parameters=est.get("parameters") or {}, estimate_source="best")
    if "drift" in est:
        out["drift"] = est["drift"]
    return out


def write_replay(log: str | Path, out: str | Path | None = None,
                 tolerance_in_std: float = REPRODUCED_TOLERANCE_IN_STD) -> dict[str, Any]:
    """``siva replay LOG [--out FILE]``: JSON to ``out`` or stdout, the verdict on stderr
    (used by service.cli)."""
    import json
    import sys

    result = replay(log, progress=True, tolerance_in_std=tolerance_in_std)
    text = json.dumps(result, indent=2)
    if out:
        Path(out).write_text(text + "\n")
    else:
        sys.stdout.write(text + "\n")
    sys.stderr.write(summary_line(result) + "\n")
    return result
