"""A recording as MCAP: kept for existing imports; the format lives in ``formats.mcap``."""
from __future__ import annotations

from typing import Sequence

from .formats.mcap import JSON_SCHEMA, MCAP_MAGIC, TOPIC, mcap_bytes
from .formats.mcap import write_mcap as write_mcap_recording
from .recording import Recording


def read_mcap_recording(raw: bytes, dofs: Sequence[str] | None = None,
                        name: str = "upload") -> Recording:
    """Read the ``/recording`` channel of an MCAP file into a validated Recording."""
    return Recording.read(bytes(raw), dofs, name=name, fmt="mcap")


__all__ = ["TOPIC", "JSON_SCHEMA", "MCAP_MAGIC", "write_mcap_recording", "read_mcap_recording",
           "mcap_bytes"]
