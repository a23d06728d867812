"""siva_core: structural system identification via validation and adaptation (SIVA).

Public surface (the rest lives under ``_impl``):

- :class:`Structure` - a model from a spec (masses + elements), batched accelerations.
- :class:`Recording` - a validated measured record (CSV / JSON / NPZ / MCAP / LVM / UFF58 /
  TDMS / MAT).
- :class:`Processing` - the configurable processing chain -> :class:`States`.
- :class:`Siva` - the estimator (``fit`` returns self; results in ``result_``).

Names are imported on first use (PEP 562), so that ``siva --help`` or reading a recording
does not load torch.
"""
from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

_WHERE = {
    "ElementKind": "elements", "register_element": "elements",
    "Processing": "processing", "States": "processing",
    "Recording": "recording", "RecordingError": "recording",
    "Identification": "siva", "Siva": "siva",
    "SpecError": "structure", "Structure": "structure",
    "SivaSettings": "training", "SivaTrainer": "training",
}

if TYPE_CHECKING:
    from ._impl.elements import ElementKind, register_element
    from ._impl.processing import Processing, States
    from ._impl.recording import Recording, RecordingError
    from ._impl.siva import Identification, Siva
    from ._impl.structure import SpecError, Structure
    from ._impl.training import SivaSettings, SivaTrainer


def __getattr__(name: str) -> Any:
    if name not in _WHERE:
        raise AttributeError(f"module 'siva_core' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"._impl.{_WHERE[name]}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *_WHERE])


__all__ = ["Structure", "Recording", "Processing", "States", "ElementKind",
           "register_element", "SpecError", "RecordingError", "Siva", "SivaSettings",
           "SivaTrainer", "Identification"]
