"""Uploads in flight, bounded in number and in declared bytes (memory follows the bytes)."""
from __future__ import annotations

import asyncio
import contextlib
from typing import AsyncIterator

from fastapi import Request

from ..errors import Unavailable


class UploadSlots:
    """Uploads in flight, bounded in number *and* in declared body bytes: many small
    uploads run side by side, large ones take turns (memory follows the bytes)."""

    def __init__(self, count: int, budget: int) -> None:
        self.count, self.budget = count, budget
        self.used, self.used_bytes = 0, 0
        self.cond = asyncio.Condition()

    def _fits(self, nbytes: int) -> bool:
        return self.used < self.count and (self.used == 0 or
                                           self.used_bytes + nbytes <= self.budget)

    async def acquire(self, nbytes: int, timeout: float) -> None:
        async with self.cond:
            if not self._fits(nbytes):
                if timeout <= 0:
                    raise asyncio.TimeoutError
                await asyncio.wait_for(self.cond.wait_for(lambda: self._fits(nbytes)),
                                       timeout)
            self.used += 1
            self.used_bytes += nbytes

    async def release(self, nbytes: int) -> None:
        async with self.cond:
            self.used -= 1
            self.used_bytes -= nbytes
            self.cond.notify_all()


@contextlib.asynccontextmanager
async def upload_slot(request: Request) -> AsyncIterator[None]:
    """At most SIVA_MAX_CONCURRENT_UPLOADS recordings, declaring at most
    SIVA_UPLOAD_BYTES_IN_FLIGHT body bytes together (a body without Content-Length counts
    as SIVA_MAX_UPLOAD_BYTES), are read and parsed at once, so memory and CPU stay bounded
    whatever the number of clients; a request waits up to SIVA_UPLOAD_QUEUE_S for room,
    then gets 503 with Retry-After.  The body stays in the socket while it waits."""
    settings = request.app.state.settings
    slots = getattr(request.app.state, "upload_slots", None)
    if slots is None:
        slots = request.app.state.upload_slots = UploadSlots(
            settings.max_concurrent_uploads, settings.upload_bytes_in_flight)
    try:
        declared = int(request.headers.get("content-length", ""))
    except ValueError:
        declared = settings.max_upload_bytes
    nbytes = max(0, min(declared, settings.max_upload_bytes))
    try:
        await slots.acquire(nbytes, settings.upload_queue_s)
    except asyncio.TimeoutError:
        raise Unavailable(f"too many uploads in flight ({slots.used}, "
                          f"{slots.used_bytes / 2**20:.0f} MiB declared) and no room within "
                          f"{settings.upload_queue_s:g} s; retry later "
                          "(SIVA_MAX_CONCURRENT_UPLOADS, SIVA_UPLOAD_BYTES_IN_FLIGHT, "
                          "SIVA_UPLOAD_QUEUE_S)", retry_after_s=5) from None
    try:
        yield
    finally:
        await slots.release(nbytes)
