"""The request-body limit as a pure ASGI middleware: a too-large Content-Length is refused
before the body is read, and streamed bytes are counted as the app reads them."""
from __future__ import annotations

import json

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from .http_errors import UploadTooLarge


class BodyLimitMiddleware:
    """413 for request bodies above ``limit`` bytes, without reading them whole.

    A declared Content-Length above the limit is refused before the app runs; otherwise
    the bytes are counted as the app reads them and the read fails with UploadTooLarge
    (answered 413) as soon as the count passes the limit.
    """

    def __init__(self, app: ASGIApp, limit: int) -> None:
        self.app = app
        self.limit = limit

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        for key, value in scope.get("headers", []):
            if key == b"content-length":
                try:
                    declared = int(value)
                except ValueError:
                    await _send_json(send, 400, "Content-Length header is not a number")
                    return
                if declared > self.limit:
                    await _send_json(send, 413, _too_large(self.limit, f"{declared} bytes declared"))
                    return
        seen = 0
        started = False

        async def counting_receive() -> Message:
            nonlocal seen
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > self.limit:
                    raise UploadTooLarge(_too_large(self.limit, f"more than {self.limit} bytes sent"))
            return message

        async def tracking_send(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, counting_receive, tracking_send)
        except UploadTooLarge as exc:  # raised where the app did not handle it itself
            if not started:
                await _send_json(send, 413, str(exc))



def _too_large(limit: int, what: str) -> str:
    return f"request body too large: {what}, the limit is {limit} bytes (SIVA_MAX_UPLOAD_BYTES)"


async def _send_json(send: Send, status: int, detail: str) -> None:
    body = json.dumps({"detail": detail}).encode()
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"application/json"),
                            (b"content-length", str(len(body)).encode()),
                            (b"connection", b"close")]})
    await send({"type": "http.response.body", "body": body})
