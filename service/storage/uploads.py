"""Upload validation: a recording is parsed and processed exactly as the worker will use it.

Why at upload time: anything the worker could not use is refused with a 4xx naming the
file and the problem, instead of being stored and failing later inside a thread.
"""
from __future__ import annotations

import csv
from typing import Sequence

import numpy as np

from siva_core import (Processing, Recording, RecordingError, Structure, check_rates,
                        check_recording, PreflightError)

from .recordings import UploadFacts


def processing_for(recordings: Sequence[Recording], dofs: Sequence[str]) -> Processing:
    """The processing chain for these records: ``Processing.auto`` (none without records)."""
    if not recordings:
        return Processing()
    return Processing.auto(list(recordings), list(dofs))


def parse_upload(structure: Structure, raw: bytes, fmt: str, name: str, *,
                 channel_map: dict[str, str] | None = None,
                 units: dict[str, str] | None = None,
                 existing_rates: dict[str, float] | None = None,
                 theta: np.ndarray | None = None) -> UploadFacts:
    """Validate an upload exactly as the worker will use it; returns facts for the meta.

    Raises RecordingError (a 4xx) for anything unusable, including a record the processing
    chain cannot handle (e.g. too short for its filters), so nothing unusable is stored.
    ``channel_map``/``units``: the upload's own mapping (over the spec's ``[channels]``);
    ``existing_rates``: {file: fs} of the system's stored records (one system, one rate);
    ``theta``: the current estimate, whose modes the sampling rate must resolve.
    The checks before training are siva_core's (:func:`siva_core.check_recording`).
    """
    import warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            rec = Recording.read(raw, structure.dofs, name=name, fmt=fmt,
                                 **structure.read_options(channel_map, units))
        except RecordingError:
            raise
        except ImportError as exc:
            raise RecordingError(f"{name}: format {fmt!r} is not supported here ({exc})") from None
        except (ValueError, TypeError, KeyError, IndexError, OverflowError, RecursionError,
                csv.Error) as exc:
            # garbage the reader did not anticipate is still the upload's fault, not a 5xx
            raise RecordingError(f"{name}: unreadable {fmt} ({type(exc).__name__}: "
                                 f"{str(exc)[:200]})") from None
    problems = check_rates([rec], existing_rates, what="this system")
    problems += check_recording(structure, rec, theta=theta)
    fatal = [p for p in problems if p.fatal]
    if fatal:
        raise PreflightError(fatal)
    try:
        proc = processing_for([rec], structure.dofs)
        st = proc.apply(rec, structure.dofs)
    except (ValueError, FloatingPointError, np.linalg.LinAlgError) as exc:
        raise RecordingError(f"{name}: cannot be processed ({exc})") from None
    if len(st) < 2 or not all(np.isfinite(x).all() for x in (st.q, st.v, st.a, st.f)):
        raise RecordingError(f"{name}: processing leaves no usable (finite) samples")
    return UploadFacts(n_samples=len(rec), fs=float(rec.fs),
                       duration_s=float(rec.time[-1] - rec.time[0]),
                       columns=("time", *rec.channels),
                       warnings=tuple([str(w.message) for w in caught]
                                      + [p.message for p in problems]),
                       channel_map=dict(channel_map) if channel_map else None,
                       units=dict(units) if units else None)
