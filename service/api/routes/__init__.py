"""The HTTP routes, one module per resource (prefix /v1, CONTRACT.md)."""
from __future__ import annotations

from .diagnosis import router as diagnosis
from .estimate import router as estimate
from .export import router as export
from .recordings import router as recordings
from .systems import router as systems

ROUTERS = (systems, recordings, estimate, diagnosis, export)
