"""The output-error phase's anchor: one linearisation, computed live and again by replay.

Why a module of its own: ``siva identify`` trains SIVA in two phases (equation error to
find the basin, then the output error through the processing chain, linearised at an
anchor, with one parametric-bootstrap replicate per epoch: docs/method.md).  The service
runs the same two phases; the anchor is computed off the trainer thread (the refiner)
and applied between two epochs.  ``siva replay`` must rebuild the very same linearisation,
so both call :func:`linearize_anchor` with what the event log holds (theta, record ids,
chain, replicate count and seed): the computation is deterministic, so the replay is exact.
"""
from __future__ import annotations

import dataclasses
from typing import Any, Mapping, Sequence

import numpy as np

from siva_core import Processing, Recording, Structure

from .types import Anchor, DataSet


def linearize_anchor(structure: Structure, theta: np.ndarray, train: Sequence[Recording],
                     validation: Sequence[Recording], processing: Processing, *,
                     n_noise: int, seed: int) -> tuple[Any, Any]:
    """(training, validation) linearisations at ``theta``, exactly as ``Siva.fit`` makes
    them for its output-error phase (the validation one feeds the discriminator)."""
    from siva_core import linearize

    theta = np.asarray(theta, dtype=float)
    lin_tr = linearize(structure, theta, list(train), processing, n_noise=n_noise, seed=seed)
    lin_va = linearize(structure, theta, list(validation), processing) if validation else None
    return lin_tr, lin_va


def build_anchor(structure: Structure, theta: np.ndarray, data: DataSet,
                 train: Sequence[Recording], validation: Sequence[Recording], *,
                 source: str, n_noise: int, seed: int) -> Anchor:
    proc = data.processing if data.processing is not None else Processing()
    lin_tr, lin_va = linearize_anchor(structure, theta, train, validation, proc,
                                      n_noise=n_noise, seed=seed)
    return Anchor(np.asarray(theta, dtype=float).copy(), data, source, n_noise, seed,
                  lin_tr, lin_va)


def apply_anchor(trainer: Any, anchor: Anchor, *, resume: bool = False) -> None:
    """Switch ``trainer`` to (or, after a data change, re-anchor) the output-error phase;
    its networks are kept (a warm start), its monitor and ensemble restart."""
    trainer.use_output_error(anchor.linearization, anchor.val_linearization, resume=resume)


def anchor_record(anchor: Anchor) -> dict[str, Any]:
    """What the event log and the checkpoint keep of an anchor (JSON: floats round-trip)."""
    return {"theta": [float(x) for x in anchor.theta], "train": list(anchor.data.train),
            "validation": list(anchor.data.validation),
            "processing": processing_fields(anchor.data.processing),
            "source": anchor.source, "n_noise": anchor.n_noise, "seed": anchor.seed,
            "data_version": anchor.data.version}


def processing_fields(proc: Processing | None) -> dict[str, Any] | None:
    """The chain's settings as JSON (tuples as lists)."""
    if proc is None:
        return None
    return {f.name: _lists(getattr(proc, f.name)) for f in dataclasses.fields(proc) if f.compare}


def processing_from(fields: Mapping[str, Any] | None) -> Processing:
    """The chain back from :func:`processing_fields` (lists back to tuples)."""
    if fields is None:
        return Processing()
    names = {f.name for f in dataclasses.fields(Processing) if f.compare}
    return Processing(**{k: _tuples(v) for k, v in fields.items() if k in names})


def _lists(v: Any) -> Any:
    if isinstance(v, tuple):
        return [_lists(x) for x in v]
    if isinstance(v, np.ndarray):
        return v.tolist()
    return v


def _tuples(v: Any) -> Any:
    return tuple(_tuples(x) for x in v) if isinstance(v, list) else v
