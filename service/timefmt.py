"""ISO 8601 UTC timestamps for payloads: a person (and Grafana) reads them, a float alone
is opaque.  Payloads keep the float too (machines compare and subtract it)."""
from __future__ import annotations

from datetime import datetime, timezone


def iso_utc(t: float | None) -> str | None:
    """``1763892000.5`` -> ``"2025-11-23T10:00:00.500Z"`` (milliseconds, UTC); None stays None."""
    if t is None:
        return None
    return datetime.fromtimestamp(float(t), tz=timezone.utc).isoformat(timespec="milliseconds"
                                                                        ).replace("+00:00", "Z")


__all__ = ["iso_utc"]
