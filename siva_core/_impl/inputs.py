"""The records of one command-line fit: read with the channel and unit mapping, then checked
before any training (:mod:`.preflight`).  Shared by ``siva identify`` and ``siva diagnose``.
"""
from __future__ import annotations

import time
from typing import Sequence

from .preflight import Preflight, preflight
from .recording import Recording
from .structure import Structure


def parse_pairs(items: Sequence[str] | None, option: str) -> dict[str, str]:
    """``["Accel LO=acc_LO", ...]`` -> ``{"Accel LO": "acc_LO"}``; the split is at the last
    ``=`` (a channel name may hold one, a column name or unit does not)."""
    out: dict[str, str] = {}
    for item in items or ():
        src, sep, dst = str(item).rpartition("=")
        if not sep or not src.strip() or not dst.strip():
            example = "Accel LO=acc_LO" if option.endswith("map") else "acc_LO=g"
            raise ValueError(f"{option} {item!r}: expected NAME=VALUE (e.g. {example!r})")
        out[src.strip()] = dst.strip()
    return out


def read_fit_records(structure: Structure, train_paths: Sequence[str],
                     val_paths: Sequence[str] | None, *, maps: Sequence[str] | None = None,
                     units: Sequence[str] | None = None, resample: bool = False
                     ) -> tuple[Preflight, float]:
    """Read and check the records of one fit; returns what passed and the seconds the
    reading and checks took (refusals are :class:`PreflightError`, a ValueError)."""
    t0 = time.perf_counter()
    opts = structure.read_options(parse_pairs(maps, "--map"), parse_pairs(units, "--unit"))
    train = [Recording.read(p, structure.dofs, **opts) for p in train_paths]
    val = [Recording.read(p, structure.dofs, **opts) for p in (val_paths or ())]
    checked = preflight(structure, train, val, resample=resample)
    return checked, time.perf_counter() - t0
