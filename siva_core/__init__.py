"""siva_core: structural system identification via validation and adaptation (SIVA).

Public surface (the rest lives under ``_impl``):

- :class:`Structure` - a model from a spec (masses + elements), batched accelerations.
- :class:`Recording` - a validated measured record (CSV / JSON / NPZ / MCAP).
- :class:`Processing` - the configurable processing chain -> :class:`States`.
- :class:`Siva` - the estimator (``fit`` returns self; results in ``result_``).
"""
from ._impl.elements import ElementKind, register_element
from ._impl.processing import Processing, States
from ._impl.recording import Recording, RecordingError
from ._impl.siva import Identification, Siva
from ._impl.structure import SpecError, Structure
from ._impl.training import SivaSettings, SivaTrainer

__all__ = ["Structure", "Recording", "Processing", "States", "ElementKind",
           "register_element", "SpecError", "RecordingError", "Siva", "SivaSettings",
           "SivaTrainer", "Identification"]
