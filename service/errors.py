"""The service's refusals, as domain errors: what went wrong, never which HTTP status.

Every layer (storage, trainer, fleet, the systems registry) raises these; the API maps
each class to a status in one place (``api/http_errors.py``), so a refusal reads the same
whether it came from the store, a Ray actor or a route.  ``detail`` names what is wrong and
where (it is the body's ``detail``).
"""
from __future__ import annotations


class ServiceError(Exception):
    """Base of the refusals; ``detail`` is the sentence the client reads."""

    def __init__(self, detail: str) -> None:
        super().__init__(detail)
        self.detail = detail


class Unreadable(ServiceError):
    """The input cannot be read at all (malformed JSON/TOML/multipart, empty body)."""


class NotFound(ServiceError):
    """No such system or recording."""


class Conflict(ServiceError):
    """The request contradicts what is stored (another spec, a role, a stored spec)."""


class TooLarge(ServiceError):
    """The input is above a documented size limit."""


class Invalid(ServiceError):
    """The input is readable but wrong; the detail names the field or setting."""


class Unavailable(ServiceError):
    """Not now (a trainer actor restarting, no room for an upload): retry later."""

    def __init__(self, detail: str, retry_after_s: float | None = None) -> None:
        super().__init__(detail)
        self.retry_after_s = retry_after_s


class StorageRefused(ServiceError):
    """The data directory is full or read-only: nothing was changed."""


# --------------------------------------------------------------------------- the store
class StoreError(ServiceError):
    """Base of the store's refusals."""


class UnknownSystem(StoreError, NotFound):
    pass


class SpecConflict(StoreError, Conflict):
    pass


class DuplicateConflict(StoreError, Conflict):
    pass


class UnknownRecording(StoreError, NotFound):
    pass
