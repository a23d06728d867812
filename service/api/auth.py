"""Who may call: the bearer token for writes (and reads with SIVA_API_TOKEN_READS=1), and no
cross-site browser request for a write hidden in a GET.  Used as route dependencies."""
from __future__ import annotations

import hmac

from fastapi import Request

from .http_errors import ApiError
from .security import cross_site


def require_token(request: Request) -> None:
    """Writes need ``Authorization: Bearer <SIVA_API_TOKEN>`` when the token is set."""
    _check_token(request, "writes")


def require_write_rights(request: Request, what: str) -> None:
    """A write hidden in a GET (starting a diagnosis): the token when one is set, and no
    cross-site browser request (the middleware checks only unsafe methods)."""
    _check_token(request, "writes")
    origins = [o for o in request.app.state.settings.allowed_origins.split(",") if o.strip()]
    why = cross_site({k.lower(): v for k, v in request.headers.items()}, origins)
    if why:
        raise ApiError(403, f"{what} is a write: cross-site request refused ({why})")


def require_read_token(request: Request) -> None:
    """Reads need the token too when ``SIVA_API_TOKEN_READS=1`` (the data is not public)."""
    if request.app.state.settings.token_for_reads:
        _check_token(request, "reads")


def _check_token(request: Request, what_needs: str) -> None:
    token = request.app.state.settings.api_token
    if not token:
        return
    auth = request.headers.get("authorization", "")
    scheme, _, given = auth.partition(" ")
    if scheme.lower() != "bearer" or not hmac.compare_digest(given.strip().encode(), token.encode()):
        what = "missing" if not auth else "wrong or malformed"
        raise ApiError(401, f"Authorization header {what}: {what_needs} need "
                            "'Authorization: Bearer <SIVA_API_TOKEN>'",
                       headers={"WWW-Authenticate": "Bearer"})
