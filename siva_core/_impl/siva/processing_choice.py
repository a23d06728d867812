"""Which processing chain a run uses: 'auto' (chosen from the data), 'none', 'paper', a
dict of settings (JSON text too) or a ``Processing``."""
from __future__ import annotations

import json
from typing import Sequence

from ..processing import Processing
from ..recording import Recording


def choose_processing(processing: str | dict | Processing | None, recordings: Sequence[Recording],
                      dofs: Sequence[str]) -> Processing:
    """'auto' (chosen from the data), 'none', 'paper', a dict of settings, or an instance."""
    if isinstance(processing, Processing):
        return processing
    if processing is None or processing == "none":
        return Processing()
    if processing == "paper":
        return Processing.paper()
    if processing == "auto":
        return Processing.auto(recordings, dofs)
    if isinstance(processing, str):
        processing = json.loads(processing)
    if isinstance(processing, dict):
        kw = dict(processing)
        if "bandpass" in kw and kw["bandpass"] is not None:
            kw["bandpass"] = tuple(kw["bandpass"])
        return Processing(**kw)
    raise ValueError(f"processing: cannot use {processing!r}")
