"""Exceptions the routes raise and the app answers: in their own module so that
``routes`` and ``app`` do not import each other."""
from __future__ import annotations


class ApiError(Exception):
    """A refusal with an HTTP status and a detail naming what is wrong and where."""

    def __init__(self, status: int, detail: str, headers: dict[str, str] | None = None) -> None:
        super().__init__(detail)
        self.status = status
        self.detail = detail
        self.headers = headers


class UploadTooLarge(Exception):
    pass


# --------------------------------------------------------------------------- the store
class StoreError(Exception):
    """Base of the store's refusals (api/http_errors.py maps them to 4xx)."""


class UnknownSystem(StoreError):
    pass


class SpecConflict(StoreError):
    pass


class DuplicateConflict(StoreError):
    pass


class UnknownRecording(StoreError):
    pass
