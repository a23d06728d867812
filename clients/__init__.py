"""Python client of the siva service (HTTP API of CONTRACT.md)."""
from .client import SivaClient, SivaClientError

__all__ = ["SivaClient", "SivaClientError"]
