"""The FastAPI application: ``create_app(settings)`` wires the systems registry
(``service/systems.py``), the routes, the error handling and the middleware.

Error policy (CONTRACT: bad input gets a 4xx with ``{"detail": "<what, where>"}``, never a
5xx): refusals are domain errors (``service/errors.py``) mapped to statuses in one place
(``http_errors.py``), or the API's own :class:`~service.api.http_errors.ApiError` (a token,
a content type); FastAPI's validation errors are flattened to one readable string;
anything else is a bug, logged with its traceback and answered 500.  The upload limit is
a pure ASGI middleware (``body_limit.py``).
"""
from __future__ import annotations

import contextlib
from typing import AsyncIterator

from fastapi import FastAPI

from ..settings import Settings
from ..systems import SivaService
from . import http_errors
from .body_limit import BodyLimitMiddleware
from .routes import ROUTERS
from .security import SecurityMiddleware, allowed_hosts


def create_app(settings: Settings | None = None) -> FastAPI:
    """Build the app; systems are loaded and workers started in the lifespan."""
    settings = settings or Settings.from_env()
    service = SivaService(settings)

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        service.start()
        try:
            yield
        finally:
            service.stop()

    app = FastAPI(title="siva", version="0.1.0", lifespan=lifespan, docs_url=None,
                  description="Streaming structural system identification (SIVA). "
                              "See docs/service.md.")
    app.state.service = service
    app.state.settings = settings

    for router in ROUTERS:
        app.include_router(router)
    from . import dashboard, metrics

    dashboard.install(app)  # GET /, /docs (offline Swagger UI), /static, latest-record

    http_errors.install(app)  # every refusal -> {"detail"} with its status (one place)

    app.add_middleware(BodyLimitMiddleware, limit=settings.max_upload_bytes)
    app.add_middleware(SecurityMiddleware,  # Host allow-list, cross-site writes, headers
                       hosts=allowed_hosts(_csv(settings.allowed_hosts), settings.bind_host),
                       origins=_csv(settings.allowed_origins))
    metrics.install(app, service)  # GET /metrics; its middleware outermost (counts 413s too)
    return app


def _csv(text: str) -> list[str]:
    return [x.strip() for x in (text or "").split(",") if x.strip()]


__all__ = ["create_app", "SivaService", "BodyLimitMiddleware"]
