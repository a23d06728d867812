"""siva service: streaming SIVA identification over HTTP (``siva serve``).

``create_app(settings)`` builds the FastAPI app; docs/service.md describes the store,
worker and drift policies.  Imports are lazy so ``import service`` stays cheap.
"""
from __future__ import annotations

from typing import Any

__all__ = ["create_app", "Settings"]


def __getattr__(name: str) -> Any:
    if name == "create_app":
        from .api.app import create_app

        return create_app
    if name == "Settings":
        from .settings import Settings

        return Settings
    raise AttributeError(name)
